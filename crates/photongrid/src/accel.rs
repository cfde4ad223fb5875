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
}

impl Accel {
    /// Build the BVH over the scene triangles.
    pub fn build(triangles: &[Triangle]) -> Self {
        let tris: Vec<obvhs::triangle::Triangle> = triangles
            .iter()
            .map(|t| obvhs::triangle::Triangle {
                v0: t.p[0].into(),
                v1: t.p[1].into(),
                v2: t.p[2].into(),
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
        }
    }

    /// Closest hit along `origin + t·dir`, `t` in (0, tmax).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, tmax);
        let mut hit = RayHit::none();
        if self.bvh.ray_traverse(ray, &mut hit, |r, id| self.tris[id].intersect(r)) {
            Some(Hit {
                t: hit.t,
                triangle: self.original[hit.primitive_id as usize],
            })
        } else {
            None
        }
    }

    /// True if anything blocks the segment from `origin` along `dir` up to `tmax`.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| self.tris[id].intersect(r))
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
