//! Helpers shared by the crate's unit tests: seeded random numbers from the crate's one
//! generator, and test geometry.

use crate::sampling::Rng;
use glam::{DVec3, Vec3};
use std::f64::consts::{PI, TAU};

/// Stream key of test data, distinct from the renderer's keys in [`crate::sampling::stream`].
const TEST_STREAM: u64 = 0x7E57_DA7A;

/// A generator for test data, reproducible from `seed`.
pub(crate) fn test_rng(seed: u64) -> Rng {
    Rng::keyed(seed, TEST_STREAM, 0)
}

/// Uniform in [0, 1) with 53 random bits, where 24 (as in [`Rng::uniform`]) are too coarse.
pub(crate) fn uniform_f64(rng: &mut Rng) -> f64 {
    let bits = (u64::from(rng.next_u32()) << 21) | u64::from(rng.next_u32() >> 11);
    bits as f64 / (1u64 << 53) as f64
}

/// UV sphere with poles on the z axis: `segments` around, `rings` from pole to pole, wound
/// outwards. The quads touching a pole are single triangles, so no triangle is degenerate.
pub(crate) fn uv_sphere(center: Vec3, r: f32, segments: usize, rings: usize) -> Vec<[Vec3; 3]> {
    let p = |ring: usize, seg: usize| -> Vec3 {
        let th = PI * ring as f64 / rings as f64;
        let ph = TAU * (seg % segments) as f64 / segments as f64;
        center + (f64::from(r) * DVec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos())).as_vec3()
    };
    let mut out = Vec::with_capacity(2 * segments * rings);
    for ring in 0..rings {
        for s in 0..segments {
            let (a, b, c, d) = (p(ring, s), p(ring, s + 1), p(ring + 1, s + 1), p(ring + 1, s));
            // Ring 0 starts at a pole (a == b), the last ring ends at the other (c == d).
            let first = (ring != 0).then_some([a, b, c]);
            let second = (ring != rings - 1).then_some([a, c, d]);
            for t in first.into_iter().chain(second) {
                let n = (t[1] - t[0]).cross(t[2] - t[0]);
                let outward = (t[0] + t[1] + t[2]) / 3.0 - center;
                out.push(if n.dot(outward) < 0.0 { [t[0], t[2], t[1]] } else { t });
            }
        }
    }
    out
}

mod tests {
    use super::*;

    #[test]
    fn uv_sphere_is_closed_outward_and_without_degenerate_triangles() {
        let (segments, rings) = (16, 8);
        let tris = uv_sphere(Vec3::new(1.0, -2.0, 0.5), 2.0, segments, rings);
        assert_eq!(tris.len(), 2 * segments * rings - 2 * segments);
        let mut area = 0.0f64;
        for t in &tris {
            let n = (t[1] - t[0]).cross(t[2] - t[0]);
            assert!(n.length() > 1e-4, "degenerate triangle {t:?}");
            let outward = (t[0] + t[1] + t[2]) / 3.0 - Vec3::new(1.0, -2.0, 0.5);
            assert!(n.dot(outward) > 0.0);
            area += 0.5 * f64::from(n.length());
        }
        // A polyhedron inscribed in the sphere: a little less than 4πr².
        let sphere = 4.0 * PI * 4.0;
        assert!(area < sphere && area > 0.95 * sphere, "{area} vs {sphere}");
    }

    #[test]
    fn test_rng_is_reproducible_and_uniform() {
        let (mut a, mut b) = (test_rng(7), test_rng(7));
        let xs: Vec<f64> = (0..10_000).map(|_| uniform_f64(&mut a)).collect();
        assert!(xs.iter().all(|&x| (0.0..1.0).contains(&x)));
        assert!(xs.iter().all(|&x| x == uniform_f64(&mut b)));
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
        assert_ne!(uniform_f64(&mut test_rng(8)), uniform_f64(&mut test_rng(7)));
    }
}
