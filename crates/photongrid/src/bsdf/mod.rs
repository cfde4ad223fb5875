//! Scattering at surfaces: Lambert, Schlick mirror, smooth dielectric, and the glTF
//! metallic-roughness BSDF ([`metallic_roughness`] on the GGX microfacet model of [`ggx`]).
//! Used by the photon tracer and the camera pass alike, so each formula lives here once;
//! [`sample`] is the one scattering step every path takes at a non-Lambert surface (Fresnel
//! branch choice at mirrors and glass, lobe sampling of the glTF BSDF, Beer absorption), and
//! [`GltfPoint::eval`] the one evaluation (light sampling, photon estimates).

pub mod bump;
pub mod ggx;
pub mod metallic_roughness;

use crate::sampling::{self, Rng};
use crate::scene::material::MetallicRoughness;
use crate::scene::{Scene, Surface};
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::{Vec2, Vec3};
pub use metallic_roughness::{LobeMask, Lobes};

/// Roughness from which a glTF reflection lobe is rendered from photons (photons are stored
/// there; the camera turns their irradiance into radiance with the lobe's albedo, as if the
/// indirect light arrived evenly); below it, the lobe is traced: photons pass on (caustics) and
/// camera rays follow it, weighted against light sampling. Chosen by measurement against the
/// Cycles references of `bench/materials`: see `docs/materials.md`.
pub const GLOSSY_ROUGHNESS: f32 = 0.4;

/// Mirror reflection of `d` (pointing towards the surface) about `n`.
pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Refraction of `d` (towards the surface) through a surface with normal `n` facing `d`'s
/// origin side, `eta = n_incident / n_transmitted`. None on total internal reflection.
pub fn refract(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = -d.dot(n);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i).max(0.0);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((eta * d + (eta * cos_i - cos_t) * n).normalize())
}

/// Unpolarised Fresnel reflectance of a smooth dielectric interface.
/// `cos_i` is the cosine on the incident side, `eta = n_i / n_t`.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// Schlick's approximation `F0 + (1 − F0)(1 − cosθ)⁵` (Cycles' metal with white F82 tint).
pub fn fresnel_schlick(f0: Rgb, cos_i: f32) -> Rgb {
    let m = (1.0 - cos_i.clamp(0.0, 1.0)).powi(5);
    f0 + (Rgb::ONE - f0) * m
}

/// Lambert BRDF value `albedo / π`.
pub fn lambert(albedo: Rgb) -> Rgb {
    albedo * std::f32::consts::FRAC_1_PI
}

/// The outcome of a specular interaction: new direction, weight, and whether it crossed.
#[derive(Clone, Copy, Debug)]
pub struct SpecularSample {
    /// New unit direction.
    pub direction: Vec3,
    /// Throughput multiplier.
    pub weight: Rgb,
    /// True if the ray went through the surface.
    pub transmitted: bool,
    /// The normal the direction was computed about (the shading normal, or the geometric one
    /// where the shading normal could not be used), on the incident side.
    pub normal: Vec3,
}

/// Veach's adjoint correction for shading normals (Veach 1997, §5.3.2; Mitsuba's particle
/// tracer applies the same): light (a photon) scattered from direction `wi` (pointing back to
/// where it came from) into `wo` at a surface whose scattering used the normal `ns`, while the
/// surface really has the geometric normal `ng`, carries |wi·ns| |wo·ng| / (|wo·ns| |wi·ng|)
/// times the BSDF weight, so that particle tracing agrees with tracing from the camera through
/// the same interpolated normals. None where `ns` and `ng` disagree about which side `wi` or `wo`
/// is on (the path would leak through the surface).
pub fn adjoint_shading_correction(wi: Vec3, wo: Vec3, ng: Vec3, ns: Vec3) -> Option<f32> {
    let (i_g, i_s, o_g, o_s) = (wi.dot(ng), wi.dot(ns), wo.dot(ng), wo.dot(ns));
    if i_g * i_s <= 0.0 || o_g * o_s <= 0.0 {
        return None;
    }
    let c = (i_s * o_g / (o_s * i_g)).abs();
    c.is_finite().then_some(c)
}

/// Both branches at a smooth dielectric for a ray `d` hitting a surface with geometric normal
/// `ng` and shading normal `ns` (either orientation; pass `ng` twice for a flat-shaded surface).
/// Returns (reflection, refraction) with Fresnel weights; refraction is None on total internal
/// reflection (then reflection carries weight 1).
///
/// The geometric normal says which side the ray is on (entering or leaving); the Fresnel
/// factor and both directions follow the interpolated shading normal, as Blender (Cycles) and
/// the references do: on a smooth-shaded wavy surface, the facets' constant normals would break
/// a caustic's continuous filaments into the images of flat facets. Where the shading normal
/// faces away from the ray, or would send a branch to the wrong side of the real surface
/// (grazing rays where the normal is bent), the geometric normal is used for both branches.
pub fn dielectric_branches(
    d: Vec3,
    ng: Vec3,
    ns: Vec3,
    ior: f32,
    tint: Rgb,
) -> (SpecularSample, Option<SpecularSample>) {
    let entering = d.dot(ng) < 0.0;
    let n_geo = if entering { ng } else { -ng };
    let eta = if entering { 1.0 / ior } else { ior };
    // Tint applies once per crossing into or out of the material (Blender's glass colour tints
    // each passage); with white glass this is 1.
    let tint = if entering { tint } else { Rgb::ONE };
    let branches = |n: Vec3| {
        let f = fresnel_dielectric(-d.dot(n), eta);
        let r = SpecularSample {
            direction: reflect(d, n),
            weight: Rgb::splat(f),
            transmitted: false,
            normal: n,
        };
        match refract(d, n, eta) {
            Some(t) if f < 1.0 => (
                r,
                Some(SpecularSample {
                    direction: t,
                    weight: tint * (1.0 - f),
                    transmitted: true,
                    normal: n,
                }),
            ),
            _ => (SpecularSample { weight: Rgb::ONE, ..r }, None),
        }
    };
    let n_sh = if ns.dot(n_geo) < 0.0 { -ns } else { ns };
    if !(n_sh.is_finite() && -d.dot(n_sh) > 0.0) {
        return branches(n_geo);
    }
    let (r, t) = branches(n_sh);
    let valid = r.direction.dot(n_geo) > 0.0 && t.is_none_or(|t| t.direction.dot(n_geo) < 0.0);
    if valid {
        (r, t)
    } else {
        branches(n_geo)
    }
}

/// A scattering direction and the throughput weight it carries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scatter {
    /// New unit direction.
    pub direction: Vec3,
    /// Throughput multiplier.
    pub weight: Rgb,
    /// The normal the direction was computed about (for the adjoint shading-normal weight).
    pub normal: Vec3,
}

/// Beer–Lambert transmittance of the path inside a dielectric that ends at this hit: the ray
/// hit the back face, so it travelled `distance` through the material.
pub fn absorption(surface: &Surface, sp: &SurfacePoint, distance: f32) -> Rgb {
    match surface {
        Surface::Dielectric {
            absorption: Some(sigma),
            ..
        } if sp.backface => (-*sigma * distance).exp(),
        Surface::Gltf(m) if sp.backface => match m.absorption {
            Some(sigma) => (-sigma * distance).exp(),
            None => Rgb::ONE,
        },
        _ => Rgb::ONE,
    }
}

/// The specular branches of a ray `d` hitting a mirror or glass at `sp`, before absorption:
/// (reflection, refraction if any), Fresnel-weighted. None for a diffuse surface.
fn fresnel_branches(surface: &Surface, d: Vec3, sp: &SurfacePoint) -> Option<(Scatter, Option<Scatter>)> {
    let scatter = |s: SpecularSample| Scatter {
        direction: s.direction,
        weight: s.weight,
        normal: s.normal,
    };
    match surface {
        Surface::Lambert { .. } | Surface::Gltf(_) => None,
        Surface::Mirror { f0 } => {
            let n = sp.facing_shading_normal;
            let r = Scatter {
                direction: reflect(d, n),
                weight: fresnel_schlick(*f0, -d.dot(n)),
                normal: n,
            };
            Some((r, None))
        }
        Surface::Dielectric { ior, tint, .. } => {
            let (r, t) = dielectric_branches(d, sp.geometric_normal, sp.facing_shading_normal, *ior, *tint);
            Some((scatter(r), t.map(scatter)))
        }
    }
}

/// The specular branches of a ray `d` hitting a mirror or glass at `sp` after travelling
/// `distance`: (reflection, refraction if any), each weighted by Fresnel and by absorption
/// inside glass. None for a diffuse surface.
pub fn specular_branches(
    surface: &Surface,
    d: Vec3,
    sp: &SurfacePoint,
    distance: f32,
) -> Option<(Scatter, Option<Scatter>)> {
    let (r, t) = fresnel_branches(surface, d, sp)?;
    let a = absorption(surface, sp, distance);
    let absorbed = |s: Scatter| Scatter {
        weight: a * s.weight,
        ..s
    };
    Some((absorbed(r), t.map(absorbed)))
}

/// One specular branch, chosen by Fresnel where there are two (reflection with probability
/// F, each weight divided by its probability, so the estimate stays unbiased), with
/// absorption inside glass; a random number is drawn only where there is a choice. None for a
/// diffuse surface.
pub fn sample_specular(surface: &Surface, d: Vec3, sp: &SurfacePoint, distance: f32, rng: &mut Rng) -> Option<Scatter> {
    let (r, t) = fresnel_branches(surface, d, sp)?;
    let chosen = match t {
        Some(t) => {
            let pr = r.weight.x; // F, the same in every channel
            if rng.uniform() >= pr {
                Scatter {
                    weight: t.weight / (1.0 - pr),
                    ..t
                }
            } else {
                Scatter { weight: Rgb::ONE, ..r }
            }
        }
        None => r,
    };
    Some(Scatter {
        weight: absorption(surface, sp, distance) * chosen.weight,
        ..chosen
    })
}

/// Both Fresnel branches of a photon at a mirror or glass, with absorption inside glass: the
/// likelier branch carries its own weight, and the other is returned too with the probability
/// of its Fresnel share, its weight divided by that. Choosing one branch by chance thins the
/// photons that land through glass like a coin toss per photon; here the likelier branch loses
/// none, so stratified photons stay stratified through smooth glass. None for a diffuse surface.
pub fn split_specular(
    surface: &Surface,
    d: Vec3,
    sp: &SurfacePoint,
    distance: f32,
    rng: &mut Rng,
) -> Option<(Scatter, Option<Scatter>)> {
    let (r, t) = fresnel_branches(surface, d, sp)?;
    let a = absorption(surface, sp, distance);
    let absorbed = |s: Scatter, w: Rgb| Scatter { weight: a * w, ..s };
    let Some(t) = t else {
        return Some((absorbed(r, r.weight), None));
    };
    let f = r.weight.x; // F, the same in every channel
    let (likelier, other, p) = if f <= 0.5 { (t, r, f) } else { (r, t, 1.0 - f) };
    let other = (rng.uniform() < p).then(|| absorbed(other, other.weight / p));
    Some((absorbed(likelier, likelier.weight), other))
}

/// Which lobes of a glTF BSDF a step samples or evaluates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// Every lobe (photon paths).
    All,
    /// The lobes rays are traced through (camera paths: narrow reflection, transmission).
    Traced,
    /// The lobes rendered from photons (diffuse base, wide reflection).
    Stored,
}

/// A scattering step: direction, throughput weight, and the density it was sampled with.
#[derive(Clone, Copy, Debug)]
pub struct Sampled {
    /// New unit direction.
    pub direction: Vec3,
    /// Throughput multiplier (`f |cosθ| / pdf`, or the Fresnel branch weight).
    pub weight: Rgb,
    /// Solid-angle density of the direction; 0 for a delta lobe (mirror, smooth glass).
    pub pdf: f32,
    /// True if it went through a lobe that is traced (see [`GLOSSY_ROUGHNESS`]) or a delta
    /// lobe: light that follows it is a caustic for photons.
    pub traced: bool,
}

/// The one scattering step of every path at a non-Lambert surface: a ray `d` met `sp` after
/// travelling `distance`. Mirrors and glass take a Fresnel branch ([`sample_specular`]); glTF
/// materials sample the lobes of `part`. None for Lambert (whose cosine step is the callers')
/// or where nothing scatters.
pub fn sample(scene: &Scene, d: Vec3, sp: &SurfacePoint, distance: f32, rng: &mut Rng, part: Part) -> Option<Sampled> {
    let surface = &scene.materials[sp.material as usize].surface;
    match surface {
        Surface::Lambert { .. } => None,
        Surface::Mirror { .. } | Surface::Dielectric { .. } => {
            sample_specular(surface, d, sp, distance, rng).map(|s| Sampled {
                direction: s.direction,
                weight: s.weight,
                pdf: 0.0,
                traced: true,
            })
        }
        Surface::Gltf(m) => {
            let g = GltfPoint::at(scene, m, sp, d);
            let s = match part {
                Part::All => g.adjoint().sample_split(rng)?,
                Part::Traced | Part::Stored => {
                    let s = g.sample(g.mask(part), rng.uniform(), rng.uniform2())?;
                    Sampled {
                        traced: part == Part::Traced,
                        ..s
                    }
                }
            };
            Some(Sampled {
                weight: s.weight * absorption(surface, sp, distance),
                ..s
            })
        }
    }
}

/// Power-heuristic weight (Veach 1997, §9.2.4, β = 2) of a sample drawn by a strategy taking
/// `n_a` samples with density `p_a`, combined with one taking `n_b` samples with density `p_b`
/// (same measure). The weights of the two strategies for one direction sum to one.
pub fn mis_weight(n_a: f32, p_a: f32, n_b: f32, p_b: f32) -> f32 {
    let (a, b) = ((n_a * p_a).powi(2), (n_b * p_b).powi(2));
    if a + b > 0.0 && (a + b).is_finite() {
        a / (a + b)
    } else if p_a.is_infinite() {
        1.0
    } else {
        0.0
    }
}

/// The photon step at a glTF surface: whether photons are stored there (it has a lobe rendered
/// from photons), and the continuation sampled over every lobe (absorption included).
pub fn gltf_photon_step(
    scene: &Scene,
    m: &MetallicRoughness,
    d: Vec3,
    sp: &SurfacePoint,
    distance: f32,
    rng: &mut Rng,
) -> (bool, Option<Sampled>) {
    let g = GltfPoint::at(scene, m, sp, d).adjoint();
    let a = absorption(&scene.materials[sp.material as usize].surface, sp, distance);
    let s = g.sample_split(rng).map(|s| Sampled {
        weight: s.weight * a,
        ..s
    });
    (!g.stored.is_empty(), s)
}

/// The glTF BSDF at a hit with its shading frame, ready to sample and evaluate in world space.
#[derive(Clone, Copy, Debug)]
pub struct GltfPoint {
    /// The lobes with the textures read.
    pub lobes: Lobes,
    /// The lobes photons are stored for (estimated from photons).
    pub stored: LobeMask,
    /// The lobes rays are traced through.
    pub traced: LobeMask,
    /// Shading frame: tangent, bitangent, normal on the side of `wo`.
    frame: [Vec3; 3],
    /// Geometric normal on the side of `wo`.
    ng: Vec3,
    /// `wo` lies inside the material (a back face of a transmissive solid).
    inside: bool,
    /// Direction towards where the path came from, local.
    wo: Vec3,
    /// The smooth normal under a normal map (None without one): the diffuse lobe is shadowed
    /// by the bump as Cycles does ([`bump`]).
    smooth: Option<Vec3>,
}

impl GltfPoint {
    /// The BSDF of material `m` at `sp` for a ray travelling along `d`.
    pub fn at(scene: &Scene, m: &MetallicRoughness, sp: &SurfacePoint, d: Vec3) -> Self {
        let lobes = lobes_at(scene, m, sp.uv);
        let w = -d;
        // Cycles lifts a glossy lobe's normal where its mirror reflection of the viewer would
        // leave below the surface; the diffuse lobe keeps the shading normal, so only lobes
        // without a diffuse part follow it here (metal, glass).
        let n = if lobes.present().diffuse || sp.facing_shading_normal == sp.facing_normal {
            sp.facing_shading_normal
        } else {
            bump::valid_reflection_normal(sp.facing_normal, w, sp.facing_shading_normal)
        };
        let (t, b) = sampling::basis(n);
        let wo = Vec3::new(w.dot(t), w.dot(b), w.dot(n).max(1e-4)).normalize();
        let (stored, traced) = lobes.split(scene.glossy_roughness * scene.glossy_roughness);
        GltfPoint {
            lobes,
            stored,
            traced,
            frame: [t, b, n],
            ng: sp.facing_normal,
            inside: sp.backface && lobes.transmission > 0.0,
            wo,
            smooth: bump::is_bumped(sp).then_some(sp.facing_smooth_normal),
        }
    }

    /// The same point on a photon path: `wo` points towards the light, and scattering follows
    /// the adjoint BSDF (see [`Lobes::adjoint`]).
    pub fn adjoint(mut self) -> Self {
        self.lobes.adjoint = true;
        self
    }

    /// The lobes of `part`.
    pub fn mask(&self, part: Part) -> LobeMask {
        match part {
            Part::All => LobeMask::ALL,
            Part::Traced => self.traced,
            Part::Stored => self.stored,
        }
    }

    fn local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.frame[0]), v.dot(self.frame[1]), v.dot(self.frame[2]))
    }

    fn world(&self, v: Vec3) -> Vec3 {
        self.frame[0] * v.x + self.frame[1] * v.y + self.frame[2] * v.z
    }

    /// A direction is usable if it lies on the same side of the geometric surface as of the
    /// shading surface (no light leaks through shading normals).
    fn consistent(&self, wi_world: Vec3, wi_local: Vec3) -> bool {
        (wi_world.dot(self.ng) > 0.0) == (wi_local.z > 0.0)
    }

    /// `f(wo, wi)` of the lobes in `mask` and the density with which [`GltfPoint::sample`]
    /// returns `wi` (world direction away from the surface).
    pub fn eval(&self, wi: Vec3, mask: LobeMask) -> (Rgb, f32) {
        let l = self.local(wi);
        if !self.consistent(wi, l) {
            return (Rgb::ZERO, 0.0);
        }
        (
            self.bumped(self.lobes.eval(self.wo, l, self.inside, mask), wi, l, mask),
            self.lobes.pdf(self.wo, l, self.inside, mask),
        )
    }

    /// `f(wo, wi)` of the lobes in `mask` alone (light sampling without a density to weigh).
    pub fn f(&self, wi: Vec3, mask: LobeMask) -> Rgb {
        let l = self.local(wi);
        if mask.is_empty() || !self.consistent(wi, l) {
            return Rgb::ZERO;
        }
        self.bumped(self.lobes.eval(self.wo, l, self.inside, mask), wi, l, mask)
    }

    /// `f`, the lobes in `mask` evaluated towards `wi` (world; `l` local), with the diffuse
    /// lobe shadowed by a normal map's bump ([`bump`]) for the light's direction: `wi`, or `wo`
    /// on a photon path.
    fn bumped(&self, f: Rgb, wi: Vec3, l: Vec3, mask: LobeMask) -> Rgb {
        let Some(smooth) = self.smooth.filter(|_| mask.diffuse) else {
            return f;
        };
        let light = if self.lobes.adjoint { self.world(self.wo) } else { wi };
        let b = bump::bump_shadowing(smooth, self.frame[2], light);
        if b == 1.0 {
            return f;
        }
        let diffuse = LobeMask {
            diffuse: true,
            ..LobeMask::NONE
        };
        f - self.lobes.eval(self.wo, l, self.inside, diffuse) * (1.0 - b)
    }

    /// Sample the lobes in `mask` with the random numbers `u_lobe`, `u`.
    pub fn sample(&self, mask: LobeMask, u_lobe: f32, u: Vec2) -> Option<Sampled> {
        if mask.is_empty() {
            return None;
        }
        let s = self.lobes.sample(self.wo, self.inside, mask, u_lobe, u)?;
        let direction = self.world(s.wi).normalize();
        if !self.consistent(direction, s.wi) {
            return None;
        }
        let weight = if self.smooth.is_some() && mask.diffuse {
            self.bumped(s.f, direction, s.wi, mask) * (s.wi.z.abs() / s.pdf)
        } else {
            s.weight
        };
        Some(Sampled {
            direction,
            weight,
            pdf: s.pdf,
            traced: false,
        })
    }

    /// Sample every lobe in two stages: the traced or the stored lobes, in proportion to their
    /// approximate albedos, then a direction within them (the photon step: a photon that took a
    /// traced lobe carries a caustic on).
    pub fn sample_split(&self, rng: &mut Rng) -> Option<Sampled> {
        let w = self.lobes.strategies(self.wo, self.inside, LobeMask::ALL);
        let weight = |m: LobeMask| {
            let mut x = 0.0;
            if m.reflection {
                x += w[0];
            }
            if m.diffuse {
                x += w[1];
            }
            if m.transmission {
                x += w[2];
            }
            x
        };
        let (pt, ps) = (weight(self.traced), weight(self.stored));
        if !(pt + ps > 0.0) {
            return None;
        }
        let pt = pt / (pt + ps);
        let (mask, p, traced) = if rng.uniform() < pt {
            (self.traced, pt, true)
        } else {
            (self.stored, 1.0 - pt, false)
        };
        let s = self.sample(mask, rng.uniform(), rng.uniform2())?;
        Some(Sampled {
            weight: s.weight / p,
            pdf: s.pdf * p,
            traced,
            ..s
        })
    }

    /// Directional albedo of the lobes in `mask` (∫ f |cosθ| dω), from `n` samples.
    pub fn albedo(&self, mask: LobeMask, n: usize) -> Rgb {
        self.lobes.albedo(self.wo, self.inside, mask, n)
    }
}

/// The lobes of material `m` at texture coordinates `uv`: factors × textures (glTF spec:
/// metalness in B and roughness in G of the metallic-roughness texture; specular in the
/// specular texture's alpha).
pub fn lobes_at(scene: &Scene, m: &MetallicRoughness, uv: Vec2) -> Lobes {
    let tex = &scene.textures;
    let mut base = m.base_color;
    if let Some(t) = &m.base_color_texture {
        base *= t.sample(tex, uv).truncate();
    }
    let (mut metallic, mut roughness) = (m.metallic, m.roughness);
    if let Some(t) = &m.metallic_roughness_texture {
        let c = t.sample(tex, uv);
        metallic *= c.z;
        roughness *= c.y;
    }
    let mut specular = m.specular;
    if let Some(t) = &m.specular_texture {
        specular *= t.sample(tex, uv).w;
    }
    let mut specular_color = m.specular_color;
    if let Some(t) = &m.specular_color_texture {
        specular_color *= t.sample(tex, uv).truncate();
    }
    let mut transmission = m.transmission;
    if let Some(t) = &m.transmission_texture {
        transmission *= t.sample(tex, uv).x;
    }
    let f0 = (Rgb::splat(metallic_roughness::f0_of_ior(m.ior)) * specular_color).min(Rgb::ONE);
    Lobes {
        base,
        metallic: metallic.clamp(0.0, 1.0),
        alpha: (roughness * roughness).max(ggx::MIN_ALPHA),
        f0,
        specular: specular.clamp(0.0, 1.0),
        transmission: transmission.clamp(0.0, 1.0),
        ior: m.ior,
        adjoint: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{uniform_sphere, Rng};

    #[test]
    fn fresnel_normal_incidence_glass() {
        // ((1 − 1.5)/(1 + 1.5))² = 0.04
        assert!((fresnel_dielectric(1.0, 1.0 / 1.5) - 0.04).abs() < 1e-6);
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        // Total internal reflection beyond the critical angle inside glass.
        assert_eq!(fresnel_dielectric(0.3, 1.5), 1.0);
        assert!((fresnel_schlick(Rgb::splat(0.95), 1.0) - Rgb::splat(0.95)).length() < 1e-6);
        assert!((fresnel_schlick(Rgb::splat(0.95), 0.0) - Rgb::ONE).length() < 1e-6);
    }

    #[test]
    fn dielectric_conserves_energy_and_obeys_snell() {
        let mut rng = Rng::keyed(9, 9, 9);
        let ng = Vec3::Y;
        for _ in 0..10_000 {
            let d = uniform_sphere(rng.uniform2());
            if d.dot(ng).abs() < 1e-3 {
                continue;
            }
            let (r, t) = dielectric_branches(d, ng, ng, 1.5, Rgb::ONE);
            let total = r.weight.x + t.map(|t| t.weight.x).unwrap_or(0.0);
            assert!((total - 1.0).abs() < 1e-5, "energy {total}");
            assert!((r.direction.length() - 1.0).abs() < 1e-4);
            // Reflection stays on the incident side.
            assert!(r.direction.dot(ng) * d.dot(ng) < 0.0);
            if let Some(t) = t {
                let entering = d.dot(ng) < 0.0;
                let (n1, n2) = if entering { (1.0, 1.5) } else { (1.5, 1.0) };
                let sin_i = (1.0 - d.dot(ng).powi(2)).sqrt();
                let sin_t = (1.0 - t.direction.dot(ng).powi(2)).sqrt();
                assert!((n1 * sin_i - n2 * sin_t).abs() < 1e-3, "snell");
                assert!(t.direction.dot(ng) * d.dot(ng) > 0.0, "transmission crosses");
            }
        }
    }

    #[test]
    fn dielectric_follows_the_shading_normal_and_stays_on_valid_sides() {
        let mut rng = Rng::keyed(9, 9, 10);
        let ng = Vec3::Y;
        // A shading normal tilted by 1° (the pool slab's wavy top: up to 1.1°).
        let ns = Vec3::new(1f32.to_radians().sin(), 1f32.to_radians().cos(), 0.0);
        let mut followed = 0;
        for _ in 0..20_000 {
            let d = uniform_sphere(rng.uniform2());
            if d.dot(ng).abs() < 1e-3 {
                continue;
            }
            let (r, t) = dielectric_branches(d, ng, ns, 1.33, Rgb::ONE);
            let total = r.weight.x + t.map(|t| t.weight.x).unwrap_or(0.0);
            assert!((total - 1.0).abs() < 1e-5, "energy {total}");
            // Reflection stays on the incident side of the real surface, refraction crosses it.
            assert!(r.direction.dot(ng) * d.dot(ng) < 0.0);
            if let Some(t) = t {
                assert!(t.direction.dot(ng) * d.dot(ng) > 0.0);
            }
            // Away from grazing, the mirror direction is the one about the shading normal.
            if d.dot(ng).abs() > 0.2 {
                let n = if d.dot(ng) < 0.0 { ns } else { -ns };
                assert!((r.direction - reflect(d, n)).length() < 1e-5);
                followed += 1;
            }
        }
        assert!(followed > 10_000);
        // Flat shading (ns = ng) is the plain geometric interface.
        let d = Vec3::new(0.3, -1.0, 0.1).normalize();
        let (r, _) = dielectric_branches(d, ng, ng, 1.33, Rgb::ONE);
        assert!((r.direction - reflect(d, ng)).length() < 1e-6);
    }

    #[test]
    fn adjoint_correction_for_shading_normals() {
        let ng = Vec3::Y;
        let wi = Vec3::new(0.6, 0.8, 0.0);
        // Flat shading: no correction, whatever the directions.
        let wo = Vec3::new(-0.3, -0.9, 0.2).normalize();
        assert!((adjoint_shading_correction(wi, wo, ng, ng).unwrap() - 1.0).abs() < 1e-6);
        // Mirror about a tilted shading normal: |wi·ns| = |wo·ns|, so the weight is the ratio of
        // the geometric cosines (Veach 1997, eq. 5.20).
        let ns = Vec3::new(0.05, 1.0, 0.0).normalize();
        let wo = reflect(-wi, ns);
        let c = adjoint_shading_correction(wi, wo, ng, ns).unwrap();
        assert!((c - wo.dot(ng).abs() / wi.dot(ng).abs()).abs() < 1e-5, "{c}");
        // A direction the shading normal puts on the other side than the surface does: leak.
        let grazing = Vec3::new(-1.0, 0.01, 0.0).normalize();
        assert!(grazing.dot(ns) < 0.0 && grazing.dot(ng) > 0.0);
        assert!(adjoint_shading_correction(wi, grazing, ng, ns).is_none());
    }

    #[test]
    fn split_specular_keeps_the_likelier_branch_and_is_unbiased() {
        let glass = Surface::Dielectric {
            ior: 1.5,
            tint: Rgb::new(0.9, 0.8, 0.7),
            absorption: None,
        };
        let ng = Vec3::Y;
        let at = |backface: bool| SurfacePoint {
            position: Vec3::ZERO,
            geometric_normal: ng,
            facing_normal: if backface { -ng } else { ng },
            facing_shading_normal: if backface { -ng } else { ng },
            facing_smooth_normal: if backface { -ng } else { ng },
            backface,
            uv: Vec2::ZERO,
            material: 0,
            triangle: 0,
            eps: 1e-6,
        };
        let mut rng = Rng::keyed(9, 9, 11);
        // Entering near normal (F 0.04) and at 85° (F 0.45), leaving at 40° (F 0.24) and at 60°
        // (F 1: total internal reflection).
        for (deg, leaving) in [(5.0f32, false), (85.0, false), (40.0, true), (60.0, true)] {
            let (s, c) = deg.to_radians().sin_cos();
            let d = Vec3::new(s, if leaving { c } else { -c }, 0.0);
            let sp = at(leaving);
            let (r, t) = specular_branches(&glass, d, &sp, 0.0).unwrap();
            let n = 200_000;
            let mut spawned = Rgb::ZERO;
            for _ in 0..n {
                let (likelier, other) = split_specular(&glass, d, &sp, 0.0, &mut rng).unwrap();
                let f = r.weight.x;
                let (want, rest) = match t {
                    Some(t) if f <= 0.5 => (t, Some(r)),
                    Some(t) => (r, Some(t)),
                    None => (r, None),
                };
                assert_eq!(likelier, want, "{deg}°: the likelier branch with its own weight");
                if let Some(o) = other {
                    let rest = rest.expect("a spawned branch where Fresnel has two");
                    assert_eq!(o.direction, rest.direction);
                    spawned += o.weight;
                }
            }
            // The spawned branch carries, on average, the other branch's Fresnel weight.
            let want = t.map_or(Rgb::ZERO, |t| if r.weight.x <= 0.5 { r.weight } else { t.weight });
            let got = spawned / n as f32;
            assert!(
                (got - want).abs().max_element() < 0.01 * want.max_element().max(0.05),
                "{deg}°: {got} vs {want}"
            );
        }
    }

    #[test]
    fn fresnel_reciprocity() {
        // Reflectance is the same from either side for corresponding angles.
        let cos_i = 0.8f32;
        let eta = 1.0 / 1.5;
        let sin_t = eta * (1.0 - cos_i * cos_i).sqrt();
        let cos_t = (1.0 - sin_t * sin_t).sqrt();
        assert!((fresnel_dielectric(cos_i, eta) - fresnel_dielectric(cos_t, 1.5)).abs() < 1e-5);
    }
}
