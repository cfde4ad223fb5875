//! Exact k-nearest-neighbour queries on a [`PointGrid`].
//!
//! The first search radius is estimated from the item count of the 3×3×3 block of cells around
//! the query (at the finest grid level containing it), assuming the items lie on a surface.
//! All accepted items within that radius are gathered; if at least `k` were found, a
//! `select_nth_unstable` on packed `(distance bits, index)` keys gives the exact answer;
//! otherwise the radius grows (using the count found) and only the new shell is gathered. If the
//! gather overshoots (more than `2k + 64` candidates), the candidates are cut to the `k` best and
//! the search radius shrinks to the current k-th distance, so overshoot stays cheap.
//! Distances are computed exactly as `(p - q).length_squared()`, so results are bit-identical to
//! brute force.
//!
//! The distance filter is branch-free (every candidate key is written, the write index
//! advances only for hits). Positions are read from the items themselves (no copy of them is
//! kept), whose cache lines are requested in batches before they are scanned.

use super::point_grid::{PointGrid, Positioned, DENSE_CELL};
use super::traverse::{dist2, dist2_aabb, touch_items, Query, Sink, SCAN_CHUNK};
use glam::Vec3;
use std::f32::consts::PI;

/// Safety factor applied to the estimated kNN radius.
const EST_SAFETY: f32 = 1.1;

/// Reusable per-thread scratch for knn (avoids allocation per query).
#[derive(Clone, Debug, Default)]
pub struct KnnBuffer {
    /// Candidates packed as `(squared distance bits << 32) | index`.
    keys: Vec<u64>,
    /// The result of the last query.
    out: Vec<(u32, f32)>,
}

impl KnnBuffer {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Results of the last [`PointGrid::knn`] query: `(index into items(), squared distance)`,
    /// in no particular order.
    pub fn as_slice(&self) -> &[(u32, f32)] {
        &self.out
    }

    /// Results of the last query, nearest first.
    pub fn sorted(&mut self) -> &[(u32, f32)] {
        // The packed keys sort as integers (non-negative floats' bits keep their order).
        self.keys.sort_unstable();
        self.out.clear();
        self.out.extend(
            self.keys
                .iter()
                .map(|&key| (key as u32, f32::from_bits((key >> 32) as u32))),
        );
        &self.out
    }

    /// Number of results of the last query.
    pub fn len(&self) -> usize {
        self.out.len()
    }

    /// True when the last query found nothing.
    pub fn is_empty(&self) -> bool {
        self.out.is_empty()
    }

    /// Forget the results.
    pub fn clear(&mut self) {
        self.out.clear();
        self.keys.clear();
    }

    /// Iterate over `(index into items(), squared distance)` of the last query.
    pub fn iter(&self) -> std::slice::Iter<'_, (u32, f32)> {
        self.out.iter()
    }

    /// Sort the results by distance ascending (ties by index).
    pub fn sort_by_distance(&mut self) {
        self.out
            .sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    }
}

/// Squared distance from `p` to the farthest corner of the box `[lo, hi]`.
#[inline(always)]
fn far2_aabb(p: Vec3, lo: Vec3, hi: Vec3) -> f32 {
    let d = (p - lo).abs().max((hi - p).abs());
    d.length_squared()
}

/// Gathers accepted items with `lo2 < d² <= hi2` as packed keys for kNN.
struct KnnSink<'a, T, F> {
    query: Query<'a, T>,
    lo2: f32,
    hi2: f32,
    k: usize,
    compact_at: usize,
    keys: &'a mut Vec<u64>,
    accept: &'a F,
}

impl<T: Positioned, F: Fn(&T) -> bool> KnnSink<'_, T, F> {
    /// Keep only the k best candidates and shrink the radius to the k-th distance.
    #[cold]
    fn compact(&mut self) {
        let k = self.k;
        self.keys.select_nth_unstable(k - 1);
        self.keys.truncate(k);
        let kth = self.keys[k - 1];
        self.hi2 = f32::from_bits((kth >> 32) as u32);
    }
}

impl<T: Positioned, F: Fn(&T) -> bool> Sink for KnnSink<'_, T, F> {
    #[inline(always)]
    fn radius2(&self) -> f32 {
        self.hi2
    }

    #[inline(always)]
    fn touch(&self, start: usize, end: usize) -> u32 {
        touch_items(self.query.items, start, end)
    }

    #[inline(always)]
    fn scan(&mut self, start: usize, end: usize) {
        let q = self.query.q;
        let mut tmp = [0u64; SCAN_CHUNK];
        let mut base = start;
        for chunk in self.query.items[start..end].chunks(SCAN_CHUNK) {
            let (lo2, hi2) = (self.lo2, self.hi2);
            // Branch-free filter: write every key, advance only for those inside the shell.
            let mut n = 0usize;
            for (j, it) in chunk.iter().enumerate() {
                let d2 = dist2(it.position().to_array(), q);
                tmp[n & (SCAN_CHUNK - 1)] = ((d2.to_bits() as u64) << 32) | (base + j) as u64;
                n += (d2 <= hi2 && d2 > lo2) as usize;
            }
            for &key in &tmp[..n] {
                if (self.accept)(&self.query.items[key as u32 as usize]) {
                    self.keys.push(key);
                }
            }
            if self.keys.len() >= self.compact_at {
                self.compact();
            }
            base += chunk.len();
        }
    }
}

impl<T> PointGrid<T> {
    /// Estimate the radius holding `k` items around `p` from the counts of the 3×3×3 block of
    /// cells around it, at the finest level containing `p`.
    fn estimate_radius(&self, p: Vec3, k: usize) -> f32 {
        let mut nid = 0;
        loop {
            let node = &self.nodes[nid];
            let (cx, cy, cz) = node.coords(p);
            let off = &node.offsets[..];
            if !node.children.is_empty() {
                let cell = (cz * node.ny + cy) * node.nx + cx;
                if off[cell + 1] - off[cell] > DENSE_CELL {
                    if let Some(child) = node.child_of(cell) {
                        let ch = &self.nodes[child];
                        if dist2_aabb(p, ch.lo, ch.hi) <= ch.cell * ch.cell {
                            nid = child;
                            continue;
                        }
                    }
                }
            }
            let (x0, x1) = (cx.saturating_sub(1), (cx + 1).min(node.nx - 1));
            let (y0, y1) = (cy.saturating_sub(1), (cy + 1).min(node.ny - 1));
            let (z0, z1) = (cz.saturating_sub(1), (cz + 1).min(node.nz - 1));
            let mut n = 0u32;
            for z in z0..=z1 {
                for y in y0..=y1 {
                    let row = (z * node.ny + y) * node.nx;
                    n += off[row + x1 + 1] - off[row + x0];
                }
            }
            let mut b = [x1 - x0 + 1, y1 - y0 + 1, z1 - z0 + 1];
            b.sort_unstable();
            let c = node.cell;
            let area = (b[2] * b[1]) as f32 * c * c;
            let r = if n > 0 {
                (k as f32 * area / (PI * n as f32)).sqrt() * EST_SAFETY
            } else {
                2.0 * c
            };
            return r.max(c * 0.01);
        }
    }
}

impl<T: Positioned + Send + Sync + Clone> PointGrid<T> {
    /// k nearest items within max_radius that pass `accept`; fills `out` (cleared first) with
    /// (index into items(), squared distance), sorted by distance ascending is NOT required but
    /// the k-th (max) distance must be exact. Returns the squared radius of the farthest kept
    /// item (or max_radius² if fewer than k found).
    ///
    /// Items at exactly `max_radius` count as inside. Ties at the k-th distance are broken
    /// arbitrarily. `k == 0` returns 0 with no results; a NaN or negative `max_radius` acts as 0.
    /// `accept` is only called for items within the current search radius; unless it is
    /// zero-sized, the cache lines of the items it may inspect are prefetched in batches.
    pub fn knn<F: Fn(&T) -> bool>(&self, p: Vec3, k: usize, max_radius: f32, accept: F, out: &mut KnnBuffer) -> f32 {
        out.clear();
        let max_radius = if max_radius >= 0.0 { max_radius } else { 0.0 };
        let max_r2 = max_radius * max_radius;
        if k == 0 {
            return 0.0;
        }
        if self.is_empty() || !p.is_finite() {
            return max_r2;
        }
        let root = &self.nodes[0];
        let pad = self.pad_for(p);
        let dmin = dist2_aabb(p, root.lo, root.hi).sqrt();
        // Beyond this radius every item is inside the search sphere.
        let r_all = far2_aabb(p, root.lo, root.hi).sqrt() * (1.0 + 1e-4) + pad;
        let mut r = (self.estimate_radius(p, k) + dmin).min(r_all).max(f32::MIN_POSITIVE);
        let mut lo2 = -1.0f32;
        let compact_at = 2 * k + 64;
        loop {
            let (hi2, last) = if r >= max_radius {
                (max_r2, true)
            } else {
                (r * r, r >= r_all)
            };
            let mut sink = KnnSink {
                query: self.query(p),
                lo2,
                hi2,
                k,
                compact_at,
                keys: &mut out.keys,
                accept: &accept,
            };
            self.visit(0, p, pad, &mut sink);
            let m = out.keys.len();
            if m >= k || last {
                break;
            }
            let grow = if m == 0 {
                2.0
            } else {
                ((k as f32 / m as f32).sqrt() * 1.1).clamp(1.25, 4.0)
            };
            lo2 = hi2;
            r = (r * grow).min(r_all);
        }
        let keys = &mut out.keys;
        let result = if keys.len() >= k {
            if keys.len() > k {
                keys.select_nth_unstable(k - 1);
                keys.truncate(k);
            }
            let kth = keys.iter().copied().max().unwrap_or(0);
            f32::from_bits((kth >> 32) as u32)
        } else {
            max_r2
        };
        out.out
            .extend(keys.iter().map(|&key| (key as u32, f32::from_bits((key >> 32) as u32))));
        result
    }
}
