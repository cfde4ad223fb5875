//! What a ray hit: position, normals oriented to the side the ray came from, texture
//! coordinates, and the material's albedo there.

use crate::accel::{Hit, Leaving, Origin};
use crate::scene::{Scene, Surface};
use crate::Rgb;
use glam::{Vec2, Vec3, Vec4};

/// Local geometry at a ray hit.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// World position (on the triangle, from barycentrics: more precise than o + t·d).
    pub position: Vec3,
    /// Unit geometric normal of the triangle's front face.
    pub geometric_normal: Vec3,
    /// Geometric normal flipped to face the incoming ray.
    pub facing_normal: Vec3,
    /// Interpolated shading normal, normal-mapped where the material has a normal map, flipped
    /// to the same side as `facing_normal`.
    pub facing_shading_normal: Vec3,
    /// The interpolated normal before any normal map, on the same side (equal to
    /// `facing_shading_normal` without a normal map; see [`crate::bsdf::bump`]).
    pub facing_smooth_normal: Vec3,
    /// True if the ray hit the back face.
    pub backface: bool,
    /// Texture coordinates.
    pub uv: Vec2,
    /// Material index.
    pub material: u32,
    /// Triangle index.
    pub triangle: u32,
    /// How far ray origins leaving this point are moved off the surface ([`offset_eps`] of
    /// the largest coordinate of the point and its triangle's vertices).
    pub eps: f32,
}

/// Ray-origin offsets relative to the float precision of a point: a 32-bit float carries 24
/// bits, and a hit position computed from a triangle's vertices — and the BVH's own
/// intersection test of that triangle — err by a few units in the last place of the largest
/// coordinate involved. 2⁻¹⁶ of it (256 units in the last place) clears that with a wide
/// margin, at any distance from the origin and any scene scale.
pub const OFFSET_REL_POSITION: f32 = 1.0 / 65536.0;
/// Floor of the offsets relative to the scene: 10⁻⁶ of its bounding-box diagonal (for points
/// near the origin, where the precision term vanishes).
pub const OFFSET_REL_SCENE: f32 = 1e-6;

/// The offset off a surface for a point whose coordinates (and its triangle's vertices') are at
/// most `magnitude` in absolute value, in a scene of diagonal `scene_diagonal`. Both terms
/// scale with the scene: a scene rendered at 10⁻⁷ or 10⁹ times its size gets the same image.
pub fn offset_eps(magnitude: f32, scene_diagonal: f32) -> f32 {
    let d = if scene_diagonal.is_finite() {
        scene_diagonal
    } else {
        0.0
    };
    magnitude * OFFSET_REL_POSITION + d * OFFSET_REL_SCENE
}

/// Where a shadow ray from a point of coordinates at most `magnitude` (already moved off its
/// surface by [`SurfacePoint::offset`]) must stop before a light `distance` away, so as not to
/// hit the surface the light lies on: the segment is shortened by the offset at the light's end.
pub fn shadow_tmax(magnitude: f32, distance: f32, scene_diagonal: f32) -> f32 {
    if !distance.is_finite() {
        return f32::INFINITY;
    }
    (distance - offset_eps(magnitude + distance, scene_diagonal)).max(0.0)
}

impl SurfacePoint {
    /// Build from a hit of the ray `origin + t·dir`.
    pub fn new(scene: &Scene, origin: Vec3, dir: Vec3, hit: Hit) -> Self {
        let tri = &scene.triangles[hit.triangle as usize];
        let e1 = tri.p[1] - tri.p[0];
        let e2 = tri.p[2] - tri.p[0];
        let pvec = dir.cross(e2);
        let det = e1.dot(pvec);
        let (b1, b2) = if det.abs() > 0.0 {
            let inv = 1.0 / det;
            let tvec = origin - tri.p[0];
            let qvec = tvec.cross(e1);
            let u = (tvec.dot(pvec) * inv).clamp(0.0, 1.0);
            let v = (dir.dot(qvec) * inv).clamp(0.0, 1.0 - u);
            (u, v)
        } else {
            (1.0 / 3.0, 1.0 / 3.0)
        };
        let position = tri.p[0] + e1 * b1 + e2 * b2;
        let magnitude = tri
            .p
            .iter()
            .fold(position.abs().max_element(), |m, p| m.max(p.abs().max_element()));
        let ng = e1.cross(e2).normalize();
        let backface = dir.dot(ng) > 0.0;
        let facing = if backface { -ng } else { ng };
        let mut ns = tri.lerp(tri.n, b1, b2).normalize_or_zero();
        if ns == Vec3::ZERO {
            ns = ng;
        }
        let uv = tri.lerp(tri.uv, b1, b2);
        let smooth = if ns.dot(facing) < 0.0 { -ns } else { ns };
        if let Some(map) = &scene.materials[tri.material as usize].normal_map {
            if let Some(t) = scene.tangents.get(hit.triangle as usize) {
                let mapped = normal_mapped(
                    ns,
                    tri.lerp(*t, b1, b2),
                    map.texture.sample(&scene.textures, uv),
                    map.scale,
                );
                // glTF: a back face's normal is the front's reversed.
                ns = if backface { -mapped } else { mapped };
                if ns.dot(facing) <= 0.0 {
                    ns = facing; // bent below the surface: keep the geometry's normal
                }
            }
        }
        if ns.dot(facing) < 0.0 {
            ns = -ns;
        }
        SurfacePoint {
            position,
            geometric_normal: ng,
            facing_normal: facing,
            facing_shading_normal: ns,
            facing_smooth_normal: smooth,
            backface,
            uv,
            material: tri.material,
            triangle: hit.triangle,
            eps: offset_eps(magnitude, scene.bounds.diagonal()),
        }
    }

    /// Diffuse albedo (with texture) of a Lambert material; zero for others.
    pub fn albedo(&self, scene: &Scene) -> Rgb {
        match &scene.materials[self.material as usize].surface {
            Surface::Lambert { albedo, texture } => match texture {
                Some(t) => *albedo * t.sample(&scene.textures, self.uv).truncate(),
                None => *albedo,
            },
            _ => Rgb::ZERO,
        }
    }

    /// A start point for a ray leaving in `dir`, nudged off the surface to the side `dir` goes
    /// by [`SurfacePoint::eps`] (relative to the point's float precision and the scene's size).
    pub fn offset(&self, dir: Vec3) -> Vec3 {
        let n = if dir.dot(self.geometric_normal) >= 0.0 {
            self.geometric_normal
        } else {
            -self.geometric_normal
        };
        self.position + n * self.eps
    }

    /// Where a ray leaving this point along `dir` starts: offset to the side it leaves by
    /// ([`offset`](Self::offset)), and for a ray leaving by the front of the face (where a
    /// surface resting against it lies: under a glass's base, above a table's top), the point
    /// it leaves, so that such a surface is hit, not started inside ([`Leaving`]).
    pub fn leave(&self, dir: Vec3) -> Origin {
        Origin {
            point: self.offset(dir),
            leaving: (dir.dot(self.geometric_normal) > 0.0).then_some(Leaving {
                triangle: self.triangle,
                material: self.material,
                at: self.position,
            }),
        }
    }

    /// The largest coordinate of this point in absolute value (for [`shadow_tmax`]).
    pub fn magnitude(&self) -> f32 {
        self.position.abs().max_element()
    }

    /// Where a shadow ray leaving this point at [`SurfacePoint::offset`] must stop before a
    /// light sample `distance` away from [`SurfacePoint::position`]: the offset origin may lie
    /// up to [`SurfacePoint::eps`] closer to the light (a large triangle's offset exceeds the
    /// light's own margin, and the ray then hit the emitter it aimed at), so that is taken off
    /// as well as the margin at the light's end ([`shadow_tmax`]).
    pub fn shadow_tmax(&self, distance: f32, scene_diagonal: f32) -> f32 {
        (shadow_tmax(self.magnitude(), distance, scene_diagonal) - self.eps).max(0.0)
    }
}

/// The shading normal of a tangent-space normal map (glTF spec 3.9.3): the texel `c` read as
/// `(2c − 1) · (scale, scale, 1)` in the frame (T, B = (N × T) · w, N) of the interpolated
/// normal `n` and tangent `t` (Gram–Schmidt orthogonalised, as MikkTSpace expects). A zero
/// tangent leaves `n`.
pub fn normal_mapped(n: Vec3, t: Vec4, c: Vec4, scale: f32) -> Vec3 {
    let tt = t.truncate();
    let tt = (tt - n * n.dot(tt)).normalize_or_zero();
    if tt == Vec3::ZERO {
        return n;
    }
    let sign = if t.w < 0.0 { -1.0 } else { 1.0 };
    let b = n.cross(tt) * sign;
    let m = Vec3::new((2.0 * c.x - 1.0) * scale, (2.0 * c.y - 1.0) * scale, 2.0 * c.z - 1.0);
    let r = (tt * m.x + b * m.y + n * m.z).normalize_or_zero();
    if r == Vec3::ZERO {
        n
    } else {
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::Accel;
    use crate::scene::material::Material;
    use crate::scene::{Bounds, Triangle};
    use crate::test_util::test_rng;

    /// The faces of the box `lo`–`hi` (wound outwards) in `material`.
    fn cuboid(lo: Vec3, hi: Vec3, material: u32) -> Vec<Triangle> {
        let c = |i: usize| {
            Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            )
        };
        let faces = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let centre = 0.5 * (lo + hi);
        let mut out = Vec::new();
        for f in faces {
            for [a, b, d] in [[f[0], f[1], f[2]], [f[0], f[2], f[3]]] {
                let (pa, pb, pd) = (c(a), c(b), c(d));
                let n = (pb - pa).cross(pd - pa);
                let (pb, pd) = if n.dot((pa + pb + pd) / 3.0 - centre) < 0.0 {
                    (pd, pb)
                } else {
                    (pb, pd)
                };
                let n = (pb - pa).cross(pd - pa).normalize();
                out.push(Triangle {
                    p: [pa, pb, pd],
                    n: [n; 3],
                    uv: [Vec2::ZERO; 3],
                    material,
                });
            }
        }
        out
    }

    /// The first of the glass cube's triangles in [`glass_on_table`].
    const GLASS: u32 = 12;

    /// A table (a Lambert box, top at y = 1) with a glass cube standing `gap` above it.
    fn glass_on_table(gap: f32) -> Scene {
        // The table's diagonals are not the glass's (a ray through both edges could slip
        // between the triangles of either).
        let mut triangles = cuboid(Vec3::new(-2.0, 0.0, -1.5), Vec3::new(2.5, 1.0, 2.0), 0);
        triangles.extend(cuboid(
            Vec3::new(-0.5, 1.0 + gap, -0.5),
            Vec3::new(0.5, 2.0 + gap, 0.5),
            1,
        ));
        let mut bounds = Bounds::empty();
        triangles.iter().flat_map(|t| t.p).for_each(|p| bounds.grow(p));
        let glass = Material {
            surface: Surface::Dielectric {
                ior: 1.5,
                tint: Rgb::ONE,
                absorption: None,
            },
            ..Material::plain()
        };
        Scene {
            source: "glass_on_table.glb".into(),
            triangles,
            materials: vec![Material::plain(), glass],
            textures: vec![],
            tangents: vec![],
            glossy_roughness: 0.0,
            lights: vec![],
            cameras: vec![],
            bounds,
            report: Default::default(),
        }
    }

    /// Rays leaving the glass cube's base downwards, from points all over it (edges and the
    /// diagonal included) and at angles down to grazing: where they start and which way.
    fn exits(scene: &Scene, base: f32) -> Vec<(SurfacePoint, Vec3)> {
        let glass = Accel::build(&scene.triangles[GLASS as usize..]);
        let mut rng = test_rng(5);
        (0..4000)
            .filter_map(|i| {
                let p = Vec3::new(rng.uniform() - 0.5, base, rng.uniform() - 0.5);
                let p = if i % 4 == 0 { Vec3::new(p.x, base, p.x) } else { p }; // on the diagonal
                let d = Vec3::new(rng.uniform() - 0.5, -(0.12 + rng.uniform()), rng.uniform() - 0.5).normalize();
                // The ray inside the glass that reached p, from a point 1 mm before it. (Where
                // the glass stands on the table, the table's top and the glass's base are hit
                // at the same distance, and either may come first: the glass's is taken.)
                let o = p - d * 1e-3;
                if o.x.abs() >= 0.5 || o.z.abs() >= 0.5 {
                    return None;
                }
                let mut hit = glass.intersect(o, d, 1.0)?;
                hit.triangle += GLASS;
                let tri = &scene.triangles[hit.triangle as usize];
                (tri.cross().y < 0.0).then(|| (SurfacePoint::new(scene, o, d, hit), d))
            })
            .collect()
    }

    #[test]
    fn a_ray_leaving_the_base_of_a_glass_hits_the_table_it_stands_on() {
        let scene = glass_on_table(0.0);
        let accel = Accel::for_scene(&scene);
        // The glass's base (its two triangles facing down) and the table's top are in contact.
        let contact: Vec<usize> = (0..scene.triangles.len()).filter(|&i| accel.contact()[i]).collect();
        assert_eq!(contact.len(), 4);
        assert!(contact
            .iter()
            .all(|&i| (scene.triangles[i].cross().y < 0.0) == (i >= GLASS as usize)));
        let exits = exits(&scene, 1.0);
        assert!(exits.len() > 1000, "{}", exits.len());
        let mut tops = 0;
        for (sp, d) in &exits {
            let o = sp.leave(*d);
            let hit = accel.intersect_from(o, *d, f32::INFINITY).expect("the table");
            let t = &scene.triangles[hit.triangle as usize];
            assert!(t.material == 0 && t.cross().y > 0.0, "{t:?} from {sp:?}");
            assert!(
                (o.point + *d * hit.t - sp.position).length() < 4.0 * sp.eps,
                "{}",
                hit.t
            );
            // Offset past the face, the ray starts inside the table and misses its top.
            let o = sp.offset(*d);
            let past = accel.intersect(o, *d, f32::INFINITY);
            tops += usize::from(past.is_some_and(|h| (o + *d * h.t).y > 0.999));
        }
        assert_eq!(tops, 0);
    }

    #[test]
    fn light_coming_down_through_a_glass_crosses_its_base_before_the_table() {
        let scene = glass_on_table(0.0);
        let accel = Accel::for_scene(&scene);
        let mut tables = 0;
        // Rays through the base's diagonal, the edge its two triangles share, are left out:
        // there a ray may slip between the two (one triangle is tested at a time).
        let exits = exits(&scene, 1.0);
        let off_edge: Vec<_> = exits
            .iter()
            .filter(|(sp, _)| (sp.position.x - sp.position.z).abs() > 1e-4)
            .collect();
        assert!(off_edge.len() > 2000, "{}", off_edge.len());
        for (sp, d) in off_edge {
            // The same ray inside the glass, traced against the whole scene: the table's top
            // lies in the base's plane, at the same distance.
            let o = sp.position - *d * 1e-3;
            let hit = accel.intersect(o, *d, f32::INFINITY).expect("the base");
            tables += usize::from(hit.triangle < GLASS);
            assert!((o + *d * hit.t - sp.position).length() < 4.0 * sp.eps, "{}", hit.t);
        }
        // A table's top hit first would take the light out of the glass without refraction or
        // Fresnel, as if the two were one optical medium (without BEHIND_GLASS: 2543 of these rays).
        assert_eq!(tables, 0);
    }

    #[test]
    fn light_the_table_reflects_under_a_glass_enters_the_glass_through_its_base() {
        let scene = glass_on_table(0.0);
        let accel = Accel::for_scene(&scene);
        let table = Accel::build(&scene.triangles[..GLASS as usize]);
        let mut rng = test_rng(6);
        let (mut entered, mut offset_entered) = (0, 0);
        for _ in 0..2000 {
            let p = Vec3::new(0.98 * (rng.uniform() - 0.5), 1.0, 0.98 * (rng.uniform() - 0.5));
            // A ray from above, inside the glass, that reached the table's top at p.
            let o = p + Vec3::Y * 1e-3;
            let hit = table.intersect(o, -Vec3::Y, 1.0).expect("the table");
            let sp = SurfacePoint::new(&scene, o, -Vec3::Y, hit);
            let up = Vec3::new(rng.uniform() - 0.5, 0.2 + rng.uniform(), rng.uniform() - 0.5).normalize();
            let is_base = |h: Option<Hit>| {
                h.is_some_and(|h| h.triangle >= GLASS && scene.triangles[h.triangle as usize].cross().y < 0.0)
            };
            entered += usize::from(is_base(accel.intersect_from(sp.leave(up), up, f32::INFINITY)));
            offset_entered += usize::from(is_base(accel.intersect(sp.offset(up), up, f32::INFINITY)));
        }
        // Every such ray enters through the base; offset off the table, none did.
        assert_eq!((entered, offset_entered), (2000, 0));
    }

    #[test]
    fn a_ray_leaving_a_glass_above_a_table_meets_no_glass_and_the_table_where_it_is() {
        let gap = 0.01;
        let scene = glass_on_table(gap);
        let accel = Accel::for_scene(&scene);
        assert!(accel.contact().iter().all(|c| !c));
        for (sp, d) in exits(&scene, 1.0 + gap) {
            let o = sp.leave(d);
            let hit = accel.intersect_from(o, d, f32::INFINITY).expect("the table");
            let t = &scene.triangles[hit.triangle as usize];
            assert!(t.material == 0 && t.cross().y > 0.0, "{t:?} from {sp:?} along {d}");
            let at = o.point + d * hit.t;
            assert!(
                (at - sp.position).length() > 0.9 * gap && (at.y - 1.0).abs() < 1e-5,
                "{at}"
            );
        }
    }

    #[test]
    fn flat_normal_map_keeps_the_normal_and_a_tilt_follows_the_tangent() {
        let n = Vec3::Z;
        let t = Vec4::new(1.0, 0.0, 0.0, 1.0);
        // The flat texel (0.5, 0.5, 1) (128/255 ≈ 0.502 in 8 bits).
        let flat = normal_mapped(n, t, Vec4::new(0.5, 0.5, 1.0, 1.0), 1.0);
        assert!((flat - n).length() < 1e-6);
        // +X in the texel tilts towards the tangent, +Y towards the bitangent N × T = +Y.
        let tilt = normal_mapped(
            n,
            t,
            Vec4::new(1.0, 0.5, 0.5 + 0.5 * 0.5f32.sqrt() * 2.0 / 2.0, 1.0),
            1.0,
        );
        assert!(tilt.x > 0.5 && tilt.y.abs() < 1e-6, "{tilt}");
        let up = normal_mapped(n, t, Vec4::new(0.5, 1.0, 1.0, 1.0), 1.0);
        assert!((up - Vec3::new(0.0, 1.0, 1.0).normalize()).length() < 1e-5, "{up}");
        // Handedness −1 mirrors the bitangent.
        let down = normal_mapped(n, Vec4::new(1.0, 0.0, 0.0, -1.0), Vec4::new(0.5, 1.0, 1.0, 1.0), 1.0);
        assert!(down.y < -0.5, "{down}");
        // Scale 0 flattens.
        let s0 = normal_mapped(n, t, Vec4::new(1.0, 1.0, 1.0, 1.0), 0.0);
        assert!((s0 - n).length() < 1e-6);
    }
}
