//! The glTF 2.0 metallic-roughness BSDF (specification, Appendix B) with
//! `KHR_materials_specular`, `KHR_materials_ior` and `KHR_materials_transmission`, at one
//! surface point whose textures have been read. Directions are in a local frame: z is the
//! shading normal on the side of `wo` (the direction the path already knows: towards the camera
//! on camera paths, towards where a photon came from on photon paths).
//!
//! ```text
//! f = (1 − metallic) · dielectric + metallic · F_metal(V·H) · D V · M(N·V)   (B.3.5–B.3.6)
//! F_metal    = baseColor + (1 − baseColor)(1 − |V·H|)⁵                       (Schlick)
//! M          = 1 + F_ms (1 − E(N·V)) / E(N·V)                                (metal_ms_compensation)
//! dielectric = s · F_d(V·H) · D V                                            (KHR_materials_specular
//!            + (1 − s · max(F_d)) · [(1 − T) · baseColor/π + T · baseColor · BTDF]  fresnel_mix)
//! F_d        = f0 + (1 − f0)(1 − |V·H|)⁵,  f0 = min(((ior − 1)/(ior + 1))² · specularColor, 1)
//!              (transmissive: the exact dielectric Fresnel · f0 / ((ior − 1)/(ior + 1))²)
//! ```
//! with `D` the GGX distribution and `V` the height-correlated Smith term ([`super::ggx`]),
//! `α = roughness²`, `s` the specular factor (0: pure Lambert), `T` the transmission factor,
//! `M` the metal's multiple-scattering compensation (not in the glTF spec: Cycles' default,
//! which the references use; `docs/materials.md`).
//! The transmission lobe is the rough dielectric BTDF of Walter et al. 2007 (eq. 21, without
//! its Fresnel factor, which the mix above supplies): the exporter writes frosted glass
//! without `KHR_materials_volume`, and it is rendered as a solid with two rough interfaces as
//! Blender does; its `F_d` is the exact Fresnel of the interface from either side, 1 beyond
//! the critical angle. Throughputs carry no `η²` radiance scaling (as the smooth glass): it cancels
//! through a closed solid, and photon and camera paths then share one BTDF.

use super::ggx;
use crate::sampling;
use crate::{luminance, Rgb};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

/// Schlick's Fresnel `f0 + (1 − f0)(1 − cosθ)⁵` (glTF spec, B.3.4).
pub fn schlick(f0: Rgb, cos: f32) -> Rgb {
    let m = (1.0 - cos.clamp(0.0, 1.0)).powi(5);
    f0 + (Rgb::ONE - f0) * m
}

/// Multiple-scattering compensation of the metal lobe seen from a direction of cosine `cos`:
/// `1 + F_ms (1 − E) / E` with `E` the single-scattering albedo ([`ggx::directional_albedo`])
/// and `F_ms = F_avg E_avg / (1 − F_avg (1 − E_avg))` (Kulla and Conty 2017), `F_avg = f0 +
/// (1 − f0)/21` Schlick's cosine-weighted mean. Turquin 2019's scaling of the lobe, as Cycles'
/// `microfacet_ggx_preserve_energy` does it: a white metal (`f0 = 1`) then has albedo 1.
pub fn metal_ms_compensation(f0: Rgb, cos: f32, alpha: f32) -> Rgb {
    let e = ggx::directional_albedo(cos, alpha);
    let e_avg = ggx::average_albedo(alpha);
    let f_avg = f0 + (Rgb::ONE - f0) / 21.0;
    let f_ms = f_avg * e_avg / (Rgb::ONE - f_avg * (1.0 - e_avg));
    Rgb::ONE + f_ms * ((1.0 - e) / e)
}

/// Reflectance at normal incidence of a dielectric of index `ior` in air, `((ior − 1)/(ior + 1))²`.
pub fn f0_of_ior(ior: f32) -> f32 {
    ((ior - 1.0) / (ior + 1.0)).powi(2)
}

/// Which lobes a query includes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct LobeMask {
    /// The Lambert base.
    pub diffuse: bool,
    /// The microfacet reflection (metal and dielectric specular).
    pub reflection: bool,
    /// The microfacet transmission.
    pub transmission: bool,
}

impl LobeMask {
    /// Every lobe.
    pub const ALL: LobeMask = LobeMask {
        diffuse: true,
        reflection: true,
        transmission: true,
    };
    /// No lobe.
    pub const NONE: LobeMask = LobeMask {
        diffuse: false,
        reflection: false,
        transmission: false,
    };

    /// True if no lobe is included.
    pub fn is_empty(self) -> bool {
        self == LobeMask::NONE
    }
}

/// The BSDF at one point: the material's factors times its textures.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lobes {
    /// Base colour (linear).
    pub base: Rgb,
    /// Metalness in [0, 1].
    pub metallic: f32,
    /// GGX α = roughness², at least [`ggx::MIN_ALPHA`].
    pub alpha: f32,
    /// Dielectric reflectance at normal incidence, before the specular factor.
    pub f0: Rgb,
    /// KHR_materials_specular weight (specularFactor × texture alpha; 1 by default).
    pub specular: f32,
    /// KHR_materials_transmission factor.
    pub transmission: f32,
    /// Index of refraction (KHR_materials_ior; 1.5 by default).
    pub ior: f32,
    /// A photon path (`wo` points towards the light): the metal's compensation, which depends
    /// on the viewing direction, is taken at `wi`, so photons scatter by the adjoint of the
    /// BSDF the camera sees (the rest is reciprocal).
    pub adjoint: bool,
}

/// A direction sampled from [`Lobes`].
#[derive(Clone, Copy, Debug)]
pub struct LobeSample {
    /// Local direction.
    pub wi: Vec3,
    /// BSDF value of the included lobes.
    pub f: Rgb,
    /// Solid-angle density of the sampling over the included lobes.
    pub pdf: f32,
    /// `f · |cosθ| / pdf`.
    pub weight: Rgb,
}

impl Lobes {
    /// Dielectric Fresnel at the microfacet cosine `cos` (on the `wo` side). Opaque: Schlick's,
    /// as the glTF specification writes it. Transmissive: the exact unpolarised reflectance
    /// (1 on total internal reflection), tinted by the specular colour (`f0` over the IOR's
    /// own), as the smooth glass and as Cycles' Principled glass: with Schlick's, a slab of
    /// roughness 0.05 passed more light than the smooth one (bench/materials/README.md, "The
    /// light through the slab").
    pub fn fresnel_dielectric(&self, cos: f32, inside: bool) -> Rgb {
        if self.transmission <= 0.0 {
            return schlick(self.f0, cos);
        }
        let eta = if inside { self.ior } else { 1.0 / self.ior };
        let own = f0_of_ior(self.ior);
        let tint = if own > 0.0 { self.f0 / own } else { Rgb::ONE };
        (tint * super::fresnel_dielectric(cos, eta)).min(Rgb::ONE)
    }

    /// Relative index `η_wi / η_wo` across the surface (transmission), given which side `wo` is.
    fn eta(&self, inside: bool) -> f32 {
        if inside {
            1.0 / self.ior
        } else {
            self.ior
        }
    }

    /// The lobes this BSDF has at all.
    pub fn present(&self) -> LobeMask {
        let dielectric = 1.0 - self.metallic;
        LobeMask {
            diffuse: dielectric > 0.0 && self.transmission < 1.0 && self.base.max_element() > 0.0,
            reflection: self.metallic > 0.0 || self.specular > 0.0,
            transmission: dielectric > 0.0 && self.transmission > 0.0 && self.base.max_element() > 0.0,
        }
    }

    /// The lobes photons are stored for and density estimation renders (the diffuse base, and
    /// the microfacet reflection when α ≥ `alpha_min`), and the lobes rays are traced through
    /// (narrower reflection, and transmission always: a density estimate on one face cannot see
    /// the photons arriving at the other).
    pub fn split(&self, alpha_min: f32) -> (LobeMask, LobeMask) {
        let p = self.present();
        let wide = self.alpha >= alpha_min;
        (
            LobeMask {
                diffuse: p.diffuse,
                reflection: p.reflection && wide,
                transmission: false,
            },
            LobeMask {
                diffuse: false,
                reflection: p.reflection && !wide,
                transmission: p.transmission,
            },
        )
    }

    /// BSDF value `f(wo, wi)` of the lobes in `mask` (local frame, `wo.z > 0`). `inside`: `wo`
    /// is inside the material (the ray hit a back face of a transmissive solid).
    pub fn eval(&self, wo: Vec3, wi: Vec3, inside: bool, mask: LobeMask) -> Rgb {
        if wo.z <= 0.0 || wi.z == 0.0 {
            return Rgb::ZERO;
        }
        let dielectric = 1.0 - self.metallic;
        if wi.z > 0.0 {
            let h = (wo + wi).normalize_or_zero();
            if h == Vec3::ZERO {
                return Rgb::ZERO;
            }
            let voh = wo.dot(h).max(0.0);
            let fd = self.fresnel_dielectric(voh, inside);
            let mut f = Rgb::ZERO;
            if mask.reflection {
                let dv = ggx::d(h.z, self.alpha) * ggx::v_smith(wo.z, wi.z, self.alpha);
                let mut metal = schlick(self.base, voh);
                if self.metallic > 0.0 {
                    let view = if self.adjoint { wi.z } else { wo.z };
                    metal *= metal_ms_compensation(self.base, view, self.alpha);
                }
                f += (dielectric * self.specular * fd + self.metallic * metal) * dv;
            }
            if mask.diffuse && self.transmission < 1.0 {
                let base = 1.0 - self.specular * fd.max_element();
                f += self.base * (dielectric * base * (1.0 - self.transmission) * FRAC_1_PI);
            }
            f
        } else {
            if !mask.transmission || self.transmission <= 0.0 || dielectric <= 0.0 {
                return Rgb::ZERO;
            }
            let eta = self.eta(inside);
            let Some(h) = half_vector_transmission(wo, wi, eta) else {
                return Rgb::ZERO;
            };
            let (oh, ih) = (wo.dot(h), wi.dot(h));
            let fd = self.fresnel_dielectric(oh, inside).max_element();
            let denom = oh + eta * ih;
            let walter = oh * ih.abs() / (wo.z * wi.z.abs())
                * eta
                * eta
                * ggx::g2(wo.z, wi.z, self.alpha)
                * ggx::d(h.z, self.alpha)
                / (denom * denom);
            // The tint applies once per passage, where the path enters the solid (as the
            // smooth glass).
            let tint = if inside { Rgb::ONE } else { self.base };
            tint * (dielectric * self.transmission * (1.0 - self.specular * fd) * walter)
        }
    }

    /// Whether reflection and transmission are sampled as one microfacet strategy: a visible
    /// normal first, then reflected or refracted by its own Fresnel ([`Lobes::reflect_share`]).
    /// Choosing by the macro surface's Fresnel instead gave fireflies inside rough glass, where
    /// a microfacet tilted past the critical angle reflects totally while the macro surface's
    /// Fresnel is small.
    fn microfacet_choice(&self, mask: LobeMask) -> bool {
        let p = self.present();
        mask.reflection && mask.transmission && p.reflection && p.transmission
    }

    /// The probability of reflecting off the visible microfacet of cosine `oh` with `wo`,
    /// against refracting through it: the share of its reflection in what it scatters.
    fn reflect_share(&self, oh: f32, inside: bool) -> f32 {
        let dielectric = 1.0 - self.metallic;
        let fd = luminance(self.fresnel_dielectric(oh, inside)).min(1.0);
        let r = self.metallic * luminance(schlick(self.base, oh)) + dielectric * self.specular * fd;
        let t = dielectric * self.transmission * (1.0 - self.specular * fd) * luminance(self.base);
        if r + t > 0.0 {
            r / (r + t)
        } else {
            0.5
        }
    }

    /// Probabilities of the three sampling strategies (reflection, diffuse, transmission),
    /// from approximate lobe albedos seen from `wo`; zero for lobes outside `mask`.
    pub fn strategies(&self, wo: Vec3, inside: bool, mask: LobeMask) -> [f32; 3] {
        let dielectric = 1.0 - self.metallic;
        let fd = luminance(self.fresnel_dielectric(wo.z, inside)).min(1.0);
        let fm = luminance(schlick(self.base, wo.z));
        let base = luminance(self.base);
        let present = self.present();
        let mut w = [0.0f32; 3];
        if mask.reflection && present.reflection {
            w[0] = self.metallic * fm + dielectric * self.specular * fd;
        }
        if mask.diffuse && present.diffuse {
            w[1] = dielectric * (1.0 - self.transmission) * (1.0 - self.specular * fd) * base;
        }
        if mask.transmission && present.transmission {
            // Floored: beyond the critical angle of the macro surface, microfacets still
            // transmit.
            w[2] = dielectric * self.transmission * (1.0 - self.specular * fd).max(0.1) * base;
        }
        let total: f32 = w.iter().sum();
        if !(total > 0.0) {
            return [0.0; 3];
        }
        w.map(|x| x / total)
    }

    /// Solid-angle density with which [`Lobes::sample`] returns `wi`.
    pub fn pdf(&self, wo: Vec3, wi: Vec3, inside: bool, mask: LobeMask) -> f32 {
        if wo.z <= 0.0 || wi.z == 0.0 {
            return 0.0;
        }
        self.pdf_of_strategies(wo, wi, inside, mask, self.strategies(wo, inside, mask))
    }

    /// [`Lobes::pdf`] for the strategies' probabilities `p` from `wo` ([`Lobes::strategies`]),
    /// which [`Lobes::sample`] has already computed; `wo.z > 0`, `wi.z ≠ 0`.
    fn pdf_of_strategies(&self, wo: Vec3, wi: Vec3, inside: bool, mask: LobeMask, p: [f32; 3]) -> f32 {
        let merged = self.microfacet_choice(mask);
        if wi.z > 0.0 {
            let mut pdf = 0.0;
            if p[0] > 0.0 {
                let h = (wo + wi).normalize_or_zero();
                let oh = wo.dot(h);
                if oh > 0.0 {
                    let share = if merged {
                        (p[0] + p[2]) * self.reflect_share(oh, inside)
                    } else {
                        p[0]
                    };
                    pdf += share * ggx::pdf_visible(wo, h, self.alpha) / (4.0 * oh);
                }
            }
            if p[1] > 0.0 {
                pdf += p[1] * wi.z * FRAC_1_PI;
            }
            pdf
        } else {
            if p[2] <= 0.0 {
                return 0.0;
            }
            let eta = self.eta(inside);
            let Some(h) = half_vector_transmission(wo, wi, eta) else {
                return 0.0;
            };
            let (oh, ih) = (wo.dot(h), wi.dot(h));
            let denom = oh + eta * ih;
            let share = if merged {
                (p[0] + p[2]) * (1.0 - self.reflect_share(oh, inside))
            } else {
                p[2]
            };
            share * ggx::pdf_visible(wo, h, self.alpha) * eta * eta * ih.abs() / (denom * denom)
        }
    }

    /// Sample a direction from the lobes in `mask`: a strategy by `u_lobe`, then a visible
    /// microfacet normal (reflected or refracted) or a cosine-weighted direction by `u`; where
    /// both microfacet lobes are included, one strategy whose normal then reflects or refracts
    /// by its own Fresnel ([`Lobes::microfacet_choice`]). The weight uses the density of the
    /// whole mixture (one-sample MIS over the strategies).
    pub fn sample(&self, wo: Vec3, inside: bool, mask: LobeMask, u_lobe: f32, u: Vec2) -> Option<LobeSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let p = self.strategies(wo, inside, mask);
        let diffuse = (p[0]..p[0] + p[1]).contains(&u_lobe);
        let (wi, reflected) = if diffuse {
            let d = sampling::concentric_disk(u);
            (Vec3::new(d.x, d.y, (1.0 - d.length_squared()).max(0.0).sqrt()), true)
        } else if self.microfacet_choice(mask) {
            // u_lobe, uniform over the two microfacet strategies' shares, picks the branch.
            let t = if u_lobe < p[0] { u_lobe } else { u_lobe - p[1] } / (p[0] + p[2]);
            let h = ggx::sample_visible(wo, self.alpha, u);
            if t < self.reflect_share(wo.dot(h), inside) {
                (super::reflect(-wo, h), true)
            } else {
                (super::refract(-wo, h, 1.0 / self.eta(inside))?, false)
            }
        } else if u_lobe < p[0] {
            let h = ggx::sample_visible(wo, self.alpha, u);
            (super::reflect(-wo, h), true)
        } else if p[2] > 0.0 {
            let h = ggx::sample_visible(wo, self.alpha, u);
            (super::refract(-wo, h, 1.0 / self.eta(inside))?, false)
        } else {
            return None;
        };
        // A microfacet can send a reflection below the surface or a refraction above it:
        // those are not the lobe's directions (the pdf counts each lobe on its own side).
        if wi.z == 0.0 || reflected != (wi.z > 0.0) {
            return None;
        }
        let pdf = self.pdf_of_strategies(wo, wi, inside, mask, p);
        if !(pdf > 0.0) || !pdf.is_finite() {
            return None;
        }
        let f = self.eval(wo, wi, inside, mask);
        let weight = f * (wi.z.abs() / pdf);
        weight.is_finite().then_some(LobeSample { wi, f, pdf, weight })
    }

    /// Directional albedo of the lobes in `mask` from `wo` (∫ f |cosθ| dω), estimated with `n`
    /// stratified samples; for reports and the estimate of wide lobes.
    pub fn albedo(&self, wo: Vec3, inside: bool, mask: LobeMask, n: usize) -> Rgb {
        let m = (n as f32).sqrt().ceil().max(1.0) as usize;
        // In f64: an f32 sum of a million weights near 1 drifts by 1 %.
        let mut sum = glam::DVec3::ZERO;
        for i in 0..m {
            for j in 0..m {
                let u = Vec2::new((i as f32 + 0.5) / m as f32, (j as f32 + 0.5) / m as f32);
                let u_lobe = ((i * m + j) as f32 * 0.618_034).fract();
                if let Some(s) = self.sample(wo, inside, mask, u_lobe, u) {
                    sum += s.weight.as_dvec3();
                }
            }
        }
        (sum / (m * m) as f64).as_vec3()
    }
}

/// The half vector of a refraction from `wo` (z > 0) to `wi` (z < 0) with relative index
/// `eta = η_wi / η_wo`, oriented to the `wo` side (Walter et al. 2007, eq. 16); None where no
/// microfacet refracts one into the other.
fn half_vector_transmission(wo: Vec3, wi: Vec3, eta: f32) -> Option<Vec3> {
    let mut h = (wo + eta * wi).normalize_or_zero();
    if h == Vec3::ZERO {
        return None;
    }
    if h.z < 0.0 {
        h = -h;
    }
    (wo.dot(h) > 0.0 && wi.dot(h) < 0.0).then_some(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{uniform_sphere, Rng};

    fn plastic(roughness: f32) -> Lobes {
        Lobes {
            base: Rgb::new(0.6, 0.06, 0.04),
            metallic: 0.0,
            alpha: roughness * roughness,
            f0: Rgb::splat(0.04),
            specular: 1.0,
            transmission: 0.0,
            ior: 1.5,
            adjoint: false,
        }
    }

    fn metal(base: Rgb, roughness: f32) -> Lobes {
        Lobes {
            base,
            metallic: 1.0,
            ..plastic(roughness)
        }
    }

    fn glass(roughness: f32) -> Lobes {
        Lobes {
            base: Rgb::ONE,
            transmission: 1.0,
            ..plastic(roughness)
        }
    }

    fn dir(cos: f32) -> Vec3 {
        Vec3::new((1.0 - cos * cos).sqrt(), 0.0, cos)
    }

    /// Every lobe and mix: the directional albedo is at most one (white furnace), estimated
    /// by uniform sphere sampling (independent of the BSDF's own sampling).
    #[test]
    fn white_furnace() {
        let white = Rgb::ONE;
        let cases = [
            ("white metal r0.3", metal(white, 0.3)),
            ("white metal r0.8", metal(white, 0.8)),
            (
                "white plastic r0.5",
                Lobes {
                    base: white,
                    ..plastic(0.5)
                },
            ),
            (
                "white plastic r1",
                Lobes {
                    base: white,
                    ..plastic(1.0)
                },
            ),
            (
                "white plastic spec 0",
                Lobes {
                    base: white,
                    specular: 0.0,
                    ..plastic(0.5)
                },
            ),
            ("rough glass r0.3", glass(0.3)),
            ("rough glass r0.7", glass(0.7)),
            (
                "half transmissive",
                Lobes {
                    base: white,
                    transmission: 0.5,
                    ..plastic(0.4)
                },
            ),
        ];
        let mut rng = Rng::keyed(7, 7, 7);
        for (name, l) in cases {
            for cos in [0.95f32, 0.6, 0.25] {
                let wo = dir(cos);
                let n = 400_000;
                let (mut sum, mut sum2) = (Rgb::ZERO, Rgb::ZERO);
                for _ in 0..n {
                    let wi = uniform_sphere(rng.uniform2());
                    let x = l.eval(wo, wi, false, LobeMask::ALL) * (wi.z.abs() * 4.0 * std::f32::consts::PI);
                    sum += x;
                    sum2 += x * x;
                }
                let a = sum / n as f32;
                // Standard error of the uniform estimate (large for narrow lobes).
                let se = ((sum2 / n as f32 - a * a).max(Rgb::ZERO) / n as f32)
                    .map(f32::sqrt)
                    .max_element();
                // The same albedo from the BSDF's own sampling (low variance on narrow lobes,
                // where uniform sampling is noisy; `sampling_matches_pdf_chi_square` checks the
                // density it divides by).
                let b = l.albedo(wo, false, LobeMask::ALL, 160_000);
                assert!(
                    (a - b).abs().max_element() < 0.01 + 4.0 * se,
                    "{name} cos {cos}: {a} ± {se} vs sampled {b}"
                );
                // The spec's fresnel_mix weights the diffuse base by 1 − F(V·H) per direction,
                // which exceeds energy conservation at grazing view (up to ~6 % for rough
                // plastic; Cycles is 13 % darker there, bench/materials/README.md): the bound
                // per lobe is 1, the plastic mix is allowed that excess.
                let bound = if l.metallic == 0.0 && l.specular > 0.0 && l.transmission < 1.0 {
                    1.08
                } else {
                    1.005
                };
                assert!(b.max_element() <= bound, "{name} cos {cos}: albedo {b}");
                for lobe in [
                    LobeMask {
                        diffuse: true,
                        ..LobeMask::NONE
                    },
                    LobeMask {
                        reflection: true,
                        ..LobeMask::NONE
                    },
                    LobeMask {
                        transmission: true,
                        ..LobeMask::NONE
                    },
                ] {
                    let a = l.albedo(wo, false, lobe, 40_000);
                    assert!(a.max_element() <= 1.005, "{name} cos {cos} {lobe:?}: albedo {a}");
                }
                if name == "white plastic spec 0" {
                    assert!((a.x - 1.0).abs() < 0.01, "spec 0 is Lambert: {a}");
                }
            }
        }
    }

    /// With the multiple-scattering compensation a white rough metal reflects everything at
    /// every angle (single scattering alone keeps E(μ=1) = 0.55 at roughness 0.8), and a gold
    /// one all of its red (f0 = 1) and less of the rest; the albedo from the BSDF's own sampling,
    /// checked against uniform sampling in `white_furnace`.
    #[test]
    fn white_metal_furnace_with_compensation() {
        let gold = Rgb::new(1.0, 0.766, 0.336);
        for roughness in [0.2f32, 0.4, 0.6, 0.8, 1.0] {
            for cos in [0.05f32, 0.1, 0.2, 0.4, 0.7, 1.0] {
                let a = metal(Rgb::ONE, roughness).albedo(dir(cos), false, LobeMask::ALL, 160_000);
                assert!(
                    (a - Rgb::ONE).abs().max_element() < 0.015,
                    "r {roughness} cos {cos}: {a}"
                );
                let g = metal(gold, roughness).albedo(dir(cos), false, LobeMask::ALL, 160_000);
                assert!(
                    (g.x - 1.0).abs() < 0.015 && g.y < 1.0 && g.z < g.y,
                    "gold r {roughness} cos {cos}: {g}"
                );
            }
        }
        // Without scattering between microfacets (a mirror-like lobe) nothing is added.
        let m = metal_ms_compensation(gold, 0.5, ggx::MIN_ALPHA);
        assert!((m - Rgb::ONE).abs().max_element() < 1e-3, "{m}");
    }

    /// Reflection is reciprocal, f(wo, wi) = f(wi, wo); transmission obeys the generalised
    /// reciprocity f(wo, wi) / η_wi² = f(wi, wo) / η_wo². The metal's multiple-scattering
    /// compensation depends on `wo` alone (as Cycles'), so the metal is reciprocal with it
    /// divided out, and the adjoint BSDF photons use is exactly f(wi, wo).
    #[test]
    fn reciprocity() {
        let mut rng = Rng::keyed(8, 8, 8);
        let gold = metal(Rgb::new(1.0, 0.766, 0.336), 0.3);
        let cases = [gold, metal(Rgb::new(0.9, 0.6, 0.5), 0.8), plastic(0.5), glass(0.4)];
        for l in cases {
            for _ in 0..2000 {
                let mut a = uniform_sphere(rng.uniform2());
                let b = uniform_sphere(rng.uniform2());
                a.z = a.z.abs().max(0.05);
                let a = a.normalize();
                if b.z.abs() < 0.05 {
                    continue;
                }
                let fab = l.eval(a, b, false, LobeMask::ALL);
                if b.z > 0.0 {
                    let fab_adjoint = Lobes { adjoint: true, ..l }.eval(b, a, false, LobeMask::ALL);
                    assert!(
                        (fab - fab_adjoint).abs().max_element() <= 1e-3 * (1.0 + fab.max_element()),
                        "{fab} {fab_adjoint}"
                    );
                    let ms = |w: Vec3| metal_ms_compensation(l.base, w.z, l.alpha);
                    let (fab, fba) = if l.metallic == 1.0 {
                        (fab / ms(a), l.eval(b, a, false, LobeMask::ALL) / ms(b))
                    } else {
                        (fab, l.eval(b, a, false, LobeMask::ALL))
                    };
                    assert!(
                        (fab - fba).abs().max_element() <= 1e-3 * (1.0 + fab.max_element()),
                        "{fab} {fba}"
                    );
                } else {
                    // b is inside: seen from b, wo is inside and a lies outside.
                    let (bi, ai) = (-b, -a);
                    let fba = l.eval(bi, ai, true, LobeMask::ALL);
                    let eta2 = l.ior * l.ior;
                    // The tint is 1 here (white glass).
                    let lhs = fab / eta2;
                    let rhs = fba;
                    assert!(
                        (lhs - rhs).abs().max_element() <= 2e-3 * (1.0 + lhs.max_element()),
                        "{lhs} {rhs}"
                    );
                }
            }
        }
    }

    /// The sampled directions follow `pdf` (chi-square test over a grid of (cosθ, φ) cells,
    /// both hemispheres), and `pdf` integrates to one.
    #[test]
    fn sampling_matches_pdf_chi_square() {
        let cases = [
            ("metal", metal(Rgb::new(1.0, 0.766, 0.336), 0.3), false),
            ("rough metal", metal(Rgb::new(1.0, 0.766, 0.336), 0.9), false),
            ("plastic", plastic(0.5), false),
            ("glass", glass(0.4), false),
            ("glass inside", glass(0.4), true),
            (
                "textured",
                Lobes {
                    metallic: 0.5,
                    ..plastic(0.7)
                },
                false,
            ),
        ];
        let (nt, np) = (20usize, 40usize);
        for (name, l, inside) in cases {
            for cos in [0.9f32, 0.4] {
                let wo = dir(cos);
                let mut rng = Rng::keyed(11, 12, 13);
                let n = 300_000;
                let mut observed = vec![0f64; 2 * nt * np];
                let cell = |w: Vec3| {
                    let t = (((w.z + 1.0) * 0.5 * 2.0 * nt as f32) as usize).min(2 * nt - 1);
                    let phi = w.y.atan2(w.x) + std::f32::consts::PI;
                    let p = ((phi / (2.0 * std::f32::consts::PI) * np as f32) as usize).min(np - 1);
                    t * np + p
                };
                let mut valid = 0;
                for _ in 0..n {
                    if let Some(s) = l.sample(wo, inside, LobeMask::ALL, rng.uniform(), rng.uniform2()) {
                        observed[cell(s.wi)] += 1.0;
                        valid += 1;
                    }
                }
                // Expected counts: integrate pdf over each cell (z uniform in the cell: dω = dz dφ).
                let mut expected = vec![0f64; 2 * nt * np];
                let sub = 8;
                let mut integral = 0.0f64;
                for t in 0..2 * nt {
                    for p in 0..np {
                        let mut acc = 0.0f64;
                        for a in 0..sub {
                            for b in 0..sub {
                                let z = -1.0 + (t as f32 + (a as f32 + 0.5) / sub as f32) / nt as f32;
                                let phi =
                                    (p as f32 + (b as f32 + 0.5) / sub as f32) / np as f32 * 2.0 * std::f32::consts::PI
                                        - std::f32::consts::PI;
                                let r = (1.0 - z * z).max(0.0).sqrt();
                                let w = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                                acc += l.pdf(wo, w, inside, LobeMask::ALL) as f64;
                            }
                        }
                        let area = (1.0 / nt as f64) * (2.0 * std::f64::consts::PI / np as f64);
                        let e = acc / (sub * sub) as f64 * area;
                        integral += e;
                        expected[t * np + p] = e * n as f64;
                    }
                }
                assert!(
                    (integral - valid as f64 / n as f64).abs() < 0.02,
                    "{name} cos {cos}: ∫pdf {integral}, valid {valid}"
                );
                // Pool cells with small expectations, then chi-square.
                let (mut chi2, mut dof, mut pool_o, mut pool_e) = (0.0f64, 0usize, 0.0f64, 0.0f64);
                for (o, e) in observed.iter().zip(&expected) {
                    if *e < 20.0 {
                        pool_o += o;
                        pool_e += e;
                    } else {
                        chi2 += (o - e).powi(2) / e;
                        dof += 1;
                    }
                }
                if pool_e > 20.0 {
                    chi2 += (pool_o - pool_e).powi(2) / pool_e;
                    dof += 1;
                }
                // The cell integration of a peaked pdf is approximate: allow a generous margin
                // over the 0.999 quantile (≈ dof + 3.1√(2 dof)).
                let limit = dof as f64 + 4.0 * (2.0 * dof as f64).sqrt() + 0.01 * n as f64 / dof.max(1) as f64;
                assert!(
                    chi2 < limit,
                    "{name} cos {cos}: χ² {chi2:.1} over {dof} cells (limit {limit:.1})"
                );
            }
        }
    }

    #[test]
    fn specular_zero_is_lambert_and_fresnel_limits() {
        let l = Lobes {
            specular: 0.0,
            ..plastic(0.5)
        };
        let f = l.eval(dir(0.7), dir(0.3), false, LobeMask::ALL);
        assert!((f - l.base * FRAC_1_PI).abs().max_element() < 1e-6);
        assert!((schlick(Rgb::splat(0.04), 1.0).x - 0.04).abs() < 1e-6);
        assert!((f0_of_ior(1.5) - 0.04).abs() < 1e-6);
        // Inside glass beyond the critical angle: total internal reflection.
        let g = glass(0.3);
        assert!((g.fresnel_dielectric(0.5, true) - Rgb::ONE).abs().max_element() < 1e-6);
        assert!((g.fresnel_dielectric(1.0, true).x - 0.04).abs() < 1e-6);
        assert!((g.fresnel_dielectric(1.0, false).x - 0.04).abs() < 1e-6);
    }

    /// The rough glass transmits, from either side, what the visible microfacets' Fresnel
    /// lets through: 1 − F averaged over normals drawn by an independent sampler (Heitz 2018,
    /// "Sampling the GGX distribution of visible normals", written here in f64), within the
    /// fraction of a percent that single scattering loses to masking. From inside, towards the
    /// critical angle, rough glass transmits much less than smooth glass (roughness 0.3 at
    /// 34°: 83 % against 92 %), so a rough slab lets less light through than a smooth one.
    #[test]
    fn rough_transmission_is_what_visible_microfacets_let_through() {
        fn visible_normal(wo: [f64; 3], a: f64, u1: f64, u2: f64) -> [f64; 3] {
            let v = [a * wo[0], a * wo[1], wo[2]];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let v = [v[0] / l, v[1] / l, v[2] / l];
            let lens = v[0] * v[0] + v[1] * v[1];
            let t1 = if lens > 0.0 {
                [-v[1] / lens.sqrt(), v[0] / lens.sqrt(), 0.0]
            } else {
                [1.0, 0.0, 0.0]
            };
            let t2 = [
                v[1] * t1[2] - v[2] * t1[1],
                v[2] * t1[0] - v[0] * t1[2],
                v[0] * t1[1] - v[1] * t1[0],
            ];
            let (r, phi) = (u1.sqrt(), 2.0 * std::f64::consts::PI * u2);
            let (p1, p2) = (r * phi.cos(), r * phi.sin());
            let s = 0.5 * (1.0 + v[2]);
            let p2 = (1.0 - s) * (1.0 - p1 * p1).sqrt() + s * p2;
            let p3 = (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
            let n = [0, 1, 2].map(|i| p1 * t1[i] + p2 * t2[i] + p3 * v[i]);
            let n = [a * n[0], a * n[1], n[2].max(1e-9)];
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            n.map(|x| x / l)
        }
        // The exact unpolarised reflectance, total internal reflection inside (n = 1.5).
        let fresnel = |c: f64, inside: bool| {
            let n = if inside { 1.0 / 1.5 } else { 1.5 };
            let s2 = (1.0 - c * c) / (n * n);
            if s2 >= 1.0 {
                return 1.0;
            }
            let t = (1.0 - s2).sqrt();
            let (rs, rp) = ((c - n * t) / (c + n * t), (n * c - t) / (n * c + t));
            0.5 * (rs * rs + rp * rp)
        };
        let l = glass(0.3);
        let only_t = LobeMask {
            diffuse: false,
            reflection: false,
            transmission: true,
        };
        let mut rng = Rng::keyed(3, 5, 7);
        for (inside, deg) in [(false, 0.0f64), (false, 57.0), (true, 0.0), (true, 34.0)] {
            let wo = [deg.to_radians().sin(), 0.0, deg.to_radians().cos()];
            let n = 200_000;
            let mut sum = 0.0;
            for _ in 0..n {
                let h = visible_normal(wo, (0.3f64).powi(2), rng.uniform() as f64, rng.uniform() as f64);
                sum += 1.0 - fresnel(wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2], inside);
            }
            let want = sum / n as f64;
            let got = l.albedo(dir(deg.to_radians().cos() as f32), inside, only_t, 1 << 20).x as f64;
            eprintln!("inside {inside}, {deg}°: transmitted {got:.4}, visible microfacets' 1 − F {want:.4}");
            assert!(
                got <= want + 0.002 && got > want - 0.008,
                "inside {inside}, {deg}°: {got} vs {want}"
            );
        }
    }
}
