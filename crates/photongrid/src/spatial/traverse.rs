//! Walking the grid for a query: which contiguous runs of items a search sphere may reach.
//!
//! A query scans each (y, z) row of cells cut by the sphere, trimmed to the sphere's x extent
//! in that row, as one run of items, and descends into the child grids of dense cells. The
//! query is memory-latency bound, so the runs of up to [`ROW_BATCH`] rows are first located and
//! one float of each of their cache lines read, then scanned: the cache misses overlap instead
//! of being paid one after another. What happens to the items of a run is up to the [`Sink`].

use super::point_grid::{cell_coord, Node, PointGrid, Positioned, DENSE_CELL, REL_PAD};
use glam::Vec3;

/// Number of cell rows whose memory is requested together before they are scanned.
const ROW_BATCH: usize = 16;
/// Items a sink examines per branch-free filtering step (a power of two).
pub(super) const SCAN_CHUNK: usize = 64;

/// What a sink scans: the grid's items, and the query point.
pub(super) struct Query<'a, T> {
    pub(super) items: &'a [T],
    pub(super) q: [f32; 3],
}

/// Receiver of the contiguous item ranges a traversal finds.
pub(super) trait Sink {
    /// Current (inclusive) squared search radius; may shrink during the traversal.
    fn radius2(&self) -> f32;
    /// Examine items `start..end`.
    fn scan(&mut self, start: usize, end: usize);
    /// Load every cache line `scan(start, end)` will read (the result only defeats dead-code
    /// elimination). Called for a batch of ranges before any is scanned, so the misses overlap.
    fn touch(&self, start: usize, end: usize) -> u32;
}

/// Read one float of (about) every cache line of `items[start..end]`.
#[inline(always)]
pub(super) fn touch_items<T: Positioned>(items: &[T], start: usize, end: usize) -> u32 {
    let step = (64 / std::mem::size_of::<T>().max(1)).max(1);
    items[start..end]
        .iter()
        .step_by(step)
        .fold(0, |a, it| a ^ it.position().x.to_bits())
}

/// Squared distance exactly as `(a - b).length_squared()` computes it.
#[inline(always)]
pub(super) fn dist2(a: [f32; 3], q: [f32; 3]) -> f32 {
    let dx = a[0] - q[0];
    let dy = a[1] - q[1];
    let dz = a[2] - q[2];
    dx * dx + dy * dy + dz * dz
}

/// Squared distance from `p` to the box `[lo, hi]` (0 inside).
#[inline(always)]
pub(super) fn dist2_aabb(p: Vec3, lo: Vec3, hi: Vec3) -> f32 {
    let d = (lo - p).max(p - hi).max(Vec3::ZERO);
    d.length_squared()
}

/// Cell range covering `[a, b]` along one axis, or `None` if it lies entirely below the grid.
#[inline(always)]
fn coord_range(a: f32, b: f32, origin: f32, inv: f32, n: usize) -> Option<(usize, usize)> {
    let fb = (b - origin) * inv;
    if fb >= 0.0 {
        Some((cell_coord(a, origin, inv, n), cell_coord(b, origin, inv, n)))
    } else {
        None
    }
}

/// Distance from `v` to the interval `[lo, hi]`.
#[inline(always)]
fn gap(v: f32, lo: f32, hi: f32) -> f32 {
    if v < lo {
        lo - v
    } else if v > hi {
        v - hi
    } else {
        0.0
    }
}

/// Radius used for culling: `sqrt(r2)` enlarged to absorb rounding in the cell arithmetic.
#[inline(always)]
fn padded(r2: f32, pad: f32) -> f32 {
    r2.sqrt() * (1.0 + REL_PAD) + pad
}

/// The culling radius of a traversal, following the sink's (possibly shrinking) radius.
struct Cull {
    pad: f32,
    r2: f32,
    /// Padded radius and its square.
    rp: f32,
    rp2: f32,
}

impl Cull {
    fn new(r2: f32, pad: f32) -> Self {
        let rp = padded(r2, pad);
        Cull {
            pad,
            r2,
            rp,
            rp2: rp * rp,
        }
    }

    /// Adopt the sink's current radius if it changed.
    #[inline(always)]
    fn update(&mut self, r2: f32) {
        if r2 != self.r2 {
            self.r2 = r2;
            self.rp = padded(r2, self.pad);
            self.rp2 = self.rp * self.rp;
        }
    }
}

/// Runs of items waiting to be scanned, whose cache lines were already requested.
struct RowBatch {
    runs: [(u32, u32); ROW_BATCH],
    len: usize,
    touch: u32,
}

impl RowBatch {
    fn new() -> Self {
        RowBatch {
            runs: [(0, 0); ROW_BATCH],
            len: 0,
            touch: 0,
        }
    }

    /// Request the cache lines of items `s..e` and queue them; scan the batch once it is full.
    #[inline(always)]
    fn push<S: Sink>(&mut self, s: u32, e: u32, sink: &mut S) {
        self.touch ^= sink.touch(s as usize, e as usize);
        self.runs[self.len] = (s, e);
        self.len += 1;
        if self.len == ROW_BATCH {
            self.flush(sink);
        }
    }

    /// Scan the queued runs in order.
    #[inline(always)]
    fn flush<S: Sink>(&mut self, sink: &mut S) {
        for &(a, b) in &self.runs[..self.len] {
            sink.scan(a as usize, b as usize);
        }
        self.len = 0;
    }
}

impl<T> PointGrid<T> {
    /// The query at `p` over this grid's items.
    pub(super) fn query(&self, p: Vec3) -> Query<'_, T> {
        Query {
            items: &self.items,
            q: p.to_array(),
        }
    }

    /// Visit every item range of node `nid` that may hold items within the sink's radius.
    pub(super) fn visit<S: Sink>(&self, nid: usize, q: Vec3, pad: f32, sink: &mut S) {
        let node = &self.nodes[nid];
        let mut cull = Cull::new(sink.radius2(), pad);
        if dist2_aabb(q, node.lo, node.hi) > cull.rp2 {
            return;
        }
        let (o, inv, c) = (node.origin, node.inv_cell, node.cell);
        let Some((z0, z1)) = coord_range(q.z - cull.rp, q.z + cull.rp, o.z, inv, node.nz) else {
            return;
        };
        let Some((y0, y1)) = coord_range(q.y - cull.rp, q.y + cull.rp, o.y, inv, node.ny) else {
            return;
        };
        let off = &node.offsets[..];
        let has_children = !node.children.is_empty();
        let mut batch = RowBatch::new();
        for z in z0..=z1 {
            let zl = o.z + z as f32 * c;
            let gz = gap(q.z, zl, zl + c);
            let gz2 = gz * gz;
            if gz2 > cull.rp2 {
                continue;
            }
            for y in y0..=y1 {
                let yl = o.y + y as f32 * c;
                let gy = gap(q.y, yl, yl + c);
                let rem = cull.rp2 - gz2 - gy * gy;
                let w = if rem >= 0.0 {
                    rem.sqrt()
                } else if cull.rp2 == f32::INFINITY {
                    // inf - inf: an infinite radius reaches everything.
                    f32::INFINITY
                } else {
                    continue;
                };
                let Some((x0, x1)) = coord_range(q.x - w, q.x + w, o.x, inv, node.nx) else {
                    continue;
                };
                let row = (z * node.ny + y) * node.nx;
                let s = off[row + x0];
                let e = off[row + x1 + 1];
                if e <= s {
                    continue;
                }
                if has_children && e - s > DENSE_CELL {
                    batch.flush(sink);
                    self.visit_cells(node, row + x0, row + x1, q, pad, sink);
                } else {
                    batch.push(s, e, sink);
                }
                cull.update(sink.radius2());
            }
        }
        batch.flush(sink);
        std::hint::black_box(batch.touch);
    }

    /// Visit cells `c0..=c1` (one row) of `node` one by one, descending into child grids.
    fn visit_cells<S: Sink>(&self, node: &Node, c0: usize, c1: usize, q: Vec3, pad: f32, sink: &mut S) {
        let off = &node.offsets[..];
        let mut run = off[c0] as usize;
        for c in c0..=c1 {
            let s = off[c] as usize;
            let e = off[c + 1] as usize;
            if e - s > DENSE_CELL as usize {
                if let Some(child) = node.child_of(c) {
                    if s > run {
                        sink.scan(run, s);
                    }
                    self.visit(child, q, pad, sink);
                    run = e;
                }
            }
        }
        let end = off[c1 + 1] as usize;
        if end > run {
            sink.scan(run, end);
        }
    }
}
