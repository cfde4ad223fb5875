//! The camera pass at a glTF metallic-roughness surface ([`Surface::Gltf`]): direct light by
//! light sampling of the whole BSDF, the lobes rendered from photons (diffuse base, wide
//! reflection) by the photon estimate, and the traced lobes (narrow reflection, transmission)
//! by sampling the BSDF, combined with light sampling by multiple importance sampling for
//! emissive lights (delta lights: light sampling only). Kept apart from `mod.rs` so that the
//! Lambert, mirror and glass paths stay as they were.
//!
//! Final gathering at a stored glossy lobe draws its rays from the BSDF and weighs what they
//! bring by it ([`super::gather_lobe`]). The photon estimate (caustics, and indirect light
//! where no gathering is needed) gives irradiance, which the stored lobes turn into radiance
//! with their directional albedo, estimated by one BSDF sample (unbiased, cheap), as if that
//! light arrived evenly: exact for the diffuse base, an approximation for wide glossy lobes
//! that the roughness threshold ([`crate::bsdf::GLOSSY_ROUGHNESS`]) bounds. Gather rays that
//! land on a stored glossy lobe make the same approximation there.

use super::gather_lobe::GatherLobe;
use super::Tracer;
use crate::accel::Hit;
use crate::bsdf::{self, GltfPoint, LobeMask};
use crate::estimate::density::{density_radiance, photon_density};
use crate::estimate::Query;
use crate::film::Aov;
use crate::sampling::Rng;
use crate::scene::material::MetallicRoughness;
use crate::settings::DirectLighting;
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::Vec3;

/// What the next hit of a ray sampled from a traced glTF lobe needs to weight the emission it
/// finds against light sampling.
#[derive(Clone, Copy, Debug)]
pub(super) struct MisRay {
    /// Solid-angle density of the BSDF sample.
    pdf: f32,
}

/// What an SPPM camera path does at a glTF surface ([`Tracer::sppm_gltf`]).
pub(super) enum SppmStep {
    /// A visible point: direct light there and the weight of its photon estimate.
    Visible {
        /// Reflected direct light.
        direct: Rgb,
        /// Multiplies the photon flux density (BSDF albedo / π).
        weight: Rgb,
    },
    /// On through a sampled direction with this throughput weight (rough glass).
    Through(Rgb, Vec3),
    /// Nothing scatters.
    Stop,
}

impl Tracer<'_> {
    /// Radiance leaving the glTF surface at `sp` towards the ray `d` (that travelled
    /// `distance`), emission excluded.
    pub(super) fn gltf(
        &mut self,
        m: &MetallicRoughness,
        sp: &SurfacePoint,
        (d, distance, depth): (Vec3, f32, u32),
        rng: &mut Rng,
        aov: &mut Option<&mut Aov>,
    ) -> Rgb {
        let g = GltfPoint::at(self.scene, m, sp, d);
        let mut l = self.gltf_direct(&g, sp, rng);
        if !g.stored.is_empty() {
            l += self.gltf_stored(&g, sp, rng, aov);
        }
        if !g.traced.is_empty() && depth < self.settings.max_specular_depth {
            if let Some(s) = g.sample(g.traced, rng.uniform(), rng.uniform2()) {
                self.mis = Some(MisRay { pdf: s.pdf });
                let li = self.radiance(sp.leave(s.direction), s.direction, depth + 1, rng, aov);
                self.mis = None;
                l += s.weight * li;
            }
        }
        let surface = &self.scene.materials[sp.material as usize].surface;
        bsdf::absorption(surface, sp, distance) * l
    }

    /// The stored lobes from the photon estimate (and final gathering where it asks for it).
    fn gltf_stored(&mut self, g: &GltfPoint, sp: &SurfacePoint, rng: &mut Rng, aov: &mut Option<&mut Aov>) -> Rgb {
        let albedo = match g.sample(g.stored, rng.uniform(), rng.uniform2()) {
            Some(s) => s.weight,
            None => Rgb::ZERO,
        };
        let e = self.photons.estimator.gather(
            &Query {
                glossy: g.stored.reflection,
                ..super::query_at(sp, self.footprint)
            },
            &mut self.knn,
        );
        let mut l = density_radiance(albedo, e.flux, e.r2);
        if self.gathers(e.needs_gathering) {
            // A glossy stored lobe reflects gathered light as its BSDF says (not gated on the
            // one-sample albedo: a failed sample would drop the whole gather, a bias); the
            // diffuse base alone reflects the cosine-weighted mean.
            if g.stored.reflection {
                l += self.final_gather(sp, GatherLobe::Stored(g), rng);
            } else if albedo.max_element() > 0.0 {
                l += albedo * self.final_gather(sp, GatherLobe::Cosine, rng);
            }
        }
        if let Some(a) = aov.take() {
            a.albedo = g.lobes.base;
            a.density = photon_density(e.count as f32, e.r2);
            a.radius = e.r2.sqrt();
        }
        l
    }

    /// Direct light by shadow rays: the stored lobes with weight one (with shadow-ray direct
    /// lighting; from photons otherwise), the traced lobes weighted against BSDF sampling.
    fn gltf_direct(&self, g: &GltfPoint, sp: &SurfacePoint, rng: &mut Rng) -> Rgb {
        self.light_sampled(g, sp, (self.plain_direct(g.stored), g.traced), rng)
    }

    /// `mask` if direct light comes from shadow rays, else no lobe (photons carry it).
    fn plain_direct(&self, mask: LobeMask) -> LobeMask {
        if self.settings.direct == DirectLighting::ShadowRays {
            mask
        } else {
            LobeMask::NONE
        }
    }

    /// Light sampling of the lobes `stored` with weight one and of `traced` weighted against
    /// BSDF sampling of them.
    fn light_sampled(
        &self,
        g: &GltfPoint,
        sp: &SurfacePoint,
        (stored, traced): (LobeMask, LobeMask),
        rng: &mut Rng,
    ) -> Rgb {
        if stored.is_empty() && traced.is_empty() {
            return Rgb::ZERO;
        }
        let mut l = Rgb::ZERO;
        for light in &self.scene.lights {
            let n = if light.is_delta() {
                1
            } else {
                self.settings.light_samples.max(1)
            };
            let mut sum = Rgb::ZERO;
            for _ in 0..n {
                let Some(inc) = light.incident(sp.position, rng) else {
                    continue;
                };
                let mut f = g.f(inc.wi, stored);
                if !traced.is_empty() {
                    let (ft, pt) = g.eval(inc.wi, traced);
                    let w = if inc.pdf > 0.0 {
                        bsdf::mis_weight(n as f32, inc.pdf, 1.0, pt)
                    } else {
                        1.0
                    };
                    f += ft * w;
                }
                let cos = inc.wi.dot(sp.facing_shading_normal).abs();
                if f.max_element() <= 0.0 || cos <= 0.0 {
                    continue;
                }
                let origin = sp.offset(inc.wi);
                let tmax = sp.shadow_tmax(inc.distance, self.scene.bounds.diagonal());
                if !self.accel.occluded(origin, inc.wi, tmax) {
                    sum += f * inc.irradiance * cos;
                }
            }
            l += sum / n as f32;
        }
        l
    }

    /// SPPM at a glTF surface: a transmissive one, or one that stores no photons (narrow
    /// reflection only), is followed like glass (one lobe sampled; delta lights are not seen in
    /// it); any other is a visible point for all its lobes — direct light through the exact BSDF,
    /// the photon estimate weighted by the albedo (one sample) as if indirect light arrived
    /// evenly (SPPM keeps one visible point per camera sample, so glossy reflections of
    /// indirect light are not traced there).
    pub(super) fn sppm_gltf(
        &self,
        m: &MetallicRoughness,
        sp: &SurfacePoint,
        (d, distance): (Vec3, f32),
        rng: &mut Rng,
    ) -> SppmStep {
        let g = GltfPoint::at(self.scene, m, sp, d);
        let a = bsdf::absorption(&self.scene.materials[sp.material as usize].surface, sp, distance);
        if g.lobes.present().transmission || g.stored.is_empty() {
            return match g.sample_split(rng) {
                Some(s) => SppmStep::Through(a * s.weight, s.direction),
                None => SppmStep::Stop,
            };
        }
        let albedo = match g.sample(LobeMask::ALL, rng.uniform(), rng.uniform2()) {
            Some(s) => s.weight,
            None => Rgb::ZERO,
        };
        let direct = self.light_sampled(&g, sp, (self.plain_direct(LobeMask::ALL), LobeMask::NONE), rng);
        SppmStep::Visible {
            direct: a * direct,
            weight: a * bsdf::lambert(albedo),
        }
    }

    /// The weight of emission found at `sp` (hit by a ray along `d`) by a ray sampled from a
    /// traced glTF lobe against light sampling of the same emitter; 1 for every other ray.
    pub(super) fn emission_weight(&self, mis: Option<MisRay>, sp: &SurfacePoint, hit: &Hit, d: Vec3) -> f32 {
        let Some(mis) = mis else {
            return 1.0;
        };
        let cos_l = -d.dot(sp.geometric_normal);
        let n = self.settings.light_samples.max(1) as f32;
        let p_light: f32 = self
            .scene
            .lights
            .iter()
            .map(|l| l.pdf_hit(hit.triangle, hit.t, cos_l))
            .sum();
        bsdf::mis_weight(1.0, mis.pdf, n, p_light)
    }

    /// A final-gather ray's radiance leaving a glTF surface: the stored lobes from precomputed
    /// irradiance, else on through one traced lobe.
    pub(super) fn gather_gltf(
        &mut self,
        m: &MetallicRoughness,
        sp: &SurfacePoint,
        (d, distance, depth): (Vec3, f32, u32),
        rng: &mut Rng,
    ) -> Rgb {
        let g = GltfPoint::at(self.scene, m, sp, d);
        let surface = &self.scene.materials[sp.material as usize].surface;
        let a = bsdf::absorption(surface, sp, distance);
        if !g.stored.is_empty() {
            let albedo = match g.sample(g.stored, rng.uniform(), rng.uniform2()) {
                Some(s) => s.weight,
                None => return Rgb::ZERO,
            };
            return a * bsdf::lambert(albedo) * self.gathered_irradiance(sp);
        }
        if depth >= super::MAX_GATHER_DEPTH {
            return Rgb::ZERO;
        }
        match g.sample(g.traced, rng.uniform(), rng.uniform2()) {
            Some(s) => a * s.weight * self.gather_ray(sp.leave(s.direction), s.direction, depth + 1, rng),
            None => Rgb::ZERO,
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::bsdf::mis_weight;

    #[test]
    fn mis_weights_of_two_strategies_sum_to_one() {
        for (pa, pb) in [(0.3f32, 2.0f32), (5.0, 0.01), (1.0, 1.0), (0.0, 3.0), (1e-10, 1e-10)] {
            for na in [1.0f32, 4.0] {
                let s = mis_weight(na, pa, 1.0, pb) + mis_weight(1.0, pb, na, pa);
                assert!((s - 1.0).abs() < 1e-5, "{pa} {pb} {na}: {s}");
            }
        }
        // A delta strategy (no density) gets everything the other cannot sample.
        assert_eq!(mis_weight(1.0, 0.0, 1.0, 2.0), 0.0);
        assert_eq!(mis_weight(1.0, 2.0, 1.0, 0.0), 1.0);
    }
}
