//! Tight rectangles around a plane's vertices: the convex hull of the projected vertices and
//! the minimum-area rectangle around it, which has a side collinear with a hull edge.

use glam::{DVec2, DVec3};

/// Largest number of convex-hull edge directions tried when fitting the
/// minimum-area rectangle; larger hulls (finely tessellated discs) are sampled
/// evenly, which is harmless because their optimum is flat.
const MAX_HULL_DIRECTIONS: usize = 1024;

/// Convex hull (counter-clockwise, without collinear points) by Andrew's
/// monotone chain. Returns fewer than 3 points for degenerate input.
pub(super) fn convex_hull(mut pts: Vec<DVec2>) -> Vec<DVec2> {
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

/// Extent `(s0, s1, t0, t1)` of `hull` along the unit direction `e` (s) and `e.perp()` (t).
pub(super) fn extent(hull: &[DVec2], e: DVec2) -> (f64, f64, f64, f64) {
    let q = e.perp();
    let (mut s0, mut s1, mut t0, mut t1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for p in hull {
        let (s, t) = (p.dot(e), p.dot(q));
        s0 = s0.min(s);
        s1 = s1.max(s);
        t0 = t0.min(t);
        t1 = t1.max(t);
    }
    (s0, s1, t0, t1)
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
        let (s0, s1, t0, t1) = extent(hull, e);
        let area = (s1 - s0) * (t1 - t0);
        if area < best.0 * (1.0 - 1e-9) {
            best = (area, e);
        }
    }
    best.1
}

/// The `u` axis of the minimum-area rectangle around `hull`, as a unit direction in the
/// in-plane basis `(a, b)` of its points: along the rectangle's longer side, and signed so
/// that the largest world component of `a·e.x + b·e.y` is positive (the same plane always
/// gets the same axes).
pub(super) fn rectangle_axis(hull: &[DVec2], a: DVec3, b: DVec3) -> DVec2 {
    let mut e = min_area_direction(hull);
    // u along the longer side; v = n × u corresponds to e.perp() in 2D.
    let (s0, s1, t0, t1) = extent(hull, e);
    if t1 - t0 > s1 - s0 {
        e = e.perp();
    }
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
    e
}
