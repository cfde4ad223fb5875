//! A plane's grid: its 2D basis and rectangle, and the cells on it.
//!
//! Each plane gets an orthonormal in-plane basis `(u, v)` with `u × v = normal`, chosen as the
//! minimum-area bounding rectangle of the plane's vertices (rotating over the convex hull edge
//! directions), so rotated walls get tight rectangles. `u` runs along the longer side. The
//! rectangle is enlarged by a margin of [`RECT_MARGIN_REL`] of its longer side on every side so
//! that border points map inside. The grid has `res_u × res_v` cells; see
//! [`PlaneParams::grid_dims`](super::PlaneParams::grid_dims) for how the resolution is chosen
//! (by default `resolution` cells along the longer side and near-square cells, i.e. 128 × 128
//! for a square plane, as in the paper).

use glam::Vec3;

/// Marker in [`PlaneSet::plane_of_triangle`] for a triangle that belongs to no plane.
pub const NO_PLANE: u32 = u32::MAX;

/// Relative margin added on each side of a plane's rectangle (fraction of the
/// longer side), so that points on the border map strictly inside.
pub const RECT_MARGIN_REL: f64 = 1e-4;

/// Relative rounding allowance always added to the `slack` of
/// [`Plane::cell_of`] (fraction of the rectangle's longer side).
pub const CELL_OF_ROUNDING_SLACK: f32 = 1e-5;

/// Bilinear interpolation along one axis of `n` cell-centred values (centres at i + 0.5) at
/// coordinate `g` (in cells): the two cells and the second one's weight. Clamped to the
/// centres, so the value is held beyond the first and last; NaN reads the first cell.
#[inline]
pub fn bilinear_axis(g: f32, n: usize) -> (usize, usize, f32) {
    // `max` first: it takes 0 over NaN. At the last centre i0 = i1 and the weight is 0.
    let x = (g - 0.5).max(0.0).min((n - 1) as f32);
    let i0 = x as usize;
    (i0, (i0 + 1).min(n - 1), x - i0 as f32)
}

/// One detected plane with its grid layout.
///
/// The rectangle is `origin + s·u + t·v` for `s ∈ [0, size_u]`,
/// `t ∈ [0, size_v]`; cell `(i, j)` covers
/// `s ∈ [i, i+1]·size_u/res_u`, `t ∈ [j, j+1]·size_v/res_v` and has the
/// row-major index `j·res_u + i`.
#[derive(Clone, Debug)]
pub struct Plane {
    /// Unit normal, oriented as the triangles' geometric normal
    /// (`(v1 − v0) × (v2 − v0)`, counter-clockwise winding).
    pub normal: Vec3,
    /// Plane equation: `dot(normal, p) = offset`.
    pub offset: f32,
    /// World position of the rectangle's `(u_min, v_min)` corner (on the plane).
    pub origin: Vec3,
    /// Unit in-plane axis along the rectangle's longer side.
    pub u: Vec3,
    /// Unit in-plane axis with `u × v = normal`.
    pub v: Vec3,
    /// Rectangle extent along `u` in metres (including the border margin).
    pub size_u: f32,
    /// Rectangle extent along `v` in metres (including the border margin).
    pub size_v: f32,
    /// Number of cells along `u`.
    pub res_u: usize,
    /// Number of cells along `v`.
    pub res_v: usize,
    /// Total area of the plane's triangles, clamped to the rectangle's area
    /// (overlapping duplicate triangles would otherwise count twice), so
    /// always ≤ `size_u * size_v`.
    pub area: f32,
    /// Indices into the input triangle slice, ascending.
    pub triangles: Vec<u32>,
}

impl Plane {
    /// Area of one grid cell in m² (cells are rectangles of
    /// `size_u/res_u × size_v/res_v`).
    pub fn cell_area(&self) -> f32 {
        (self.size_u / self.res_u.max(1) as f32) * (self.size_v / self.res_v.max(1) as f32)
    }

    /// Total number of cells, `res_u * res_v`.
    pub fn cell_count(&self) -> usize {
        self.res_u.max(1) * self.res_v.max(1)
    }

    /// Signed distance of `p` from the plane (positive on the normal's side).
    pub fn signed_distance(&self, p: Vec3) -> f32 {
        self.normal.dot(p) - self.offset
    }

    /// In-plane coordinates `(s, t)` in metres of `p` projected onto the plane,
    /// relative to [`Plane::origin`] along `u` and `v`.
    pub fn local_coords(&self, p: Vec3) -> (f32, f32) {
        let d = p - self.origin;
        (d.dot(self.u), d.dot(self.v))
    }

    /// Continuous grid coordinates (cells), for a point projected onto the plane.
    /// (0,0) = corner; cell centres at i+0.5.
    ///
    /// Not clamped: points outside the rectangle give coordinates outside
    /// `[0, res_u] × [0, res_v]`.
    pub fn grid_coords(&self, p: Vec3) -> (f32, f32) {
        let (s, t) = self.local_coords(p);
        self.local_to_grid(s, t)
    }

    fn local_to_grid(&self, s: f32, t: f32) -> (f32, f32) {
        (
            s * (self.res_u.max(1) as f32 / self.size_u),
            t * (self.res_v.max(1) as f32 / self.size_v),
        )
    }

    /// World position of continuous grid coordinates `(gx, gy)` (inverse of
    /// [`Plane::grid_coords`] for points on the plane).
    pub fn grid_to_world(&self, gx: f32, gy: f32) -> Vec3 {
        self.origin
            + self.u * (gx * self.size_u / self.res_u.max(1) as f32)
            + self.v * (gy * self.size_v / self.res_v.max(1) as f32)
    }

    /// World position of the centre of cell `cell` (row-major index
    /// `j·res_u + i`).
    pub fn cell_center(&self, cell: usize) -> Vec3 {
        let ru = self.res_u.max(1);
        let (i, j) = (cell % ru, cell / ru);
        self.grid_to_world(i as f32 + 0.5, j as f32 + 0.5)
    }

    /// Cell index (clamped into the grid), row-major: j*res_u + i. None if the point is
    /// farther than `slack` metres outside the rectangle.
    ///
    /// A rounding allowance of [`CELL_OF_ROUNDING_SLACK`] × the longer side is
    /// always added to `slack`, so points computed on the border (e.g. the
    /// far corner `origin + size_u·u + size_v·v` in f32) are inside.
    /// Only the in-plane position matters: the distance from the plane along
    /// the normal is not checked (use [`Plane::signed_distance`]). A negative
    /// or NaN `slack` counts as 0; points with NaN coordinates give `None`.
    pub fn cell_of(&self, p: Vec3, slack: f32) -> Option<usize> {
        let slack = if slack > 0.0 { slack } else { 0.0 };
        let slack = slack + CELL_OF_ROUNDING_SLACK * self.size_u.max(self.size_v);
        let (s, t) = self.local_coords(p);
        let inside = s >= -slack && s <= self.size_u + slack && t >= -slack && t <= self.size_v + slack;
        if !inside {
            return None;
        }
        let (gx, gy) = self.local_to_grid(s, t);
        Some(self.grid_cell(gx, gy))
    }

    /// The cell holding continuous grid coordinates `(gx, gy)`, clamped to the grid.
    pub fn grid_cell(&self, gx: f32, gy: f32) -> usize {
        let (ru, rv) = (self.res_u.max(1), self.res_v.max(1));
        // `as usize` truncates, which is the floor for the non-negative values `max` leaves (and
        // saturates: NaN → 0, +inf → MAX); no floorf call on the photon-counting path.
        let index = |g: f32, res: usize| -> usize { (g.max(0.0) as usize).min(res - 1) };
        index(gy, rv) * ru + index(gx, ru)
    }

    /// Four (cell index, weight) pairs for bilinear interpolation of cell-centred values at p
    /// (weights ≥0 and sum to 1, clamped at borders).
    ///
    /// The interpolation position `grid_coords(p) − (0.5, 0.5)` is clamped to
    /// the range of cell centres, so outside the centres the value is held
    /// constant along the clamped axis; the interpolant is continuous
    /// everywhere and never reads outside the grid. Indices may repeat at the
    /// borders (the weights of repeated indices add up). Non-finite input maps
    /// to the corner cell.
    pub fn bilinear(&self, p: Vec3) -> [(usize, f32); 4] {
        let (gx, gy) = self.grid_coords(p);
        self.bilinear_at(gx, gy)
    }

    /// [`Plane::bilinear`] at fine grid coordinates `(gx, gy)`.
    pub fn bilinear_at(&self, gx: f32, gy: f32) -> [(usize, f32); 4] {
        let ru = self.res_u.max(1);
        let (i0, i1, fx) = bilinear_axis(gx, ru);
        let (j0, j1, fy) = bilinear_axis(gy, self.res_v.max(1));
        [
            (j0 * ru + i0, (1.0 - fx) * (1.0 - fy)),
            (j0 * ru + i1, fx * (1.0 - fy)),
            (j1 * ru + i0, (1.0 - fx) * fy),
            (j1 * ru + i1, fx * fy),
        ]
    }

    /// Returns this plane with a different grid resolution (each at least 1);
    /// the rectangle is unchanged.
    pub fn with_resolution(mut self, res_u: usize, res_v: usize) -> Self {
        self.res_u = res_u.max(1);
        self.res_v = res_v.max(1);
        self
    }
}

/// Result: planes and, per input triangle, the plane it belongs to (u32::MAX = none).
#[derive(Clone, Debug, Default)]
pub struct PlaneSet {
    /// The detected planes, in detection order (largest seed triangle first).
    pub planes: Vec<Plane>,
    /// For every input triangle, the index into [`PlaneSet::planes`] of its
    /// plane, or [`NO_PLANE`] (`u32::MAX`) if it is in none.
    pub plane_of_triangle: Vec<u32>,
}

impl PlaneSet {
    /// The plane containing input triangle `triangle`, if any.
    pub fn plane_for(&self, triangle: usize) -> Option<&Plane> {
        match self.plane_of_triangle.get(triangle) {
            Some(&p) if p != NO_PLANE => self.planes.get(p as usize),
            _ => None,
        }
    }
}
