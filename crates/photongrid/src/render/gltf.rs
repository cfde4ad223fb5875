//! The camera pass at a glTF metallic-roughness surface ([`Surface::Gltf`]): direct light by
//! light sampling of the whole BSDF, the lobes rendered from photons (diffuse base, wide
//! reflection) by the photon estimate, and the traced lobes (narrow reflection, transmission)
//! by sampling the BSDF, combined with light sampling by multiple importance sampling for
//! emissive lights (delta lights: light sampling only). Kept apart from `mod.rs` so that the
//! Lambert, mirror and glass paths stay as they were.
//!
//! The photon estimate gives irradiance; the stored lobes turn it into radiance with their
//! directional albedo, estimated by one BSDF sample (unbiased, cheap), as if the indirect light
//! arrived evenly: exact for the diffuse base, an approximation for wide glossy lobes that the
//! roughness threshold ([`crate::bsdf::GLOSSY_ROUGHNESS`]) bounds.

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
                let li = self.radiance(sp.offset(s.direction), s.direction, depth + 1, rng, aov);
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
        let query = Query {
            position: sp.position,
            facing_normal: sp.facing_normal,
            geometric_normal: sp.geometric_normal,
            triangle: sp.triangle,
        };
        let e = self.photons.estimator.gather(&query, &mut self.knn);
        let mut l = density_radiance(albedo, e.flux, e.r2);
        if e.needs_gathering && self.settings.gather > 0 && albedo.max_element() > 0.0 {
            l += albedo * self.final_gather(sp, rng);
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
        let stored = if self.settings.direct == DirectLighting::ShadowRays {
            g.stored
        } else {
            LobeMask::NONE
        };
        if stored.is_empty() && g.traced.is_empty() {
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
                if !g.traced.is_empty() {
                    let (ft, pt) = g.eval(inc.wi, g.traced);
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
            Some(s) => a * s.weight * self.gather_ray(sp.offset(s.direction), s.direction, depth + 1, rng),
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
