//! Plane detection on scenes built to probe it (Cornell boxes, curved meshes, bent and
//! welded quads, degenerate input) and the grid geometry of the planes it finds.

use super::*;
use crate::test_util::{test_rng, uv_sphere};
use glam::{Quat, Vec3};
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

/// One axis of the bilinear weights: between two centres, held past the first and last, and
/// NaN or infinite coordinates read the border cells with finite weights.
#[test]
fn bilinear_axis_between_centres_and_at_the_borders() {
    assert_eq!(bilinear_axis(2.75, 8), (2, 3, 0.25));
    assert_eq!(bilinear_axis(0.2, 8), (0, 1, 0.0));
    assert_eq!(bilinear_axis(7.9, 8), (7, 7, 0.0));
    assert_eq!(bilinear_axis(0.7, 1), (0, 0, 0.0));
    assert_eq!(bilinear_axis(f32::NAN, 8), (0, 1, 0.0));
    assert_eq!(bilinear_axis(f32::INFINITY, 8), (7, 7, 0.0));
    assert_eq!(bilinear_axis(f32::NEG_INFINITY, 8), (0, 1, 0.0));
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
