//! Plane detection and per-plane photon-count grids.
//!
//! Following Watanabe et al., *Adaptive Photon Mapping with Reference to Grid
//! Structures*, every plane of the scene carries a grid of cells that counts the
//! photons landing in each cell. A Blender glTF export is only a triangle soup,
//! so the planes have to be *found*; this module does that and provides the
//! grid geometry (world point → grid coordinates, cell index and bilinear
//! interpolation weights).
//!
//! # What is a plane
//!
//! A plane is a connected set of (nearly) coplanar triangles with the same
//! orientation:
//!
//! * **Connectivity** is by vertex *position* (glTF exports duplicate vertices
//!   per face), with positions welded within the offset tolerance. Two
//!   triangles are connected when they share a welded vertex (an edge or a
//!   corner). Coplanar pieces that do not touch (the tops of two separate boxes
//!   at the same height) are separate planes.
//! * **Coplanarity** is checked against the plane of the *seed* triangle
//!   (regions are grown from the largest unassigned triangle first): the
//!   candidate's oriented normal must be within
//!   [`PlaneParams::normal_tolerance_deg`] of the seed's normal and each of its
//!   vertices within `offset_tolerance_rel × scene diagonal` of the seed's
//!   plane. Testing against the fixed seed plane (not the neighbour) prevents
//!   drift along gently curved surfaces. The oriented normal is used, so the
//!   two sheets of a double-sided wall are separate planes.
//! * **Degenerate** triangles (non-finite vertices, or twice the area at most
//!   `(1e-6 × scene diagonal)²`) are never part of a plane. **Slivers** (height
//!   over the longest edge below the offset tolerance, whose normal is
//!   numerically meaningless) never seed a plane; they may join one if all
//!   their vertices lie within the offset tolerance and their normal points to
//!   the same side.
//!
//! # Rejecting curved meshes
//!
//! Tessellated curved surfaces (UV spheres, cylinders, tori, Suzanne) consist
//! of many small planar facets (every quad of a UV sphere is exactly planar).
//! A connected coplanar region only becomes a [`Plane`] if it passes all of:
//!
//! 1. **Area**: its triangle area is at least
//!    [`PlaneParams::min_area_rel`] × total (non-degenerate) scene area. A plane
//!    receiving a tiny fraction of the photons cannot fill its grid anyway.
//! 2. **Extent**: the shorter side of its (tight) bounding rectangle is at least
//!    [`PlaneParams::min_extent_rel`] × scene diagonal, which removes long
//!    slivers such as the side strips of a finely tessellated cylinder.
//! 3. **Not a facet of a smooth surface**: let the *boundary* of the region be
//!    its triangle edges not shared with another triangle of the region. A
//!    boundary edge is *smooth* if a triangle across it (outside the region)
//!    has a normal at an angle `θ` below [`PlaneParams::smooth_angle_deg`] from
//!    the plane normal (same orientation) and the surface continues there with
//!    a curvature radius `R = depth / θ` of at least [`SMOOTH_RADIUS_RATIO`] ×
//!    the region's shorter rectangle side, where `depth` is the neighbour's
//!    height across the edge (or the shorter rectangle side of the
//!    neighbour's own coplanar region, if larger). Open edges count as sharp;
//!    edges bordered only by needle-thin triangles (height below `1e-5 ×`
//!    scene diagonal, imprecise normal) are ignored. If more than
//!    [`SMOOTH_BOUNDARY_FRACTION`] of the boundary length is smooth, the
//!    region is a small facet of a tessellated curved surface (a facet that is
//!    flat within tolerance is necessarily small compared with the curvature
//!    radius) and is rejected. This is independent of scene scale and
//!    tessellation density. A large flat face that blends into a tight bevel
//!    or cove (radius smaller than the face) stays a plane, while the bevel
//!    strips themselves are rejected.
//!    Sharp low-poly solids (an octagonal prism, 45° creases) keep their faces.
//!
//! Triangles that end up in no plane fall back to plain kNN in the renderer.
//! Cylinder caps are genuine planar discs and become planes when large enough.
//!
//! # Grid layout
//!
//! Each plane gets an orthonormal in-plane basis `(u, v)` with `u × v = normal`,
//! chosen as the minimum-area bounding rectangle of the plane's vertices
//! (rotating over the convex hull edge directions), so rotated walls get tight
//! rectangles. `u` runs along the longer side. The rectangle is enlarged by a
//! margin of `1e-4` of its longer side on every side so that border points
//! map inside. The grid has `res_u × res_v` cells; see
//! [`PlaneParams::grid_dims`] for how the resolution is chosen (by default
//! `resolution` cells along the longer side and near-square cells, i.e.
//! 128 × 128 for a square plane, as in the paper).

#![forbid(unsafe_code)]
#![warn(missing_docs)]

use glam::{DVec2, DVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Marker in [`PlaneSet::plane_of_triangle`] for a triangle that belongs to no plane.
pub const NO_PLANE: u32 = u32::MAX;

/// Fraction of a region's boundary length that must border smooth, similarly
/// sized neighbours for the region to be rejected as a facet of a curved
/// surface (see the module documentation).
pub const SMOOTH_BOUNDARY_FRACTION: f64 = 0.5;

/// A shallow crease only counts as a continuation of a smooth surface if the
/// curvature radius it implies (neighbour depth / crease angle) is at least
/// this multiple of the region's shorter rectangle side (see the module
/// documentation).
pub const SMOOTH_RADIUS_RATIO: f64 = 1.0;

/// Relative margin added on each side of a plane's rectangle (fraction of the
/// longer side), so that points on the border map strictly inside.
pub const RECT_MARGIN_REL: f64 = 1e-4;

/// Relative rounding allowance always added to the `slack` of
/// [`Plane::cell_of`] (fraction of the rectangle's longer side).
pub const CELL_OF_ROUNDING_SLACK: f32 = 1e-5;

/// Largest number of convex-hull edge directions tried when fitting the
/// minimum-area rectangle; larger hulls (finely tessellated discs) are sampled
/// evenly, which is harmless because their optimum is flat.
const MAX_HULL_DIRECTIONS: usize = 1024;

/// Tolerances and limits for plane detection (with [`Default`]).
///
/// All "relative" lengths are relative to the diagonal of the scene's bounding
/// box (over all finite vertices), areas relative to the total area of the
/// non-degenerate input triangles.
#[derive(Clone, Debug)]
pub struct PlaneParams {
    /// Maximum angle (degrees) between a triangle's oriented normal and the
    /// seed triangle's normal. Default `0.5`.
    pub normal_tolerance_deg: f32,
    /// Maximum distance of a triangle vertex from the seed plane, relative to
    /// the scene diagonal. Also used as the vertex welding distance for
    /// connectivity and as the sliver threshold. Values below `1e-7` are
    /// clamped to `1e-7` (f32 precision). Default `1e-4` (0.35 mm in a
    /// 2 m Cornell box).
    pub offset_tolerance_rel: f32,
    /// Minimum total triangle area of a plane, as a fraction of the total scene
    /// area. Default `1e-3`: a plane that is hit by about 0.1 % of the photons
    /// (if lit like the average surface) is the smallest for which a 128²
    /// grid makes any sense; smaller surfaces use kNN.
    pub min_area_rel: f32,
    /// Minimum length of the *shorter* side of a plane's tight bounding
    /// rectangle, relative to the scene diagonal. Default `5e-3` (1.7 cm in
    /// a 2 m Cornell box, 7 cm in a 10 m room).
    pub min_extent_rel: f32,
    /// Crease angle (degrees) below which a neighbouring facet may be a
    /// continuation of a smooth curved surface (test 3 in the module
    /// documentation). Default `30` (Blender's auto-smooth default): 16- and
    /// 32-segment cylinders/spheres and subdivided icospheres are curved,
    /// octagonal prisms and icosahedra are faceted. `0` disables the test.
    pub smooth_angle_deg: f32,
    /// Number of grid cells along the *longer* side of each plane's rectangle.
    /// Default `128`, as in the paper. Values below 1 are treated as 1.
    pub resolution: usize,
    /// If `true` (default), the shorter side gets
    /// `round(resolution × short / long)` cells (at least 1), giving
    /// near-square cells, so a 2 × 2 m wall gets 128 × 128 cells and a
    /// 2 × 1 m table 128 × 64. If `false`, every plane gets
    /// `resolution × resolution` cells (possibly elongated cells).
    pub square_cells: bool,
    /// Minimum cell side length in metres (world units); a plane too small for
    /// its resolution gets fewer cells along that side (at least one). `0`
    /// (default) disables the limit, matching the paper's fixed grid size.
    pub min_cell_size: f32,
}

impl Default for PlaneParams {
    fn default() -> Self {
        Self {
            normal_tolerance_deg: 0.5,
            offset_tolerance_rel: 1e-4,
            min_area_rel: 1e-3,
            min_extent_rel: 5e-3,
            smooth_angle_deg: 30.0,
            resolution: 128,
            square_cells: true,
            min_cell_size: 0.0,
        }
    }
}

impl PlaneParams {
    /// Returns these parameters with [`PlaneParams::resolution`] replaced.
    pub fn with_resolution(mut self, resolution: usize) -> Self {
        self.resolution = resolution;
        self
    }

    /// Grid dimensions `(res_u, res_v)` for a rectangle of `size_u × size_v`
    /// metres under these parameters: [`PlaneParams::resolution`] cells along
    /// the longer side, the shorter side according to
    /// [`PlaneParams::square_cells`], then each side limited so that cells are
    /// at least [`PlaneParams::min_cell_size`] long. Both are at least 1.
    pub fn grid_dims(&self, size_u: f32, size_v: f32) -> (usize, usize) {
        let res = self.resolution.max(1);
        let (mut ru, mut rv) = if self.square_cells {
            let long = size_u.max(size_v);
            let along = |s: f32| -> usize {
                if long > 0.0 && s.is_finite() && long.is_finite() {
                    ((res as f64 * s as f64 / long as f64).round() as usize).clamp(1, res)
                } else {
                    res
                }
            };
            (along(size_u), along(size_v))
        } else {
            (res, res)
        };
        if self.min_cell_size > 0.0 {
            let cap = |s: f32| -> usize {
                // Tiny relative tolerance so that 2.0 / 0.1 gives 20, not 19.
                let n = (s as f64 / self.min_cell_size as f64 * (1.0 + 1e-6)).floor();
                if n.is_finite() {
                    (n.max(1.0) as usize).max(1)
                } else {
                    usize::MAX
                }
            };
            ru = ru.min(cap(size_u));
            rv = rv.min(cap(size_v));
        }
        (ru.max(1), rv.max(1))
    }
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
        let (ru, rv) = (self.res_u.max(1), self.res_v.max(1));
        let (gx, gy) = self.local_to_grid(s, t);
        // `as usize` saturates (negative → 0, NaN → 0, +inf → MAX).
        let index = |g: f32, res: usize| -> usize { (g.floor().max(0.0) as usize).min(res - 1) };
        Some(index(gy, rv) * ru + index(gx, ru))
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
        let (ru, rv) = (self.res_u.max(1), self.res_v.max(1));
        let (gx, gy) = self.grid_coords(p);
        let axis = |g: f32, res: usize| -> (usize, usize, f32) {
            let x = g - 0.5;
            let x = if x.is_nan() {
                0.0
            } else {
                x.clamp(0.0, (res - 1) as f32)
            };
            let i0 = (x as usize).min(res - 1);
            let i1 = (i0 + 1).min(res - 1);
            let f = if i1 == i0 { 0.0 } else { (x - i0 as f32).clamp(0.0, 1.0) };
            (i0, i1, f)
        };
        let (i0, i1, fx) = axis(gx, ru);
        let (j0, j1, fy) = axis(gy, rv);
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

// ---------------------------------------------------------------------------
// Detection
// ---------------------------------------------------------------------------

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

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kind {
    Degenerate,
    Sliver,
    Regular,
}

#[derive(Clone, Copy, Debug)]
struct TriInfo {
    /// Unit oriented normal (zero for degenerate triangles).
    normal: DVec3,
    area: f64,
    /// Height over the longest edge (0 for degenerate triangles).
    height: f64,
    kind: Kind,
}

fn tri_info(t: &[Vec3; 3], min_twice_area: f64, eps: f64) -> TriInfo {
    let degenerate = TriInfo {
        normal: DVec3::ZERO,
        area: 0.0,
        height: 0.0,
        kind: Kind::Degenerate,
    };
    if !t.iter().all(|v| v.is_finite()) {
        return degenerate;
    }
    let p = t.map(|v| v.as_dvec3());
    let c = (p[1] - p[0]).cross(p[2] - p[0]);
    let twice_area = c.length();
    if !twice_area.is_finite() || twice_area <= min_twice_area {
        return degenerate;
    }
    let longest = (p[1] - p[0])
        .length()
        .max((p[2] - p[1]).length())
        .max((p[0] - p[2]).length());
    let height = twice_area / longest;
    TriInfo {
        normal: c / twice_area,
        area: 0.5 * twice_area,
        height,
        kind: if height < eps { Kind::Sliver } else { Kind::Regular },
    }
}

/// Welds vertex positions: returns per triangle its three welded vertex ids
/// (`NO_PLANE` for degenerate triangles) and the number of welded vertices.
fn weld(triangles: &[[Vec3; 3]], infos: &[TriInfo], tol: f64) -> (Vec<[u32; 3]>, usize) {
    // 1. Exact duplicates (bitwise, with -0.0 == 0.0).
    let mut exact: FxMap<(u32, u32, u32), u32> = FxMap::default();
    exact.reserve(triangles.len() * 3 / 2 + 1);
    let mut upos: Vec<DVec3> = Vec::new();
    let mut corner: Vec<[u32; 3]> = vec![[NO_PLANE; 3]; triangles.len()];
    for (t, tri) in triangles.iter().enumerate() {
        if infos[t].kind == Kind::Degenerate {
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
    drop(exact);

    // 2. Near duplicates: greedy clustering in index order on a uniform grid
    //    of cell size `tol`. A position joins the first existing cluster
    //    representative within `tol` (searched in the 27 surrounding cells),
    //    otherwise it becomes a new representative. Unlike a transitive
    //    union, this never chains a dense run of vertices into one huge
    //    cluster (cluster diameter ≤ 2·tol).
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

/// Read-only data shared by the per-region evaluation.
struct Ctx<'a> {
    triangles: &'a [[Vec3; 3]],
    infos: &'a [TriInfo],
    tri_verts: &'a [[u32; 3]],
    v_off: &'a [u32],
    v_list: &'a [u32],
    region_of: &'a [u32],
    /// Shorter rectangle side of every region (0 if it has no fit).
    region_short: &'a [f64],
    params: &'a PlaneParams,
    min_area: f64,
    min_extent: f64,
    cos_smooth: Option<f64>,
    /// Minimum triangle height for its normal to be used in the smooth-facet
    /// test (`1e-5 ×` scene diagonal).
    reliable_height: f64,
}

impl Ctx<'_> {
    fn vert_tris(&self, v: u32) -> &[u32] {
        &self.v_list[self.v_off[v as usize] as usize..self.v_off[v as usize + 1] as usize]
    }
}

fn centroid(t: &[Vec3; 3]) -> DVec3 {
    (t[0].as_dvec3() + t[1].as_dvec3() + t[2].as_dvec3()) / 3.0
}

/// Find planes among the triangles (world space, [v0, v1, v2]). `params.resolution` sets the grid size.
///
/// See the module documentation for the criteria. The result is
/// deterministic. Runs in roughly linear time (hash-based welding, region
/// growing with per-region visit stamps, parallel per-plane fitting): about
/// 40 ms for an 80k-triangle plane and 80 ms for a 100k-triangle sphere on
/// two cores.
///
/// # Panics
///
/// If `triangles.len() >= u32::MAX`.
pub fn detect_planes(triangles: &[[Vec3; 3]], params: &PlaneParams) -> PlaneSet {
    let n = triangles.len();
    assert!(n < NO_PLANE as usize, "too many triangles for u32 indices");
    let mut result = PlaneSet {
        planes: Vec::new(),
        plane_of_triangle: vec![NO_PLANE; n],
    };

    // Scene size over all finite triangles.
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for t in triangles.iter().filter(|t| t.iter().all(|v| v.is_finite())) {
        for v in t {
            lo = lo.min(v.as_dvec3());
            hi = hi.max(v.as_dvec3());
        }
    }
    let diag = (hi - lo).length();
    if !diag.is_finite() || diag <= 0.0 {
        return result;
    }
    let eps = (params.offset_tolerance_rel.max(0.0) as f64).max(1e-7) * diag;
    let min_twice_area = (1e-6 * diag) * (1e-6 * diag);

    let infos: Vec<TriInfo> = triangles.par_iter().map(|t| tri_info(t, min_twice_area, eps)).collect();
    let total_area: f64 = infos.iter().map(|i| i.area).sum();

    // Connectivity by welded position.
    let (tri_verts, nv) = weld(triangles, &infos, eps);
    let mut v_off = vec![0u32; nv + 1];
    let distinct = |vs: &[u32; 3], k: usize| vs[k] != NO_PLANE && !vs[..k].contains(&vs[k]);
    for vs in &tri_verts {
        for k in 0..3 {
            if distinct(vs, k) {
                v_off[vs[k] as usize + 1] += 1;
            }
        }
    }
    for i in 0..nv {
        v_off[i + 1] += v_off[i];
    }
    let mut cursor = v_off.clone();
    let mut v_list = vec![0u32; v_off[nv] as usize];
    for (t, vs) in tri_verts.iter().enumerate() {
        for k in 0..3 {
            if distinct(vs, k) {
                let c = &mut cursor[vs[k] as usize];
                v_list[*c as usize] = t as u32;
                *c += 1;
            }
        }
    }

    // Seeds: regular triangles, largest first (ties by index).
    let mut seeds: Vec<u32> = (0..n as u32)
        .filter(|&t| infos[t as usize].kind == Kind::Regular)
        .collect();
    seeds.par_sort_unstable_by(|&a, &b| {
        infos[b as usize]
            .area
            .total_cmp(&infos[a as usize].area)
            .then(a.cmp(&b))
    });

    // Region growing against the seed plane.
    let cos_tol = (params.normal_tolerance_deg.max(0.0) as f64).to_radians().cos();
    let mut region_of = vec![NO_PLANE; n];
    let mut tri_stamp = vec![NO_PLANE; n];
    let mut vert_stamp = vec![NO_PLANE; nv];
    let mut regions: Vec<Vec<u32>> = Vec::new();
    let mut stack: Vec<u32> = Vec::new();
    for &seed in &seeds {
        if region_of[seed as usize] != NO_PLANE {
            continue;
        }
        let r = regions.len() as u32;
        let ns = infos[seed as usize].normal;
        let ds = ns.dot(centroid(&triangles[seed as usize]));
        let accepts = |t: usize| -> bool {
            let info = &infos[t];
            let d = info.normal.dot(ns);
            let normal_ok = match info.kind {
                Kind::Regular => d >= cos_tol,
                Kind::Sliver => d > 0.0,
                Kind::Degenerate => false,
            };
            normal_ok && triangles[t].iter().all(|p| (ns.dot(p.as_dvec3()) - ds).abs() <= eps)
        };
        region_of[seed as usize] = r;
        tri_stamp[seed as usize] = r;
        let mut members = vec![seed];
        stack.push(seed);
        while let Some(t) = stack.pop() {
            for &v in &tri_verts[t as usize] {
                if vert_stamp[v as usize] == r {
                    continue;
                }
                vert_stamp[v as usize] = r;
                for &nb in &v_list[v_off[v as usize] as usize..v_off[v as usize + 1] as usize] {
                    let nbu = nb as usize;
                    if tri_stamp[nbu] == r {
                        continue;
                    }
                    tri_stamp[nbu] = r;
                    if region_of[nbu] == NO_PLANE && accepts(nbu) {
                        region_of[nbu] = r;
                        members.push(nb);
                        stack.push(nb);
                    }
                }
            }
        }
        regions.push(members);
    }

    // Per-region fitting, then acceptance tests (which look at the fitted
    // sizes of neighbouring regions), in parallel.
    let fits: Vec<Option<Fit>> = regions
        .par_iter()
        .map(|members| fit_region(triangles, &infos, members))
        .collect();
    let region_short: Vec<f64> = fits
        .iter()
        .map(|f| f.as_ref().map_or(0.0, |f| f.ext_u.min(f.ext_v)))
        .collect();
    let ctx = Ctx {
        triangles,
        infos: &infos,
        tri_verts: &tri_verts,
        v_off: &v_off,
        v_list: &v_list,
        region_of: &region_of,
        region_short: &region_short,
        params,
        min_area: params.min_area_rel.max(0.0) as f64 * total_area,
        min_extent: params.min_extent_rel.max(0.0) as f64 * diag,
        cos_smooth: (params.smooth_angle_deg > 0.0).then(|| (params.smooth_angle_deg as f64).to_radians().cos()),
        reliable_height: 1e-5 * diag,
    };
    let fitted: Vec<Option<Plane>> = regions
        .par_iter()
        .zip(fits.par_iter())
        .enumerate()
        .map(|(r, (members, fit))| fit.as_ref().and_then(|fit| accept_region(&ctx, r as u32, members, fit)))
        .collect();
    for plane in fitted.into_iter().flatten() {
        let id = result.planes.len() as u32;
        for &t in &plane.triangles {
            result.plane_of_triangle[t as usize] = id;
        }
        result.planes.push(plane);
    }
    result
}

/// Area-weighted plane fit and tight rectangle of one region.
struct Fit {
    area: f64,
    normal: DVec3,
    /// Area-weighted centroid (on the plane).
    p0: DVec3,
    /// In-plane axes, `u` along the longer side, `v = normal × u`.
    u: DVec3,
    v: DVec3,
    /// Rectangle `[s0, s0 + ext_u] × [t0, t0 + ext_v]` relative to `p0`.
    s0: f64,
    t0: f64,
    ext_u: f64,
    ext_v: f64,
}

/// Fits the plane (area-weighted normal and centroid) and the minimum-area
/// bounding rectangle of a region. `None` for regions without area.
fn fit_region(triangles: &[[Vec3; 3]], infos: &[TriInfo], members: &[u32]) -> Option<Fit> {
    let area: f64 = members.iter().map(|&t| infos[t as usize].area).sum();
    if !area.is_finite() || area <= 0.0 {
        return None;
    }
    let mut nsum = DVec3::ZERO;
    let mut csum = DVec3::ZERO;
    for &t in members {
        let info = &infos[t as usize];
        nsum += info.normal * info.area;
        csum += centroid(&triangles[t as usize]) * info.area;
    }
    let n = nsum.normalize_or_zero();
    if n == DVec3::ZERO {
        return None;
    }
    let p0 = csum / area;

    // Project the vertices into an arbitrary in-plane basis (a, b), b = n × a.
    let a = n.any_orthonormal_vector();
    let b = n.cross(a);
    let pts: Vec<DVec2> = members
        .iter()
        .flat_map(|&t| triangles[t as usize].iter())
        .map(|v| {
            let d = v.as_dvec3() - p0;
            DVec2::new(d.dot(a), d.dot(b))
        })
        .collect();
    let hull = convex_hull(pts);
    let mut e = min_area_direction(&hull);
    let extent = |e: DVec2| -> (f64, f64, f64, f64) {
        let q = e.perp();
        let (mut s0, mut s1, mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for p in &hull {
            let (s, t) = (p.dot(e), p.dot(q));
            s0 = s0.min(s);
            s1 = s1.max(s);
            t0 = t0.min(t);
            t1 = t1.max(t);
        }
        (s0, s1, t0, t1)
    };
    // u along the longer side; v = n × u corresponds to e.perp() in 2D.
    let (s0, s1, t0, t1) = extent(e);
    if t1 - t0 > s1 - s0 {
        e = e.perp();
    }
    // Deterministic sign: the largest world component of u is positive.
    let u3 = a * e.x + b * e.y;
    let au = u3.abs();
    let major = if au.x >= au.y && au.x >= au.z {
        u3.x
    } else if au.y >= au.z {
        u3.y
    } else {
        u3.z
    };
    if major < 0.0 {
        e = -e;
    }
    let (s0, s1, t0, t1) = extent(e);
    let (ext_u, ext_v) = (s1 - s0, t1 - t0);
    if !ext_u.is_finite() || !ext_v.is_finite() {
        return None;
    }
    let u = a * e.x + b * e.y;
    Some(Fit {
        area,
        normal: n,
        p0,
        u,
        v: n.cross(u),
        s0,
        t0,
        ext_u,
        ext_v,
    })
}

/// Applies the acceptance tests to a fitted region and builds its [`Plane`].
fn accept_region(ctx: &Ctx, r: u32, members: &[u32], fit: &Fit) -> Option<Plane> {
    let shorter = fit.ext_u.min(fit.ext_v);
    if fit.area < ctx.min_area || shorter < ctx.min_extent {
        return None;
    }
    if let Some(cos_smooth) = ctx.cos_smooth {
        if is_smooth_facet(ctx, r, members, fit.normal, shorter, cos_smooth) {
            return None;
        }
    }

    // Output in f32, re-orthonormalised.
    let margin = RECT_MARGIN_REL * fit.ext_u.max(fit.ext_v) + 1e-7 * fit.p0.abs().max_element();
    let origin = fit.p0 + fit.u * (fit.s0 - margin) + fit.v * (fit.t0 - margin);
    let normal = fit.normal.as_vec3().normalize();
    let u = (fit.u.as_vec3() - normal * normal.dot(fit.u.as_vec3())).normalize();
    let v = normal.cross(u).normalize();
    let size_u = (fit.ext_u + 2.0 * margin) as f32;
    let size_v = (fit.ext_v + 2.0 * margin) as f32;
    let (res_u, res_v) = ctx.params.grid_dims(size_u, size_v);
    let mut triangles = members.to_vec();
    triangles.sort_unstable();
    Some(Plane {
        normal,
        offset: fit.normal.dot(fit.p0) as f32,
        origin: origin.as_vec3(),
        u,
        v,
        size_u,
        size_v,
        res_u,
        res_v,
        // Overlapping duplicates could make the sum exceed the rectangle.
        area: (fit.area.min(fit.ext_u * fit.ext_v)) as f32,
        triangles,
    })
}

/// The "facet of a smooth surface" test (see the module documentation).
fn is_smooth_facet(ctx: &Ctx, r: u32, members: &[u32], n: DVec3, shorter: f64, cos_smooth: f64) -> bool {
    let mut boundary = 0.0f64;
    let mut smooth = 0.0f64;
    for &t in members {
        let vs = ctx.tri_verts[t as usize];
        let ps = &ctx.triangles[t as usize];
        for k in 0..3 {
            let k1 = (k + 1) % 3;
            let (va, vb) = (vs[k], vs[k1]);
            if va == vb {
                continue;
            }
            let len = (ps[k1].as_dvec3() - ps[k].as_dvec3()).length();
            if len.is_nan() || len <= 0.0 {
                continue;
            }
            let mut internal = false;
            let mut outside_nb = false;
            let mut informative = false;
            let mut smooth_nb = false;
            for &nb in ctx.vert_tris(va) {
                if nb == t || !ctx.tri_verts[nb as usize].contains(&vb) {
                    continue;
                }
                if ctx.region_of[nb as usize] == r {
                    internal = true;
                    break;
                }
                outside_nb = true;
                let info = &ctx.infos[nb as usize];
                if info.height < ctx.reliable_height {
                    continue; // normal too imprecise to judge the crease
                }
                informative = true;
                let dot = info.normal.dot(n);
                if dot < cos_smooth {
                    continue;
                }
                // Depth of the neighbouring facet away from the edge: its
                // height across the edge, or the shorter side of its own
                // coplanar region if larger. depth / crease angle estimates
                // the radius of curvature of the surface continuing there.
                let region = ctx.region_of[nb as usize];
                let depth = if region == NO_PLANE {
                    0.0
                } else {
                    ctx.region_short[region as usize]
                };
                let depth = depth.max(2.0 * info.area / len);
                let angle = dot.clamp(-1.0, 1.0).acos();
                if depth >= SMOOTH_RADIUS_RATIO * angle * shorter {
                    smooth_nb = true;
                }
            }
            // Edges bordered only by needle-thin triangles carry no evidence
            // either way; open edges (no neighbour) count as sharp.
            if internal || (outside_nb && !informative) {
                continue;
            }
            boundary += len;
            if smooth_nb {
                smooth += len;
            }
        }
    }
    boundary > 0.0 && smooth > SMOOTH_BOUNDARY_FRACTION * boundary
}

/// Convex hull (counter-clockwise, without collinear points) by Andrew's
/// monotone chain. Returns fewer than 3 points for degenerate input.
fn convex_hull(mut pts: Vec<DVec2>) -> Vec<DVec2> {
    pts.retain(|p| p.is_finite());
    pts.sort_unstable_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<DVec2> = Vec::with_capacity(pts.len() + 1);
    for &p in &pts {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
            hull.pop();
        }
        hull.push(p);
    }
    let lower_len = hull.len() + 1;
    for &p in pts.iter().rev().skip(1) {
        while hull.len() >= lower_len && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
            hull.pop();
        }
        hull.push(p);
    }
    hull.pop();
    hull
}

/// Unit direction of one side of the minimum-area bounding rectangle of a
/// convex polygon (the optimum has a side collinear with a hull edge).
fn min_area_direction(hull: &[DVec2]) -> DVec2 {
    let h = hull.len();
    if h < 2 {
        return DVec2::X;
    }
    if h == 2 {
        return (hull[1] - hull[0]).try_normalize().unwrap_or(DVec2::X);
    }
    let stride = h.div_ceil(MAX_HULL_DIRECTIONS).max(1);
    let mut best = (f64::INFINITY, DVec2::X);
    for i in (0..h).step_by(stride) {
        let Some(e) = (hull[(i + 1) % h] - hull[i]).try_normalize() else {
            continue;
        };
        let q = e.perp();
        let (mut s0, mut s1, mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for p in hull {
            let (s, t) = (p.dot(e), p.dot(q));
            s0 = s0.min(s);
            s1 = s1.max(s);
            t0 = t0.min(t);
            t1 = t1.max(t);
        }
        let area = (s1 - s0) * (t1 - t0);
        if area < best.0 * (1.0 - 1e-9) {
            best = (area, e);
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{test_rng, uv_sphere};
    use glam::Quat;
    use std::f32::consts::{PI, TAU};

    // ---------------------------------------------------------------- helpers

    fn orient(t: [Vec3; 3], dir: Vec3) -> [Vec3; 3] {
        if (t[1] - t[0]).cross(t[2] - t[0]).dot(dir) < 0.0 {
            [t[0], t[2], t[1]]
        } else {
            t
        }
    }

    /// Rectangle `c ± hu ± hv` as two triangles facing `n`.
    fn quad(c: Vec3, hu: Vec3, hv: Vec3, n: Vec3) -> Vec<[Vec3; 3]> {
        let (a, b, cc, d) = (c - hu - hv, c + hu - hv, c + hu + hv, c - hu + hv);
        vec![orient([a, b, cc], n), orient([a, cc, d], n)]
    }

    /// Box with half extents `half`, rotated by `angle` about +y, outward faces.
    fn rotated_box(center: Vec3, half: Vec3, angle: f32) -> Vec<[Vec3; 3]> {
        let q = Quat::from_rotation_y(angle);
        let axes = [Vec3::X * half.x, Vec3::Y * half.y, Vec3::Z * half.z];
        let mut out = Vec::new();
        for k in 0..3 {
            for sign in [1.0f32, -1.0] {
                let n = axes[k] * sign;
                let (hu, hv) = (axes[(k + 1) % 3], axes[(k + 2) % 3]);
                out.extend(quad(center + q * n, q * hu, q * hv, q * n));
            }
        }
        out
    }

    fn torus(center: Vec3, big_r: f32, r: f32, nu: usize, nv: usize) -> Vec<[Vec3; 3]> {
        let p = |i: usize, j: usize| -> Vec3 {
            let a = TAU * (i % nu) as f32 / nu as f32;
            let b = TAU * (j % nv) as f32 / nv as f32;
            let rr = big_r + r * b.cos();
            center + Vec3::new(rr * a.cos(), r * b.sin(), rr * a.sin())
        };
        let mut out = Vec::new();
        for i in 0..nu {
            for j in 0..nv {
                let (a, b, c, d) = (p(i, j), p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                for t in [[a, b, c], [a, c, d]] {
                    let cen = (t[0] + t[1] + t[2]) / 3.0 - center;
                    let core = Vec3::new(cen.x, 0.0, cen.z).normalize() * big_r;
                    out.push(orient(t, cen - core));
                }
            }
        }
        out
    }

    /// Cylinder along +y: side quads (2 triangles each) then two cap fans.
    /// Returns (triangles, number of side triangles).
    fn cylinder(base: Vec3, r: f32, h: f32, seg: usize) -> (Vec<[Vec3; 3]>, usize) {
        let p = |i: usize, y: f32| -> Vec3 {
            let a = TAU * (i % seg) as f32 / seg as f32;
            base + Vec3::new(r * a.cos(), y, r * a.sin())
        };
        let mut out = Vec::new();
        for i in 0..seg {
            let (a, b, c, d) = (p(i, 0.0), p(i + 1, 0.0), p(i + 1, h), p(i, h));
            for t in [[a, b, c], [a, c, d]] {
                let cen = (t[0] + t[1] + t[2]) / 3.0 - base;
                out.push(orient(t, Vec3::new(cen.x, 0.0, cen.z)));
            }
        }
        let sides = out.len();
        for (y, dir) in [(0.0, -Vec3::Y), (h, Vec3::Y)] {
            let c = base + Vec3::Y * y;
            for i in 0..seg {
                out.push(orient([c, p(i, y), p(i + 1, y)], dir));
            }
        }
        (out, sides)
    }

    fn no_min_sizes() -> PlaneParams {
        PlaneParams {
            min_area_rel: 0.0,
            min_extent_rel: 0.0,
            ..PlaneParams::default()
        }
    }

    /// Structural invariants every detection result must satisfy.
    fn check_invariants(set: &PlaneSet, tris: &[[Vec3; 3]]) {
        assert_eq!(set.plane_of_triangle.len(), tris.len());
        let mut count = 0;
        for (pi, pl) in set.planes.iter().enumerate() {
            assert!((pl.normal.length() - 1.0).abs() < 1e-5);
            assert!((pl.u.length() - 1.0).abs() < 1e-5);
            assert!((pl.v.length() - 1.0).abs() < 1e-5);
            assert!(pl.u.dot(pl.normal).abs() < 1e-5);
            assert!(pl.u.cross(pl.v).distance(pl.normal) < 1e-5);
            assert!(pl.signed_distance(pl.origin).abs() < 1e-4);
            assert!(pl.size_u >= pl.size_v * 0.9999, "u is the longer side");
            assert!(pl.area <= pl.size_u * pl.size_v * 1.00001);
            assert!(pl.res_u >= 1 && pl.res_v >= 1);
            assert!(!pl.triangles.is_empty());
            for &t in &pl.triangles {
                count += 1;
                assert_eq!(set.plane_of_triangle[t as usize], pi as u32);
                for &p in &tris[t as usize] {
                    assert!(pl.signed_distance(p).abs() < 1e-3);
                    let (gx, gy) = pl.grid_coords(p);
                    assert!(gx > 0.0 && gx < pl.res_u as f32, "gx {gx}");
                    assert!(gy > 0.0 && gy < pl.res_v as f32, "gy {gy}");
                    assert!(pl.cell_of(p, 0.0).is_some());
                }
            }
        }
        let assigned = set.plane_of_triangle.iter().filter(|&&p| p != NO_PLANE).count();
        assert_eq!(assigned, count);
    }

    // ------------------------------------------------------------------ tests

    /// Cornell box walls (10 triangles), rotated box (12), UV sphere 64×32.
    fn cornell() -> Vec<[Vec3; 3]> {
        let mut t = Vec::new();
        t.extend(quad(Vec3::ZERO, Vec3::X, Vec3::Z, Vec3::Y)); // floor
        t.extend(quad(Vec3::new(0.0, 2.0, 0.0), Vec3::X, Vec3::Z, -Vec3::Y)); // ceiling
        t.extend(quad(Vec3::new(0.0, 1.0, -1.0), Vec3::X, Vec3::Y, Vec3::Z)); // back
        t.extend(quad(Vec3::new(-1.0, 1.0, 0.0), Vec3::Z, Vec3::Y, Vec3::X)); // left
        t.extend(quad(Vec3::new(1.0, 1.0, 0.0), Vec3::Z, Vec3::Y, -Vec3::X)); // right
        t.extend(rotated_box(
            Vec3::new(0.3, 0.6, -0.2),
            Vec3::new(0.3, 0.6, 0.3),
            20f32.to_radians(),
        ));
        t.extend(uv_sphere(Vec3::new(-0.45, 0.35, 0.35), 0.35, 64, 32));
        t
    }

    fn check_cornell(set: &PlaneSet, tris: &[[Vec3; 3]]) {
        check_invariants(set, tris);
        assert_eq!(set.planes.len(), 11);
        for t in 22..tris.len() {
            assert_eq!(set.plane_of_triangle[t], NO_PLANE, "sphere triangle {t}");
        }
        // Walls: pairs of triangles, each its own 2×2 plane, 128×128 cells.
        for w in 0..5 {
            let pa = set.plane_of_triangle[2 * w];
            assert_ne!(pa, NO_PLANE);
            assert_eq!(set.plane_of_triangle[2 * w + 1], pa);
            let pl = &set.planes[pa as usize];
            assert_eq!(pl.triangles, vec![2 * w as u32, 2 * w as u32 + 1]);
            assert!((pl.size_u - 2.0).abs() < 1e-3, "{}", pl.size_u);
            assert!((pl.size_v - 2.0).abs() < 1e-3, "{}", pl.size_v);
            assert!((pl.area - 4.0).abs() < 1e-4);
            assert_eq!((pl.res_u, pl.res_v), (128, 128));
            let tn = (tris[2 * w][1] - tris[2 * w][0]).cross(tris[2 * w][2] - tris[2 * w][0]);
            assert!(pl.normal.dot(tn.normalize()) > 0.9999);
        }
        // Box faces: tight rectangles despite the 20° rotation.
        for f in 0..6 {
            let t0 = 10 + 2 * f;
            let pa = set.plane_of_triangle[t0];
            assert_ne!(pa, NO_PLANE);
            let pl = &set.planes[pa as usize];
            assert_eq!(pl.triangles, vec![t0 as u32, t0 as u32 + 1]);
            let rect = pl.size_u * pl.size_v;
            assert!(
                (rect - pl.area).abs() / pl.area < 0.01,
                "face {f}: rect {rect} vs area {}",
                pl.area
            );
        }
    }

    #[test]
    fn cornell_box_with_rotated_box_and_sphere() {
        let tris = cornell();
        assert_eq!(tris.len(), 10 + 12 + 3968);
        check_cornell(&detect_planes(&tris, &PlaneParams::default()), &tris);
        // The smooth-facet test alone keeps the sphere out as well.
        check_cornell(&detect_planes(&tris, &no_min_sizes()), &tris);
        // ... and it is what does it: without it, the sphere's planar quads
        // become (tiny) planes.
        let p = PlaneParams {
            smooth_angle_deg: 0.0,
            ..no_min_sizes()
        };
        assert!(detect_planes(&tris, &p).planes.len() > 1000);
    }

    #[test]
    fn disjoint_coplanar_quads_are_separate_planes() {
        let mut tris = quad(Vec3::ZERO, Vec3::X * 0.5, Vec3::Z * 0.5, Vec3::Y);
        tris.extend(quad(Vec3::X * 2.0, Vec3::X * 0.5, Vec3::Z * 0.5, Vec3::Y));
        let set = detect_planes(&tris, &PlaneParams::default());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 2);
        assert_eq!(set.plane_of_triangle[0], set.plane_of_triangle[1]);
        assert_eq!(set.plane_of_triangle[2], set.plane_of_triangle[3]);
        assert_ne!(set.plane_of_triangle[0], set.plane_of_triangle[2]);
    }

    #[test]
    fn double_sided_sheet_is_two_planes() {
        let mut tris = quad(Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z);
        tris.extend(quad(Vec3::ZERO, Vec3::X, Vec3::Y, -Vec3::Z));
        let set = detect_planes(&tris, &PlaneParams::default());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 2);
        let (a, b) = (&set.planes[0], &set.planes[1]);
        assert!(a.normal.dot(b.normal) < -0.9999);
        assert_eq!(a.triangles.len(), 2);
        assert_eq!(b.triangles.len(), 2);
    }

    #[test]
    fn welding_connects_nearly_identical_vertices() {
        // The second triangle's shared vertices are displaced by 1 µm:
        // still one plane. A 1 cm gap gives two planes.
        let a = Vec3::new(0.0, 0.0, 0.0);
        let b = Vec3::new(1.0, 0.0, 0.0);
        let c = Vec3::new(1.0, 1.0, 0.0);
        let d = Vec3::new(0.0, 1.0, 0.0);
        let j = Vec3::new(1e-6, -1e-6, 0.0);
        let tris = vec![[a, b, c], [a + j, c + j, d]];
        let set = detect_planes(&tris, &PlaneParams::default());
        assert_eq!(set.planes.len(), 1);
        let g = Vec3::new(-0.01, 0.01, 0.0);
        let tris = vec![[a, b, c], [a + g, c + g, d + g]];
        assert_eq!(detect_planes(&tris, &PlaneParams::default()).planes.len(), 2);
    }

    #[test]
    fn torus_and_cylinder_only_caps_are_planes() {
        // Decision: cylinder caps are planar discs and legitimately planes;
        // the side strips and every torus quad are facets of smooth surfaces.
        let (mut tris, sides) = cylinder(Vec3::ZERO, 0.5, 1.5, 128);
        let cyl = tris.len();
        tris.extend(torus(Vec3::new(2.5, 0.5, 0.0), 1.0, 0.3, 48, 24));
        for params in [PlaneParams::default(), no_min_sizes()] {
            let set = detect_planes(&tris, &params);
            check_invariants(&set, &tris);
            assert_eq!(set.planes.len(), 2);
            for t in 0..tris.len() {
                let in_cap = (sides..cyl).contains(&t);
                assert_eq!(set.plane_of_triangle[t] != NO_PLANE, in_cap, "tri {t}");
            }
            for pl in &set.planes {
                assert_eq!(pl.triangles.len(), 128);
                assert!(pl.normal.y.abs() > 0.9999);
                // Tight square around the disc (tolerance: polygon vs circle).
                assert!((pl.size_u - 1.0).abs() < 2e-3 && (pl.size_v - 1.0).abs() < 2e-3);
            }
        }
        // Without the smooth-facet test and the minimum sizes, the flat strips
        // and quads would be accepted: the assertions above can fail.
        let p = PlaneParams {
            smooth_angle_deg: 0.0,
            ..no_min_sizes()
        };
        assert!(detect_planes(&tris, &p).planes.len() > 100);
    }

    #[test]
    fn coarse_sphere_alone_has_no_planes_but_octagonal_prism_does() {
        // A 16×8 UV sphere alone: each quad is ~1 % of the scene area, so only
        // the smooth-facet test (22.5° creases) rejects them.
        let tris = uv_sphere(Vec3::ZERO, 1.0, 16, 8);
        let set = detect_planes(&tris, &PlaneParams::default());
        assert_eq!(set.planes.len(), 0);
        assert!(set.plane_of_triangle.iter().all(|&p| p == NO_PLANE));
        // An octagonal prism has 45° creases: 8 sides + 2 caps.
        let (tris, _) = cylinder(Vec3::ZERO, 1.0, 1.0, 8);
        let set = detect_planes(&tris, &PlaneParams::default());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 10);
        assert!(set.plane_of_triangle.iter().all(|&p| p != NO_PLANE));
    }

    fn icosphere(subdivisions: usize) -> Vec<[Vec3; 3]> {
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let v = [
            (-1.0, t, 0.0),
            (1.0, t, 0.0),
            (-1.0, -t, 0.0),
            (1.0, -t, 0.0),
            (0.0, -1.0, t),
            (0.0, 1.0, t),
            (0.0, -1.0, -t),
            (0.0, 1.0, -t),
            (t, 0.0, -1.0),
            (t, 0.0, 1.0),
            (-t, 0.0, -1.0),
            (-t, 0.0, 1.0),
        ]
        .map(|(x, y, z)| Vec3::new(x, y, z).normalize());
        let f = [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        let mut tris: Vec<[Vec3; 3]> = f.iter().map(|f| f.map(|i| v[i])).collect();
        for _ in 0..subdivisions {
            let mut next = Vec::new();
            for [a, b, c] in tris {
                let (ab, bc, ca) = (
                    ((a + b) * 0.5).normalize(),
                    ((b + c) * 0.5).normalize(),
                    ((c + a) * 0.5).normalize(),
                );
                next.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
            }
            tris = next;
        }
        tris.into_iter().map(|t| orient(t, t[0] + t[1] + t[2])).collect()
    }

    #[test]
    fn icosahedron_faces_are_planes_but_icospheres_are_not() {
        // 41.8° creases: every face is a plane.
        let tris = icosphere(0);
        let set = detect_planes(&tris, &PlaneParams::default());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 20);
        // Subdivided once (≈ 20° creases) and twice: curved, no planes.
        for sub in [1, 2, 3] {
            let tris = icosphere(sub);
            let set = detect_planes(&tris, &PlaneParams::default());
            assert_eq!(set.planes.len(), 0, "subdivision {sub}");
        }
    }

    #[test]
    fn normal_tolerance_separates_bent_quads() {
        // Two 1 m squares sharing an edge, the second bent by `deg` about it.
        let bent = |deg: f32| -> Vec<[Vec3; 3]> {
            let q = Quat::from_rotation_x(deg.to_radians());
            let mut t = quad(Vec3::new(0.0, 0.0, -0.5), Vec3::X * 0.5, Vec3::Z * 0.5, Vec3::Y);
            t.extend(quad(
                q * Vec3::new(0.0, 0.0, 0.5),
                q * Vec3::X * 0.5,
                q * Vec3::Z * 0.5,
                q * Vec3::Y,
            ));
            t
        };
        let p = PlaneParams::default();
        // 0.005° bends the far edge by 0.09 mm < offset tolerance
        // (1e-4 × 1.41 m): coplanar. 0.05° is within the normal tolerance but
        // lifts the far edge by 0.9 mm: not coplanar.
        assert_eq!(detect_planes(&bent(0.005), &p).planes.len(), 1);
        assert_eq!(detect_planes(&bent(0.05), &p).planes.len(), 2);
        let loose = PlaneParams {
            offset_tolerance_rel: 1e-3,
            ..PlaneParams::default()
        };
        assert_eq!(detect_planes(&bent(0.05), &loose).planes.len(), 1);
        let set = detect_planes(&bent(2.0), &p);
        check_invariants(&set, &bent(2.0));
        assert_eq!(set.planes.len(), 2);
        // Bent by 45°: two planes as well (a sharp fold, not a curved surface).
        assert_eq!(detect_planes(&bent(45.0), &p).planes.len(), 2);
    }

    #[test]
    fn floor_blending_into_cove_stays_a_plane() {
        // Floor [0,2]² at y=0, a cove of 8 narrow strips (radius 0.3, 11.25°
        // steps) along x = 2, then a wall x = 2.3 from y = 0.3 to 2.
        let (r, c) = (0.3f32, Vec3::new(2.0, 0.3, 0.0));
        let mut tris = quad(Vec3::new(1.0, 0.0, 1.0), Vec3::X, Vec3::Z, Vec3::Y);
        let arc = |k: usize| {
            let a = -PI / 2.0 + PI / 2.0 * k as f32 / 8.0;
            c + Vec3::new(r * a.cos(), r * a.sin(), 0.0)
        };
        for k in 0..8 {
            let (p, q) = (arc(k), arc(k + 1));
            let z = Vec3::Z * 2.0;
            let inward = c - (p + q) * 0.5;
            tris.push(orient([p, q, q + z], inward));
            tris.push(orient([p, q + z, p + z], inward));
        }
        let wall = tris.len();
        tris.extend(quad(Vec3::new(2.3, 1.15, 1.0), Vec3::Y * 0.85, Vec3::Z, -Vec3::X));
        let set = detect_planes(&tris, &no_min_sizes());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 2);
        assert_ne!(set.plane_of_triangle[0], NO_PLANE);
        assert_ne!(set.plane_of_triangle[wall], NO_PLANE);
        for t in 2..wall {
            assert_eq!(set.plane_of_triangle[t], NO_PLANE);
        }
    }

    /// A 3 × 1.5 m quad, tilted and rotated arbitrarily, at resolution 16.
    fn tilted_plane(resolution: usize) -> (Plane, Vec<[Vec3; 3]>) {
        let q = Quat::from_euler(glam::EulerRot::XYZ, 0.3, 0.7, -0.4);
        let tris = quad(
            Vec3::new(0.5, 1.0, -2.0),
            q * Vec3::X * 1.5,
            q * Vec3::Z * 0.75,
            q * Vec3::Y,
        );
        let set = detect_planes(&tris, &PlaneParams::default().with_resolution(resolution));
        assert_eq!(set.planes.len(), 1);
        (set.planes[0].clone(), tris)
    }

    #[test]
    fn grid_geometry_corner_centres_and_clamping() {
        let (pl, tris) = tilted_plane(16);
        assert_eq!((pl.res_u, pl.res_v), (16, 8));
        assert!((pl.size_u - 3.0).abs() < 1e-3 && (pl.size_v - 1.5).abs() < 1e-3);
        assert!((pl.cell_area() - pl.size_u * pl.size_v / 128.0).abs() < 1e-6);
        let (gx, gy) = pl.grid_coords(pl.origin);
        assert!(gx.abs() < 1e-4 && gy.abs() < 1e-4);
        let far = pl.origin + pl.u * pl.size_u + pl.v * pl.size_v;
        let (gx, gy) = pl.grid_coords(far);
        assert!((gx - 16.0).abs() < 1e-3 && (gy - 8.0).abs() < 1e-3);
        assert_eq!(pl.cell_of(pl.origin, 0.0), Some(0));
        assert_eq!(pl.cell_of(far, 0.0), Some(pl.cell_count() - 1));
        // Off-plane offset along the normal does not change the cell.
        assert_eq!(pl.cell_of(pl.origin + pl.normal * 5.0, 0.0), Some(0));
        // Cell centres: exact coordinates, own cell, full bilinear weight.
        for cell in 0..pl.cell_count() {
            let p = pl.cell_center(cell);
            let (gx, gy) = pl.grid_coords(p);
            let (i, j) = (cell % pl.res_u, cell / pl.res_u);
            assert!((gx - (i as f32 + 0.5)).abs() < 1e-3 && (gy - (j as f32 + 0.5)).abs() < 1e-3);
            assert_eq!(pl.cell_of(p, 0.0), Some(cell));
            let w: f32 = pl.bilinear(p).iter().filter(|(c, _)| *c == cell).map(|(_, w)| w).sum();
            assert!(w > 0.999, "cell {cell}: weight {w}");
        }
        // Border points (the quad's corners) are inside; slack semantics.
        for t in &tris {
            for &p in t {
                let c = pl.cell_of(p, 0.0).expect("corner inside");
                assert!(c < pl.cell_count());
            }
        }
        let just_out = pl.origin - pl.u * 0.005 + pl.v * 0.7;
        assert_eq!(pl.cell_of(just_out, 0.0), None);
        let c = pl.cell_of(just_out, 0.01).expect("within slack");
        assert_eq!(c % pl.res_u, 0, "clamped to the first column");
        assert_eq!(pl.cell_of(pl.origin - pl.u, 0.01), None);
        assert_eq!(pl.cell_of(Vec3::NAN, 1.0), None);
        // Far-away and non-finite points: valid, clamped bilinear weights.
        for p in [
            pl.origin - pl.u * 100.0 - pl.v * 100.0,
            far + pl.u * 100.0,
            Vec3::NAN,
            Vec3::INFINITY,
        ] {
            let b = pl.bilinear(p);
            let sum: f32 = b.iter().map(|x| x.1).sum();
            assert!((sum - 1.0).abs() < 1e-5);
            assert!(b.iter().all(|&(c, w)| c < pl.cell_count() && w >= 0.0));
        }
        // Corner beyond the far corner → last cell only.
        let b = pl.bilinear(far + pl.u + pl.v);
        assert!(b.iter().all(|&(c, _)| c == pl.cell_count() - 1));
        // Re-gridding.
        let re = pl.clone().with_resolution(4, 0);
        assert_eq!((re.res_u, re.res_v), (4, 1));
        assert_eq!(re.cell_of(far, 0.0), Some(3));
    }

    #[test]
    fn bilinear_is_continuous() {
        let (pl, _) = tilted_plane(16);
        let mut rng = test_rng(7);
        let field: Vec<f32> = (0..pl.cell_count()).map(|_| rng.uniform()).collect();
        let value = |p: Vec3| -> f32 { pl.bilinear(p).iter().map(|&(c, w)| field[c] * w).sum() };
        // Lines crossing the whole rectangle (and beyond), several directions.
        let lines = [
            (pl.grid_to_world(-2.0, -1.0), pl.grid_to_world(18.0, 9.0)),
            (pl.grid_to_world(-1.0, 4.3), pl.grid_to_world(17.0, 4.3)),
            (pl.grid_to_world(7.7, -1.0), pl.grid_to_world(3.1, 10.0)),
            (pl.grid_to_world(16.5, -0.5), pl.grid_to_world(-0.5, 8.5)),
        ];
        let steps = 20_000;
        let mut max_jump = 0.0f32;
        for (a, b) in lines {
            let mut prev_g = pl.grid_coords(a);
            let mut prev = value(a);
            for k in 1..=steps {
                let p = a.lerp(b, k as f32 / steps as f32);
                let g = pl.grid_coords(p);
                let val = value(p);
                // Field values in [0, 1] ⇒ |∂f/∂g| ≤ 1 per axis.
                let bound = (g.0 - prev_g.0).abs() + (g.1 - prev_g.1).abs() + 1e-4;
                let jump = (val - prev).abs();
                max_jump = max_jump.max(jump);
                assert!(jump <= bound, "jump {jump} > {bound} at {g:?}");
                prev_g = g;
                prev = val;
            }
        }
        assert!(max_jump > 0.0);
    }

    #[test]
    fn tiny_plane_and_min_cell_size() {
        // Decision: in a 10 m scene, a 2 cm card is far below both minimum
        // sizes (area 4e-4 m² < 1e-3 × 100 m²; side 2 cm < 5e-3 × 14.1 m), so
        // it is not a plane and its photons use kNN. The floor is a plane.
        let mut tris = quad(Vec3::ZERO, Vec3::X * 5.0, Vec3::Z * 5.0, Vec3::Y);
        tris.extend(quad(Vec3::new(1.0, 1.0, 1.0), Vec3::X * 0.01, Vec3::Z * 0.01, Vec3::Y));
        let set = detect_planes(&tris, &PlaneParams::default());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 1);
        assert_eq!(set.planes[0].triangles, vec![0, 1]);
        assert_eq!(set.plane_of_triangle[2], NO_PLANE);
        assert_eq!(set.plane_of_triangle[3], NO_PLANE);
        // With the minimum sizes disabled it is a plane with the full
        // 128×128 grid (0.16 mm cells) ...
        let set = detect_planes(&tris, &no_min_sizes());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 2);
        let card = set.plane_for(2).unwrap();
        assert_eq!((card.res_u, card.res_v), (128, 128));
        // ... unless a minimum cell size (5 mm) is set: 4×4 cells; the 10 m
        // floor keeps 128×128 (7.8 cm cells).
        let p = PlaneParams {
            min_cell_size: 0.005,
            ..no_min_sizes()
        };
        let set = detect_planes(&tris, &p);
        let card = set.plane_for(2).unwrap();
        assert_eq!((card.res_u, card.res_v), (4, 4));
        assert!((card.cell_area() - 0.02f32.powi(2) / 16.0).abs() < 1e-7);
        let floor = set.plane_for(0).unwrap();
        assert_eq!((floor.res_u, floor.res_v), (128, 128));
    }

    #[test]
    fn grid_dims_policy() {
        let p = PlaneParams::default();
        assert_eq!(p.grid_dims(2.0, 2.0), (128, 128));
        assert_eq!(p.grid_dims(2.0, 1.0), (128, 64));
        assert_eq!(p.grid_dims(1.0, 2.0), (64, 128));
        assert_eq!(p.grid_dims(100.0, 0.01), (128, 1));
        let p = PlaneParams {
            square_cells: false,
            ..p
        };
        assert_eq!(p.grid_dims(2.0, 1.0), (128, 128));
        let p = PlaneParams {
            min_cell_size: 0.1,
            ..p
        };
        assert_eq!(p.grid_dims(2.0, 0.35), (20, 3));
        assert_eq!(p.grid_dims(0.01, 0.01), (1, 1));
        assert_eq!(PlaneParams::default().with_resolution(0).grid_dims(1.0, 1.0), (1, 1));
    }

    #[test]
    fn degenerate_slivers_and_empty_input() {
        assert_eq!(detect_planes(&[], &PlaneParams::default()).planes.len(), 0);
        let a = Vec3::ZERO;
        let mut tris = quad(Vec3::ZERO, Vec3::X, Vec3::Z, Vec3::Y);
        tris.push([a, Vec3::X, Vec3::X * 2.0]); // collinear
        tris.push([Vec3::X; 3]); // a point
        tris.push([a, Vec3::NAN, Vec3::Z]); // NaN
        tris.push([a, Vec3::INFINITY, Vec3::Z]); // infinite
                                                 // A sliver lying in the floor, along the diagonal (height 1e-7 m).
        tris.push(orient(
            [
                Vec3::new(-1.0, 0.0, -1.0),
                Vec3::new(0.0, 0.0, 1e-7),
                Vec3::new(1.0, 0.0, 1.0),
            ],
            Vec3::Y,
        ));
        let set = detect_planes(&tris, &PlaneParams::default());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 1);
        assert_eq!(set.plane_of_triangle[0], 0);
        assert_eq!(set.plane_of_triangle[1], 0);
        for t in 2..6 {
            assert_eq!(set.plane_of_triangle[t], NO_PLANE);
        }
        // The sliver may join the floor (it lies in it) but never forms its own.
        assert!(set.plane_of_triangle[6] == NO_PLANE || set.plane_of_triangle[6] == 0);
        assert!((set.planes[0].area - 4.0).abs() < 1e-3);
        // Only degenerate input: nothing, no panic.
        let set = detect_planes(&tris[2..6], &PlaneParams::default());
        assert!(set.planes.is_empty());
        assert_eq!(set.plane_of_triangle, vec![NO_PLANE; 4]);
        // A lone sliver cannot seed a plane.
        let set = detect_planes(&tris[6..], &PlaneParams::default());
        assert!(set.planes.is_empty());
    }

    #[test]
    fn box_faces_subdivided_are_six_planes() {
        // Each face tessellated 4×4 (32 triangles), vertices duplicated per
        // triangle as in glTF exports.
        let mut tris = Vec::new();
        let q = Quat::from_rotation_y(0.3);
        for k in 0..3 {
            for sign in [1.0f32, -1.0] {
                let mut n = Vec3::ZERO;
                n[k] = sign;
                let mut u = Vec3::ZERO;
                u[(k + 1) % 3] = 1.0;
                let mut v = Vec3::ZERO;
                v[(k + 2) % 3] = 1.0;
                for i in 0..4 {
                    for j in 0..4 {
                        let c = n + u * (-0.75 + 0.5 * i as f32) + v * (-0.75 + 0.5 * j as f32);
                        for t in quad(q * c, q * u * 0.25, q * v * 0.25, q * n) {
                            tris.push(t);
                        }
                    }
                }
            }
        }
        let set = detect_planes(&tris, &PlaneParams::default());
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 6);
        for pl in &set.planes {
            assert_eq!(pl.triangles.len(), 32);
            assert!((pl.size_u - 2.0).abs() < 1e-3 && (pl.size_v - 2.0).abs() < 1e-3);
        }
    }

    #[test]
    fn tessellated_plane_80k_triangles_is_one_plane() {
        let q = Quat::from_euler(glam::EulerRot::XYZ, 0.2, 0.9, 0.1);
        let n = 200;
        let mut tris = Vec::with_capacity(2 * n * n);
        let p = |i: usize, j: usize| -> Vec3 {
            q * Vec3::new(i as f32 * 0.02 - 2.0, 0.0, j as f32 * 0.01 - 1.0) + Vec3::new(3.0, 1.0, -2.0)
        };
        for i in 0..n {
            for j in 0..n {
                tris.push(orient([p(i, j), p(i + 1, j), p(i + 1, j + 1)], q * Vec3::Y));
                tris.push(orient([p(i, j), p(i + 1, j + 1), p(i, j + 1)], q * Vec3::Y));
            }
        }
        let start = std::time::Instant::now();
        let set = detect_planes(&tris, &PlaneParams::default());
        let elapsed = start.elapsed();
        eprintln!("80k-triangle plane: {elapsed:?}");
        check_invariants(&set, &tris);
        assert_eq!(set.planes.len(), 1);
        let pl = &set.planes[0];
        assert_eq!(pl.triangles.len(), 80_000);
        assert!((pl.size_u - 4.0).abs() < 2e-3 && (pl.size_v - 2.0).abs() < 2e-3);
        assert_eq!((pl.res_u, pl.res_v), (128, 64));
        assert!(elapsed.as_secs_f32() < 3.0, "too slow: {elapsed:?}");
    }

    #[test]
    fn dense_sphere_100k_triangles_is_fast_and_has_no_planes() {
        let tris = uv_sphere(Vec3::ZERO, 1.0, 256, 196);
        assert!(tris.len() > 99_000);
        let start = std::time::Instant::now();
        let set = detect_planes(&tris, &no_min_sizes());
        let elapsed = start.elapsed();
        eprintln!("{}-triangle sphere: {elapsed:?}", tris.len());
        assert!(set.planes.is_empty());
        assert!(elapsed.as_secs_f32() < 3.0, "too slow: {elapsed:?}");
    }

    #[test]
    fn dense_spheres_in_a_large_scene_are_never_planar() {
        // 100 m floor: the tolerances (relative to the scene) are loose for
        // the spheres (offset tolerance 1.4 cm, many triangles thinner than
        // that). Even without minimum sizes only the floor is a plane.
        for r in [0.05f32, 0.2, 0.5, 2.0] {
            let mut tris = quad(Vec3::ZERO, Vec3::X * 50.0, Vec3::Z * 50.0, Vec3::Y);
            tris.extend(uv_sphere(Vec3::new(0.0, 1.0 + r, 0.0), r, 256, 196));
            let set = detect_planes(&tris, &no_min_sizes());
            check_invariants(&set, &tris);
            assert_eq!(set.planes.len(), 1, "radius {r}");
            assert_eq!(set.planes[0].triangles, vec![0, 1]);
        }
    }

    #[test]
    fn deterministic() {
        let tris = cornell();
        let a = detect_planes(&tris, &PlaneParams::default());
        let b = detect_planes(&tris, &PlaneParams::default());
        assert_eq!(a.plane_of_triangle, b.plane_of_triangle);
        for (x, y) in a.planes.iter().zip(&b.planes) {
            assert_eq!((x.origin, x.u, x.size_u, x.size_v), (y.origin, y.u, y.size_u, y.size_v));
        }
    }

    proptest::proptest! {
        // No failure persistence: the regression file would be written next
        // to the crate root, outside this module.
        #![proptest_config(proptest::prelude::ProptestConfig {
            failure_persistence: None,
            ..proptest::prelude::ProptestConfig::with_cases(64)
        })]
        #[test]
        fn random_soups_satisfy_invariants(
            coords in proptest::collection::vec(-2i32..=2, 9..=270),
            quads in proptest::collection::vec((-2i32..=2, -2i32..=2, 0usize..3), 0..8),
        ) {
            // Random triangles on a coarse lattice (many coplanar, touching,
            // degenerate or duplicate triangles) plus random unit quads.
            let mut tris: Vec<[Vec3; 3]> = coords
                .chunks_exact(9)
                .map(|c| {
                    let v = |k: usize| Vec3::new(c[k] as f32, c[k + 1] as f32, c[k + 2] as f32) * 0.5;
                    [v(0), v(3), v(6)]
                })
                .collect();
            for (a, b, axis) in quads {
                let mut n = Vec3::ZERO;
                n[axis] = 1.0;
                let mut hu = Vec3::ZERO;
                hu[(axis + 1) % 3] = 0.5;
                let mut hv = Vec3::ZERO;
                hv[(axis + 2) % 3] = 0.5;
                let c = hu * 2.0 * a as f32 + hv * 2.0 * b as f32;
                tris.extend(quad(c, hu, hv, n));
            }
            let set = detect_planes(&tris, &PlaneParams::default());
            check_invariants(&set, &tris);
        }

        #[test]
        fn bilinear_and_cell_of_always_valid(
            x in -20.0f32..20.0, y in -20.0f32..20.0, z in -20.0f32..20.0,
        ) {
            let (pl, _) = tilted_plane(16);
            let p = Vec3::new(x, y, z);
            let b = pl.bilinear(p);
            let sum: f32 = b.iter().map(|e| e.1).sum();
            proptest::prop_assert!((sum - 1.0).abs() < 1e-5);
            for (c, w) in b {
                proptest::prop_assert!(c < pl.cell_count());
                proptest::prop_assert!((0.0..=1.0).contains(&w));
            }
            let c = pl.cell_of(p, f32::INFINITY);
            proptest::prop_assert!(matches!(c, Some(c) if c < pl.cell_count()));
            // The interpolation position agrees with cell_of inside the grid.
            let (gx, gy) = pl.grid_coords(p);
            if gx > 0.01 && gy > 0.01 && gx < 15.99 && gy < 7.99 {
                let i = gx.floor() as usize;
                let j = gy.floor() as usize;
                proptest::prop_assert_eq!(pl.cell_of(p, 0.0), Some(j * 16 + i));
            }
        }
    }
}
