//! Tangents for normal maps when a primitive has no TANGENT attribute: MikkTSpace's, which the
//! glTF specification asks for and which Blender's Normal Map node uses (Blender's exporter writes
//! no tangents by default, so a render matches Cycles only with the same tangent field).
//!
//! Follows Morten Mikkelsen's reference implementation (mikktspace.c, `genTangSpaceDefault`):
//!
//! * per triangle, the direction of increasing u (and of v) from positions and TEXCOORD_0
//!   (its equations 18 and 19); the triangle's orientation is the sign of its signed uv area,
//!   taken with v reversed (below);
//! * per corner, that direction projected onto the corner's normal and normalised *before* it is
//!   averaged, weighted by the corner's angle measured in the normal's plane;
//! * summed over all corners that share a vertex and have the same orientation, a vertex being
//!   a (position, normal, uv) value welded bit for bit (-0 = +0), not an index: a file may repeat
//!   a vertex under several indices and the reference welds them. Mirrored UVs meet at vertices
//!   of both orientations; keeping the two groups apart keeps the two tangents (averaging them
//!   would cancel them);
//! * the sum normalised (it stays orthogonal to the normal: every term is), w = +1 where the
//!   orientation is preserved (uv area > 0), −1 elsewhere; the renderer rebuilds the bitangent
//!   as w · n × t, so the reference's bitangent and magnitudes are not kept;
//! * triangles whose uv area or derivatives are zero contribute nothing (the reference's
//!   `GROUP_WITH_ANY`) and take the averaged tangents at their vertices.
//!
//! The uvs are those Blender runs MikkTSpace on: its v (= 1 − glTF's v, the exporter's flip)
//! runs up the image, as a normal map's +Y (green) does, where glTF's v runs down. Reversing v
//! leaves the tangent as it is and reverses the orientation, so w is the handedness Cycles
//! shades with and the one Blender's exporter writes into a TANGENT attribute (its
//! `bitangent_sign`, unchanged), which [`super::meshes`] keeps as it is: both agree. The other
//! choice (glTF's v) mirrors every normal map's green channel.
//!
//! Left out or simplified:
//!
//! * Groups: the reference groups, around a vertex, the same-orientation triangles that are
//!   connected through shared edges; here all same-orientation corners at a welded vertex form
//!   one group. They differ only where a vertex's fan has several separate runs of one
//!   orientation (orientation alternating around a vertex, or non-manifold vertices).
//! * The angular-threshold sub-groups: the default threshold (180°) never splits a group.
//! * Degenerate triangles: the reference drops triangles with two identical (welded) corners and
//!   copies into them the tangent space of the same vertex in the first good triangle (and has
//!   rules for quads with one such triangle); a triangle without usable derivatives joins the
//!   first group it meets. Here every triangle that does not contribute (zero uv or position
//!   area, repeated corners) takes the orientation with the larger angle sum over its corners'
//!   groups and, at each corner, that group's tangent (the other orientation's if that one is
//!   empty), else a tangent built from the normal alone.
//! * Quads: Blender hands quads and n-gons to MikkTSpace, which splits them and forces both
//!   halves of a quad to one orientation; glTF has triangles only, whose angle weights add up to
//!   the quad's corner angle for planar quads.
//! * Scope: welding runs per primitive; Blender computes tangents over a whole mesh, which the
//!   exporter splits into one primitive per material, so vertices on a material boundary are
//!   averaged over their own primitive's triangles only.
//! * Corners without a usable NORMAL (the flat normal stands in) are not welded: they keep their
//!   triangle's own tangent.

use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;

/// What [`generate`] made: the tangents and how many triangles needed a fallback.
pub(super) struct Generated {
    /// Per triangle, the tangents at its corners (unit xyz orthogonal to the corner's normal,
    /// handedness in w).
    pub(super) tangents: Vec<[Vec4; 3]>,
    /// Triangles that contribute nothing (degenerate uvs or positions) and took their tangents
    /// from the groups at their vertices.
    pub(super) from_neighbours: usize,
    /// Of those, the ones where some corner had no group to take from (tangent from the normal).
    pub(super) from_normal: usize,
}

/// One primitive's vertex data, as read from its accessors (object space).
pub(super) struct Mesh<'a> {
    pub(super) positions: &'a [Vec3],
    pub(super) normals: Option<&'a [Vec3]>,
    pub(super) uvs: &'a [Vec2],
    pub(super) tris: &'a [[u32; 3]],
}

/// What a triangle contributes: its u direction and orientation.
#[derive(Clone, Copy)]
struct Face {
    /// Unit direction of increasing u; zero where undefined.
    os: Vec3,
    /// The flat normal; zero for a zero-area triangle.
    flat: Vec3,
    /// Signed uv area > 0, v reversed (MikkTSpace's `ORIENT_PRESERVING` on Blender's uvs).
    preserving: bool,
    /// Contributes to its vertices' groups (nonzero uv and position area, valid corners).
    good: bool,
}

/// MikkTSpace-equivalent tangents for `mesh` (see the module's documentation).
pub(super) fn generate(mesh: &Mesh) -> Generated {
    let faces: Vec<Face> = mesh.tris.par_iter().map(|t| face(mesh, t)).collect();
    let class = weld(mesh);
    let slots = 2 * (class.iter().copied().max().map_or(0, |m| m as usize + 1));
    let (start, members) = group_members(mesh, &faces, &class, slots);
    // Per group: the angle-weighted sum of projected tangents (xyz) and the angle sum (w).
    let sums: Vec<Vec4> = (0..slots)
        .into_par_iter()
        .map(|s| {
            members[start[s] as usize..start[s + 1] as usize]
                .iter()
                .map(|&c| contribution(mesh, &faces, c as usize))
                .sum()
        })
        .collect();
    let per_face: Vec<([Vec4; 3], u8)> = mesh
        .tris
        .par_iter()
        .zip(faces.par_iter())
        .map(|(t, f)| resolve(mesh, t, f, &class, &sums))
        .collect();
    let from_neighbours = per_face.iter().filter(|(_, k)| *k >= 1).count();
    let from_normal = per_face.iter().filter(|(_, k)| *k == 2).count();
    Generated {
        tangents: per_face.into_iter().map(|(t, _)| t).collect(),
        from_neighbours,
        from_normal,
    }
}

/// A triangle's u direction, flat normal and orientation (`InitTriInfo` in the reference).
fn face(mesh: &Mesh, t: &[u32; 3]) -> Face {
    let bad = Face {
        os: Vec3::ZERO,
        flat: Vec3::ZERO,
        preserving: true,
        good: false,
    };
    let p = t.map(|i| mesh.positions.get(i as usize).copied());
    let uv = t.map(|i| mesh.uvs.get(i as usize).copied());
    let (Some(p0), Some(p1), Some(p2), Some(t0), Some(t1), Some(t2)) = (p[0], p[1], p[2], uv[0], uv[1], uv[2]) else {
        return bad;
    };
    let (e1, e2) = (p1 - p0, p2 - p0);
    // Blender's uvs: v reversed (see the module's documentation).
    let (d1, d2) = ((t1 - t0) * Vec2::new(1.0, -1.0), (t2 - t0) * Vec2::new(1.0, -1.0));
    let area = d1.x * d2.y - d1.y * d2.x;
    let flat = e1.cross(e2).normalize_or_zero();
    // Equations 18 and 19, before the division by the uv area (whose sign is the orientation).
    let os = e1 * d2.y - e2 * d1.y;
    let ot = e2 * d1.x - e1 * d2.x;
    let preserving = area > 0.0;
    let sign = if preserving { 1.0 } else { -1.0 };
    let os = (os * sign).normalize_or_zero();
    let ot = (ot * sign).normalize_or_zero();
    let repeated = t[0] == t[1] || t[1] == t[2] || t[2] == t[0];
    let good =
        area != 0.0 && area.is_finite() && os != Vec3::ZERO && ot != Vec3::ZERO && flat != Vec3::ZERO && !repeated;
    Face {
        os,
        flat,
        preserving,
        good,
    }
}

/// The file's normal at vertex `i`, normalised, if it is usable; corners without one take the
/// flat normal and are not welded.
fn file_normal(mesh: &Mesh, i: u32) -> Option<Vec3> {
    let n = mesh.normals?.get(i as usize).copied()?;
    let n = n.normalize_or_zero();
    (n.is_finite() && n != Vec3::ZERO).then_some(n)
}

/// The normal a corner's tangent is made orthogonal to: the file's, else the flat one.
fn corner_normal(mesh: &Mesh, face: &Face, i: u32) -> Vec3 {
    file_normal(mesh, i).unwrap_or(face.flat)
}

/// Per vertex index, the id of its (position, normal, uv) value: equal values, equal ids. A
/// parallel sort of the indices by value, so linear memory and no hashing of floats.
fn weld(mesh: &Mesh) -> Vec<u32> {
    let n = mesh.positions.len();
    // + 0.0 turns -0 into +0, which compare equal as floats (the reference compares floats).
    let bits = |x: f32| (x + 0.0).to_bits();
    let key = |i: u32| -> [u32; 8] {
        let p = mesh.positions[i as usize];
        let nr = mesh
            .normals
            .and_then(|ns| ns.get(i as usize))
            .copied()
            .unwrap_or(Vec3::ZERO);
        let uv = mesh.uvs.get(i as usize).copied().unwrap_or(Vec2::ZERO);
        [p.x, p.y, p.z, nr.x, nr.y, nr.z, uv.x, uv.y].map(bits)
    };
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.par_sort_unstable_by_key(|&i| key(i));
    let mut class = vec![0u32; n];
    let mut id = 0u32;
    for w in 1..n {
        if key(order[w]) != key(order[w - 1]) {
            id += 1;
        }
        class[order[w] as usize] = id;
    }
    class
}

/// The group (slot) of a corner: welded vertex × orientation; None for corners that are not
/// welded (no usable normal).
fn slot(mesh: &Mesh, class: &[u32], i: u32, preserving: bool) -> Option<usize> {
    file_normal(mesh, i)?;
    Some(2 * *class.get(i as usize)? as usize + usize::from(preserving))
}

/// The contributing corners (3 · triangle + corner) of each group, as a counting sort: group `s`
/// has `members[start[s]..start[s + 1]]`.
fn group_members(mesh: &Mesh, faces: &[Face], class: &[u32], slots: usize) -> (Vec<u32>, Vec<u32>) {
    let corner_slots = |f: usize| -> [Option<usize>; 3] {
        let face = &faces[f];
        if !face.good {
            return [None; 3];
        }
        mesh.tris[f].map(|i| slot(mesh, class, i, face.preserving))
    };
    let mut start = vec![0u32; slots + 1];
    for f in 0..faces.len() {
        for s in corner_slots(f).into_iter().flatten() {
            start[s + 1] += 1;
        }
    }
    for s in 0..slots {
        start[s + 1] += start[s];
    }
    let mut fill = start.clone();
    let mut members = vec![0u32; start[slots] as usize];
    for f in 0..faces.len() {
        for (k, s) in corner_slots(f).into_iter().enumerate() {
            if let Some(s) = s {
                members[fill[s] as usize] = (3 * f + k) as u32;
                fill[s] += 1;
            }
        }
    }
    (start, members)
}

/// A corner's share of its group: the triangle's u direction projected onto the corner's normal
/// and normalised, times the corner's angle in the normal's plane (xyz), and that angle (w).
fn contribution(mesh: &Mesh, faces: &[Face], corner: usize) -> Vec4 {
    let (f, k) = (corner / 3, corner % 3);
    let t = mesh.tris[f];
    let n = corner_normal(mesh, &faces[f], t[k]);
    let os = project(faces[f].os, n);
    let p = |j: usize| mesh.positions[t[j] as usize];
    let v1 = project(p((k + 2) % 3) - p(k), n);
    let v2 = project(p((k + 1) % 3) - p(k), n);
    let angle = v1.dot(v2).clamp(-1.0, 1.0).acos();
    (os * angle).extend(angle)
}

/// `v` without its component along the unit `n`, normalised (zero if nothing is left).
fn project(v: Vec3, n: Vec3) -> Vec3 {
    (v - n * n.dot(v)).normalize_or_zero()
}

/// A triangle's corner tangents from the group sums, and which fallback it needed: 0 none, 1 its
/// vertices' groups (a triangle that contributes nothing), 2 the normal alone at some corner.
fn resolve(mesh: &Mesh, t: &[u32; 3], face: &Face, class: &[u32], sums: &[Vec4]) -> ([Vec4; 3], u8) {
    let group = |i: u32, preserving: bool| slot(mesh, class, i, preserving).map_or(Vec4::ZERO, |s| sums[s]);
    let preserving = if face.good {
        face.preserving
    } else {
        // The orientation with more (angle) weight around the triangle's corners.
        let weight = |o: bool| t.iter().map(|&i| group(i, o).w).sum::<f32>();
        weight(true) >= weight(false)
    };
    let w = if preserving { 1.0 } else { -1.0 };
    let mut level = u8::from(!face.good);
    let tangents = t.map(|i| {
        let n = corner_normal(mesh, face, i);
        let own = if face.good && slot(mesh, class, i, preserving).is_none() {
            project(face.os, n) // not welded: the triangle's own tangent
        } else {
            let mut s = group(i, preserving).truncate();
            if s == Vec3::ZERO && !face.good {
                s = group(i, !preserving).truncate();
            }
            project(s, n)
        };
        if own != Vec3::ZERO {
            own.extend(w)
        } else {
            level = 2;
            normal_frame(n).extend(w)
        }
    });
    (tangents, level)
}

/// A unit vector orthogonal to `n` (any: no uv direction is known), or x for a zero normal.
fn normal_frame(n: Vec3) -> Vec3 {
    let n = n.normalize_or_zero();
    if n == Vec3::ZERO {
        Vec3::X
    } else {
        n.any_orthonormal_vector()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn run(positions: &[Vec3], normals: Option<&[Vec3]>, uvs: &[Vec2], tris: &[[u32; 3]]) -> Generated {
        generate(&Mesh {
            positions,
            normals,
            uvs,
            tris,
        })
    }

    /// The rule before MikkTSpace: each triangle's own u direction, orthogonalised against each
    /// corner's normal, w from n × t against the v direction; None when degenerate.
    fn per_triangle_rule(positions: &[Vec3], normals: &[Vec3], uvs: &[Vec2], t: [u32; 3]) -> Option<[Vec4; 3]> {
        let p = t.map(|i| positions[i as usize]);
        let uv = t.map(|i| uvs[i as usize]);
        let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
        let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
        let det = d1.x * d2.y - d2.x * d1.y;
        if !(det.abs() > 0.0) {
            return None;
        }
        let tangent = (e1 * d2.y - e2 * d1.y) / det;
        let bitangent = (e2 * d1.x - e1 * d2.x) / det;
        let mut out = [Vec4::ZERO; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let n = normals[t[k] as usize].normalize();
            let tn = (tangent - n * n.dot(tangent)).normalize_or_zero();
            let w = if n.cross(tn).dot(bitangent) < 0.0 { -1.0 } else { 1.0 };
            *o = tn.extend(w);
        }
        Some(out)
    }

    /// A smooth UV sphere of radius 1 as Blender builds it: `rings` × `segments` quads, a seam
    /// column of duplicated vertices at u = 1, one pole vertex per segment, outward winding,
    /// normals = positions, v growing downwards (glTF).
    fn uv_sphere(segments: u32, rings: u32) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec2>, Vec<[u32; 3]>) {
        let (mut p, mut uv, mut tris) = (Vec::new(), Vec::new(), Vec::new());
        for r in 0..=rings {
            for s in 0..=segments {
                let theta = std::f64::consts::PI * r as f64 / rings as f64;
                let phi = std::f64::consts::TAU * s as f64 / segments as f64;
                let q = [theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()];
                p.push(Vec3::from(q.map(|x| x as f32)));
                uv.push(Vec2::new(s as f32 / segments as f32, r as f32 / rings as f32));
            }
        }
        for r in 0..rings {
            for s in 0..segments {
                let a = r * (segments + 1) + s;
                let (b, c) = (a + 1, a + segments + 1);
                if r > 0 {
                    tris.push([a, b, c]);
                }
                if r + 1 < rings {
                    tris.push([b, c + 1, c]);
                }
            }
        }
        let n = p.iter().map(|q| q.normalize()).collect();
        (p, n, uv, tris)
    }

    fn assert_unit_and_orthogonal(t: Vec4, n: Vec3) {
        assert!(t.is_finite(), "{t}");
        assert!((t.truncate().length() - 1.0).abs() < 1e-5, "not unit: {t}");
        assert!(
            t.truncate().dot(n.normalize()).abs() < 1e-5,
            "not orthogonal to {n}: {t}"
        );
        assert!(t.w == 1.0 || t.w == -1.0, "{t}");
    }

    /// The largest difference between the tangents of corners at one vertex index.
    fn spread_at_shared_vertices(tris: &[[u32; 3]], tangents: &[[Vec4; 3]]) -> f32 {
        let mut first = std::collections::HashMap::new();
        let mut spread = 0.0f32;
        for (t, ts) in tris.iter().zip(tangents) {
            for k in 0..3 {
                let seen = *first.entry(t[k]).or_insert(ts[k]);
                spread = spread.max((seen - ts[k]).length());
            }
        }
        spread
    }

    #[test]
    fn smooth_sphere_corners_at_a_shared_vertex_get_one_tangent() {
        let (p, n, uv, tris) = uv_sphere(24, 12);
        let g = run(&p, Some(&n), &uv, &tris);
        assert_eq!((g.from_neighbours, g.from_normal), (0, 0));
        for (t, ts) in tris.iter().zip(&g.tangents) {
            for k in 0..3 {
                assert_unit_and_orthogonal(ts[k], n[t[k] as usize]);
            }
        }
        assert!(spread_at_shared_vertices(&tris, &g.tangents) < 1e-6);
        // Per triangle, the tangents at a shared vertex differ (the seams a normal map showed).
        let old: Vec<[Vec4; 3]> = tris
            .iter()
            .map(|&t| per_triangle_rule(&p, &n, &uv, t).unwrap())
            .collect();
        assert!(spread_at_shared_vertices(&tris, &old) > 1e-2);
        // Away from the poles and the uv seam (whose vertices see triangles on one side only)
        // the average is the sphere's own u direction (increasing φ).
        for (t, ts) in tris.iter().zip(&g.tangents) {
            for k in 0..3 {
                let (q, u) = (p[t[k] as usize], uv[t[k] as usize].x);
                if q.y.abs() < 0.9 && u > 0.0 && u < 1.0 {
                    let analytic = Vec3::new(-q.z, 0.0, q.x).normalize();
                    assert!(ts[k].truncate().dot(analytic) > 0.9995, "{q}: {}", ts[k]);
                }
            }
        }
    }

    #[test]
    fn vertices_are_welded_by_value_not_by_index() {
        let (p, n, uv, tris) = uv_sphere(16, 8);
        let indexed = run(&p, Some(&n), &uv, &tris);
        // Every corner its own vertex: the same values under different indices.
        let corners: Vec<u32> = tris.iter().flatten().copied().collect();
        let take = |v: &[Vec3]| corners.iter().map(|&i| v[i as usize]).collect::<Vec<_>>();
        let (p2, n2) = (take(&p), take(&n));
        let uv2: Vec<Vec2> = corners.iter().map(|&i| uv[i as usize]).collect();
        let tris2: Vec<[u32; 3]> = (0..tris.len() as u32).map(|f| [3 * f, 3 * f + 1, 3 * f + 2]).collect();
        let unindexed = run(&p2, Some(&n2), &uv2, &tris2);
        for (a, b) in indexed.tangents.iter().zip(&unindexed.tangents) {
            for k in 0..3 {
                assert!((a[k] - b[k]).length() < 1e-6, "{} vs {}", a[k], b[k]);
            }
        }
    }

    #[test]
    fn flat_quad_keeps_the_per_triangle_tangent() {
        let p = [
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let n = [Vec3::Z; 4];
        let tris = [[0, 1, 2], [0, 2, 3]];
        // A rotated, stretched mapping with glTF's v running down the image as y goes up (as
        // Blender exports an unmirrored one: handedness +1), and the same mirrored (−1).
        for flip in [1.0, -1.0] {
            let uv: Vec<Vec2> = p
                .iter()
                .map(|q| Vec2::new(0.3 * q.x + 0.2 * q.y, 1.0 - flip * (0.5 * q.y - 0.1 * q.x)))
                .collect();
            let g = run(&p, Some(&n), &uv, &tris);
            for (f, &t) in tris.iter().enumerate() {
                let old = per_triangle_rule(&p, &n, &uv, t).unwrap();
                for k in 0..3 {
                    let new = g.tangents[f][k];
                    assert!(
                        (new.truncate() - old[k].truncate()).length() < 1e-6,
                        "{new} vs {}",
                        old[k]
                    );
                    // The old rule's handedness took v down the image (see the module's doc).
                    assert_eq!((new.w, old[k].w), (flip, -flip));
                }
            }
        }
    }

    #[test]
    fn mirrored_uvs_keep_two_handedness_groups() {
        // A strip x ∈ [−1, 1] whose left half maps u = −x (mirrored), right half u = x, v down
        // the image; the two vertices at x = 0 are shared by both halves.
        let p: Vec<Vec3> = (0..6)
            .map(|i| Vec3::new((i % 3) as f32 - 1.0, (i / 3) as f32, 0.0))
            .collect();
        let n = vec![Vec3::Z; 6];
        let uv: Vec<Vec2> = p.iter().map(|q| Vec2::new(q.x.abs(), 1.0 - q.y)).collect();
        let tris = [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]];
        let g = run(&p, Some(&n), &uv, &tris);
        for (f, ts) in g.tangents.iter().enumerate() {
            // Left (mirrored): tangent −x, w −1; right: +x, w +1 — at the shared vertices too.
            let (dir, w) = if f < 2 { (-Vec3::X, -1.0) } else { (Vec3::X, 1.0) };
            for t in ts {
                assert!((t.truncate() - dir).length() < 1e-6 && t.w == w, "triangle {f}: {t}");
            }
        }
        // The old rule's tangents (no averaging across the mirror seam), its handedness reversed.
        for (f, &t) in tris.iter().enumerate() {
            let old = per_triangle_rule(&p, &n, &uv, t).unwrap();
            for k in 0..3 {
                let new = g.tangents[f][k];
                assert!(
                    (new - old[k] * Vec4::new(1.0, 1.0, 1.0, -1.0)).length() < 1e-6,
                    "{new} vs {}",
                    old[k]
                );
            }
        }
    }

    #[test]
    fn bitangent_points_up_the_image_as_a_normal_maps_green() {
        // A quad facing +z mapped as Blender exports an image seen the right way up: u along
        // +x, glTF's v running down the image, so up the image is +y.
        let p = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        let n = [Vec3::Z; 4];
        let uv: Vec<Vec2> = p.iter().map(|q| Vec2::new(q.x, 1.0 - q.y)).collect();
        let g = run(&p, Some(&n), &uv, &[[0, 1, 2], [0, 2, 3]]);
        for t in g.tangents.iter().flatten() {
            // Cycles' Normal Map node and the renderer: bitangent = w · n × t, the map's +Y.
            let bitangent = Vec3::Z.cross(t.truncate()) * t.w;
            assert!((t.truncate() - Vec3::X).length() < 1e-6, "{t}");
            assert!((bitangent - Vec3::Y).length() < 1e-6, "{t}");
        }
    }

    #[test]
    fn degenerate_uv_triangles_get_a_finite_unit_tangent() {
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::Y,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(5.0, 0.0, 0.0),
            Vec3::new(6.0, 0.0, 0.0),
            Vec3::new(5.0, 1.0, 0.0),
        ];
        let n = vec![Vec3::Z; p.len()];
        let mut uv: Vec<Vec2> = p.iter().map(|q| Vec2::new(q.x, 1.0 - q.y)).collect();
        // Triangle [1, 4, 2] gets a zero uv area: vertex 4's uv on the line from 1's to 2's.
        uv[4] = Vec2::new(1.0, 0.5);
        // An isolated triangle with all uvs equal: nothing to take from, the normal's frame.
        uv[5] = Vec2::splat(0.25);
        uv[6] = Vec2::splat(0.25);
        uv[7] = Vec2::splat(0.25);
        let tris = [[0, 1, 2], [0, 2, 3], [1, 4, 2], [5, 6, 7], [0, 0, 1], [0, 1, 9]];
        let g = run(&p, Some(&n), &uv, &tris);
        for ts in &g.tangents {
            for t in ts {
                assert_unit_and_orthogonal(*t, Vec3::Z);
            }
        }
        // The attached degenerate triangle takes the quad's tangent (x) at the shared vertices.
        assert!((g.tangents[2][0] - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-6);
        assert!((g.tangents[2][2] - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-6);
        assert_eq!((g.from_neighbours, g.from_normal), (4, 3));
    }

    proptest! {
        #[test]
        fn any_mesh_gives_finite_unit_tangents(
            verts in prop::collection::vec((-2i8..3, -2i8..3, -2i8..3, -1i8..2, -1i8..2, 0i8..3, 0i8..3), 1..10),
            with_normals in any::<bool>(),
            idx in prop::collection::vec(0u32..12, 0..30),
        ) {
            let p: Vec<Vec3> = verts.iter().map(|v| Vec3::new(v.0 as f32, v.1 as f32, v.2 as f32)).collect();
            let n: Vec<Vec3> = verts.iter().map(|v| Vec3::new(v.3 as f32, v.4 as f32, 0.5 * v.3 as f32)).collect();
            let uv: Vec<Vec2> = verts.iter().map(|v| Vec2::new(v.5 as f32 * 0.5, v.6 as f32)).collect();
            let tris: Vec<[u32; 3]> = idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            let g = run(&p, with_normals.then_some(&n[..]), &uv, &tris);
            prop_assert_eq!(g.tangents.len(), tris.len());
            for t in g.tangents.iter().flatten() {
                prop_assert!(t.is_finite() && (t.truncate().length() - 1.0).abs() < 1e-5, "{}", t);
                prop_assert!(t.w == 1.0 || t.w == -1.0);
            }
        }
    }
}
