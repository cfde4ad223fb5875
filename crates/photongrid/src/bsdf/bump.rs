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
    fn light_on_the_other_side_of_the_smooth_surface_than_of_the_bump_is_rejected() {
        // The bump faces the light, the smooth surface does not: Cycles returns 0.
        let n = Vec3::Z;
        let bumped = Vec3::new(0.5, 0.0, 1.0).normalize();
        let wi = Vec3::new(1.0, 0.0, -0.1).normalize();
        assert!(bumped.dot(wi) > 0.0 && n.dot(wi) < 0.0);
        assert_eq!(bump_shadowing(n, bumped, wi), 0.0);
    }
}
