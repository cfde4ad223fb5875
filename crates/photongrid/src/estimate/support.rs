//! The surface a photon kernel covers off the planes. A gather sphere next to an edge, a
//! corner or the end of a thin shelf front holds photons from only part of the disc πr²; the
//! estimate divides them by the area of the receiving surface inside the sphere instead
//! (boundary-correct normalisation; the planes do the same with their polygons).

use super::photon_map::NORMAL_AGREEMENT;
use crate::accel::Accel;
use crate::scene::{Scene, Triangle};
use crate::settings::Settings;
use glam::{DVec2, Vec3};
use std::f32::consts::PI;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::OnceLock;

/// A disc whose surface is within this share of πr² counts as whole: below the kNN
/// estimate's own bias at a few hundred photons, and above the tessellation's error on curved
/// surfaces (the area of a sphere within a ball about one of its points is πr²).
const WHOLE_DISC_TOLERANCE: f32 = 0.005;

/// Not yet measured (an f32 NaN pattern in [`Surfaces`]'s clearances).
const UNKNOWN: u32 = u32::MAX;

/// The scene's surfaces as photon kernels see them.
pub struct Surfaces<'a> {
    accel: &'a Accel,
    triangles: &'a [Triangle],
    /// Per material: photons are stored on it (mirrors and glass hold none).
    receives: Vec<bool>,
    /// Built at the first query (renders with final gathering never ask).
    tables: OnceLock<Tables>,
    /// Largest radius a clearance is measured to: twice the largest a photon query reaches.
    reach: f32,
}

/// Per triangle: what decides most triangles without clipping, and per side (front, back),
/// measured when first queried, the radius about its centroid within which the surface is a
/// whole disc ([`WHOLE_DISC_TOLERANCE`]). Kernels inside it skip the triangles: on a finely
/// tessellated sphere they cost as much as the photon search.
struct Tables {
    patches: Vec<Patch>,
    clearance: Vec<[AtomicU32; 2]>,
}

impl<'a> Surfaces<'a> {
    /// The receiving surfaces of `scene`, found through its BVH, for photon queries of
    /// `settings` (whose `max_radius` bounds them).
    pub fn new(scene: &'a Scene, accel: &'a Accel, settings: &Settings) -> Self {
        let receives: Vec<bool> = scene.materials.iter().map(|m| m.receives_photons()).collect();
        let max_radius = settings.max_radius * scene.bounds.diagonal();
        Surfaces::of(&scene.triangles, &receives, accel, max_radius)
    }

    /// `triangles` (indexed by `accel`), of which those whose material `m` has `receives[m]`
    /// hold photons, for queries reaching `max_radius` at most.
    pub fn of(triangles: &'a [Triangle], receives: &[bool], accel: &'a Accel, max_radius: f32) -> Self {
        Surfaces {
            accel,
            triangles,
            receives: receives.to_vec(),
            tables: OnceLock::new(),
            reach: 2.0 * max_radius,
        }
    }

    fn tables(&self) -> &Tables {
        // Sequential: the first query comes from a parallel camera pass, and a rayon job
        // waiting inside `get_or_init` could pick up another query of the same lock.
        self.tables.get_or_init(|| {
            let receives = |t: &Triangle| self.receives.get(t.material as usize).copied().unwrap_or(false);
            Tables {
                patches: self.triangles.iter().map(|t| Patch::of(t, receives(t))).collect(),
                clearance: (0..self.triangles.len())
                    .map(|_| [AtomicU32::new(UNKNOWN), AtomicU32::new(UNKNOWN)])
                    .collect(),
            }
        })
    }

    /// For each squared radius `r2[j]`, the area of the receiving surface within √r2[j] of `x`
    /// that a photon query at `x` on triangle `triangle`, on the side `facing`, gathers from:
    /// triangles whose normal agrees with `facing` as a photon's must ([`NORMAL_AGREEMENT`]),
    /// taking each triangle's side by its winding relative to the query's triangle (so the
    /// inner faces of a closed solid, which photons never reach, do not count; an open sheet
    /// folded so that its other side faces the query is not counted either). Each
    /// triangle's part is the disc where the sphere cuts its plane, clipped to it. No area
    /// exceeds πr²: the rule shrinks the divisor where a disc leaves the surface, and
    /// overlapping triangles (a decal, doubled geometry) must not halve the estimate.
    pub fn kernel_areas(&self, x: Vec3, facing: Vec3, triangle: u32, r2: &[f32], areas: &mut [f32]) {
        let areas = &mut areas[..r2.len()];
        let Some(own) = self.triangles.get(triangle as usize) else {
            return flat_disc_areas(r2, areas);
        };
        let front = own.cross().dot(facing) >= 0.0;
        let reach = r2.iter().fold(0.0f32, |a, &b| a.max(b)).sqrt();
        let d = (x - self.tables().patches[triangle as usize].centroid).length();
        if reach + d <= self.clearance(triangle, front) {
            return flat_disc_areas(r2, areas);
        }
        for (r2, areas) in r2.chunks(32).zip(areas.chunks_mut(32)) {
            self.surface_in_spheres(x, facing, front, r2, areas);
        }
        for (a, &r2) in areas.iter_mut().zip(r2) {
            // A query point on a sliver the BVH rounds away: never divide by nothing.
            *a = if *a > 0.0 { a.min(PI * r2) } else { PI * r2 };
        }
    }

    /// The radius about triangle `t`'s centroid within which the surface on its side (`front`)
    /// is a whole disc, measured by doubling radii from the triangle's size on, up to twice
    /// the largest query radius (a gently curved mesh of a million triangles would otherwise
    /// be searched whole). Approximate: a deficit under the tolerance at one radius may be a
    /// larger share of a smaller disc inside it.
    fn clearance(&self, t: u32, front: bool) -> f32 {
        let slot = &self.tables().clearance[t as usize][usize::from(!front)];
        let known = slot.load(Ordering::Relaxed);
        if known != UNKNOWN {
            return f32::from_bits(known);
        }
        let patch = &self.tables().patches[t as usize];
        let (c, n) = (patch.centroid, patch.normal * if front { 1.0 } else { -1.0 });
        let mut r = 2.0 * patch.spread;
        let mut whole = 0.0;
        let mut area = [0.0];
        while r > 0.0 && r <= self.reach {
            self.surface_in_spheres(c, n, front, &[r * r], &mut area);
            if area[0] < (1.0 - WHOLE_DISC_TOLERANCE) * PI * r * r {
                break;
            }
            whole = r;
            r *= 2.0;
        }
        // Threads that race here measure the same value (it depends on the geometry only).
        slot.store(f32::to_bits(whole), Ordering::Relaxed);
        whole
    }

    /// [`Surfaces::kernel_areas`] from the triangles, for at most 32 radii.
    fn surface_in_spheres(&self, x: Vec3, facing: Vec3, front: bool, r2: &[f32], areas: &mut [f32]) {
        debug_assert!(r2.len() <= 32 && areas.len() >= r2.len());
        areas.fill(0.0);
        let side = if front { 1.0 } else { -1.0 };
        let reach = r2.iter().fold(0.0f32, |a, &b| a.max(b)).sqrt();
        let patches = &self.tables().patches;
        self.accel.for_each_near(x - reach, x + reach, |t| {
            let p = &patches[t as usize];
            let d = (x - p.centroid).length();
            if d > reach + p.spread || side * p.normal.dot(facing) <= NORMAL_AGREEMENT {
                return;
            }
            // Bounds on the triangle's distances from x decide the spheres it lies wholly
            // inside or outside; the others clip it.
            let (near, far) = ((d - p.spread).max(0.0).powi(2), (d + p.spread).powi(2));
            let mut clip = 0u32;
            for (j, (a, &r2)) in areas.iter_mut().zip(r2).enumerate() {
                if far <= r2 {
                    *a += p.area;
                } else if near < r2 {
                    clip |= 1 << j;
                }
            }
            if clip != 0 {
                add_clipped(&self.triangles[t as usize], p.normal, x, r2, clip, areas);
            }
        });
    }
}

/// A triangle's centroid, the radius about it that holds the triangle, its unit normal (zero
/// where photons are not stored) and its area.
struct Patch {
    centroid: Vec3,
    spread: f32,
    normal: Vec3,
    area: f32,
}

impl Patch {
    fn of(t: &Triangle, receives: bool) -> Self {
        let centroid = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
        Patch {
            centroid,
            spread: t.p.iter().fold(0.0f32, |m, p| m.max((*p - centroid).length())),
            normal: if receives {
                t.cross().normalize_or_zero()
            } else {
                Vec3::ZERO
            },
            area: t.area(),
        }
    }
}

/// The kernel areas of a plane without edges: πr² for each squared radius.
pub fn flat_disc_areas(r2: &[f32], areas: &mut [f32]) {
    for (a, &r2) in areas.iter_mut().zip(r2) {
        *a = PI * r2;
    }
}

/// Add to `areas[j]`, for the `j` set in `clip`, the area of triangle `tri` (unit normal `n`)
/// inside the sphere of squared radius `r2[j]` about `x`.
fn add_clipped(tri: &Triangle, n: Vec3, x: Vec3, r2: &[f32], clip: u32, areas: &mut [f32]) {
    let h = (x - tri.p[0]).dot(n);
    let foot = x - h * n;
    let u = (tri.p[1] - tri.p[0]).normalize_or_zero();
    let v = n.cross(u);
    let flat = tri.p.map(|p| {
        let d = p - foot;
        DVec2::new(d.dot(u) as f64, d.dot(v) as f64)
    });
    let near = distance_squared_to_triangle(flat) as f32 + h * h;
    let far = tri.p.iter().fold(0.0f32, |m, p| m.max((*p - x).length_squared()));
    for (j, (a, &r2)) in areas.iter_mut().zip(r2).enumerate() {
        if clip & (1 << j) == 0 || near >= r2 {
            continue;
        }
        *a += if far <= r2 {
            tri.area()
        } else {
            disc_triangle_area(flat, ((r2 - h * h) as f64).sqrt()) as f32
        };
    }
}

/// Squared distance from the origin to the triangle `t` (0 inside).
fn distance_squared_to_triangle(t: [DVec2; 3]) -> f64 {
    let side = |a: DVec2, b: DVec2| (b - a).perp_dot(-a);
    let (s0, s1, s2) = (side(t[0], t[1]), side(t[1], t[2]), side(t[2], t[0]));
    if (s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0) || (s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0) {
        return 0.0;
    }
    (0..3)
        .map(|i| {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            let d = b - a;
            let s = (-a.dot(d) / d.length_squared().max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
            (a + d * s).length_squared()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Area of the disc of radius `r` about the origin inside the triangle `t` (either winding):
/// the sum over the edges of the disc's part of the signed triangle (origin, edge).
pub fn disc_triangle_area(t: [DVec2; 3], r: f64) -> f64 {
    (0..3)
        .map(|i| disc_wedge_area(t[i], t[(i + 1) % 3], r))
        .sum::<f64>()
        .abs()
}

/// Signed area of the disc of radius `r` about the origin inside the triangle (origin, a, b):
/// straight where the edge ab runs inside the disc, circular sectors where it runs outside.
fn disc_wedge_area(a: DVec2, b: DVec2, r: f64) -> f64 {
    let sector = |p: DVec2, q: DVec2| 0.5 * r * r * atan2_approx(p.perp_dot(q), p.dot(q));
    let d = b - a;
    let (aa, bb, cc) = (d.dot(d), a.dot(d), a.dot(a) - r * r);
    let disc = bb * bb - aa * cc;
    if aa <= 0.0 || disc <= 0.0 {
        return sector(a, b);
    }
    let s = disc.sqrt();
    let t1 = ((-bb - s) / aa).clamp(0.0, 1.0);
    let t2 = ((-bb + s) / aa).clamp(0.0, 1.0);
    let (p1, p2) = (a + d * t1, a + d * t2);
    sector(a, p1) + 0.5 * p1.perp_dot(p2) + sector(p2, b)
}

/// atan2 within 1.2·10⁻⁵ rad (a minimax polynomial on [0, 1] and the octant's symmetries):
/// the clipped discs' sectors took a fifth of a camera pass with libm's.
fn atan2_approx(y: f64, x: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (num, den) = if ay > ax { (ax, ay) } else { (ay, ax) };
    if den == 0.0 {
        return 0.0;
    }
    let a = num / den;
    let s = a * a;
    let mut t = a * (0.999_866 + s * (-0.330_299_5 + s * (0.180_141 + s * (-0.085_133 + s * 0.020_835_1))));
    if ay > ax {
        t = FRAC_PI_2 - t;
    }
    if x < 0.0 {
        t = PI - t;
    }
    if y < 0.0 {
        -t
    } else {
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;
    use glam::Vec2;

    fn monte_carlo(t: [DVec2; 3], r: f64, rng: &mut Rng) -> f64 {
        let n = 400_000;
        let inside = |p: DVec2| {
            let s = |a: DVec2, b: DVec2| (b - a).perp_dot(p - a);
            let (d0, d1, d2) = (s(t[0], t[1]), s(t[1], t[2]), s(t[2], t[0]));
            (d0 >= 0.0 && d1 >= 0.0 && d2 >= 0.0) || (d0 <= 0.0 && d1 <= 0.0 && d2 <= 0.0)
        };
        let hits = (0..n)
            .filter(|_| {
                let p = DVec2::new(rng.uniform() as f64 * 2.0 - 1.0, rng.uniform() as f64 * 2.0 - 1.0) * r;
                p.length_squared() <= r * r && inside(p)
            })
            .count();
        hits as f64 / n as f64 * 4.0 * r * r
    }

    #[test]
    fn atan2_approx_is_close_everywhere() {
        let mut worst = 0.0f64;
        for i in 0..10_000 {
            let phi = -std::f64::consts::PI + std::f64::consts::TAU * (i as f64 + 0.5) / 10_000.0;
            for r in [1e-6, 1.0, 1e5] {
                let (y, x) = (r * phi.sin(), r * phi.cos());
                worst = worst.max((atan2_approx(y, x) - y.atan2(x)).abs());
            }
        }
        assert!(worst < 1.2e-5, "{worst}");
        assert_eq!(atan2_approx(0.0, 0.0), 0.0);
    }

    /// The closed form against counting random points, for triangles inside, around, across
    /// and beside the disc, in both windings.
    #[test]
    fn disc_triangle_area_matches_counting() {
        let mut rng = Rng::keyed(5, 0, 0);
        let cases = [
            [(-0.2, -0.2), (0.3, -0.1), (0.0, 0.4)], // inside
            [(-5.0, -5.0), (5.0, -5.0), (0.0, 8.0)], // around
            [(0.5, -2.0), (3.0, 0.0), (0.5, 2.0)],   // cut by an edge through the disc
            [(0.0, 0.0), (2.0, 0.0), (0.0, 2.0)],    // a corner at the centre: a quarter
            [(1.5, 1.5), (3.0, 1.5), (1.5, 3.0)],    // beside
            [(-0.9, 0.3), (0.9, 0.35), (0.1, -1.4)], // vertices in and out
        ];
        for c in cases {
            let t = c.map(|(x, y)| DVec2::new(x, y));
            let exact = disc_triangle_area(t, 1.0);
            let reversed = disc_triangle_area([t[2], t[1], t[0]], 1.0);
            let counted = monte_carlo(t, 1.0, &mut rng);
            assert!((exact - reversed).abs() < 1e-12, "{c:?}: {exact} vs {reversed}");
            assert!((exact - counted).abs() < 0.01, "{c:?}: {exact} vs counted {counted}");
        }
        let quarter = disc_triangle_area([DVec2::ZERO, DVec2::new(2.0, 0.0), DVec2::new(0.0, 2.0)], 1.0);
        assert!((quarter - std::f64::consts::PI / 4.0).abs() < 1e-12, "{quarter}");
    }

    fn tri(a: Vec3, b: Vec3, c: Vec3, material: u32) -> Triangle {
        let n = (b - a).cross(c - a).normalize();
        Triangle {
            p: [a, b, c],
            n: [n; 3],
            uv: [Vec2::ZERO; 3],
            material,
        }
    }

    /// A quad as two triangles, front towards the cross product of its sides.
    fn quad(o: Vec3, s: Vec3, t: Vec3, material: u32) -> [Triangle; 2] {
        [tri(o, o + s, o + s + t, material), tri(o, o + s + t, o + t, material)]
    }

    /// A thin board (a box 1 m × 4 cm × 0.4 m) lying on nothing: on its front face the
    /// kernel is the strip's part of the disc; on its top, the disc's part of the top only
    /// (the front and the bottom face other ways); a mirror's triangles never count.
    #[test]
    fn a_thin_board_counts_its_own_faces_only() {
        let (w, h, d) = (Vec3::X, Vec3::Y * 0.04, Vec3::Z * 0.4);
        let o = Vec3::ZERO;
        let mut triangles = Vec::new();
        triangles.extend(quad(o + d, w, h, 0)); // front (+z)
        triangles.extend(quad(o + h, d, w, 0)); // top (+y)
        triangles.extend(quad(o, w, d, 0)); // bottom (−y)
        triangles.extend(quad(o + d + Vec3::Z * 0.01, w, h, 1)); // a mirror just in front
        let accel = Accel::build(&triangles);
        let s = Surfaces::of(&triangles, &[true, false], &accel, 0.5);
        let r2 = [0.01f32 * 0.01, 0.1 * 0.1];
        let mut areas = [0.0; 2];
        // Mid-front, 2 cm up: a 1 cm disc lies within the strip, a 10 cm one keeps its
        // 4 cm-high band: 2·∫ over |y| ≤ 2 cm of √(r² − y²) dy.
        s.kernel_areas(Vec3::new(0.5, 0.02, 0.4), Vec3::Z, 0, &r2, &mut areas);
        let band = |r: f32, half: f32| {
            let a = (half / r).asin();
            2.0 * r * r * (a + a.sin() * a.cos())
        };
        assert!((areas[0] / (PI * r2[0]) - 1.0).abs() < 1e-3, "{areas:?}");
        assert!(
            (areas[1] / band(0.1, 0.02) - 1.0).abs() < 1e-3,
            "{} vs {}",
            areas[1],
            band(0.1, 0.02)
        );
        // The top's middle edge: half discs (the front faces +z, the bottom −y).
        s.kernel_areas(Vec3::new(0.5, 0.04, 0.4), Vec3::Y, 2, &r2, &mut areas);
        assert!((areas[1] / (0.5 * PI * r2[1]) - 1.0).abs() < 1e-3, "{areas:?}");
    }

    /// A plate of 64 × 64 small quads: kernels that skip the triangles inside the measured
    /// clearance give the triangles' own areas, a half disc at an edge and a quarter at a
    /// corner.
    #[test]
    fn a_tessellated_plate_is_clipped_at_its_edges_only() {
        let n = 64;
        let cell = 1.0 / n as f32;
        let mut triangles = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let o = Vec3::new(i as f32 * cell, 0.0, j as f32 * cell);
                triangles.extend(quad(o, Vec3::Z * cell, Vec3::X * cell, 0));
            }
        }
        let accel = Accel::build(&triangles);
        let s = Surfaces::of(&triangles, &[true], &accel, 0.5);
        let mut rng = Rng::keyed(9, 0, 0);
        let r2 = [0.01f32 * 0.01, 0.05 * 0.05, 0.1 * 0.1];
        let (mut fast, mut exact) = ([0.0; 3], [0.0; 3]);
        for _ in 0..400 {
            let x = Vec3::new(rng.uniform(), 0.0, rng.uniform());
            let t = ((x.x / cell) as usize).min(n - 1) * n + ((x.z / cell) as usize).min(n - 1);
            let t = 2 * t as u32 + u32::from((x.z / cell).fract() < (x.x / cell).fract());
            s.kernel_areas(x, Vec3::Y, t, &r2, &mut fast);
            s.surface_in_spheres(x, Vec3::Y, true, &r2, &mut exact);
            for j in 0..3 {
                assert!(
                    (fast[j] - exact[j]).abs() <= 0.006 * PI * r2[j],
                    "at {x}: {fast:?} vs {exact:?}"
                );
            }
        }
        // The shortcut does fire inside the plate.
        let middle = 2 * (32 * n + 32) as u32;
        assert!(s.clearance(middle, true) >= 0.2, "{}", s.clearance(middle, true));
        s.kernel_areas(Vec3::new(0.5, 0.0, 0.0), Vec3::Y, 2 * 32 * n as u32, &r2, &mut fast);
        assert!((fast[2] / (0.5 * PI * r2[2]) - 1.0).abs() < 1e-3, "{fast:?}");
        s.kernel_areas(Vec3::ZERO, Vec3::Y, 0, &r2, &mut fast);
        assert!((fast[2] / (0.25 * PI * r2[2]) - 1.0).abs() < 1e-3, "{fast:?}");
    }

    /// A quad seen from its back counts whole (its side by winding); a copy of it lying on it
    /// does not double the area.
    #[test]
    fn back_sides_and_doubled_triangles() {
        let mut triangles = quad(Vec3::new(-1.0, 0.0, -1.0), Vec3::Z * 2.0, Vec3::X * 2.0, 0).to_vec();
        let accel = Accel::build(&triangles);
        let s = Surfaces::of(&triangles, &[true], &accel, 0.5);
        let r2 = [0.1f32 * 0.1];
        let mut a = [0.0];
        s.kernel_areas(Vec3::ZERO, -Vec3::Y, 0, &r2, &mut a);
        assert!((a[0] / (PI * r2[0]) - 1.0).abs() < 1e-4, "from the back: {a:?}");
        triangles.extend_from_within(..);
        let accel = Accel::build(&triangles);
        let s = Surfaces::of(&triangles, &[true], &accel, 0.5);
        s.surface_in_spheres(Vec3::new(0.95, 0.0, 0.0), Vec3::Y, true, &r2, &mut a);
        assert!(a[0] > 1.5 * 0.5 * PI * r2[0], "the copy is counted: {a:?}");
        s.kernel_areas(Vec3::new(0.95, 0.0, 0.0), Vec3::Y, 0, &r2, &mut a);
        assert!(a[0] <= PI * r2[0] * 1.0001, "capped: {a:?}");
    }

    /// Light on a strip 4 cm wide (a shelf board's front), read by the nested discs of up to
    /// 400 photons: divided by πr² the discs that overhang the strip read it dark and stop
    /// widening where the darkening shows; divided by the strip's part of each disc they read
    /// it right and widen.
    #[test]
    fn nested_discs_on_a_strip_read_its_light() {
        use crate::estimate::PhotonMap;
        use crate::photon::{Photon, PhotonKind};
        use crate::spatial::KnnBuffer;
        let (len, width, per_m2) = (2.0f32, 0.04f32, 40_000.0f32);
        let triangles = quad(Vec3::new(-1.0, 0.0, -0.02), Vec3::X * len, Vec3::Z * width, 0)
            .map(|t| tri(t.p[0], t.p[2], t.p[1], 0));
        let accel = Accel::build(&triangles);
        let s = Surfaces::of(&triangles, &[true], &accel, 0.5);
        let mut rng = Rng::keyed(13, 0, 0);
        let n = (len * width * per_m2) as usize;
        let photons: Vec<Photon> = (0..n)
            .map(|_| {
                let p = Vec3::new(rng.uniform() * len - 1.0, 0.0, (rng.uniform() - 0.5) * width);
                Photon::new(
                    p,
                    crate::Rgb::splat(1.0 / per_m2),
                    Vec3::Y,
                    Vec3::Y,
                    PhotonKind::Caustic,
                )
            })
            .collect();
        let map = PhotonMap::build(photons, 100, len * width, 1.0);
        let mut buf = KnnBuffer::new();
        let (mut flat, mut clipped) = (0.0, 0.0);
        let (mut flat_count, mut clipped_count) = (0, 0);
        for i in 0..40 {
            let x = Vec3::new(-0.8 + 0.04 * i as f32, 0.0, 0.01 * ((i % 3) as f32 - 1.0));
            let t = u32::from(x.x - -1.0 < x.z + 0.02);
            let area = |r2: &[f32], a: &mut [f32]| s.kernel_areas(x, Vec3::Y, t, r2, a);
            let g = map.adaptive_knn(x, Vec3::Y, (400, 0.0), &area, &mut buf);
            clipped += crate::luminance(g.flux) / (PI * g.r2) / 40.0;
            clipped_count += g.count;
            let g = map.adaptive_knn(x, Vec3::Y, (400, 0.0), &flat_disc_areas, &mut buf);
            flat += crate::luminance(g.flux) / (PI * g.r2) / 40.0;
            flat_count += g.count;
        }
        assert!((clipped - 1.0f32).abs() < 0.05, "with the strip's areas: {clipped}");
        assert!(flat < 0.9, "with πr²: {flat}");
        assert!(
            clipped_count > 2 * flat_count,
            "the discs widen: {clipped_count} photons against {flat_count}"
        );
    }

    /// On a sphere the surface within a ball about one of its points is πr² (Archimedes):
    /// a curved surface keeps the flat kernel's area, tessellated or not.
    #[test]
    fn a_sphere_keeps_the_flat_area() {
        let triangles: Vec<Triangle> = crate::test_util::uv_sphere(Vec3::ZERO, 0.5, 96, 48)
            .into_iter()
            .map(|[a, b, c]| tri(a, b, c, 0))
            .collect();
        let accel = Accel::build(&triangles);
        let s = Surfaces::of(&triangles, &[true], &accel, 0.5);
        let r2 = [0.02f32 * 0.02, 0.1 * 0.1, 0.2 * 0.2];
        let mut areas = [0.0; 3];
        for (i, t) in triangles.iter().enumerate().step_by(97) {
            let x = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
            let x = x.normalize() * 0.5;
            s.kernel_areas(x, x.normalize(), i as u32, &r2, &mut areas);
            for (a, r2) in areas.iter().zip(r2) {
                assert!((a / (PI * r2) - 1.0).abs() < 0.02, "at {x}: {a} vs {}", PI * r2);
            }
        }
    }
}
