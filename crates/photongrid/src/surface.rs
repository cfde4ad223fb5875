//! What a ray hit: position, normals oriented to the side the ray came from, texture
//! coordinates, and the material's albedo there.

use crate::accel::Hit;
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
