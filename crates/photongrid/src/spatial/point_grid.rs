//! The grid itself: a uniform grid over the items' bounding box whose dense cells get child
//! grids, and how it is built.
//!
//! * The items are owned by the grid and stored **sorted by cell** in one contiguous `Vec<T>`:
//!   the caller's vector, sorted in place (`cell_sort`), so that they exist once; distance
//!   tests read the positions from the items.
//! * The top-level grid covers the bounding box of the items with the caller's cell size. Its
//!   cell count is capped (`min(2^24, 4 n)`) by enlarging the cell size, so its dense offset
//!   table (counting sort, one `u32` per cell) is never larger than about 16 bytes per item.
//! * Any cell holding more than [`DENSE_CELL`] items (bright caustics, or everything when the
//!   cap forced huge cells over a mostly empty bounding box) gets a child grid over the tight
//!   bounding box of its items, sized for about 12 items per occupied sub-cell; child grids
//!   nest up to 8 levels. Because the items of a cell are contiguous, a child grid simply
//!   re-sorts that sub-range. This replaces a hashed cell table: memory stays `O(n)` whatever
//!   the bounding box (a hashed table at the requested tiny cell size would also be `O(n)`, but
//!   a search would then have to probe huge numbers of empty cells), and resolution follows
//!   the local density.
//! * Cells along x are adjacent in memory, so a query can scan each (y, z) row of cells as one
//!   contiguous run of items.

use super::cell_sort::{counting_sort, sort_by_cell};
use glam::Vec3;
use rayon::prelude::*;

/// Upper bound on the number of cells of the top-level grid.
const MAX_ROOT_CELLS: usize = 1 << 24;
/// The top-level grid has at most this many cells per item.
const ROOT_CELLS_PER_ITEM: usize = 4;
/// Cells holding more items than this get a child grid.
pub(super) const DENSE_CELL: u32 = 160;
/// Wanted items per occupied cell of a child grid.
const CHILD_TARGET: f32 = 12.0;
/// A child grid has at most this many cells per item.
const CHILD_CELLS_PER_ITEM: usize = 2;
/// Maximum nesting depth of child grids.
const MAX_DEPTH: u32 = 8;
/// Relative padding applied to search radii before cell culling (guards float rounding).
pub(super) const REL_PAD: f32 = 1e-5;

/// Anything stored in the grid has a position.
pub trait Positioned {
    /// World-space position of the item.
    fn position(&self) -> Vec3;
}

/// One level of the grid hierarchy.
#[derive(Clone, Debug)]
pub(super) struct Node {
    /// Minimum corner of the grid (= minimum corner of its items' bounding box).
    pub(super) origin: Vec3,
    /// Edge length of a (cubic) cell.
    pub(super) cell: f32,
    /// `1 / cell`.
    pub(super) inv_cell: f32,
    pub(super) nx: usize,
    pub(super) ny: usize,
    pub(super) nz: usize,
    /// Tight bounding box of the items of this node.
    pub(super) lo: Vec3,
    pub(super) hi: Vec3,
    /// `offsets[c]..offsets[c + 1]` are the (absolute) indices of the items of cell `c`, where
    /// `c = (z * ny + y) * nx + x`.
    pub(super) offsets: Vec<u32>,
    /// `(cell, node index)` of the child grids, sorted by cell.
    pub(super) children: Vec<(u32, u32)>,
}

impl Node {
    /// A grid with its origin at the minimum corner `lo` of its items, without children yet.
    fn new(lo: Vec3, hi: Vec3, cell: f32, inv_cell: f32, [nx, ny, nz]: [usize; 3], offsets: Vec<u32>) -> Self {
        Node {
            origin: lo,
            cell,
            inv_cell,
            nx,
            ny,
            nz,
            lo,
            hi,
            offsets,
            children: Vec::new(),
        }
    }

    #[inline(always)]
    pub(super) fn child_of(&self, cell: usize) -> Option<usize> {
        self.children
            .binary_search_by_key(&(cell as u32), |c| c.0)
            .ok()
            .map(|i| self.children[i].1 as usize)
    }

    #[inline(always)]
    pub(super) fn coords(&self, p: Vec3) -> (usize, usize, usize) {
        (
            cell_coord(p.x, self.origin.x, self.inv_cell, self.nx),
            cell_coord(p.y, self.origin.y, self.inv_cell, self.ny),
            cell_coord(p.z, self.origin.z, self.inv_cell, self.nz),
        )
    }

    fn memory_bytes(&self) -> usize {
        std::mem::size_of::<Node>()
            + self.offsets.capacity() * std::mem::size_of::<u32>()
            + self.children.capacity() * std::mem::size_of::<(u32, u32)>()
    }
}

/// Uniform-grid spatial index that owns its items, sorted by cell.
#[derive(Clone)]
pub struct PointGrid<T> {
    /// Items sorted by cell (and by sub-cell inside dense cells).
    pub(super) items: Vec<T>,
    /// Grid hierarchy; `nodes[0]` is the top level (empty when there are no items).
    pub(super) nodes: Vec<Node>,
    /// Effective cell size of the top level.
    cell_size: f32,
    /// Absolute padding for culling, proportional to the magnitude of the coordinates.
    pad_abs: f32,
}

impl<T> std::fmt::Debug for PointGrid<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let root = self.nodes.first();
        f.debug_struct("PointGrid")
            .field("len", &self.items.len())
            .field("cell_size", &self.cell_size)
            .field("dims", &root.map(|r| [r.nx, r.ny, r.nz]))
            .field("bounds", &root.map(|r| (r.lo, r.hi)))
            .field("child_grids", &self.nodes.len().saturating_sub(1))
            .finish()
    }
}

/// Cell size for which a disc of that radius holds `k` points when `n_points` are spread
/// uniformly over `surface_area`: `sqrt(k · A / (π · n))`, i.e. the expected kNN radius.
/// Returns 1.0 when the inputs are degenerate (no points, zero or non-finite area).
///
/// This is the `cell_size` to pass to [`PointGrid::build`] for kNN queries.
pub fn suggest_cell_size(n_points: usize, surface_area: f32, k: usize) -> f32 {
    // The expected kNN radius was the fastest cell size in benchmarks; nearby sizes cost more.
    let r = ((k.max(1) as f64 * surface_area as f64) / (std::f64::consts::PI * n_points as f64)).sqrt() as f32;
    if r.is_finite() && r > 0.0 {
        r
    } else {
        1.0
    }
}

// ---------------------------------------------------------------------------------------------
// Cell arithmetic.

/// Cell coordinate of `v` along one axis, clamped to `0..n`.
#[inline(always)]
pub(super) fn cell_coord(v: f32, origin: f32, inv: f32, n: usize) -> usize {
    let f = (v - origin) * inv;
    if f >= 0.0 {
        // `as` truncates (= floor for f >= 0) and saturates.
        (f as usize).min(n - 1)
    } else {
        0
    }
}

/// Row-major cell index `(z * ny + y) * nx + x` of position `p` in a grid with origin `lo`.
#[inline(always)]
fn cell_key(p: &[f32; 3], lo: Vec3, inv: f32, [nx, ny, nz]: [usize; 3]) -> u32 {
    let x = cell_coord(p[0], lo.x, inv, nx);
    let y = cell_coord(p[1], lo.y, inv, ny);
    let z = cell_coord(p[2], lo.z, inv, nz);
    ((z * ny + y) * nx + x) as u32
}

#[inline(always)]
pub(super) fn max_abs(p: Vec3) -> f32 {
    p.abs().max_element()
}

/// Bounding box of the items' positions.
fn bounds_of<T: Positioned>(items: &[T]) -> (Vec3, Vec3) {
    items.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), t| {
            let p = t.position();
            (lo.min(p), hi.max(p))
        },
    )
}

/// Number of cells along an axis of extent `e`.
fn axis_cells(e: f32, cell: f32) -> usize {
    let d = (e as f64 / cell as f64).ceil();
    if d >= 1.0 {
        d.min(1e12) as usize
    } else {
        1
    }
}

/// Enlarge `cell` until the grid over `ext` has at most `max_cells` cells.
fn grid_dims(ext: Vec3, mut cell: f32, max_cells: usize) -> (f32, [usize; 3]) {
    loop {
        let d = [
            axis_cells(ext.x, cell),
            axis_cells(ext.y, cell),
            axis_cells(ext.z, cell),
        ];
        let total = d[0] as f64 * d[1] as f64 * d[2] as f64;
        if total <= max_cells as f64 {
            return (cell, d);
        }
        let f = (total / max_cells as f64).cbrt().max(1.0) * 1.0001;
        cell = (cell as f64 * f) as f32;
    }
}

// ---------------------------------------------------------------------------------------------
// Building.

/// Build a child grid (and its descendants) over `items`, whose first item has the absolute
/// index `base`. Returns `None` when subdividing would not help (degenerate extent). Node 0 of
/// the result is the child's own grid; child indices are relative to the result.
fn build_subtree<T: Positioned + Clone>(items: &mut [T], base: usize, depth: u32) -> Option<Vec<Node>> {
    let m = items.len();
    let (lo, hi) = bounds_of(items);
    let ext = hi - lo;
    let mut e = ext.to_array();
    e.sort_unstable_by(|a, b| b.total_cmp(a));
    if e[0] <= 0.0 || !e[0].is_finite() {
        return None;
    }
    let mf = m as f32;
    // Cell size for ~CHILD_TARGET items per occupied cell if the items lie on a surface
    // (or on a line, whichever gives bigger cells).
    let h = (e[0] * CHILD_TARGET / mf).max((e[0] * e[1] * CHILD_TARGET / mf).sqrt());
    if h <= 0.0 || !h.is_finite() {
        return None;
    }
    let (cell, dims) = grid_dims(ext, h, (CHILD_CELLS_PER_ITEM * m).max(8));
    let ncells = dims[0] * dims[1] * dims[2];
    if ncells <= 1 {
        return None;
    }
    let inv = 1.0 / cell;
    if !inv.is_finite() {
        return None;
    }
    let keys: Vec<u32> = items
        .iter()
        .map(|t| cell_key(&t.position().to_array(), lo, inv, dims))
        .collect();
    let mut offsets = counting_sort(items, &keys, ncells);
    drop(keys);
    let mut nodes = vec![Node::new(lo, hi, cell, inv, dims, Vec::new())];
    if depth < MAX_DEPTH {
        for c in 0..ncells {
            let (s, t) = (offsets[c] as usize, offsets[c + 1] as usize);
            if t - s > DENSE_CELL as usize {
                if let Some(sub) = build_subtree(&mut items[s..t], base + s, depth + 1) {
                    let id = nodes.len();
                    nodes[0].children.push((c as u32, id as u32));
                    append_nodes(&mut nodes, sub, id);
                }
            }
        }
    }
    for o in offsets.iter_mut() {
        *o += base as u32;
    }
    nodes[0].offsets = offsets;
    Some(nodes)
}

/// Append `sub` (whose child indices are relative to itself) to `nodes` at index `id`.
fn append_nodes(nodes: &mut Vec<Node>, sub: Vec<Node>, id: usize) {
    debug_assert_eq!(nodes.len(), id);
    for mut n in sub {
        for c in n.children.iter_mut() {
            c.1 += id as u32;
        }
        nodes.push(n);
    }
}

/// Drop the items whose position is not finite, in place.
fn drop_non_finite<T: Positioned + Send + Sync>(items: &mut Vec<T>) {
    let finite = |t: &T| t.position().is_finite();
    if !items.par_iter().all(finite) {
        items.retain(finite);
    }
}

/// Cell size, inverse and dimensions of the top-level grid over `ext` for `n` items and the
/// caller's `cell_size` (see [`PointGrid::build`] for the special values).
fn root_grid(ext: Vec3, cell_size: f32, n: usize) -> (f32, f32, [usize; 3]) {
    let ext_max = ext.max_element();
    let cell0 = if cell_size.is_finite() && cell_size > 0.0 {
        cell_size
    } else if cell_size == f32::INFINITY {
        if ext_max > 0.0 && ext_max.is_finite() {
            ext_max
        } else {
            1.0
        }
    } else {
        f32::MIN_POSITIVE
    };
    let max_cells = (ROOT_CELLS_PER_ITEM * n).clamp(1, MAX_ROOT_CELLS);
    let (cell, dims) = grid_dims(ext, cell0, max_cells);
    let inv = 1.0 / cell;
    if inv.is_finite() && inv > 0.0 && cell.is_finite() {
        (cell, inv, dims)
    } else {
        // Extent beyond f32 range: one cell whose slab still covers every item.
        (f32::MAX, 1.0 / f32::MAX, dims)
    }
}

/// Child grids for the dense cells of the top level (cell `c` holds `offsets[c]..offsets[c+1]`),
/// built in parallel over disjoint sub-slices of `items`; appended to `nodes`, whose node 0 is
/// the top level.
fn add_dense_children<T: Positioned + Clone + Send>(nodes: &mut Vec<Node>, items: &mut [T]) {
    let dense: Vec<(usize, usize, usize)> = nodes[0]
        .offsets
        .par_windows(2)
        .enumerate()
        .filter(|(_, w)| w[1] - w[0] > DENSE_CELL)
        .map(|(c, w)| (c, w[0] as usize, w[1] as usize))
        .collect();
    let mut segments = Vec::with_capacity(dense.len());
    {
        let mut rest: &mut [T] = items;
        let mut consumed = 0usize;
        for &(c, s, e) in &dense {
            let (_, tail) = std::mem::take(&mut rest).split_at_mut(s - consumed);
            let (seg, tail) = tail.split_at_mut(e - s);
            rest = tail;
            consumed = e;
            segments.push((c, s, seg));
        }
    }
    let subtrees: Vec<(usize, Option<Vec<Node>>)> = segments
        .into_par_iter()
        .map(|(c, s, seg)| (c, build_subtree(seg, s, 1)))
        .collect();
    for (c, sub) in subtrees {
        if let Some(sub) = sub {
            let id = nodes.len();
            nodes[0].children.push((c as u32, id as u32));
            append_nodes(nodes, sub, id);
        }
    }
}

impl<T> PointGrid<T> {
    fn empty(cell_size: f32) -> Self {
        PointGrid {
            items: Vec::new(),
            nodes: Vec::new(),
            cell_size,
            pad_abs: 0.0,
        }
    }

    /// Culling padding for a query at `p`.
    #[inline(always)]
    pub(super) fn pad_for(&self, p: Vec3) -> f32 {
        self.pad_abs + REL_PAD * max_abs(p)
    }
}

impl<T: Positioned + Send + Sync + Clone> PointGrid<T> {
    /// Build (parallel with rayon where it pays). Items with non-finite positions are dropped.
    ///
    /// `cell_size` should be about the expected kNN radius (see [`suggest_cell_size`]); it is
    /// enlarged when the top-level grid would have more than `min(2^24, 4 n)` cells. A
    /// non-positive or NaN cell size is treated as tiny (i.e. the cap decides), an infinite one
    /// gives a single top-level cell. Dense cells are refined automatically.
    ///
    /// # Panics
    /// If there are `u32::MAX` items or more.
    pub fn build(items: Vec<T>, cell_size: f32) -> Self {
        let mut items = items;
        drop_non_finite(&mut items);
        let n = items.len();
        assert!(n < u32::MAX as usize, "PointGrid holds fewer than u32::MAX items");
        if n == 0 {
            return Self::empty(cell_size);
        }
        let (lo, hi) = items.par_chunks(1 << 16).map(bounds_of).reduce(
            || (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        );
        let (cell, inv, dims) = root_grid(hi - lo, cell_size, n);
        let ncells = dims[0] * dims[1] * dims[2];
        let key = |t: &T| cell_key(&t.position().to_array(), lo, inv, dims);
        let offsets = sort_by_cell(&mut items, key, ncells);
        let mut nodes = vec![Node::new(lo, hi, cell, inv, dims, offsets)];
        add_dense_children(&mut nodes, &mut items);
        let pad_abs = REL_PAD * max_abs(lo).max(max_abs(hi)) + f32::MIN_POSITIVE;
        PointGrid {
            items,
            nodes,
            cell_size: cell,
            pad_abs,
        }
    }

    /// Number of items stored.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when no items are stored.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// The items, sorted by cell. Query results index into this slice.
    pub fn items(&self) -> &[T] {
        &self.items
    }

    /// Effective cell size of the top-level grid (larger than requested when the cell count
    /// had to be capped; the requested size for an empty grid).
    pub fn cell_size(&self) -> f32 {
        self.cell_size
    }

    /// Approximate heap memory in bytes.
    pub fn memory_bytes(&self) -> usize {
        self.items.capacity() * std::mem::size_of::<T>() + self.nodes.iter().map(Node::memory_bytes).sum::<usize>()
    }
}
