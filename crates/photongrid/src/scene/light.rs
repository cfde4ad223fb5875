//! The closed set of lights: point, spot, sun, and emissive triangles. Each emits photons and
//! gives direct illumination for shadow rays.

use super::units;
use crate::sampling::{self, Distribution, Rng, Sampler};
use crate::Rgb;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// One emitting triangle (world space), self-contained so lights need not know the mesh.
#[derive(Clone, Debug)]
pub struct EmitterTriangle {
    /// First vertex.
    pub p0: Vec3,
    /// p1 − p0.
    pub e1: Vec3,
    /// p2 − p0.
    pub e2: Vec3,
    /// Unit geometric normal (front face).
    pub normal: Vec3,
    /// Area in m².
    pub area: f32,
    /// Emitted radiance.
    pub radiance: Rgb,
    /// Emits from both faces.
    pub double_sided: bool,
    /// Index of the triangle in the scene mesh (so a hit on it can be recognised).
    pub triangle: u32,
}

impl EmitterTriangle {
    fn sides(&self) -> f32 {
        if self.double_sided {
            2.0
        } else {
            1.0
        }
    }

    /// Flux leaving the triangle, all faces.
    pub fn power(&self) -> Rgb {
        self.radiance * units::lambert_emitter_flux(1.0, self.area) * self.sides()
    }

    /// The point of the triangle for the uniform pair `u` (uniform by area).
    pub(crate) fn point(&self, u: Vec2) -> Vec3 {
        let (b1, b2) = sampling::uniform_triangle(u);
        self.p0 + self.e1 * b1 + self.e2 * b2
    }

    /// `p` (a point of the triangle) moved off it to the side `dir` leaves by, so that a photon
    /// leaving there does not hit its own emitter ([`crate::surface::offset_eps`] of the
    /// triangle's coordinates).
    pub fn leave(&self, p: Vec3, dir: Vec3) -> Vec3 {
        let m = [self.p0, self.p0 + self.e1, self.p0 + self.e2]
            .iter()
            .fold(p.abs().max_element(), |m, v| m.max(v.abs().max_element()));
        let side = if dir.dot(self.normal) >= 0.0 { 1.0 } else { -1.0 };
        p + self.normal * (side * crate::surface::offset_eps(m, 0.0))
    }
}

/// A light source in world space, in radiometric units (see [`units`]).
#[derive(Clone, Debug)]
pub enum Light {
    /// Isotropic point light.
    Point {
        /// Name from the file.
        name: String,
        /// Position.
        position: Vec3,
        /// Radiant intensity [W/sr] per channel.
        intensity: Rgb,
    },
    /// Spot light with Blender's smoothstep falloff.
    Spot {
        /// Name from the file.
        name: String,
        /// Position.
        position: Vec3,
        /// Unit axis the spot points along.
        direction: Vec3,
        /// Peak radiant intensity [W/sr].
        intensity: Rgb,
        /// Cosine of the outer cone angle.
        cos_outer: f32,
        /// Blender's blend, `1 − inner/outer`.
        blend: f32,
    },
    /// Sun: parallel light.
    Directional {
        /// Name from the file.
        name: String,
        /// Unit direction the light travels.
        direction: Vec3,
        /// Irradiance on a surface facing the light [W/m²].
        irradiance: Rgb,
        /// Centre of the scene's bounding sphere (photons are emitted over its cross-section).
        scene_center: Vec3,
        /// Radius of the scene's bounding sphere.
        scene_radius: f32,
    },
    /// All emissive triangles of the scene, sampled by power.
    Emissive {
        /// The triangles.
        triangles: Vec<EmitterTriangle>,
        /// Inclusive CDF of luminous power over `triangles`.
        cdf: Distribution,
        /// Scene triangle index → index into `triangles` (the light-sampling density of a
        /// direction that reached an emitter by other means, for multiple importance sampling).
        by_triangle: std::collections::HashMap<u32, usize>,
    },
}

/// Light arriving at a point from one light sample.
#[derive(Clone, Copy, Debug)]
pub struct Incident {
    /// Unit direction from the receiver towards the light.
    pub wi: Vec3,
    /// Distance to the light sample (∞ for the sun).
    pub distance: f32,
    /// Irradiance on a surface facing `wi` (multiply by the receiver's cosθ).
    pub irradiance: Rgb,
    /// Solid-angle density with which `wi` was sampled; 0 for a delta light.
    pub pdf: f32,
}

/// A photon leaving a light: origin, direction and the flux it stands for (per unit photon).
#[derive(Clone, Copy, Debug)]
pub struct Emission {
    /// Start point.
    pub origin: Vec3,
    /// Unit direction.
    pub direction: Vec3,
    /// Flux estimate: its expectation over samples is the light's total power.
    pub flux: Rgb,
}

/// Luminance-like scalar used to share photons between lights.
pub fn power_weight(p: Rgb) -> f32 {
    (p.x + p.y + p.z) / 3.0
}

/// The emitting triangle for the uniform `u`, chosen in proportion to its power, with the
/// probability of that choice: the one triangle choice of photon emission, shadow rays and
/// the caustic pass.
pub(crate) fn pick_emitter<'a>(
    triangles: &'a [EmitterTriangle],
    cdf: &Distribution,
    u: f32,
) -> (&'a EmitterTriangle, f32) {
    let t = &triangles[cdf.sample(u)];
    (t, cdf.pmf_of(power_weight(t.power())))
}

impl Light {
    /// Build the emissive-triangle light (None if there are no emitters).
    pub fn emissive(triangles: Vec<EmitterTriangle>) -> Option<Light> {
        if triangles.is_empty() {
            return None;
        }
        let cdf = Distribution::new(triangles.iter().map(|t| power_weight(t.power())));
        let by_triangle = triangles.iter().enumerate().map(|(i, t)| (t.triangle, i)).collect();
        Some(Light::Emissive {
            triangles,
            cdf,
            by_triangle,
        })
    }

    /// Short description for reports.
    pub fn describe(&self) -> String {
        match self {
            Light::Point { name, intensity, .. } => {
                format!(
                    "point '{name}': {:.4} W/sr ({:.3} W)",
                    intensity.max_element(),
                    self.power().max_element()
                )
            }
            Light::Spot {
                name,
                intensity,
                cos_outer,
                blend,
                ..
            } => format!(
                "spot '{name}': {:.4} W/sr, outer {:.2}°, blend {:.3}, flux {:.3} W",
                intensity.max_element(),
                cos_outer.acos().to_degrees(),
                blend,
                self.power().max_element()
            ),
            Light::Directional { name, irradiance, .. } => {
                format!("sun '{name}': {:.4} W/m²", irradiance.max_element())
            }
            Light::Emissive { triangles, .. } => {
                format!(
                    "{} emissive triangles, {:.3} W",
                    triangles.len(),
                    power_weight(self.power())
                )
            }
        }
    }

    /// Total emitted flux [W] per channel (sun: through the scene's bounding-sphere disc).
    pub fn power(&self) -> Rgb {
        match self {
            Light::Point { intensity, .. } => *intensity * units::point_flux(1.0),
            Light::Spot {
                intensity,
                cos_outer,
                blend,
                ..
            } => *intensity * units::spot_flux(1.0, *cos_outer, *blend),
            Light::Directional {
                irradiance,
                scene_radius,
                ..
            } => *irradiance * (PI * scene_radius * scene_radius),
            Light::Emissive { triangles, .. } => triangles.iter().map(|t| t.power()).sum(),
        }
    }

    /// True for lights with no area (one shadow ray is exact).
    pub fn is_delta(&self) -> bool {
        !matches!(self, Light::Emissive { .. })
    }

    /// Sample a photon leaving the light.
    pub fn emit(&self, rng: &mut impl Sampler) -> Emission {
        match self {
            Light::Point { position, .. } => Emission {
                origin: *position,
                direction: sampling::uniform_sphere(rng.uniform2()),
                flux: self.power(),
            },
            Light::Spot {
                position,
                direction,
                cos_outer,
                blend,
                ..
            } => {
                // Rejection sampling of the smoothstep profile keeps every photon's flux equal.
                let mut d = *direction;
                for _ in 0..64 {
                    d = sampling::uniform_cone(rng.uniform2(), *cos_outer, *direction);
                    if rng.uniform() < units::spot_mask(d.dot(*direction), *cos_outer, *blend) {
                        break;
                    }
                }
                Emission {
                    origin: *position,
                    direction: d,
                    flux: self.power(),
                }
            }
            Light::Directional {
                direction,
                scene_center,
                scene_radius,
                ..
            } => {
                let disk = sampling::concentric_disk(rng.uniform2()) * *scene_radius;
                let (t, b) = sampling::basis(*direction);
                let origin = *scene_center - *direction * (*scene_radius * 1.01) + t * disk.x + b * disk.y;
                Emission {
                    origin,
                    direction: *direction,
                    flux: self.power(),
                }
            }
            Light::Emissive { triangles, cdf, .. } => {
                let (t, pdf) = pick_emitter(triangles, cdf, rng.uniform());
                let mut n = t.normal;
                if t.double_sided && rng.uniform() < 0.5 {
                    n = -n;
                }
                let origin = t.point(rng.uniform2());
                let direction = sampling::cosine_hemisphere(rng.uniform2(), n);
                Emission {
                    origin: t.leave(origin, direction),
                    direction,
                    flux: t.power() / pdf.max(1e-30),
                }
            }
        }
    }

    /// Radiant intensity of a point or spot light in the unit direction `d` leaving it: the
    /// one place the spot's cone applies. None outside the cone, and for lights with area or
    /// at infinity.
    pub(crate) fn intensity_towards(&self, d: Vec3) -> Option<Rgb> {
        match self {
            Light::Point { intensity, .. } => Some(*intensity),
            Light::Spot {
                direction,
                intensity,
                cos_outer,
                blend,
                ..
            } => {
                let mask = units::spot_mask(d.dot(*direction), *cos_outer, *blend);
                (mask > 0.0).then(|| *intensity * mask)
            }
            Light::Directional { .. } | Light::Emissive { .. } => None,
        }
    }

    /// Sample the light as seen from `x` (for a shadow ray).
    pub fn incident(&self, x: Vec3, rng: &mut Rng) -> Option<Incident> {
        match self {
            Light::Point { position, .. } | Light::Spot { position, .. } => {
                let d = *position - x;
                let dist2 = d.length_squared();
                if !(dist2 > 0.0) {
                    return None;
                }
                let wi = d / dist2.sqrt();
                let intensity = self.intensity_towards(-wi)?;
                Some(Incident {
                    wi,
                    distance: dist2.sqrt(),
                    irradiance: intensity / dist2,
                    pdf: 0.0,
                })
            }
            Light::Directional {
                direction, irradiance, ..
            } => Some(Incident {
                wi: -*direction,
                distance: f32::INFINITY,
                irradiance: *irradiance,
                pdf: 0.0,
            }),
            Light::Emissive { triangles, cdf, .. } => {
                let (t, pdf_tri) = pick_emitter(triangles, cdf, rng.uniform());
                let p = t.point(rng.uniform2());
                let d = p - x;
                let dist2 = d.length_squared();
                if dist2 <= 0.0 {
                    return None;
                }
                let wi = d / dist2.sqrt();
                let cos_l = t.normal.dot(-wi);
                if cos_l <= 0.0 && !t.double_sided {
                    return None;
                }
                // Area sampling: E = L cosθₗ A / (d² · p(tri)) = L / p(ω).
                let irradiance = t.radiance * (cos_l.abs() * t.area / (dist2 * pdf_tri.max(1e-30)));
                Some(Incident {
                    wi,
                    distance: dist2.sqrt(),
                    irradiance,
                    pdf: emitter_pdf(pdf_tri, t.area, dist2, cos_l),
                })
            }
        }
    }
}

/// Solid-angle density of sampling a point on an emitting triangle (chosen with probability
/// `p_tri`, area `area`) seen at squared distance `dist2` under the emitter cosine `cos_l`.
fn emitter_pdf(p_tri: f32, area: f32, dist2: f32, cos_l: f32) -> f32 {
    p_tri.max(1e-30) * dist2 / (cos_l.abs() * area).max(1e-30)
}

impl Light {
    /// The density with which [`Light::incident`] would have sampled the point of scene triangle
    /// `triangle` that a ray from the receiver reached at distance `distance`, meeting the
    /// emitter's normal under `cos_l`; 0 if the light cannot sample it (delta lights, other
    /// triangles).
    pub fn pdf_hit(&self, triangle: u32, distance: f32, cos_l: f32) -> f32 {
        let Light::Emissive {
            triangles,
            cdf,
            by_triangle,
        } = self
        else {
            return 0.0;
        };
        let Some(&i) = by_triangle.get(&triangle) else {
            return 0.0;
        };
        let t = &triangles[i];
        if cos_l <= 0.0 && !t.double_sided {
            return 0.0;
        }
        emitter_pdf(cdf.pmf_of(power_weight(t.power())), t.area, distance * distance, cos_l)
    }
}

/// Chooses a light in proportion to its power ([`power_weight`]): the one light choice of the
/// photon pass and the caustic pass.
#[derive(Clone, Debug, Default)]
pub struct LightSampler {
    weights: Vec<f32>,
    distribution: Distribution,
}

impl LightSampler {
    /// A sampler over `lights`.
    pub fn new(lights: &[Light]) -> Self {
        let weights: Vec<f32> = lights.iter().map(|l| power_weight(l.power())).collect();
        LightSampler {
            distribution: Distribution::new(weights.iter().copied()),
            weights,
        }
    }

    /// A light index for the uniform `u`, with its probability.
    pub fn sample(&self, u: f32) -> (usize, f32) {
        let l = self.distribution.sample(u);
        (l, self.distribution.pmf_of(self.weights[l]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spot_emission_respects_cone_and_profile() {
        let l = Light::Spot {
            name: "s".into(),
            position: Vec3::ZERO,
            direction: Vec3::NEG_Y,
            intensity: Rgb::ONE,
            cos_outer: (30f32).to_radians().cos(),
            blend: 0.5,
        };
        let mut rng = Rng::keyed(3, 0, 0);
        let n = 200_000;
        // Fraction of photons inside the inner, full-intensity cone must match ∫mask there.
        let cos_outer = (30f32).to_radians().cos();
        let cos_inner_full = cos_outer + (1.0 - cos_outer) * 0.5; // mask = 1 above this cosine
        let mut inner = 0;
        for _ in 0..n {
            let e = l.emit(&mut rng);
            let c = e.direction.dot(Vec3::NEG_Y);
            assert!(c >= cos_outer - 1e-5);
            if c >= cos_inner_full {
                inner += 1;
            }
        }
        let expected = (1.0 - cos_inner_full) / ((1.0 - cos_outer) * (1.0 - 0.25));
        let got = inner as f32 / n as f32;
        assert!((got - expected).abs() < 0.005, "{got} vs {expected}");
    }

    #[test]
    fn stratified_emission_spreads_photons_evenly() {
        // A point light's photons counted in 16 × 16 cells of equal solid angle (cosθ, φ): from
        // scrambled Sobol points each cell holds its share exactly; from independent draws the
        // counts scatter as Poisson's (variance ≈ mean).
        let l = Light::Point {
            name: "p".into(),
            position: Vec3::ZERO,
            intensity: Rgb::ONE,
        };
        let n = 1u32 << 14;
        let cell = |d: Vec3| {
            let (z, phi) = (d.z, d.y.atan2(d.x).rem_euclid(2.0 * PI));
            let row = (((1.0 - z) / 2.0 * 16.0) as usize).min(15);
            let col = ((phi / (2.0 * PI) * 16.0) as usize).min(15);
            row * 16 + col
        };
        let variance_over_mean = |counts: &[u32]| {
            let mean = n as f64 / 256.0;
            let var = counts.iter().map(|&c| (c as f64 - mean).powi(2)).sum::<f64>() / 256.0;
            var / mean
        };
        let scrambles = sampling::Scrambles::new(5, sampling::stream::PHOTONS);
        let mut walk = sampling::SobolWalk::starting_at(0);
        let (mut even, mut random) = (vec![0u32; 256], vec![0u32; 256]);
        for i in 0..n {
            let mut rng = Rng::keyed(5, 1, i as u64);
            random[cell(l.emit(&mut rng).direction)] += 1;
            let mut s = sampling::Stratified::new(walk.next_point(), &scrambles, &mut rng);
            even[cell(l.emit(&mut s).direction)] += 1;
        }
        assert!(variance_over_mean(&even) < 0.05, "{}", variance_over_mean(&even));
        assert!(variance_over_mean(&random) > 0.6, "{}", variance_over_mean(&random));
    }

    #[test]
    fn emissive_direct_matches_flux() {
        // A 1×1 m one-sided emitter of radiance 1, facing −Y at y = 1: irradiance at the centre
        // below it at distance 1 is ∫ L cos² / d² dA; check the estimator against a fine quadrature.
        let tri = |p0: Vec3, p1: Vec3, p2: Vec3, k| {
            let e1 = p1 - p0;
            let e2 = p2 - p0;
            let c = e1.cross(e2);
            EmitterTriangle {
                p0,
                e1,
                e2,
                normal: c.normalize(),
                area: 0.5 * c.length(),
                radiance: Rgb::ONE,
                double_sided: false,
                triangle: k,
            }
        };
        let a = Vec3::new(-0.5, 1.0, -0.5);
        let b = Vec3::new(0.5, 1.0, -0.5);
        let c = Vec3::new(0.5, 1.0, 0.5);
        let d = Vec3::new(-0.5, 1.0, 0.5);
        let l = Light::emissive(vec![tri(a, b, c, 0), tri(a, c, d, 1)]).unwrap();
        assert!((l.power().x - PI).abs() < 1e-5);
        let mut rng = Rng::keyed(1, 1, 1);
        let n = 400_000;
        let mut e = 0.0f64;
        for _ in 0..n {
            if let Some(i) = l.incident(Vec3::ZERO, &mut rng) {
                e += (i.irradiance.x * i.wi.y.max(0.0)) as f64;
            }
        }
        e /= n as f64;
        let m = 400;
        let mut q = 0.0f64;
        for i in 0..m {
            for j in 0..m {
                let x = -0.5 + (i as f64 + 0.5) / m as f64;
                let z = -0.5 + (j as f64 + 0.5) / m as f64;
                let r2 = x * x + 1.0 + z * z;
                q += 1.0 / (r2 * r2) / (m * m) as f64;
            }
        }
        assert!((e / q - 1.0).abs() < 0.01, "{e} vs {q}");
    }
}
