//! Stochastic progressive photon mapping (Hachisuka & Jensen 2009, "Stochastic Progressive
//! Photon Mapping"), with the radius update of Knaus & Zwicker 2011 and α = 2/3 as pbrt-v4's
//! `SPPMIntegrator`.
//!
//! Every camera sample (pixel × sample index) keeps statistics across passes: a radius `r`, an
//! accumulated photon count `N` and flux `τ`. In each pass the sample's ray is followed through
//! mirrors and glass (one branch chosen by Fresnel) to its first diffuse hit, the *visible
//! point*; emission met on the way and direct light there (shadow rays, unless
//! `--direct photons`) are averaged over passes as in a path tracer; the `M` photons of the
//! pass's own map within `r` of the visible point update the statistics ([`SppmPixel::update`]).
//! A sample's radius starts at the kNN radius (k = `neighbours`) of the first pass's map
//! where it first meets a diffuse surface.

use super::{camera_ray, pixel_strata, DirectLighting, RenderSettings, Tracer};
use crate::accel::Accel;
use crate::bsdf;
use crate::estimate::PhotonMap;
use crate::film::{Aov, Film};
use crate::sampling::Rng;
use crate::scene::{Camera, Scene, Surface};
use crate::spatial::KnnBuffer;
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::Vec3;
use rayon::prelude::*;
use std::f32::consts::PI;

/// Share of a pass's photons kept in the accumulated count (Hachisuka et al. 2008, eq. 6;
/// pbrt-v4 uses 2/3).
pub const ALPHA: f32 = 2.0 / 3.0;

/// The statistics of one camera sample across passes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SppmPixel {
    /// Squared gather radius (0: no visible point yet, radius not chosen).
    pub r2: f32,
    /// Accumulated photon count `N`.
    pub n: f32,
    /// Accumulated flux `τ` (BSDF and path weight applied), in units of one pass's photons.
    pub tau: Rgb,
}

impl SppmPixel {
    /// Add a pass in which `m` photons with weighted flux sum `phi` fell within the radius
    /// (Hachisuka & Jensen 2009, eqs. 5–8; α = [`ALPHA`]):
    /// `N' = N + αM`, `r'² = r² (N + αM)/(N + M)`, `τ' = (τ + Φ_M)(N + αM)/(N + M)`.
    /// Without photons nothing changes (the pass still counts in [`SppmPixel::radiance`]).
    pub fn update(&mut self, m: usize, phi: Rgb) {
        if m == 0 {
            return;
        }
        let m = m as f32;
        let n_new = self.n + ALPHA * m;
        let shrink = n_new / (self.n + m);
        self.r2 *= shrink;
        self.tau = (self.tau + phi) * shrink;
        self.n = n_new;
    }

    /// Reflected radiance from photons after `passes` passes: `τ / (P π r²)`.
    ///
    /// Normalisation: the SPPM estimate is `L = τ / (N_e π r²)` when each photon carries the
    /// power of one emitted path, `Φ_light / p_light`, and `N_e` paths were emitted over all
    /// passes. Our photons already carry `Φ_light / (p_light N_pass)` (the pass's paths,
    /// `photon::trace`), so our `τ` is pbrt's divided by `N_pass`, and with `N_e = P N_pass`
    /// the estimate is `τ / (P π r²)`. This holds for any mixture of global and caustic-pass
    /// paths, since every pass's photons are by themselves an unbiased flux estimate.
    pub fn radiance(&self, passes: u32) -> Rgb {
        if self.r2 <= 0.0 || passes == 0 {
            return Rgb::ZERO;
        }
        self.tau / (passes as f32 * PI * self.r2)
    }
}

/// Where a camera sample's path meets its first diffuse surface.
struct VisiblePoint {
    position: Vec3,
    normal: Vec3,
    /// Path weight × Lambert BSDF (albedo/π): photon flux × this is reflected radiance × area.
    weight: Rgb,
}

/// The progressive state of one camera's image.
pub struct SppmFilm {
    width: u32,
    height: u32,
    spp: u32,
    /// `width × height × spp` samples, row-major, a pixel's samples together.
    samples: Vec<SppmPixel>,
    /// Per pixel: sum over passes of the mean of its samples' emission and direct light.
    direct: Vec<Rgb>,
    aov: Vec<Aov>,
    passes: u32,
}

impl SppmFilm {
    /// A film with no pass yet.
    pub fn new(width: u32, height: u32, spp: u32) -> Self {
        let n = width as usize * height as usize;
        let spp = spp.max(1);
        SppmFilm {
            width,
            height,
            spp,
            samples: vec![SppmPixel::default(); n * spp as usize],
            direct: vec![Rgb::ZERO; n],
            aov: vec![Aov::default(); n],
            passes: 0,
        }
    }

    /// Passes added so far.
    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// Add one pass: visible points for `settings.seed`'s camera samples, gathered from `map`
    /// (this pass's photons only). `progress(rows)` is called as rows finish.
    #[allow(clippy::too_many_arguments)]
    pub fn add_pass(
        &mut self,
        scene: &Scene,
        accel: &Accel,
        map: &PhotonMap,
        camera: &Camera,
        settings: &RenderSettings,
        progress: &(dyn Fn(usize) + Sync),
    ) {
        assert_eq!((settings.width, settings.height), (self.width, self.height));
        assert_eq!(settings.spp.max(1), self.spp);
        let w = self.width as usize;
        let spp = self.spp;
        let first_pass = self.passes == 0;
        self.samples
            .par_chunks_mut(w * spp as usize)
            .zip(self.direct.par_chunks_mut(w))
            .zip(self.aov.par_chunks_mut(w))
            .enumerate()
            .for_each_init(
                || Tracer {
                    scene,
                    accel,
                    map,
                    grids: None,
                    irradiance: None,
                    settings,
                    knn: KnnBuffer::default(),
                },
                |tracer, (y, ((samples, direct), aovs))| {
                    for x in 0..w {
                        let strata = pixel_strata(settings, (y * w + x) as u64);
                        let mut l = Rgb::ZERO;
                        for s in 0..spp {
                            let (o, d, mut rng) = camera_ray(camera, settings, &strata, x, y, s);
                            let aov = (first_pass && s == 0).then_some(&mut aovs[x]);
                            let (le, vp) = tracer.visible_point(o, d, &mut rng, aov);
                            l += le;
                            if let Some(vp) = vp {
                                tracer.gather_sppm(&mut samples[x * spp as usize + s as usize], &vp);
                            }
                        }
                        direct[x] += l / spp as f32;
                    }
                    progress(1);
                },
            );
        self.passes += 1;
    }

    /// The image so far: direct light averaged over passes plus each sample's photon estimate,
    /// averaged over the pixel's samples. The photon AOVs show sample 0's current radius.
    pub fn film(&self) -> Film {
        let mut film = Film::new(self.width, self.height);
        let p = self.passes.max(1);
        let spp = self.spp as usize;
        for (i, c) in film.color.iter_mut().enumerate() {
            let samples = &self.samples[i * spp..(i + 1) * spp];
            let photons: Rgb = samples.iter().map(|s| s.radiance(p)).sum::<Rgb>() / spp as f32;
            *c = self.direct[i] / p as f32 + photons;
        }
        for (i, a) in film.aov.iter_mut().enumerate() {
            *a = self.aov[i];
            let s = &self.samples[i * spp];
            a.radius = s.r2.sqrt();
            a.density = if s.r2 > 0.0 { s.n / (PI * s.r2) } else { 0.0 };
        }
        film
    }
}

impl Tracer<'_> {
    /// Follow a camera ray through mirrors and glass (one branch, chosen by Fresnel) to its
    /// first diffuse surface. Returns the emission met on the way plus direct light there
    /// (shadow rays), both weighted by the path, and the visible point if any.
    fn visible_point(
        &mut self,
        mut o: Vec3,
        mut d: Vec3,
        rng: &mut Rng,
        mut aov: Option<&mut Aov>,
    ) -> (Rgb, Option<VisiblePoint>) {
        let mut beta = Rgb::ONE;
        let mut l = Rgb::ZERO;
        for depth in 0..=self.settings.max_specular_depth {
            let Some(hit) = self.accel.intersect(o, d, f32::INFINITY) else {
                break;
            };
            let sp = SurfacePoint::new(self.scene, o, d, hit);
            let material = &self.scene.materials[sp.material as usize];
            if depth == 0 {
                if let Some(a) = aov.as_deref_mut() {
                    a.normal = sp.facing_shading_normal;
                    a.depth = hit.t;
                }
            }
            if material.is_emissive() && (material.double_sided || !sp.backface) {
                l += beta * material.emission;
            }
            if !matches!(material.surface, Surface::Lambert { .. }) && depth == self.settings.max_specular_depth {
                break; // as the camera pass: no mirror/glass bounce beyond the limit
            }
            let (dir, weight) = match &material.surface {
                Surface::Lambert { .. } => {
                    let albedo = sp.albedo(self.scene);
                    if let Some(a) = aov.as_deref_mut() {
                        a.albedo = albedo;
                    }
                    if albedo.max_element() <= 0.0 {
                        break;
                    }
                    let f = bsdf::lambert(albedo);
                    if self.settings.direct == DirectLighting::ShadowRays {
                        l += beta * f * self.direct_irradiance(&sp, rng);
                    }
                    let vp = VisiblePoint {
                        position: sp.position,
                        normal: sp.facing_normal,
                        weight: beta * f,
                    };
                    return (l, Some(vp));
                }
                Surface::Mirror { f0 } => {
                    let f = bsdf::fresnel_schlick(*f0, -d.dot(sp.facing_shading_normal));
                    (bsdf::reflect(d, sp.facing_shading_normal), f)
                }
                Surface::Dielectric { ior, tint, absorption } => {
                    if let (Some(sigma), true) = (absorption, sp.backface) {
                        beta *= (-*sigma * hit.t).exp();
                    }
                    let (r, t) = bsdf::dielectric_branches(d, sp.geometric_normal, *ior, *tint);
                    match t {
                        Some(t) if rng.uniform() >= r.weight.x => (t.direction, t.weight / (1.0 - r.weight.x)),
                        Some(_) => (r.direction, Rgb::ONE),
                        None => (r.direction, r.weight),
                    }
                }
            };
            beta *= weight;
            if beta.max_element() <= 0.0 || !beta.is_finite() {
                break;
            }
            o = sp.offset(dir);
            d = dir;
        }
        (l, None)
    }

    /// Gather this pass's photons around a visible point into a sample's statistics; the
    /// first time, the radius is the kNN radius there.
    fn gather_sppm(&mut self, px: &mut SppmPixel, vp: &VisiblePoint) {
        if px.r2 <= 0.0 {
            let g = self
                .map
                .knn(vp.position, vp.normal, self.settings.neighbours, &mut self.knn);
            px.r2 = g.r2.min(self.map.max_radius * self.map.max_radius);
            if px.r2 <= 0.0 {
                return;
            }
        }
        let g = self.map.within(vp.position, vp.normal, px.r2.sqrt());
        px.update(g.count, vp.weight * g.flux);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// Photons spread uniformly over a unit square, a visible point at its centre: after many
    /// passes the estimate converges to the true density and the radius shrinks.
    #[test]
    fn update_converges_on_a_uniform_field() {
        let per_pass = 2000; // photons per pass over 1 m²
        let e = Rgb::new(3.0, 2.0, 1.0); // irradiance [W/m²]: each photon carries e / per_pass
        let phi = e / per_pass as f32;
        let mut px = SppmPixel {
            r2: 0.2f32 * 0.2,
            ..Default::default()
        };
        let r2_start = px.r2;
        let mut rng = Rng::keyed(1, 2, 3);
        let passes = 2000;
        let mut r2_at = Vec::new();
        for p in 1..=passes {
            let (mut m, mut flux) = (0, Rgb::ZERO);
            for _ in 0..per_pass {
                let q = rng.uniform2() - glam::Vec2::splat(0.5);
                if q.length_squared() <= px.r2 {
                    m += 1;
                    flux += phi;
                }
            }
            px.update(m, flux);
            if p == 10 || p == 100 || p == 1000 {
                r2_at.push(px.r2);
            }
        }
        // Weight 1 (no BSDF): the estimate is the irradiance itself.
        let got = px.radiance(passes);
        let rel = (got / e - Rgb::ONE).abs().max_element();
        assert!(rel < 0.02, "estimate {got} vs {e} ({rel})");
        // The radius shrinks monotonically, roughly as P^(α−1) = P^(−1/3) in r².
        assert!(r2_at.windows(2).all(|w| w[1] < w[0]) && px.r2 < r2_at[2]);
        let ratio = r2_at[2] / r2_at[1]; // 1000 vs 100 passes: 10^(−1/3) ≈ 0.46
        assert!((0.35..0.6).contains(&ratio), "r² ratio {ratio}");
        assert!(px.r2 < 0.1 * r2_start);
        // No photons: nothing changes.
        let before = px;
        px.update(0, Rgb::ZERO);
        assert_eq!(px, before);
    }
}
