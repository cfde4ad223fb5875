//! The point grid against brute force: kNN and range queries over clustered, degenerate and
//! far-flung point sets, and a property test over random ones.

use super::*;
use crate::sampling::Rng;
use crate::test_util::test_rng;
use glam::Vec3;
use proptest::prelude::*;

#[derive(Clone, Debug)]
struct Item {
    p: Vec3,
    id: u32,
}

impl Positioned for Item {
    fn position(&self) -> Vec3 {
        self.p
    }
}

/// Random points for the tests, drawn from the crate's generator.
trait Points {
    fn range(&mut self, a: f32, b: f32) -> f32;
    fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3;
    fn on_box_faces(&mut self, half: f32) -> Vec3;
    fn in_ball(&mut self, c: Vec3, r: f32) -> Vec3;
}

impl Points for Rng {
    fn range(&mut self, a: f32, b: f32) -> f32 {
        a + (b - a) * self.uniform()
    }
    fn in_box(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        Vec3::new(self.range(lo.x, hi.x), self.range(lo.y, hi.y), self.range(lo.z, hi.z))
    }
    fn on_box_faces(&mut self, half: f32) -> Vec3 {
        let face = (self.next_u32() % 6) as usize;
        let u = self.range(-half, half);
        let v = self.range(-half, half);
        let s = if face.is_multiple_of(2) { half } else { -half };
        match face / 2 {
            0 => Vec3::new(s, u, v),
            1 => Vec3::new(u, s, v),
            _ => Vec3::new(u, v, s),
        }
    }
    fn in_ball(&mut self, c: Vec3, r: f32) -> Vec3 {
        loop {
            let v = self.in_box(Vec3::splat(-1.0), Vec3::splat(1.0));
            if v.length_squared() <= 1.0 {
                return c + v * r;
            }
        }
    }
}

fn items_from(points: Vec<Vec3>) -> Vec<Item> {
    points
        .into_iter()
        .enumerate()
        .map(|(i, p)| Item { p, id: i as u32 })
        .collect()
}

/// Compare `knn` with brute force; panics with a message on mismatch.
fn check_knn<F: Fn(&Item) -> bool + Copy>(
    g: &PointGrid<Item>,
    q: Vec3,
    k: usize,
    max_r: f32,
    accept: F,
    buf: &mut KnnBuffer,
) {
    let ret = g.knn(q, k, max_r, accept, buf);
    let max_r2 = max_r * max_r;
    let mut brute: Vec<(u32, f32)> = g
        .items()
        .iter()
        .enumerate()
        .filter(|(_, it)| accept(it))
        .map(|(i, it)| (i as u32, (it.p - q).length_squared()))
        .filter(|&(_, d2)| d2 <= max_r2)
        .collect();
    brute.sort_by(|a, b| a.1.total_cmp(&b.1));
    let want = k.min(brute.len());
    assert_eq!(
        buf.len(),
        want,
        "result count q={q:?} k={k} max_r={max_r} n={}",
        g.len()
    );
    let kth = if brute.len() >= k && k > 0 {
        brute[k - 1].1
    } else {
        max_r2
    };
    if k == 0 {
        assert_eq!(ret, 0.0);
        return;
    }
    assert_eq!(
        ret.to_bits(),
        kth.to_bits(),
        "k-th distance q={q:?} k={k} max_r={max_r}: got {ret}, want {kth}"
    );
    let mut seen = std::collections::HashSet::new();
    for &(i, d2) in buf.as_slice() {
        assert!(seen.insert(i), "duplicate index {i}");
        let it = &g.items()[i as usize];
        assert!(accept(it), "rejected item returned");
        assert_eq!(d2.to_bits(), (it.p - q).length_squared().to_bits());
        assert!(d2 <= kth, "item beyond k-th distance");
    }
    // Everything strictly closer than the k-th distance must be in the result.
    for &(i, d2) in &brute {
        if d2 < kth || (brute.len() < k) {
            assert!(seen.contains(&i), "missing item {i} at d2={d2} (kth={kth})");
        }
    }
}

fn check_within(g: &PointGrid<Item>, q: Vec3, r: f32) {
    let mut got: Vec<(u32, f32)> = Vec::new();
    g.for_each_within(q, r, |it, d2| got.push((it.id, d2)));
    let mut want: Vec<(u32, f32)> = g
        .items()
        .iter()
        .map(|it| (it.id, (it.p - q).length_squared()))
        .filter(|&(_, d2)| d2 <= r * r)
        .collect();
    got.sort_by_key(|a| a.0);
    want.sort_by_key(|a| a.0);
    assert_eq!(got.len(), want.len(), "within count q={q:?} r={r}");
    for (a, b) in got.iter().zip(&want) {
        assert_eq!(a.0, b.0);
        assert_eq!(a.1.to_bits(), b.1.to_bits());
    }
    assert_eq!(g.count_within(q, r), want.len());
}

fn box_points(n: usize, seed: u64) -> Vec<Vec3> {
    let mut rng = test_rng(seed);
    (0..n).map(|_| rng.on_box_faces(1.0)).collect()
}

#[test]
fn suggest_cell_size_formula() {
    let r = suggest_cell_size(1_000_000, 24.0, 100);
    let want = (100.0f64 * 24.0 / (std::f64::consts::PI * 1e6)).sqrt() as f32;
    assert!((r - want).abs() <= want * 1e-6);
    assert_eq!(suggest_cell_size(0, 1.0, 10), 1.0);
    assert_eq!(suggest_cell_size(10, 0.0, 10), 1.0);
}

#[test]
fn knn_box_faces_matches_brute_force() {
    let n = 60_000;
    let g = PointGrid::build(items_from(box_points(n, 1)), suggest_cell_size(n, 24.0, 50));
    assert_eq!(g.len(), n);
    let mut rng = test_rng(2);
    let mut buf = KnnBuffer::new();
    for i in 0..300 {
        let q = if i % 3 == 0 {
            rng.in_box(Vec3::splat(-1.2), Vec3::splat(1.2))
        } else {
            rng.on_box_faces(1.0)
        };
        for &k in &[1usize, 7, 50, 400] {
            check_knn(&g, q, k, f32::INFINITY, |_| true, &mut buf);
        }
        check_knn(&g, q, 50, 0.03, |_| true, &mut buf);
    }
}

#[test]
fn knn_with_various_cell_sizes() {
    let n = 5_000;
    let items = items_from(box_points(n, 3));
    for &cell in &[
        1e-9f32,
        1e-3,
        0.02,
        0.1,
        0.5,
        3.0,
        1e9,
        0.0,
        -1.0,
        f32::NAN,
        f32::INFINITY,
    ] {
        let g = PointGrid::build(items.clone(), cell);
        let root = &g.nodes[0];
        let cells = root.nx * root.ny * root.nz;
        assert!(cells <= 4 * n, "cell count {cells} not capped for cell size {cell}");
        assert!(g.cell_size() > 0.0 && g.cell_size().is_finite());
        if cell > 0.0 {
            assert!(
                g.cell_size() >= cell.min(2.0),
                "cell size shrank: {cell} -> {}",
                g.cell_size()
            );
        }
        if cell >= 3.0 {
            assert_eq!(cells, 1, "a huge cell size gives one top-level cell");
        }
        let mut rng = test_rng(4);
        let mut buf = KnnBuffer::default();
        for _ in 0..60 {
            let q = rng.on_box_faces(1.0);
            for &k in &[1usize, 20, 130] {
                check_knn(&g, q, k, f32::INFINITY, |_| true, &mut buf);
            }
            check_within(&g, q, 0.07);
        }
    }
}

#[test]
fn dense_cluster_in_sparse_field() {
    let mut rng = test_rng(5);
    let centre = Vec3::new(0.3, -0.2, 0.1);
    let mut pts: Vec<Vec3> = (0..20_000)
        .map(|_| rng.in_box(Vec3::splat(-5.0), Vec3::splat(5.0)))
        .collect();
    pts.extend((0..10_000).map(|_| rng.in_ball(centre, 0.001)));
    let g = PointGrid::build(items_from(pts), suggest_cell_size(20_000, 6.0 * 100.0, 30));
    assert!(g.nodes.len() > 1, "expected a child grid for the cluster");
    let mut buf = KnnBuffer::new();
    for i in 0..200 {
        let q = match i % 4 {
            0 => rng.in_ball(centre, 0.001),
            1 => rng.in_ball(centre, 0.01),
            2 => rng.in_ball(centre, 0.5),
            _ => rng.in_box(Vec3::splat(-5.0), Vec3::splat(5.0)),
        };
        for &k in &[1usize, 30, 300, 3000] {
            check_knn(&g, q, k, f32::INFINITY, |_| true, &mut buf);
        }
        check_knn(&g, q, 100, 0.0005, |_| true, &mut buf);
        check_within(&g, q, 0.0003);
        check_within(&g, q, 0.3);
    }
}

#[test]
fn caustic_disc_on_box() {
    // 20 % of the photons in a 5 cm disc on the floor: thousands share a top-level cell.
    let mut rng = test_rng(6);
    let n = 50_000;
    let mut pts = box_points(n * 4 / 5, 7);
    for _ in 0..n / 5 {
        let v = loop {
            let v = rng.in_box(Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0));
            if v.length_squared() <= 1.0 {
                break v;
            }
        };
        pts.push(Vec3::new(0.2, -0.3, -1.0) + v * 0.025);
    }
    let g = PointGrid::build(items_from(pts), suggest_cell_size(n, 24.0, 100));
    let mut buf = KnnBuffer::new();
    for i in 0..300 {
        let q = if i % 2 == 0 {
            Vec3::new(rng.range(0.15, 0.25), rng.range(-0.35, -0.25), -1.0)
        } else {
            rng.on_box_faces(1.0)
        };
        check_knn(&g, q, 100, f32::INFINITY, |_| true, &mut buf);
        check_knn(&g, q, 1, 0.01, |_| true, &mut buf);
        check_within(&g, q, 0.004);
    }
}

#[test]
fn queries_far_outside() {
    let n = 10_000;
    let g = PointGrid::build(items_from(box_points(n, 8)), 0.05);
    let mut buf = KnnBuffer::new();
    for q in [
        Vec3::new(1e4, 0.0, 0.0),
        Vec3::new(-3.0, 7.0, 2.0),
        Vec3::new(0.0, 0.0, -1e6),
        Vec3::splat(1e30),
    ] {
        for &k in &[1usize, 10, 100] {
            check_knn(&g, q, k, f32::INFINITY, |_| true, &mut buf);
            check_knn(&g, q, k, 5.0, |_| true, &mut buf);
        }
        check_within(&g, q, 10.0);
    }
}

#[test]
fn empty_regions_limited_by_max_radius() {
    // Two far-apart planes; queries between them find nothing within max_radius.
    let mut rng = test_rng(9);
    let mut pts: Vec<Vec3> = (0..5000)
        .map(|_| Vec3::new(rng.range(0.0, 1.0), rng.range(0.0, 1.0), 0.0))
        .collect();
    pts.extend((0..5000).map(|_| Vec3::new(rng.range(0.0, 1.0), rng.range(0.0, 1.0), 10.0)));
    let g = PointGrid::build(items_from(pts), 0.02);
    let mut buf = KnnBuffer::new();
    for _ in 0..100 {
        let q = Vec3::new(rng.range(0.0, 1.0), rng.range(0.0, 1.0), rng.range(0.5, 9.5));
        let ret = g.knn(q, 10, 0.4, |_| true, &mut buf);
        assert!(buf.is_empty());
        assert_eq!(ret, 0.4 * 0.4);
        for &mr in &[0.1f32, 0.6, 1.0, 4.0] {
            check_knn(&g, q, 10, mr, |_| true, &mut buf);
        }
    }
}

#[test]
fn degenerate_sets() {
    let mut buf = KnnBuffer::new();
    // 0 points.
    let g = PointGrid::<Item>::build(Vec::new(), 0.1);
    assert!(g.is_empty());
    assert_eq!(g.knn(Vec3::ZERO, 5, 2.0, |_| true, &mut buf), 4.0);
    assert!(buf.is_empty());
    assert_eq!(g.count_within(Vec3::ZERO, 1.0), 0);
    // 1 point.
    let g = PointGrid::build(items_from(vec![Vec3::new(1.0, 2.0, 3.0)]), 0.1);
    for q in [Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0), Vec3::splat(-50.0)] {
        for &k in &[1usize, 2, 10] {
            check_knn(&g, q, k, f32::INFINITY, |_| true, &mut buf);
            check_knn(&g, q, k, 1.0, |_| true, &mut buf);
        }
        check_within(&g, q, 3.8);
    }
    // All points identical.
    let g = PointGrid::build(items_from(vec![Vec3::new(0.5, 0.5, 0.5); 3000]), 0.01);
    for q in [Vec3::ZERO, Vec3::splat(0.5), Vec3::new(0.5, 0.5, 0.51)] {
        for &k in &[1usize, 10, 2999, 3000, 5000] {
            check_knn(&g, q, k, f32::INFINITY, |_| true, &mut buf);
        }
        check_within(&g, q, 0.02);
    }
    // Coordinates spanning more than f32::MAX (extent overflows, distances overflow to inf).
    let mut pts = box_points(300, 17);
    pts.extend([Vec3::splat(3e38), Vec3::splat(-3e38), Vec3::new(3e38, -3e38, 0.0)]);
    let g = PointGrid::build(items_from(pts), 0.1);
    for q in [Vec3::ZERO, Vec3::splat(1e38), Vec3::new(1.0, 0.5, -1.0)] {
        for &k in &[1usize, 10, 303] {
            check_knn(&g, q, k, f32::INFINITY, |_| true, &mut buf);
            check_knn(&g, q, k, 1.5, |_| true, &mut buf);
        }
        check_within(&g, q, 0.5);
    }
    // k larger than the number of points, and k = 0.
    let g = PointGrid::build(items_from(box_points(500, 10)), 0.1);
    check_knn(&g, Vec3::ZERO, 501, f32::INFINITY, |_| true, &mut buf);
    check_knn(&g, Vec3::ZERO, 10_000, 1.2, |_| true, &mut buf);
    check_knn(&g, Vec3::ZERO, 0, 1.2, |_| true, &mut buf);
    assert!(buf.is_empty());
}

#[test]
fn non_finite_items_are_dropped() {
    let mut pts = box_points(1000, 11);
    pts[3] = Vec3::new(f32::NAN, 0.0, 0.0);
    pts[500] = Vec3::new(0.0, f32::INFINITY, 0.0);
    let g = PointGrid::build(items_from(pts), 0.1);
    assert_eq!(g.len(), 998);
    assert!(g.items().iter().all(|it| it.p.is_finite()));
    let mut buf = KnnBuffer::new();
    check_knn(&g, Vec3::ZERO, 998, f32::INFINITY, |_| true, &mut buf);
    // Non-finite queries find nothing.
    g.knn(Vec3::NAN, 3, 1.0, |_| true, &mut buf);
    assert!(buf.is_empty());
}

#[test]
fn accept_filter_is_honoured() {
    let n = 20_000;
    let g = PointGrid::build(items_from(box_points(n, 12)), suggest_cell_size(n, 24.0, 30));
    let mut rng = test_rng(13);
    let mut buf = KnnBuffer::new();
    let even = |it: &Item| it.id.is_multiple_of(2);
    let rare = |it: &Item| it.id.is_multiple_of(97);
    for _ in 0..200 {
        let q = rng.on_box_faces(1.0);
        check_knn(&g, q, 30, f32::INFINITY, even, &mut buf);
        assert!(buf.iter().all(|&(i, _)| g.items()[i as usize].id.is_multiple_of(2)));
        check_knn(&g, q, 30, f32::INFINITY, rare, &mut buf);
        check_knn(&g, q, 30, 0.2, rare, &mut buf);
        // A capturing (non-zero-sized) filter takes the item-prefetching path.
        let (m, face_x) = (3u32, q.x.abs() > 0.999);
        let capturing = move |it: &Item| it.id % m != 1 && (it.p.x.abs() > 0.999) == face_x;
        assert_ne!(std::mem::size_of_val(&capturing), 0);
        check_knn(&g, q, 30, f32::INFINITY, capturing, &mut buf);
        check_knn(&g, q, 300, 0.3, capturing, &mut buf);
        check_knn(&g, q, 5, 1.0, |_| false, &mut buf);
        assert!(buf.is_empty());
    }
}

#[test]
fn results_can_be_sorted() {
    let g = PointGrid::build(items_from(box_points(2000, 14)), 0.1);
    let mut buf = KnnBuffer::new();
    let r2 = g.knn(Vec3::new(1.0, 0.2, 0.3), 40, f32::INFINITY, |_| true, &mut buf);
    buf.sort_by_distance();
    let d: Vec<f32> = buf.iter().map(|x| x.1).collect();
    assert!(d.windows(2).all(|w| w[0] <= w[1]));
    assert_eq!(*d.last().unwrap(), r2);
}

#[test]
fn bounded_memory_for_huge_box() {
    let mut rng = test_rng(15);
    let pts: Vec<Vec3> = (0..1000)
        .map(|_| rng.in_box(Vec3::splat(-5e5), Vec3::splat(5e5)))
        .collect();
    let g = PointGrid::build(items_from(pts), 1e-4);
    assert!(g.memory_bytes() < 1 << 20, "memory {} bytes", g.memory_bytes());
    let mut buf = KnnBuffer::new();
    for _ in 0..50 {
        let q = rng.in_box(Vec3::splat(-6e5), Vec3::splat(6e5));
        check_knn(&g, q, 10, f32::INFINITY, |_| true, &mut buf);
        check_within(&g, q, 1e5);
    }
    // A small dense room plus far-away stragglers: the room gets refined.
    let mut pts = box_points(20_000, 16);
    pts.extend((0..50).map(|_| rng.in_box(Vec3::splat(-5e5), Vec3::splat(5e5))));
    let g = PointGrid::build(items_from(pts), 1e-4);
    assert!(g.memory_bytes() < 4 << 20, "memory {}", g.memory_bytes());
    for _ in 0..100 {
        let q = rng.on_box_faces(1.0);
        check_knn(&g, q, 50, f32::INFINITY, |_| true, &mut buf);
        check_within(&g, q, 0.05);
    }
}

/// Point sets for the property test.
fn gen_points(mode: u8, n: usize, seed: u64, scale: f32) -> Vec<Vec3> {
    let mut rng = test_rng(seed);
    let s = scale;
    (0..n)
        .map(|i| match mode {
            0 => rng.in_box(Vec3::splat(-s), Vec3::splat(s)),
            1 => rng.on_box_faces(s),
            2 => {
                if i % 3 == 0 {
                    rng.in_ball(Vec3::splat(0.1 * s), 1e-3 * s)
                } else {
                    rng.on_box_faces(s)
                }
            }
            3 => Vec3::splat(0.25 * s),
            4 => {
                // Grid-aligned points with many exact ties.
                let v = rng.next_u32();
                Vec3::new(
                    (v % 5) as f32 * 0.25 * s,
                    ((v >> 8) % 5) as f32 * 0.25 * s,
                    ((v >> 16) % 2) as f32 * 0.25 * s,
                )
            }
            _ => Vec3::new(rng.range(-s, s), 0.3 * s, rng.range(-s, s)),
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    #[test]
    fn prop_knn_and_range_match_brute_force(
        mode in 0u8..6,
        n in 0usize..400,
        seed in any::<u64>(),
        scale_exp in -3i32..5,
        cell_exp in -12i32..12,
        k in 1usize..80,
        max_r_frac in prop_oneof![Just(f32::INFINITY), 0.0f32..1.5],
        filter in 0u8..3,
    ) {
        let scale = 10f32.powi(scale_exp);
        let cell = 10f32.powi(cell_exp) * scale;
        let g = PointGrid::build(items_from(gen_points(mode, n, seed, scale)), cell);
        prop_assert_eq!(g.len(), n);
        let mut rng = test_rng(seed ^ 0xABCD);
        let mut buf = KnnBuffer::new();
        let max_r = max_r_frac * scale;
        for i in 0..12 {
            let q = match i % 3 {
                0 => rng.in_box(Vec3::splat(-1.5 * scale), Vec3::splat(1.5 * scale)),
                1 if n > 0 => g.items()[rng.next_u32() as usize % n].p,
                _ => rng.on_box_faces(scale),
            };
            match filter {
                0 => check_knn(&g, q, k, max_r, |_| true, &mut buf),
                1 => check_knn(&g, q, k, max_r, |it| it.id.is_multiple_of(2), &mut buf),
                _ => check_knn(&g, q, k, max_r, |it| it.id % 7 == 3, &mut buf),
            }
            check_within(&g, q, rng.range(0.0, 0.6) * scale);
        }
    }
}
