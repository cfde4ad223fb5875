//! Exact receiving area per voxel: each triangle is clipped (Sutherland–Hodgman, in f64 grid
//! space) slab by slab: first against the x-slab `[i, i+1]`, the result against y-slabs within
//! its y-range, that against z-slabs within its z-range. The cost follows the number of voxels
//! actually crossed. Clip planes are integers in grid space, so a triangle lying on a voxel
//! face is visited in exactly one voxel layer (the one `floor` selects) and is never double
//! counted; pieces of zero area are not stored.

use glam::DVec3;

/// Clipped pieces smaller than this (in voxel-face units, i.e. `× s²`) are discarded.
const MIN_PIECE_AREA: f64 = 1e-12;

const MAX_POLY: usize = 16;

#[derive(Clone, Copy)]
struct Poly {
    v: [DVec3; MAX_POLY],
    n: usize,
}

impl Poly {
    fn empty() -> Self {
        Poly {
            v: [DVec3::ZERO; MAX_POLY],
            n: 0,
        }
    }

    fn triangle(t: [DVec3; 3]) -> Self {
        let mut p = Poly::empty();
        p.v[..3].copy_from_slice(&t);
        p.n = 3;
        p
    }

    #[inline]
    fn push(&mut self, p: DVec3) {
        // A convex polygon gains at most one vertex per plane (3 + 6 = 9 < MAX_POLY); the
        // guard only matters for numerically non-convex slivers, whose area is negligible.
        if self.n < MAX_POLY {
            self.v[self.n] = p;
            self.n += 1;
        }
    }

    /// Keep the part with `p[axis] >= value` (`keep_above`) or `p[axis] <= value`.
    fn clip(&self, axis: usize, value: f64, keep_above: bool) -> Poly {
        let mut out = Poly::empty();
        if self.n == 0 {
            return out;
        }
        let dist = |p: DVec3| if keep_above { p[axis] - value } else { value - p[axis] };
        let mut a = self.v[self.n - 1];
        let mut da = dist(a);
        for i in 0..self.n {
            let b = self.v[i];
            let db = dist(b);
            if (da >= 0.0) != (db >= 0.0) {
                let t = da / (da - db);
                let mut p = a + (b - a) * t;
                p[axis] = value;
                out.push(p);
            }
            if db >= 0.0 {
                out.push(b);
            }
            a = b;
            da = db;
        }
        out
    }

    fn slab(&self, axis: usize, i: i32) -> Poly {
        let lo = f64::from(i);
        self.clip(axis, lo, true).clip(axis, lo + 1.0, false)
    }

    fn area(&self) -> f64 {
        if self.n < 3 {
            return 0.0;
        }
        let o = self.v[0];
        let mut s = DVec3::ZERO;
        for i in 1..self.n - 1 {
            s += (self.v[i] - o).cross(self.v[i + 1] - o);
        }
        0.5 * s.length()
    }

    fn floor_range(&self, axis: usize) -> (i32, i32) {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for p in &self.v[..self.n] {
            lo = lo.min(p[axis]);
            hi = hi.max(p[axis]);
        }
        (lo.floor() as i32, hi.floor() as i32)
    }
}

/// Split a grid-space triangle into per-voxel pieces; `emit(key, area_in_voxel_units)`.
pub(super) fn clip_triangle(tri: [DVec3; 3], emit: &mut impl FnMut([i32; 3], f64)) {
    let lo = tri[0].min(tri[1]).min(tri[2]);
    let hi = tri[0].max(tri[1]).max(tri[2]);
    let kl = [lo.x.floor() as i32, lo.y.floor() as i32, lo.z.floor() as i32];
    let kh = [hi.x.floor() as i32, hi.y.floor() as i32, hi.z.floor() as i32];
    let full = Poly::triangle(tri);
    if kl == kh {
        let a = full.area();
        if a > MIN_PIECE_AREA {
            emit(kl, a);
        }
        return;
    }
    for ix in kl[0]..=kh[0] {
        let px = full.slab(0, ix);
        if px.n < 3 {
            continue;
        }
        let (y0, y1) = px.floor_range(1);
        for iy in y0..=y1 {
            let pxy = px.slab(1, iy);
            if pxy.n < 3 {
                continue;
            }
            let (z0, z1) = pxy.floor_range(2);
            for iz in z0..=z1 {
                let piece = if z0 == z1 { pxy } else { pxy.slab(2, iz) };
                let a = piece.area();
                if a > MIN_PIECE_AREA {
                    emit([ix, iy, iz], a);
                }
            }
        }
    }
}
