//! The camera pass: jittered camera rays, specular chains followed, and at diffuse points
//! direct light by shadow rays plus indirect light and caustics from the photon map.

use crate::accel::Accel;
use crate::bsdf;
use crate::estimate::{density_radiance, Gather, IrradianceCache, PhotonMap};
use crate::film::{Aov, Film};
use crate::grid::{blended_radius, progressive_neighbours, Assumed, Grids};
use crate::sampling::{self, stream, Rng};
use crate::scene::{Camera, Scene, Surface};
use crate::spatial::KnnBuffer;
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::{Vec2, Vec3};
use rayon::prelude::*;

pub mod progressive;
pub mod sppm;

/// Where direct illumination comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum DirectLighting {
    /// Shadow rays to every light; the photon map gives indirect light and caustics only.
    ShadowRays,
    /// The paper's single map: all light, direct included, from photons.
    Photons,
}

/// How the photon estimate chooses its radius.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Classic k nearest neighbours (Jensen): r = distance to the k-th photon.
    Knn,
    /// The paper's: assumed radius from the filtered plane grids, blended with r_k.
    Adaptive,
    /// Stochastic progressive photon mapping (Hachisuka & Jensen 2009): a radius per pixel
    /// that shrinks as passes add photons (see [`sppm`]).
    Sppm,
}

/// Settings of the camera pass.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RenderSettings {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera rays per pixel.
    pub spp: u32,
    /// Photons per estimate (k).
    pub neighbours: usize,
    /// Direct light by shadow rays or photons.
    pub direct: DirectLighting,
    /// Shadow rays per emissive-light evaluation (delta lights always take one).
    pub light_samples: u32,
    /// Longest chain of mirror/glass bounces followed from the camera.
    pub max_specular_depth: u32,
    /// Up to this depth both glass branches are followed; deeper, one is chosen by Fresnel.
    pub split_depth: u32,
    /// Random seed (of this pass: [`crate::sampling::pass_seed`]).
    pub seed: u64,
    /// Progressive pass (0-based); the adaptive radius shrinks with it
    /// ([`progressive_neighbours`]).
    pub pass: u32,
    /// Radius choice.
    pub method: Method,
    /// Blend factor α of `r = r_a + α (r_k − r_a)`.
    pub alpha: f32,
    /// Filtered count per cell below which r_k is used.
    pub shadow_count: f32,
    /// Final-gather rays per camera sample (0: none).
    pub gather: u32,
}

/// Per-thread state of the camera pass.
struct Tracer<'a> {
    scene: &'a Scene,
    accel: &'a Accel,
    map: &'a PhotonMap,
    grids: Option<&'a Grids>,
    irradiance: Option<&'a IrradianceCache>,
    settings: &'a RenderSettings,
    knn: KnnBuffer,
}

/// What the camera pass reads from the photon pass: the photons shown directly, the grids of
/// the adaptive radius, and precomputed irradiance for final gathering.
#[derive(Clone, Copy)]
pub struct PhotonData<'a> {
    /// The photons estimated at visible points.
    pub map: &'a PhotonMap,
    /// Plane and voxel grids (adaptive method).
    pub grids: Option<&'a Grids>,
    /// Irradiance points (final gathering).
    pub irradiance: Option<&'a IrradianceCache>,
}

/// Render `camera` into a film. `progress(rows)` is called as rows finish.
pub fn render(
    scene: &Scene,
    accel: &Accel,
    photons: PhotonData<'_>,
    camera: &Camera,
    settings: &RenderSettings,
    progress: &(dyn Fn(usize) + Sync),
) -> Film {
    let PhotonData { map, grids, irradiance } = photons;
    let (w, h) = (settings.width, settings.height);
    let mut film = Film::new(w, h);
    let spp = settings.spp.max(1);
    film.color
        .par_chunks_mut(w as usize)
        .zip(film.aov.par_chunks_mut(w as usize))
        .enumerate()
        .for_each_init(
            || Tracer {
                scene,
                accel,
                map,
                grids,
                irradiance,
                settings,
                knn: KnnBuffer::default(),
            },
            |tracer, (y, (row, aovs))| {
                for x in 0..w as usize {
                    let pixel = (y * w as usize + x) as u64;
                    let mut sum = Rgb::ZERO;
                    let strata = pixel_strata(settings, pixel);
                    for s in 0..spp {
                        let (o, d, mut rng) = camera_ray(camera, settings, &strata, x, y, s);
                        let mut aov = (s == 0).then_some(&mut aovs[x]);
                        sum += tracer.radiance(o, d, 0, &mut rng, &mut aov);
                    }
                    row[x] = sum / spp as f32;
                }
                progress(1);
            },
        );
    film
}

/// The N-rooks strata of a pixel's `spp` samples.
fn pixel_strata(settings: &RenderSettings, pixel: u64) -> sampling::NRooks {
    sampling::n_rooks(
        settings.spp.max(1) as usize,
        &mut Rng::keyed(settings.seed, stream::PIXEL, pixel),
    )
}

/// The jittered ray of sample `s` of pixel (x, y), and the random stream the rest of its path
/// uses (keyed by pixel and sample: independent of threads).
fn camera_ray(
    camera: &Camera,
    settings: &RenderSettings,
    strata: &sampling::NRooks,
    x: usize,
    y: usize,
    s: u32,
) -> (Vec3, Vec3, Rng) {
    let (w, h) = (settings.width, settings.height);
    let spp = settings.spp.max(1) as u64;
    let pixel = (y * w as usize + x) as u64;
    let mut rng = Rng::keyed(settings.seed, stream::CAMERA, pixel * spp + s as u64);
    let film_pos = Vec2::new(x as f32, y as f32) + strata.jitter(s as usize, rng.uniform2());
    let (o, d) = camera.generate_ray(film_pos, w, h);
    (o, d, rng)
}

impl Tracer<'_> {
    fn radiance(&mut self, o: Vec3, d: Vec3, depth: u32, rng: &mut Rng, aov: &mut Option<&mut Aov>) -> Rgb {
        let Some(hit) = self.accel.intersect(o, d, f32::INFINITY) else {
            return Rgb::ZERO; // black world, as the reference scenes
        };
        let sp = SurfacePoint::new(self.scene, o, d, hit);
        let material = &self.scene.materials[sp.material as usize];
        if depth == 0 {
            if let Some(a) = aov.as_deref_mut() {
                a.normal = sp.facing_shading_normal;
                a.depth = hit.t;
            }
        }
        let mut l = Rgb::ZERO;
        if material.is_emissive() && (material.double_sided || !sp.backface) {
            l += material.emission;
        }
        match &material.surface {
            Surface::Lambert { .. } => l += self.diffuse(&sp, rng, aov),
            Surface::Mirror { f0 } => {
                if depth < self.settings.max_specular_depth {
                    let f = bsdf::fresnel_schlick(*f0, -d.dot(sp.facing_shading_normal));
                    let r = bsdf::reflect(d, sp.facing_shading_normal);
                    l += f * self.radiance(sp.offset(r), r, depth + 1, rng, aov);
                }
            }
            Surface::Dielectric { ior, tint, absorption } => {
                let mut weight = Rgb::ONE;
                if let (Some(sigma), true) = (absorption, sp.backface) {
                    weight = (-*sigma * hit.t).exp();
                }
                if depth < self.settings.max_specular_depth {
                    let (r, t) = bsdf::dielectric_branches(d, sp.geometric_normal, *ior, *tint);
                    let branch =
                        |tr: &mut Self, s: bsdf::SpecularSample, w: Rgb, rng: &mut Rng, aov: &mut Option<&mut Aov>| {
                            w * tr.radiance(sp.offset(s.direction), s.direction, depth + 1, rng, aov)
                        };
                    match t {
                        Some(t) if depth < self.settings.split_depth => {
                            l += weight * branch(self, t, t.weight, rng, aov);
                            l += weight * branch(self, r, r.weight, rng, &mut None);
                        }
                        Some(t) => {
                            let pr = r.weight.x;
                            if rng.uniform() < pr {
                                l += weight * branch(self, r, Rgb::ONE, rng, aov);
                            } else {
                                l += weight * branch(self, t, t.weight / (1.0 - pr), rng, aov);
                            }
                        }
                        None => l += weight * branch(self, r, r.weight, rng, aov),
                    }
                }
            }
        }
        l
    }

    /// Radiance leaving a Lambert surface towards the camera.
    fn diffuse(&mut self, sp: &SurfacePoint, rng: &mut Rng, aov: &mut Option<&mut Aov>) -> Rgb {
        let albedo = sp.albedo(self.scene);
        if albedo.max_element() <= 0.0 {
            return Rgb::ZERO;
        }
        let mut l = Rgb::ZERO;
        if self.settings.direct == DirectLighting::ShadowRays {
            l += bsdf::lambert(albedo) * self.direct_irradiance(sp, rng);
        }
        let g = self.gather(sp);
        l += density_radiance(albedo, g.flux, g.r2);
        if let (Some(cache), true) = (self.irradiance, self.settings.gather > 0) {
            l += albedo * self.final_gather(sp, cache, rng);
        }
        if let Some(a) = aov.take() {
            a.albedo = albedo;
            a.density = g.count as f32 / (std::f32::consts::PI * g.r2.max(1e-30));
            a.radius = g.r2.sqrt();
        }
        l
    }

    /// Mean radiance arriving over the hemisphere from other surfaces (cosine-weighted
    /// directions, so indirect radiance = albedo × this mean), read from precomputed irradiance
    /// at the first diffuse surface each gather ray reaches through mirrors and glass.
    fn final_gather(&mut self, sp: &SurfacePoint, cache: &IrradianceCache, rng: &mut Rng) -> Rgb {
        let n = self.settings.gather;
        let mut sum = Rgb::ZERO;
        for _ in 0..n {
            let d = sampling::cosine_hemisphere(rng.uniform2(), sp.facing_shading_normal);
            if d.dot(sp.facing_normal) <= 0.0 {
                continue;
            }
            sum += self.gather_ray(sp.offset(d), d, 0, cache, rng);
        }
        sum / n as f32
    }

    /// Radiance leaving the first diffuse surface along a gather ray, emission excluded (direct
    /// light is counted by shadow rays, light through glass by caustic photons).
    fn gather_ray(&mut self, o: Vec3, d: Vec3, depth: u32, cache: &IrradianceCache, rng: &mut Rng) -> Rgb {
        let Some(hit) = self.accel.intersect(o, d, f32::INFINITY) else {
            return Rgb::ZERO;
        };
        let sp = SurfacePoint::new(self.scene, o, d, hit);
        match &self.scene.materials[sp.material as usize].surface {
            Surface::Lambert { .. } => {
                let e = cache.lookup(sp.position, sp.facing_normal, &mut self.knn);
                bsdf::lambert(sp.albedo(self.scene)) * e
            }
            _ if depth >= 4 => Rgb::ZERO,
            Surface::Mirror { f0 } => {
                let f = bsdf::fresnel_schlick(*f0, -d.dot(sp.facing_shading_normal));
                let r = bsdf::reflect(d, sp.facing_shading_normal);
                f * self.gather_ray(sp.offset(r), r, depth + 1, cache, rng)
            }
            Surface::Dielectric { ior, tint, absorption } => {
                let mut w = Rgb::ONE;
                if let (Some(sigma), true) = (absorption, sp.backface) {
                    w = (-*sigma * hit.t).exp();
                }
                let (r, t) = bsdf::dielectric_branches(d, sp.geometric_normal, *ior, *tint);
                let s = match t {
                    Some(t) if rng.uniform() >= r.weight.x => bsdf::SpecularSample {
                        weight: t.weight / (1.0 - r.weight.x),
                        ..t
                    },
                    Some(_) => bsdf::SpecularSample { weight: Rgb::ONE, ..r },
                    None => r,
                };
                w * s.weight * self.gather_ray(sp.offset(s.direction), s.direction, depth + 1, cache, rng)
            }
        }
    }

    /// Photons around a diffuse point, with the radius the method chooses.
    ///
    /// Progressive passes: kNN keeps `k` in every pass's own map (the passes' images are
    /// averaged: noise falls, the bias of k neighbours among `photons` stays); the adaptive
    /// method's counts hold every pass's photons so far and its neighbours grow with the pass
    /// so that its radius shrinks ([`progressive_neighbours`]).
    fn gather(&mut self, sp: &SurfacePoint) -> Gather {
        let (n_all, k) = match self.settings.method {
            Method::Adaptive => progressive_neighbours(self.settings.neighbours, self.settings.pass),
            _ => (self.settings.neighbours, self.settings.neighbours),
        };
        let gk = self.map.knn(sp.position, sp.facing_normal, k, &mut self.knn);
        if self.settings.method != Method::Adaptive {
            return gk;
        }
        let Some(grids) = self.grids else { return gk };
        let r_a = match grids.assumed(
            sp.triangle,
            sp.position,
            sp.geometric_normal,
            n_all,
            self.settings.shadow_count,
        ) {
            Assumed::Radius(r) => r,
            // Shadows, dark corners, surfaces no grid covers: the real kNN radius.
            Assumed::Shadow | Assumed::Uncovered => return gk,
        };
        if gk.count < k {
            return gk; // fewer than k photons within the largest radius: nothing to blend with
        }
        let r_k = gk.r2.sqrt();
        let r = blended_radius(r_a, r_k, self.settings.alpha).min(self.map.max_radius);
        if r <= r_k {
            let items = self.map.grid().items();
            let r2 = r * r;
            let mut g = Gather {
                r2,
                ..Default::default()
            };
            for &(i, d2) in self.knn.as_slice() {
                if d2 <= r2 {
                    g.flux += items[i as usize].power();
                    g.count += 1;
                }
            }
            g
        } else {
            self.map.within(sp.position, sp.facing_normal, r)
        }
    }

    /// Irradiance from all lights by shadow rays.
    fn direct_irradiance(&self, sp: &SurfacePoint, rng: &mut Rng) -> Rgb {
        let mut e = Rgb::ZERO;
        for light in &self.scene.lights {
            let samples = if light.is_delta() {
                1
            } else {
                self.settings.light_samples.max(1)
            };
            let mut sum = Rgb::ZERO;
            for _ in 0..samples {
                let Some(inc) = light.incident(sp.position, rng) else {
                    continue;
                };
                let cos = inc.wi.dot(sp.facing_shading_normal);
                if cos <= 0.0 || inc.wi.dot(sp.facing_normal) <= 0.0 {
                    continue;
                }
                let origin = sp.offset(inc.wi);
                let tmax = if inc.distance.is_finite() {
                    (inc.distance * (1.0 - 1e-4) - 1e-4).max(0.0)
                } else {
                    f32::INFINITY
                };
                if !self.accel.occluded(origin, inc.wi, tmax) {
                    sum += inc.irradiance * cos;
                }
            }
            e += sum / samples as f32;
        }
        e
    }
}
