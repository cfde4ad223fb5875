//! Photons aimed at mirrors and glass (Jensen's projection maps, as cones and discs): every
//! caustic path starts by hitting a specular object, so emitting only towards the bounding
//! spheres of those objects renders caustics with far more photons for the same work.
//!
//! Several cones (or sun discs) may overlap; a photon's flux divides by the density of the
//! whole mixture at its direction (one-sample balance heuristic), which keeps it unbiased.

use crate::sampling::{self, Distribution, Sampler};
use crate::scene::light::{pick_emitter, Emission};
use crate::scene::{Light, Scene};
use glam::Vec3;
use std::collections::HashMap;
use std::f32::consts::PI;

/// A bounding sphere of one connected specular object.
#[derive(Clone, Copy, Debug)]
pub struct Target {
    /// Centre.
    pub center: Vec3,
    /// Radius.
    pub radius: f32,
}

/// The specular objects of a scene.
#[derive(Clone, Debug, Default)]
pub struct SpecularTargets {
    /// One sphere per connected group of mirror/glass triangles.
    pub targets: Vec<Target>,
}

impl SpecularTargets {
    /// Group the specular triangles into connected objects (shared vertex positions) and
    /// bound each by a sphere.
    pub fn find(scene: &Scene) -> Self {
        let spec: Vec<usize> = (0..scene.triangles.len())
            .filter(|&i| scene.materials[scene.triangles[i].material as usize].is_specular())
            .collect();
        if spec.is_empty() {
            return SpecularTargets::default();
        }
        let q = scene.bounds.diagonal().max(1e-6) * 1e-5;
        let key = |p: Vec3| (p / q).round().as_ivec3().to_array();
        let mut parent: Vec<usize> = (0..spec.len()).collect();
        fn root(p: &mut [usize], mut i: usize) -> usize {
            while p[i] != i {
                p[i] = p[p[i]];
                i = p[i];
            }
            i
        }
        let mut first: HashMap<[i32; 3], usize> = HashMap::new();
        for (k, &t) in spec.iter().enumerate() {
            for p in scene.triangles[t].p {
                let e = *first.entry(key(p)).or_insert(k);
                let (a, b) = (root(&mut parent, e), root(&mut parent, k));
                if a != b {
                    parent[a] = b;
                }
            }
        }
        let mut groups: HashMap<usize, (Vec3, Vec3, Vec<Vec3>)> = HashMap::new();
        for (k, &t) in spec.iter().enumerate() {
            let r = root(&mut parent, k);
            let g = groups
                .entry(r)
                .or_insert((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY), Vec::new()));
            for p in scene.triangles[t].p {
                g.0 = g.0.min(p);
                g.1 = g.1.max(p);
                g.2.push(p);
            }
        }
        let mut targets: Vec<Target> = groups
            .into_values()
            .map(|(lo, hi, pts)| {
                let center = 0.5 * (lo + hi);
                let radius = pts.iter().map(|p| (*p - center).length()).fold(0.0, f32::max) * 1.001 + q;
                Target { center, radius }
            })
            .collect();
        targets.sort_by(|a, b| {
            a.center
                .to_array()
                .partial_cmp(&b.center.to_array())
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        SpecularTargets { targets }
    }

    /// True if the scene has nothing specular (no caustic pass needed).
    pub fn is_empty(&self) -> bool {
        self.targets.is_empty()
    }

    /// How `light`'s caustic photons are aimed at the targets ([`Aim`]).
    pub fn aim(&self, light: &Light) -> Aim {
        match light {
            Light::Point { position, .. } | Light::Spot { position, .. } => Aim::Cones(self.cones_from(*position)),
            Light::Directional {
                direction,
                scene_center,
                ..
            } => {
                let (t, b) = sampling::basis(*direction);
                let discs: Vec<(glam::Vec2, f32)> = self
                    .targets
                    .iter()
                    .map(|s| {
                        let c = s.center - *scene_center;
                        (glam::Vec2::new(c.dot(t), c.dot(b)), s.radius)
                    })
                    .collect();
                // Discs are chosen in proportion to their area.
                let choice = Distribution::new(discs.iter().map(|d| d.1 * d.1));
                Aim::Discs { t, b, discs, choice }
            }
            Light::Emissive { .. } => Aim::FromEachPoint,
        }
    }

    /// Sample a photon from `light` towards the targets, aimed as `aim` (`self.aim(light)`)
    /// says. Its `flux` has the light's power restricted to the targets as expectation.
    pub fn emit(&self, light: &Light, aim: &Aim, rng: &mut impl Sampler) -> Option<Emission> {
        match (light, aim) {
            (Light::Point { position, .. } | Light::Spot { position, .. }, Aim::Cones(cones)) => {
                let (d, pdf) = cones.sample(rng)?;
                let intensity = light.intensity_towards(d)?;
                Some(Emission {
                    origin: *position,
                    direction: d,
                    flux: intensity / pdf,
                })
            }
            (
                Light::Directional {
                    direction,
                    irradiance,
                    scene_center,
                    scene_radius,
                    ..
                },
                Aim::Discs { t, b, discs, choice },
            ) => {
                let j = choice.sample(rng.uniform());
                let x = discs[j].0 + sampling::concentric_disk(rng.uniform2()) * discs[j].1;
                // Mixture density over the union of discs (per m²); disc `j` counts even where
                // rounding puts `x` a hair outside it.
                let pdf: f32 = discs
                    .iter()
                    .enumerate()
                    .filter(|&(k, d)| k == j || (x - d.0).length_squared() <= d.1 * d.1)
                    .map(|(_, d)| choice.pmf_of(d.1 * d.1) / (PI * d.1 * d.1))
                    .sum();
                let origin = *scene_center - *direction * (*scene_radius * 1.01) + *t * x.x + *b * x.y;
                Some(Emission {
                    origin,
                    direction: *direction,
                    flux: *irradiance / pdf.max(f32::MIN_POSITIVE),
                })
            }
            (Light::Emissive { triangles, cdf, .. }, _) => {
                let (tri, p_tri) = pick_emitter(triangles, cdf, rng.uniform());
                let origin = tri.point(rng.uniform2());
                let (d, pdf) = self.cones_from(origin).sample(rng)?;
                let cos = tri.normal.dot(d);
                if cos <= 0.0 && !tri.double_sided {
                    return None;
                }
                // Radiance × |cosθ| / (p(tri) · p(point) · p(direction)).
                let flux = tri.radiance * (cos.abs() * tri.area / (p_tri.max(1e-30) * pdf));
                Some(Emission {
                    origin: tri.leave(origin, d),
                    direction: d,
                    flux,
                })
            }
            // An aim made for another kind of light: nothing is aimed.
            _ => None,
        }
    }

    /// The targets' cones seen from `o`.
    fn cones_from(&self, o: Vec3) -> Cones {
        let cones: Vec<(Vec3, f32)> = self
            .targets
            .iter()
            .map(|s| {
                let v = s.center - o;
                let d = v.length();
                if d <= s.radius {
                    (Vec3::Z, -1.0) // inside: the whole sphere of directions
                } else {
                    (v / d, (1.0 - (s.radius / d).powi(2)).max(0.0).sqrt())
                }
            })
            .collect();
        // Cones are chosen in proportion to their solid angle.
        let choice = Distribution::new(cones.iter().map(|c| solid_angle(c.1)));
        Cones { cones, choice }
    }
}

/// How a light's caustic photons are aimed at the targets: made once per light
/// ([`SpecularTargets::aim`]) where it is the same for every photon, so emitting one builds
/// nothing.
#[derive(Clone, Debug)]
pub enum Aim {
    /// The cones from a point or spot light's position.
    Cones(Cones),
    /// The targets' discs across a sun's beam, in the basis (`t`, `b`) of its direction,
    /// chosen by area.
    Discs {
        /// First axis across the beam.
        t: Vec3,
        /// Second axis across the beam.
        b: Vec3,
        /// Centre (in `t`, `b`) and radius of each target's disc.
        discs: Vec<(glam::Vec2, f32)>,
        /// Chooses a disc in proportion to its area.
        choice: Distribution,
    },
    /// An emissive surface: the cones from each emitted point.
    FromEachPoint,
}

/// The targets' cones seen from one point: axis and cosine of the half-angle of each, chosen in
/// proportion to their solid angles.
#[derive(Clone, Debug)]
pub struct Cones {
    cones: Vec<(Vec3, f32)>,
    choice: Distribution,
}

/// Solid angle of a cone of half-angle cosine `cos_max`.
fn solid_angle(cos_max: f32) -> f32 {
    2.0 * PI * (1.0 - cos_max)
}

impl Cones {
    /// A direction uniform within one cone, the cone chosen in proportion to its solid angle,
    /// with the mixture's solid-angle density.
    fn sample(&self, rng: &mut impl Sampler) -> Option<(Vec3, f32)> {
        if !(self.choice.total() > 0.0) {
            return None;
        }
        let j = self.choice.sample(rng.uniform());
        let d = sampling::uniform_cone(rng.uniform2(), self.cones[j].1, self.cones[j].0);
        // Cone `j` counts even where rounding puts `d` a hair outside it (else the density
        // misses it and the flux is divided by 10⁻³⁰).
        let pdf: f32 = self
            .cones
            .iter()
            .enumerate()
            .filter(|&(k, c)| k == j || d.dot(c.0) >= c.1)
            .map(|(_, c)| self.choice.pmf_of(solid_angle(c.1)) / solid_angle(c.1))
            .sum();
        Some((d, pdf.max(1e-30)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;
    use crate::Rgb;

    #[test]
    fn cone_mixture_is_unbiased() {
        // Two overlapping targets: E[flux · 1(direction hits target A's cone)] must equal
        // I · Ω_A whatever the overlap.
        let t = SpecularTargets {
            targets: vec![
                Target {
                    center: Vec3::new(0.0, 0.0, -2.0),
                    radius: 0.5,
                },
                Target {
                    center: Vec3::new(0.3, 0.0, -2.0),
                    radius: 0.5,
                },
            ],
        };
        let l = Light::Point {
            name: "p".into(),
            position: Vec3::ZERO,
            intensity: Rgb::ONE,
        };
        let aim = t.aim(&l);
        let mut rng = Rng::keyed(1, 2, 3);
        let n = 400_000;
        let axis = Vec3::new(0.0, 0.0, -1.0);
        let cos_a = (1.0f32 - 0.25 / 4.0).sqrt();
        let mut sum = 0.0f64;
        for _ in 0..n {
            let e = t.emit(&l, &aim, &mut rng).unwrap();
            if e.direction.dot(axis) >= cos_a {
                sum += e.flux.x as f64;
            }
        }
        let expect = 2.0 * std::f64::consts::PI * (1.0 - cos_a as f64);
        assert!(
            (sum / n as f64 / expect - 1.0).abs() < 0.01,
            "{} vs {}",
            sum / n as f64,
            expect
        );
    }

    /// A direction or sun position drawn from one cone or disc belongs to it, even where
    /// rounding puts it a hair outside: its density never misses the part it was drawn from
    /// (it was 0 there, and the flux divided by 10⁻³⁰).
    #[test]
    fn every_photon_aimed_at_one_target_carries_the_same_flux() {
        let target = |x: f32, y: f32, z: f32| SpecularTargets {
            targets: vec![Target {
                center: Vec3::new(x, y, z),
                radius: 0.013,
            }],
        };
        let point = Light::Point {
            name: "p".into(),
            position: Vec3::new(0.1, 0.2, 0.3),
            intensity: Rgb::ONE,
        };
        let sun = Light::Directional {
            name: "s".into(),
            direction: Vec3::new(0.3, -0.9, 0.2).normalize(),
            irradiance: Rgb::ONE,
            scene_center: Vec3::ZERO,
            scene_radius: 10.0,
        };
        // The sun's disc far from the scene's centre, where its points round coarsely.
        for (light, t) in [(point, target(0.31, -7.7, 2.9)), (sun, target(31.0, -77.0, 29.0))] {
            let aim = t.aim(&light);
            let mut rng = Rng::keyed(4, 5, 6);
            let fluxes: Vec<f32> = (0..200_000)
                .filter_map(|_| t.emit(&light, &aim, &mut rng))
                .map(|e| e.flux.x)
                .collect();
            let (lo, hi) = fluxes
                .iter()
                .fold((f32::INFINITY, 0f32), |(lo, hi), &f| (lo.min(f), hi.max(f)));
            assert!(
                fluxes.len() == 200_000 && hi <= lo * 1.000_01,
                "{light:?}: {lo:e} to {hi:e}"
            );
        }
    }
}
