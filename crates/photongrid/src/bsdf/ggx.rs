//! The Trowbridge–Reitz (GGX) microfacet distribution with height-correlated Smith masking and
//! shadowing, in a local frame whose z axis is the shading normal. `alpha` is the glTF
//! `roughness²`. Each formula once, with its source; the tests check the normalisations.

use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Smallest α used: below it the lobe is narrower than 32-bit directions resolve (the
/// material is then a mirror or smooth glass, which the loader maps to the delta models).
pub const MIN_ALPHA: f32 = 1e-3;

/// Microfacet normal distribution `D(h) = α² / (π ((n·h)²(α² − 1) + 1)²)` for `n·h > 0`
/// (glTF 2.0 spec, Appendix B.3.2; Walter et al. 2007, eq. 33).
pub fn d(cos_h: f32, alpha: f32) -> f32 {
    if cos_h <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let t = cos_h * cos_h * (a2 - 1.0) + 1.0;
    a2 / (PI * t * t)
}

/// Smith's `Λ(ω) = (−1 + √(1 + α² tan²θ)) / 2` for GGX (Heitz 2014, eq. 72), from `|cosθ|`.
pub fn lambda(cos: f32, alpha: f32) -> f32 {
    let c2 = (cos * cos).max(1e-12);
    let tan2 = (1.0 - c2).max(0.0) / c2;
    0.5 * (-1.0 + (1.0 + alpha * alpha * tan2).sqrt())
}

/// Smith masking of one direction `G1 = 1 / (1 + Λ)`.
pub fn g1(cos: f32, alpha: f32) -> f32 {
    1.0 / (1.0 + lambda(cos, alpha))
}

/// Height-correlated masking–shadowing `G2 = 1 / (1 + Λ(o) + Λ(i))` (Heitz 2014, eq. 99), for
/// reflection and transmission alike.
pub fn g2(cos_o: f32, cos_i: f32, alpha: f32) -> f32 {
    1.0 / (1.0 + lambda(cos_o, alpha) + lambda(cos_i, alpha))
}

/// The visibility term `V = G2 / (4 |n·l| |n·v|)` as the glTF spec writes it (Appendix B.3.2):
/// `0.5 / (|n·l| √(α² + (1 − α²)(n·v)²) + |n·v| √(α² + (1 − α²)(n·l)²))`.
pub fn v_smith(cos_v: f32, cos_l: f32, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let (nv, nl) = (cos_v.abs(), cos_l.abs());
    let gv = nl * (a2 + (1.0 - a2) * nv * nv).sqrt();
    let gl = nv * (a2 + (1.0 - a2) * nl * nl).sqrt();
    let s = gv + gl;
    if s > 0.0 {
        0.5 / s
    } else {
        0.0
    }
}

/// A microfacet normal sampled from the distribution of normals visible from `v` (local frame,
/// `v.z > 0`), Heitz 2018, "Sampling the GGX Distribution of Visible Normals", listing 1.
/// Its density is [`pdf_visible`].
pub fn sample_visible(v: Vec3, alpha: f32, u: Vec2) -> Vec3 {
    // Stretch the view direction to the hemisphere configuration.
    let vh = Vec3::new(alpha * v.x, alpha * v.y, v.z).normalize();
    let len2 = vh.x * vh.x + vh.y * vh.y;
    let t1 = if len2 > 0.0 {
        Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    // A point on the projected disc, warped towards the visible half.
    let r = u.x.sqrt();
    let phi = 2.0 * PI * u.y;
    let p1 = r * phi.cos();
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
    let p3 = (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
    let nh = p1 * t1 + p2 * t2 + p3 * vh;
    // Unstretch.
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(1e-6)).normalize()
}

/// Density of [`sample_visible`] over microfacet normals: `G1(v) max(0, v·h) D(h) / v.z`
/// (Heitz 2018, eq. 3).
pub fn pdf_visible(v: Vec3, h: Vec3, alpha: f32) -> f32 {
    if v.z <= 0.0 {
        return 0.0;
    }
    g1(v.z, alpha) * v.dot(h).max(0.0) * d(h.z, alpha) / v.z
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{uniform_sphere, Rng};

    /// ∫ D(h) (n·h) dω_h = 1 (the projected microfacet area is the macro surface's).
    #[test]
    fn distribution_is_normalised() {
        for alpha in [0.05f32, 0.2, 0.5, 1.0] {
            let n = 400_000;
            let mut rng = Rng::keyed(1, 2, 3);
            let mut sum = 0.0f64;
            for _ in 0..n {
                let h = uniform_sphere(rng.uniform2());
                sum += (d(h.z, alpha) * h.z.max(0.0)) as f64;
            }
            let integral = sum / n as f64 * 4.0 * std::f64::consts::PI;
            // Uniform sampling of a narrow lobe is noisy; α = 0.05 still resolves to ~3 %.
            let tol = if alpha < 0.1 { 0.05 } else { 0.01 };
            assert!((integral - 1.0).abs() < tol, "α {alpha}: {integral}");
        }
    }

    /// ∫ G1(v) max(0, v·h) D(h) dω_h = v.z (the visible projected area), so the visible-normal
    /// density integrates to one; and sampled normals follow it (their mean matches the
    /// density-weighted mean).
    #[test]
    fn visible_normals_are_a_density_and_sampled_from_it() {
        let alpha = 0.3;
        let v = Vec3::new(0.6, 0.0, 0.8);
        let n = 400_000;
        let mut rng = Rng::keyed(4, 5, 6);
        let (mut total, mut mean_x) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let h = uniform_sphere(rng.uniform2());
            let p = pdf_visible(v, h, alpha) as f64;
            total += p;
            mean_x += p * h.x as f64;
        }
        let norm = 4.0 * std::f64::consts::PI / n as f64;
        assert!((total * norm - 1.0).abs() < 0.02, "{}", total * norm);
        let expect_x = mean_x * norm;
        let m = 200_000;
        let sampled: f64 = (0..m)
            .map(|_| sample_visible(v, alpha, rng.uniform2()).x as f64)
            .sum::<f64>()
            / m as f64;
        assert!((sampled - expect_x).abs() < 0.01, "{sampled} vs {expect_x}");
    }

    #[test]
    fn visibility_is_g2_over_4_cosines() {
        for (nv, nl, a) in [(0.9f32, 0.3f32, 0.25f32), (0.2, 0.7, 0.6), (1.0, 1.0, 0.1)] {
            let v = v_smith(nv, nl, a);
            let g = g2(nv, nl, a) / (4.0 * nv * nl);
            assert!((v - g).abs() / g < 1e-4, "{v} vs {g}");
        }
        assert!((g1(1.0, 0.5) - 1.0).abs() < 1e-6);
    }
}
