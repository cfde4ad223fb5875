//! Shadowing of diffuse light by a normal map, as Blender's Cycles renders it (its
//! "Bump Map Correction", on by default): a bumped normal leans towards or away from the light
//! independently of the smooth surface under it, so light grazing the smooth surface would
//! otherwise light bumps fully that the surrounding relief hides. Cycles 5.0
//! (`kernel/closure/bsdf.h`, `bump_shadowing_term`) multiplies every diffuse evaluation by the
//! GGX masking term G1 of a roughness made from the bump's tilt (Conty Estevez, Lecocq and
//! Stein, "A Microfacet-Based Shadowing Function to Solve the Bump Terminator Problem", Ray
//! Tracing Gems, 2019), and rejects directions on opposite sides of the smooth and the bumped
//! surface. Measured on `bench/materials`' normal-mapped Lambert floor against Cycles:
//! `bench/materials/README.md`.

use crate::sampling::{self, Rng};
use crate::surface::SurfacePoint;
use glam::Vec3;

/// The factor Cycles applies to a diffuse lobe with bumped normal `mapped` over the smooth
/// (interpolated) normal `smooth`, for light arriving from `wi` (unit vectors; `smooth` and
/// `mapped` on the same side). 1 where the two normals are the same.
pub fn bump_shadowing(smooth: Vec3, mapped: Vec3, wi: Vec3) -> f32 {
    if smooth == mapped {
        return 1.0;
    }
    let cos_si = smooth.dot(wi);
    let cos_sn = smooth.dot(mapped);
    if cos_si * cos_sn * mapped.dot(wi) < 0.0 {
        return 0.0;
    }
    let (cos_i, cos_d) = (cos_si.abs(), cos_sn.abs());
    if cos_d >= 1.0 || cos_i >= 1.0 {
        return 1.0;
    }
    if cos_i < 1e-6 {
        return 0.0;
    }
    let tan2_d = 1.0 / (cos_d * cos_d) - 1.0;
    let alpha2 = (0.125 * tan2_d).clamp(0.0, 1.0);
    let lambda = 0.5 * ((1.0 + alpha2 * (1.0 / (cos_i * cos_i) - 1.0).max(0.0)).sqrt() - 1.0);
    1.0 / (1.0 + lambda)
}

/// The shading normal Cycles gives a glossy lobe (`ensure_valid_specular_reflection`,
/// `kernel/closure/bsdf_util.h`): `n` rotated towards the geometric normal `ng` just enough that
/// the mirror reflection of `i` (unit, towards the viewer, `i·ng ≥ 0`) leaves at least
/// min(0.9 i·ng, 0.01) above the surface; `n` itself where it already does. Cycles applies it
/// wherever the shading normal differs from the geometric one (smooth shading, normal maps).
pub fn valid_reflection_normal(ng: Vec3, i: Vec3, n: Vec3) -> Vec3 {
    let r = 2.0 * n.dot(i) * n - i;
    let iz = i.dot(ng);
    let threshold = (0.9 * iz).min(0.01);
    if ng.dot(r) >= threshold {
        return n;
    }
    let x = (n - n.dot(ng) * ng).try_normalize().unwrap_or(n);
    let ix = i.dot(x);
    let a = ix * ix + iz * iz;
    let b = 2.0 * (a + iz * threshold);
    let c = (threshold + iz) * (threshold + iz);
    let root = (b * b - 4.0 * a * c).max(0.0).sqrt();
    let nz2 = if ix < 0.0 {
        0.25 * (b + root) / a
    } else {
        0.25 * (b - root) / a
    };
    (1.0 - nz2).max(0.0).sqrt() * x + nz2.max(0.0).sqrt() * ng
}

/// [`bump_shadowing`] at a surface point for light from `wi`.
pub fn at(sp: &SurfacePoint, wi: Vec3) -> f32 {
    bump_shadowing(sp.facing_smooth_normal, sp.facing_shading_normal, wi)
}

/// Whether `sp` has a bumped normal (a normal map moved it off the smooth normal).
pub fn is_bumped(sp: &SurfacePoint) -> bool {
    sp.facing_smooth_normal != sp.facing_shading_normal
}

/// One-sample estimate of the cosine-weighted mean of [`bump_shadowing`] at `sp` over light
/// arriving evenly (cosine-distributed around the bumped normal): what a Lambert surface's
/// irradiance from photons, which carry no direction here, is scaled by. Unbiased; 1 without a
/// normal map (no random number drawn then).
pub fn mean_sample(sp: &SurfacePoint, rng: &mut Rng) -> f32 {
    if !is_bumped(sp) {
        return 1.0;
    }
    let d = sampling::cosine_hemisphere(rng.uniform2(), sp.facing_shading_normal);
    at(sp, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unbumped_normal_or_light_along_it_is_not_shadowed() {
        let n = Vec3::Z;
        let tilted = Vec3::new(0.3, 0.0, 1.0).normalize();
        assert_eq!(bump_shadowing(n, n, Vec3::new(0.9, 0.0, 0.1).normalize()), 1.0);
        assert_eq!(bump_shadowing(n, tilted, n), 1.0, "cos_i = 1");
    }

    #[test]
    fn grazing_light_is_shadowed_more_the_more_the_bump_tilts() {
        let n = Vec3::Z;
        let wi = Vec3::new(0.95, 0.0, 0.2).normalize();
        let small = bump_shadowing(n, Vec3::new(0.1, 0.0, 1.0).normalize(), wi);
        let large = bump_shadowing(n, Vec3::new(0.6, 0.0, 1.0).normalize(), wi);
        assert!(1.0 > small && small > large && large > 0.0, "{small} {large}");
        // Against the closed form: cos_d = 1/√1.36, tan²d = 0.36, α² = 0.045; G1 at cos_i.
        let cos_i = wi.z;
        let lambda = 0.5 * ((1.0 + 0.045 * (1.0 / (cos_i * cos_i) - 1.0)).sqrt() - 1.0);
        assert!((large - 1.0 / (1.0 + lambda)).abs() < 1e-5);
    }

    #[test]
    fn a_reflection_below_the_surface_is_lifted_to_the_threshold() {
        let ng = Vec3::Z;
        // Seen at grazing incidence, a normal tilted away from the viewer reflects below.
        let i = Vec3::new(-0.99, 0.0, 0.1411).normalize();
        let n = Vec3::new(0.3, 0.0, 1.0).normalize();
        assert!(ng.dot(2.0 * n.dot(i) * n - i) < 0.0);
        let v = valid_reflection_normal(ng, i, n);
        let r = 2.0 * v.dot(i) * v - i;
        assert!((v.length() - 1.0).abs() < 1e-5);
        assert!((r.dot(ng) - (0.9 * i.z).min(0.01)).abs() < 1e-4, "{}", r.dot(ng));
        assert!(v.dot(ng) > n.dot(ng), "rotated towards the geometric normal");
        // A valid reflection keeps its normal.
        let head_on = Vec3::new(0.2, 0.0, 1.0).normalize();
        assert_eq!(valid_reflection_normal(ng, head_on, n), n);
    }

    #[test]
    fn light_on_the_other_side_of_the_smooth_surface_than_of_the_bump_is_rejected() {
        // The bump faces the light, the smooth surface does not: Cycles returns 0.
        let n = Vec3::Z;
        let bumped = Vec3::new(0.5, 0.0, 1.0).normalize();
        let wi = Vec3::new(1.0, 0.0, -0.1).normalize();
        assert!(bumped.dot(wi) > 0.0 && n.dot(wi) < 0.0);
        assert_eq!(bump_shadowing(n, bumped, wi), 0.0);
    }
}
