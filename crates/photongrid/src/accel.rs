//! Ray queries against the scene's triangles: an obvhs CWBVH with closest-hit and shadow rays.

use crate::scene::Triangle;
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::BvhBuildParams;

/// A ray–triangle hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Index of the triangle in the scene.
    pub triangle: u32,
}

/// The acceleration structure.
pub struct Accel {
    bvh: CwBvh,
    /// Triangles in BVH leaf order, so traversal reads memory in order.
    tris: Vec<RtTriangle>,
    /// Scene triangle index for each entry of `tris`.
    original: Vec<u32>,
    /// The BVH holds the scene multiplied by this power of two, which brings its bounding-box
    /// diagonal into [4, 8): obvhs culls nodes closer than an absolute 10⁻⁴ along a ray
    /// (`cwbvh::node::EPSILON`), which would hide a whole scene of 10⁻⁵ m. A power of two
    /// scales exactly, so a scene of diagonal 4 to 8 keeps 1 and the same bits.
    scale: f32,
}

/// The power of two that brings a diagonal `d` into [4, 8) (1 for a diagonal that is zero or
/// not finite).
fn unit_scale(d: f32) -> f32 {
    if !(d.is_finite() && d > 0.0) {
        return 1.0;
    }
    let e = d.log2().floor() as i32;
    2f32.powi((2 - e).clamp(-120, 120))
}

impl Accel {
    /// Build the BVH over the scene triangles.
    pub fn build(triangles: &[Triangle]) -> Self {
        let (lo, hi) = triangles.iter().flat_map(|t| t.p).fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(p), hi.max(p)),
        );
        let scale = unit_scale((hi - lo).length());
        let tris: Vec<obvhs::triangle::Triangle> = triangles
            .iter()
            .map(|t| obvhs::triangle::Triangle {
                v0: (t.p[0] * scale).into(),
                v1: (t.p[1] * scale).into(),
                v2: (t.p[2] * scale).into(),
            })
            .collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Default::default(),
        );
        let original = bvh.primitive_indices.clone();
        let rt = original.iter().map(|&i| RtTriangle::from(&tris[i as usize])).collect();
        Accel {
            bvh,
            tris: rt,
            original,
            scale,
        }
    }

    /// Closest hit along `origin + t·dir`, `t` in (0, tmax).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let ray = self.ray(origin, dir, tmax);
        let mut hit = RayHit::none();
        if self.bvh.ray_traverse(ray, &mut hit, |r, id| self.tris[id].intersect(r)) {
            Some(Hit {
                t: hit.t / self.scale,
                triangle: self.original[hit.primitive_id as usize],
            })
        } else {
            None
        }
    }

    /// True if anything blocks the segment from `origin` along `dir` up to `tmax`.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        let ray = self.ray(origin, dir, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| self.tris[id].intersect(r))
    }

    /// The ray in the BVH's scaled space (distances scale with it; the direction is kept).
    fn ray(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Ray {
        Ray::new(
            Vec3A::from(origin * self.scale),
            Vec3A::from(dir),
            0.0,
            tmax * self.scale,
        )
    }

    /// Approximate heap memory in bytes.
    pub fn memory_bytes(&self) -> usize {
        self.bvh.nodes.len() * std::mem::size_of::<obvhs::cwbvh::node::CwBvhNode>()
            + self.tris.len() * std::mem::size_of::<RtTriangle>()
            + self.original.len() * 8
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    fn tri(a: Vec3, b: Vec3, c: Vec3) -> Triangle {
        let n = (b - a).cross(c - a).normalize();
        Triangle {
            p: [a, b, c],
            n: [n; 3],
            uv: [Vec2::ZERO; 3],
            material: 0,
        }
    }

    #[test]
    fn tiny_and_huge_scenes_are_hit_alike() {
        // obvhs alone misses every node within 10⁻⁴ of the origin: a 10⁻⁶ scene was invisible.
        for s in [1e-7f32, 1e-6, 1.0, 1e4, 1e9] {
            let t = vec![tri(
                Vec3::new(-1.0, -1.0, -2.0) * s,
                Vec3::new(1.0, -1.0, -2.0) * s,
                Vec3::new(0.0, 1.0, -2.0) * s,
            )];
            let a = Accel::build(&t);
            let h = a.intersect(Vec3::ZERO, Vec3::NEG_Z, f32::INFINITY).expect("hit");
            assert!((h.t / (2.0 * s) - 1.0).abs() < 1e-6, "scale {s}: t {}", h.t);
            assert!(a.occluded(Vec3::ZERO, Vec3::NEG_Z, 3.0 * s), "scale {s}");
            assert!(!a.occluded(Vec3::ZERO, Vec3::NEG_Z, 1.9 * s), "scale {s}");
        }
        assert_eq!(unit_scale(7.0), 1.0);
        assert_eq!(unit_scale(4.0), 1.0);
        assert_eq!(unit_scale(8.0), 0.5);
        assert_eq!(unit_scale(f32::NAN), 1.0);
    }

    #[test]
    fn hits_closest_and_occludes() {
        let t = vec![
            tri(
                Vec3::new(-1.0, -1.0, -2.0),
                Vec3::new(1.0, -1.0, -2.0),
                Vec3::new(0.0, 1.0, -2.0),
            ),
            tri(
                Vec3::new(-1.0, -1.0, -1.0),
                Vec3::new(1.0, -1.0, -1.0),
                Vec3::new(0.0, 1.0, -1.0),
            ),
        ];
        let a = Accel::build(&t);
        let h = a.intersect(Vec3::ZERO, Vec3::NEG_Z, f32::INFINITY).unwrap();
        assert_eq!(h.triangle, 1);
        assert!((h.t - 1.0).abs() < 1e-6);
        assert!(a.occluded(Vec3::ZERO, Vec3::NEG_Z, 1.5));
        assert!(!a.occluded(Vec3::ZERO, Vec3::NEG_Z, 0.5));
        assert!(a.intersect(Vec3::ZERO, Vec3::Z, f32::INFINITY).is_none());
    }
}
