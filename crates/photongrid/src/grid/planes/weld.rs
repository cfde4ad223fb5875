//! Welding vertex positions, so that triangles that touch are connected although glTF exports
//! duplicate the vertices of every face.

use super::geometry::NO_PLANE;
use glam::{DVec3, Vec3};
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Small, fast, non-cryptographic hasher (FxHash) for the position maps.
#[derive(Default, Clone, Copy)]
struct FxHasher(u64);

impl FxHasher {
    #[inline]
    fn add(&mut self, w: u64) {
        self.0 = (self.0.rotate_left(5) ^ w).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

impl Hasher for FxHasher {
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            self.add(u64::from_le_bytes(b));
        }
    }
    fn write_u32(&mut self, i: u32) {
        self.add(i as u64);
    }
    fn write_u64(&mut self, i: u64) {
        self.add(i);
    }
    fn write_i64(&mut self, i: i64) {
        self.add(i as u64);
    }
    fn write_usize(&mut self, i: usize) {
        self.add(i as u64);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

type FxMap<K, V> = HashMap<K, V, BuildHasherDefault<FxHasher>>;

/// Welds vertex positions within `tol`: returns per triangle its three welded vertex ids
/// (`NO_PLANE` for the triangles `degenerate` names) and the number of welded vertices.
pub(super) fn weld(triangles: &[[Vec3; 3]], degenerate: impl Fn(usize) -> bool, tol: f64) -> (Vec<[u32; 3]>, usize) {
    let (upos, corner) = distinct_positions(triangles, degenerate);
    let (compact, nv) = cluster_positions(&upos, tol);
    let tri_verts = corner
        .iter()
        .map(|c| {
            if c[0] == NO_PLANE {
                [NO_PLANE; 3]
            } else {
                c.map(|id| compact[id as usize])
            }
        })
        .collect();
    (tri_verts, nv as usize)
}

/// Exact duplicates (bitwise, with -0.0 == 0.0): the distinct positions, and per triangle the
/// ids of its corners among them (`NO_PLANE` for degenerate triangles).
fn distinct_positions(triangles: &[[Vec3; 3]], degenerate: impl Fn(usize) -> bool) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut exact: FxMap<(u32, u32, u32), u32> = FxMap::default();
    exact.reserve(triangles.len() * 3 / 2 + 1);
    let mut upos: Vec<DVec3> = Vec::new();
    let mut corner: Vec<[u32; 3]> = vec![[NO_PLANE; 3]; triangles.len()];
    for (t, tri) in triangles.iter().enumerate() {
        if degenerate(t) {
            continue;
        }
        for k in 0..3 {
            let p = tri[k] + Vec3::ZERO; // -0.0 + 0.0 == +0.0
            let key = (p.x.to_bits(), p.y.to_bits(), p.z.to_bits());
            let id = *exact.entry(key).or_insert_with(|| {
                upos.push(p.as_dvec3());
                (upos.len() - 1) as u32
            });
            corner[t][k] = id;
        }
    }
    (upos, corner)
}

/// Near duplicates: greedy clustering in index order on a uniform grid of cell size `tol`.
/// A position joins the first existing cluster representative within `tol` (searched in the
/// 27 surrounding cells), otherwise it becomes a new representative. Unlike a transitive
/// union, this never chains a dense run of vertices into one huge cluster (cluster diameter
/// ≤ 2·tol). Returns the cluster of every position and the number of clusters.
fn cluster_positions(upos: &[DVec3], tol: f64) -> (Vec<u32>, u32) {
    let cell_of = |p: DVec3| -> (i64, i64, i64) {
        let q = (p / tol).floor();
        (q.x as i64, q.y as i64, q.z as i64)
    };
    let mut reps: FxMap<(i64, i64, i64), Vec<u32>> = FxMap::default();
    let mut compact = vec![NO_PLANE; upos.len()];
    let mut nv = 0u32;
    let tol2 = tol * tol;
    for (i, &p) in upos.iter().enumerate() {
        let k = cell_of(p);
        let mut found = NO_PLANE;
        'search: for dx in -1i64..=1 {
            for dy in -1i64..=1 {
                for dz in -1i64..=1 {
                    let nk = (k.0.wrapping_add(dx), k.1.wrapping_add(dy), k.2.wrapping_add(dz));
                    if let Some(list) = reps.get(&nk) {
                        for &j in list {
                            if upos[j as usize].distance_squared(p) <= tol2 {
                                found = compact[j as usize];
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
        if found == NO_PLANE {
            found = nv;
            nv += 1;
            reps.entry(k).or_default().push(i as u32);
        }
        compact[i] = found;
    }
    (compact, nv)
}
