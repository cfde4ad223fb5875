//! Ray queries against the scene's triangles: an obvhs CWBVH with closest-hit and shadow rays.

use crate::scene::material::{AlphaMode, Material, Texture};
use crate::scene::{Scene, Triangle};
use glam::{Vec2, Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

/// A ray–triangle hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Index of the triangle in the scene.
    pub triangle: u32,
}

/// Where a ray starts: a point off the surface it leaves, and which surface that is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Origin {
    /// The start point, offset to the side the ray leaves by.
    pub point: Vec3,
    /// The surface point left, where there is one ([`Leaving`]).
    pub leaving: Option<Leaving>,
}

/// The surface point a ray leaves.
///
/// Offset off the face, a ray leaving the base of a glass standing on a table would start
/// inside the table and miss its top (the light through the base was lost, and the table seen
/// through it was dark: a cone on a shelf showed a dark cross); and light the table reflects
/// under the glass would start inside the glass, never entering it through its base. Where a
/// glass and another surface rest against each other ([`Accel::for_scene`] finds those
/// faces), a ray leaving either by its front (towards the other) is searched instead from
/// [`CONTACT_LEAD`] before its point, hits nothing of the face's own material within that
/// distance of the point (the face, and its neighbours where it leaves near an edge), and
/// finds the other. Elsewhere the offset start is kept: starting before the face tests the
/// face's own BVH leaf, a cost every glass crossing would pay (docs/materials.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Leaving {
    /// The scene triangle left.
    pub triangle: u32,
    /// Its material.
    pub material: u32,
    /// The point left, on the triangle.
    pub at: Vec3,
}

/// How far before its point a ray leaving a face in contact ([`Leaving`]) is searched, in the
/// BVH's units (the scene's diagonal brought into [4, 8)): four times the distance within
/// which obvhs culls a node along a ray, so a flat box (a table's top) at the point is not
/// culled.
pub const CONTACT_LEAD: f32 = 4e-4;

/// Distance, in offsets off a surface ([`crate::surface::offset_eps`]), within which a surface
/// facing a glass face in the same plane rests against it.
const RESTING_OFFSETS: f32 = 4.0;

impl From<Vec3> for Origin {
    fn from(point: Vec3) -> Self {
        Origin { point, leaving: None }
    }
}

/// Closest-hit queries, all the photon tracer asks of the scene's geometry. [`Accel`] answers
/// them; `photongrid throughput` wraps it to record the photon pass's own rays.
pub trait ClosestHit: Sync {
    /// Closest hit along `origin + t·dir`, `t` in (0, tmax).
    fn closest_hit(&self, origin: Origin, dir: Vec3, tmax: f32) -> Option<Hit>;
}

impl ClosestHit for Accel {
    #[inline]
    fn closest_hit(&self, origin: Origin, dir: Vec3, tmax: f32) -> Option<Hit> {
        self.intersect_from(origin, dir, tmax)
    }
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
    /// Alpha coverage of the triangles whose material has alpha (None: every triangle opaque).
    coverage: Option<Coverage>,
    /// Per entry of `tris`: its material ([`Leaving`]). Empty when built without materials.
    material: Vec<u32>,
    /// Per scene triangle: a glass face and another surface resting against each other
    /// ([`Leaving`]). Empty when built without materials.
    contact: Vec<bool>,
    /// Per entry of `tris`: a surface a glass face rests against, found [`BEHIND_GLASS`]
    /// farther than it is. Empty when built without materials.
    under_glass: Vec<bool>,
}

/// How much farther, in the BVH's units, traversal finds a surface a glass face rests against
/// (a table's top under a glass's base) than it is, its true distance then given back: light
/// coming down through the glass meets the glass's base and the table's top at the same
/// distance, and the base must be crossed first (refracted, or reflected by Fresnel). Found
/// first, the table took the light out of the glass as if the two were one optical medium, and
/// the light it reflected went up through the glass unrefracted (shelf_objects: the shadowed
/// wall above a glass cylinder 2.4 % too bright, docs/materials.md). As wide as the window in
/// which [`Accel::intersect_from`] passes over the face a ray leaves.
const BEHIND_GLASS: f32 = 2.0 * CONTACT_LEAD;

/// The triangles with alpha, tested inside traversal: a hit where a MASK material's alpha is
/// below its cutoff, or a BLEND material's stochastic coverage says no, is not a hit — for
/// camera rays, shadow rays and photons alike.
struct Coverage {
    /// Per scene triangle: index into `shapes`, or `u32::MAX` for an opaque triangle.
    of_triangle: Vec<u32>,
    /// Position, edges and texture coordinates of each triangle with alpha, and its material.
    shapes: Vec<(Vec3, Vec3, Vec3, [Vec2; 3], u32)>,
    /// The scene's materials and textures (alpha is read from them).
    materials: Vec<Material>,
    textures: Vec<Texture>,
}

impl Coverage {
    fn of(scene: &Scene) -> Option<Coverage> {
        if !scene.has_alpha() {
            return None;
        }
        let mut of_triangle = vec![u32::MAX; scene.triangles.len()];
        let mut shapes = Vec::new();
        for (i, t) in scene.triangles.iter().enumerate() {
            if scene.materials[t.material as usize].has_alpha() {
                of_triangle[i] = shapes.len() as u32;
                shapes.push((t.p[0], t.p[1] - t.p[0], t.p[2] - t.p[0], t.uv, t.material));
            }
        }
        Some(Coverage {
            of_triangle,
            shapes,
            materials: scene.materials.clone(),
            textures: scene.textures.clone(),
        })
    }

    /// Whether scene triangle `triangle` is there at the (unscaled) point `p` for the ray
    /// `ray` (whose bits key the stochastic choice of BLEND coverage).
    fn covers(&self, triangle: u32, p: Vec3, ray: &Ray) -> bool {
        let k = self.of_triangle[triangle as usize];
        if k == u32::MAX {
            return true;
        }
        let (p0, e1, e2, uv, material) = self.shapes[k as usize];
        let (b1, b2) = barycentric(p - p0, e1, e2);
        let uv = uv[0] * (1.0 - b1 - b2) + uv[1] * b1 + uv[2] * b2;
        let m = &self.materials[material as usize];
        let alpha = m.alpha_at(&self.textures, uv);
        match m.alpha_mode {
            AlphaMode::Opaque => true,
            AlphaMode::Mask { cutoff } => alpha >= cutoff,
            AlphaMode::Blend => coverage_uniform(ray, triangle) < alpha,
        }
    }
}

/// Barycentric coordinates (b1, b2) of the point `v = p − p0` in the plane of the edges `e1`,
/// `e2` (`p = p0 + b1·e1 + b2·e2`), clamped into the triangle.
fn barycentric(v: Vec3, e1: Vec3, e2: Vec3) -> (f32, f32) {
    let (d00, d01, d11) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d20, d21) = (v.dot(e1), v.dot(e2));
    let det = d00 * d11 - d01 * d01;
    if !(det.abs() > 0.0) {
        return (1.0 / 3.0, 1.0 / 3.0);
    }
    let b1 = ((d11 * d20 - d01 * d21) / det).clamp(0.0, 1.0);
    let b2 = ((d00 * d21 - d01 * d20) / det).clamp(0.0, 1.0 - b1);
    (b1, b2)
}

/// A uniform number in [0, 1) from the bits of a ray and a triangle: stochastic coverage that
/// stays the same whenever traversal tests that triangle again for that ray, and changes from
/// ray to ray (each path's rays start elsewhere or go elsewhere).
fn coverage_uniform(ray: &Ray, triangle: u32) -> f32 {
    let mut h = triangle as u64 ^ 0x9e37_79b9_7f4a_7c15;
    for v in [
        ray.origin.x,
        ray.origin.y,
        ray.origin.z,
        ray.direction.x,
        ray.direction.y,
        ray.direction.z,
    ] {
        h = (h ^ v.to_bits() as u64).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        h ^= h >> 31;
    }
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// `v` with every −0.0 component made +0.0 (IEEE: −0 + +0 = +0; nothing else changes).
/// obvhs 0.4 picks a ray's octant by `d < 0` but inverts −0.0 to a negative number, so a ray
/// with a −0.0 component read the wrong slab planes and missed everything: shadow rays
/// towards a sun pointing straight down (Blender's default) found no occluder at all.
#[inline]
fn positive_zeros(v: Vec3A) -> Vec3A {
    v + Vec3A::ZERO
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

/// Per scene triangle: whether it is a glass face that another surface rests against, or such
/// a surface — one of another material facing the glass face, in its plane within
/// [`RESTING_OFFSETS`] offsets, their boxes overlapping (a glass's base and the table's top).
fn contact_faces(scene: &Scene, accel: &Accel) -> Vec<bool> {
    let diagonal = scene.bounds.diagonal();
    let pairs: Vec<(usize, Vec<u32>)> = (0..scene.triangles.len())
        .into_par_iter()
        .filter_map(|i| {
            let t = &scene.triangles[i];
            let n = t.cross().normalize_or_zero();
            if !scene.materials[t.material as usize].transmits() || n == Vec3::ZERO {
                return None;
            }
            let magnitude = t.p.iter().fold(0.0f32, |m, p| m.max(p.abs().max_element()));
            let near = RESTING_OFFSETS * crate::surface::offset_eps(magnitude, diagonal);
            let lo = t.p[0].min(t.p[1]).min(t.p[2]) - near;
            let hi = t.p[0].max(t.p[1]).max(t.p[2]) + near;
            let mut partners = Vec::new();
            accel.for_each_near(lo, hi, |j| {
                let o = &scene.triangles[j as usize];
                if o.material != t.material
                    && o.cross().normalize_or_zero().dot(n) < -0.999
                    && o.p.iter().any(|p| (*p - t.p[0]).dot(n).abs() <= near)
                    && t.p.iter().all(|p| (*p - o.p[0]).dot(n).abs() <= near)
                {
                    partners.push(j);
                }
            });
            (!partners.is_empty()).then_some((i, partners))
        })
        .collect();
    let mut contact = vec![false; scene.triangles.len()];
    for (i, partners) in pairs {
        contact[i] = true;
        for j in partners {
            contact[j as usize] = true;
        }
    }
    contact
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
            coverage: None,
            material: Vec::new(),
            contact: Vec::new(),
            under_glass: Vec::new(),
        }
    }

    /// Build the BVH over the scene's triangles, with alpha coverage where materials have alpha.
    pub fn for_scene(scene: &Scene) -> Self {
        let accel = Accel::build(&scene.triangles);
        let material = accel
            .original
            .iter()
            .map(|&i| scene.triangles[i as usize].material)
            .collect();
        let contact = contact_faces(scene, &accel);
        let under_glass = accel
            .original
            .iter()
            .map(|&i| {
                let t = &scene.triangles[i as usize];
                contact[i as usize] && !scene.materials[t.material as usize].transmits()
            })
            .collect();
        Accel {
            under_glass,
            coverage: Coverage::of(scene),
            material,
            contact,
            ..accel
        }
    }

    /// The triangle test of traversal: the distance to entry `id` of `tris`, infinite where
    /// alpha cuts the triangle away.
    #[inline]
    fn test(&self, r: &Ray, id: usize) -> f32 {
        let t = self.tris[id].intersect(r);
        let t = match &self.coverage {
            Some(c) if t < f32::INFINITY => {
                let p = Vec3::from(r.origin + r.direction * t) / self.scale;
                if c.covers(self.original[id], p, r) {
                    t
                } else {
                    f32::INFINITY
                }
            }
            _ => t,
        };
        t + self.behind(id)
    }

    /// How much farther traversal finds entry `id` of `tris` than it is: [`BEHIND_GLASS`] for
    /// a surface a glass face rests against, else nothing.
    #[inline]
    fn behind(&self, id: usize) -> f32 {
        if self.under_glass.get(id).copied().unwrap_or(false) {
            BEHIND_GLASS
        } else {
            0.0
        }
    }

    /// Closest hit along `origin + t·dir`, `t` in (0, tmax).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        self.closest(self.ray(origin, dir, tmax), |r, id| self.test(r, id))
    }

    /// The closest hit of `ray` (in the BVH's units) by the triangle test `test`, in the
    /// scene's units and triangles.
    #[inline]
    fn closest(&self, ray: Ray, test: impl FnMut(&Ray, usize) -> f32) -> Option<Hit> {
        let mut hit = RayHit::none();
        self.bvh.ray_traverse(ray, &mut hit, test).then(|| {
            let id = hit.primitive_id as usize;
            Hit {
                t: (hit.t - self.behind(id)).max(0.0) / self.scale,
                triangle: self.original[id],
            }
        })
    }

    /// Closest hit along `origin.point + t·dir`, `t` in (0, tmax); for a ray leaving a face in
    /// contact, searched from before the face ([`Leaving`]).
    pub fn intersect_from(&self, origin: Origin, dir: Vec3, tmax: f32) -> Option<Hit> {
        let l = match origin.leaving {
            Some(l) if self.contact.get(l.triangle as usize).copied().unwrap_or(false) => l,
            _ => return self.intersect(origin.point, dir, tmax),
        };
        let lead = CONTACT_LEAD / self.scale;
        let ray = self.ray(l.at - dir * lead, dir, tmax + lead);
        let test = |r: &Ray, id: usize| {
            let t = self.test(r, id);
            if t - self.behind(id) < 2.0 * CONTACT_LEAD && self.material[id] == l.material {
                f32::INFINITY
            } else {
                t
            }
        };
        // Measured from `origin.point`, as every hit.
        let before = lead + (l.at - origin.point).dot(dir);
        self.closest(ray, test).map(|h| Hit {
            t: (h.t - before).max(0.0),
            ..h
        })
    }

    /// True if anything blocks the segment from `origin` along `dir` up to `tmax`.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        let ray = self.ray(origin, dir, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| self.test(r, id))
    }

    /// Calls `f` with the scene index of every triangle in a BVH leaf whose box overlaps the
    /// box `lo`–`hi`: a superset of the triangles that overlap it, each once.
    pub fn for_each_near(&self, lo: Vec3, hi: Vec3, mut f: impl FnMut(u32)) {
        use glam::UVec2;
        let aabb = obvhs::aabb::Aabb::new(Vec3A::from(lo * self.scale), Vec3A::from(hi * self.scale));
        let mut state = self.bvh.new_traversal(Vec3A::ONE);
        let mut node;
        obvhs::traverse!(self.bvh, node, state, node.intersect_aabb(&aabb, state.oct_inv4), {
            f(self.original[state.primitive_id as usize]);
        });
    }

    /// The ray in the BVH's scaled space (distances scale with it; the direction is kept).
    fn ray(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Ray {
        Ray::new(
            Vec3A::from(origin * self.scale),
            positive_zeros(Vec3A::from(dir)),
            0.0,
            tmax * self.scale,
        )
    }

    /// The faces in contact ([`Leaving`]), per scene triangle.
    #[cfg(test)]
    pub(crate) fn contact(&self) -> &[bool] {
        &self.contact
    }

    /// Approximate heap memory in bytes.
    pub fn memory_bytes(&self) -> usize {
        self.bvh.nodes.len() * std::mem::size_of::<obvhs::cwbvh::node::CwBvhNode>()
            + self.tris.len() * std::mem::size_of::<RtTriangle>()
            + self.original.len() * 8
            + self.material.len() * 4
            + self.contact.len()
            + self.under_glass.len()
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

    /// The box query returns every triangle whose bounds overlap the box (and each once).
    #[test]
    fn for_each_near_finds_every_overlapping_triangle() {
        let mut rng = crate::sampling::Rng::keyed(21, 0, 0);
        let mut p = || Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 4.0;
        let triangles: Vec<Triangle> = (0..2000)
            .map(|_| {
                let a = p();
                let d = Vec3::new(0.1, 0.0, 0.05);
                tri(a, a + d, a + Vec3::new(0.0, 0.08, 0.02))
            })
            .collect();
        let accel = Accel::build(&triangles);
        for i in 0..50 {
            let c = Vec3::splat(0.08 * i as f32);
            let (lo, hi) = (c - 0.3, c + 0.3);
            let mut seen = vec![0u32; triangles.len()];
            accel.for_each_near(lo, hi, |t| seen[t as usize] += 1);
            for (t, n) in triangles.iter().zip(&seen) {
                let (tlo, thi) = (t.p[0].min(t.p[1]).min(t.p[2]), t.p[0].max(t.p[1]).max(t.p[2]));
                let overlaps = tlo.cmple(hi).all() && thi.cmpge(lo).all();
                assert!(*n <= 1 && (!overlaps || *n == 1), "{t:?} overlaps {overlaps}, seen {n}");
            }
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

    /// Axis-aligned rays hit and are blocked whatever the sign of their zero components: a
    /// −0.0 once sent obvhs's traversal down the wrong octant (every such ray missed).
    #[test]
    fn rays_with_negative_zero_components_hit() {
        let square = |y: f32| {
            [
                tri(
                    Vec3::new(-1.0, y, -1.0),
                    Vec3::new(1.0, y, 1.0),
                    Vec3::new(1.0, y, -1.0),
                ),
                tri(
                    Vec3::new(-1.0, y, -1.0),
                    Vec3::new(-1.0, y, 1.0),
                    Vec3::new(1.0, y, 1.0),
                ),
            ]
        };
        let a = Accel::build(&[square(1.0), square(-1.0)].concat());
        let o = Vec3::new(0.3, 0.0, 0.2);
        for (x, z) in [(0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -0.0)] {
            for y in [1.0f32, -1.0] {
                let d = Vec3::new(x, y, z);
                let h = a.intersect(o, d, f32::INFINITY);
                assert!(h.is_some_and(|h| (h.t - 1.0).abs() < 1e-6), "{d:?}: {h:?}");
                assert!(a.occluded(o, d, f32::INFINITY), "{d:?}");
                assert!(a.occluded(o, d, 2.0) && !a.occluded(o, d, 0.5), "{d:?}");
            }
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
