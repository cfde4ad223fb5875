//! Finding the planes: grouping connected, coplanar triangles of the same orientation, and
//! keeping the groups that are real planes rather than facets of curved meshes.
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

use super::geometry::{Plane, PlaneSet, NO_PLANE, RECT_MARGIN_REL};
use super::hull::{convex_hull, extent, rectangle_axis};
use super::weld::weld;
use glam::{DVec2, DVec3, Vec3};
use rayon::prelude::*;

/// Fraction of a region's boundary length that must border smooth, similarly
/// sized neighbours for the region to be rejected as a facet of a curved
/// surface (see the module documentation).
pub const SMOOTH_BOUNDARY_FRACTION: f64 = 0.5;

/// A shallow crease only counts as a continuation of a smooth surface if the
/// curvature radius it implies (neighbour depth / crease angle) is at least
/// this multiple of the region's shorter rectangle side (see the module
/// documentation).
pub const SMOOTH_RADIUS_RATIO: f64 = 1.0;

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

/// Which triangles touch: the welded vertices of every triangle and, per welded vertex, the
/// triangles using it (compressed rows: `vert_list[vert_off[v]..vert_off[v + 1]]`).
struct Connectivity {
    tri_verts: Vec<[u32; 3]>,
    vert_off: Vec<u32>,
    vert_list: Vec<u32>,
}

impl Connectivity {
    /// Inverts `tri_verts` (welded vertex ids in `0..nv`, `NO_PLANE` for none); a triangle
    /// listing the same vertex twice is recorded once.
    fn new(tri_verts: Vec<[u32; 3]>, nv: usize) -> Self {
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
        Connectivity {
            tri_verts,
            vert_off: v_off,
            vert_list: v_list,
        }
    }

    fn vertex_count(&self) -> usize {
        self.vert_off.len() - 1
    }

    fn vert_tris(&self, v: u32) -> &[u32] {
        &self.vert_list[self.vert_off[v as usize] as usize..self.vert_off[v as usize + 1] as usize]
    }
}

/// Read-only data shared by the per-region evaluation.
struct Ctx<'a> {
    triangles: &'a [[Vec3; 3]],
    infos: &'a [TriInfo],
    conn: &'a Connectivity,
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

fn centroid(t: &[Vec3; 3]) -> DVec3 {
    (t[0].as_dvec3() + t[1].as_dvec3() + t[2].as_dvec3()) / 3.0
}

/// Find planes among the triangles (world space, [v0, v1, v2]). `params.resolution` sets the grid size.
///
/// See the module documentation for the criteria. The result is
/// deterministic. Runs in roughly linear time (hash-based welding, region
/// growing with per-region visit stamps, parallel per-plane fitting).
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
    let Some(diag) = scene_diagonal(triangles) else {
        return result;
    };
    let eps = (params.offset_tolerance_rel.max(0.0) as f64).max(1e-7) * diag;
    let min_twice_area = (1e-6 * diag) * (1e-6 * diag);

    let infos: Vec<TriInfo> = triangles.par_iter().map(|t| tri_info(t, min_twice_area, eps)).collect();
    let total_area: f64 = infos.iter().map(|i| i.area).sum();

    // Connectivity by welded position.
    let (tri_verts, nv) = weld(triangles, |t| infos[t].kind == Kind::Degenerate, eps);
    let conn = Connectivity::new(tri_verts, nv);
    let cos_tol = (params.normal_tolerance_deg.max(0.0) as f64).to_radians().cos();
    let (regions, region_of) = grow_regions(triangles, &infos, &conn, cos_tol, eps);

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
        conn: &conn,
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

/// Diagonal of the bounding box of all finite triangles; `None` if there is no extent.
fn scene_diagonal(triangles: &[[Vec3; 3]]) -> Option<f64> {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for t in triangles.iter().filter(|t| t.iter().all(|v| v.is_finite())) {
        for v in t {
            lo = lo.min(v.as_dvec3());
            hi = hi.max(v.as_dvec3());
        }
    }
    let diag = (hi - lo).length();
    (diag.is_finite() && diag > 0.0).then_some(diag)
}

/// Grows regions from regular seed triangles, largest first (ties by index), against the
/// seed's plane (see the module documentation). Returns the regions' members and, per
/// triangle, its region (`NO_PLANE` for none).
fn grow_regions(
    triangles: &[[Vec3; 3]],
    infos: &[TriInfo],
    conn: &Connectivity,
    cos_tol: f64,
    eps: f64,
) -> (Vec<Vec<u32>>, Vec<u32>) {
    let n = triangles.len();
    let mut seeds: Vec<u32> = (0..n as u32)
        .filter(|&t| infos[t as usize].kind == Kind::Regular)
        .collect();
    seeds.par_sort_unstable_by(|&a, &b| {
        infos[b as usize]
            .area
            .total_cmp(&infos[a as usize].area)
            .then(a.cmp(&b))
    });

    let mut region_of = vec![NO_PLANE; n];
    let mut tri_stamp = vec![NO_PLANE; n];
    let mut vert_stamp = vec![NO_PLANE; conn.vertex_count()];
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
            for &v in &conn.tri_verts[t as usize] {
                if vert_stamp[v as usize] == r {
                    continue;
                }
                vert_stamp[v as usize] = r;
                for &nb in conn.vert_tris(v) {
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
    (regions, region_of)
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
    let e = rectangle_axis(&hull, a, b);
    let (s0, s1, t0, t1) = extent(&hull, e);
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
        let vs = ctx.conn.tri_verts[t as usize];
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
            for &nb in ctx.conn.vert_tris(va) {
                if nb == t || !ctx.conn.tri_verts[nb as usize].contains(&vb) {
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
