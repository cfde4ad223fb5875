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

use super::gltf::SppmStep;
use super::{camera_ray, first_hit_aov, CameraPass, Tracer};
use crate::accel::Origin;
use crate::bsdf;
use crate::estimate::density::photon_density;
use crate::estimate::sppm::SppmPixel;
use crate::estimate::Query;
use crate::film::{Aov, Film};
use crate::sampling::Rng;
use crate::scene::Surface;
use crate::settings::DirectLighting;
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::Vec3;
use rayon::prelude::*;

/// Where a camera sample's path meets its first diffuse surface.
struct VisiblePoint {
    query: Query,
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

    /// Camera samples per pixel and pass.
    pub fn spp(&self) -> u32 {
        self.spp
    }

    /// Add one pass: visible points for `settings.seed`'s camera samples, gathered from this
    /// pass's photons only. `progress(rows)` is called as rows finish.
    pub fn add_pass(&mut self, pass: CameraPass<'_>, progress: &(dyn Fn(usize) + Sync)) {
        let (camera, settings) = (pass.camera, pass.settings);
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
                || Tracer::of(pass),
                |tracer, (y, ((samples, direct), aovs))| {
                    for x in 0..w {
                        let mut l = Rgb::ZERO;
                        for s in 0..spp {
                            let (o, d, mut rng) = camera_ray(camera, settings, x, y, s);
                            let aov = (first_pass && s == 0).then_some(&mut aovs[x]);
                            let (le, vp) = tracer.visible_point(o.into(), d, &mut rng, aov);
                            if first_pass && s == 0 {
                                aovs[x].depth *= d.dot(camera.forward()); // along the axis, see Aov
                            }
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
            a.density = photon_density(s.n, s.r2);
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
        mut o: Origin,
        mut d: Vec3,
        rng: &mut Rng,
        mut aov: Option<&mut Aov>,
    ) -> (Rgb, Option<VisiblePoint>) {
        let mut beta = Rgb::ONE;
        let mut l = Rgb::ZERO;
        for depth in 0..=self.settings.max_specular_depth {
            let Some(hit) = self.accel.intersect_from(o, d, f32::INFINITY) else {
                break;
            };
            let sp = SurfacePoint::new(self.scene, o.point, d, hit);
            let material = &self.scene.materials[sp.material as usize];
            if depth == 0 {
                first_hit_aov(&mut aov, &sp, hit.t);
            }
            if material.is_emissive() && (material.double_sided || !sp.backface) {
                l += beta * material.emission;
            }
            if let Surface::Lambert { .. } = material.surface {
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
                let query = super::query_at(&sp, 0.0);
                return (
                    l,
                    Some(VisiblePoint {
                        query,
                        weight: beta * f,
                    }),
                );
            }
            if let Surface::Gltf(m) = &material.surface {
                match self.sppm_gltf(m, &sp, (d, hit.t), rng) {
                    SppmStep::Visible { direct, weight } => {
                        let vp = VisiblePoint {
                            query: super::query_at(&sp, 0.0),
                            weight: beta * weight,
                        };
                        return (l + beta * direct, Some(vp));
                    }
                    SppmStep::Through(w, dir) if depth < self.settings.max_specular_depth => {
                        (beta, o, d) = (beta * w, sp.leave(dir), dir);
                        continue;
                    }
                    _ => break,
                }
            }
            if depth == self.settings.max_specular_depth {
                break; // as the camera pass: no mirror/glass bounce beyond the limit
            }
            let Some(s) = bsdf::sample_specular(&material.surface, d, &sp, hit.t, rng) else {
                break;
            };
            beta *= s.weight;
            if beta.max_element() <= 0.0 || !beta.is_finite() {
                break;
            }
            o = sp.leave(s.direction);
            d = s.direction;
        }
        (l, None)
    }

    /// Gather this pass's photons around a visible point into a sample's statistics; the
    /// first time, the radius is the kNN radius there.
    fn gather_sppm(&mut self, px: &mut SppmPixel, vp: &VisiblePoint) {
        let map = self.photons.estimator.map();
        if px.r2 <= 0.0 {
            let g = self.photons.estimator.gather(&vp.query, &mut self.knn);
            px.r2 = g.r2.min(map.max_radius * map.max_radius);
            if px.r2 <= 0.0 {
                return;
            }
        }
        let g = map.within(vp.query.position, vp.query.facing_normal, px.r2.sqrt());
        px.update(g.count, vp.weight * g.flux);
    }
}
