//! The paper's grid method, checked on its own terms: which triangles of the sample scenes
//! become planes, where the shadow fallback switches to kNN, planes without photons or
//! smaller than a cell, continuity of the interpolated counts across cells and across the
//! border of two planes, and what counting flux instead of photons changes.

use glam::Vec3;
use photongrid::accel::Accel;
use photongrid::grid::planes::{PlaneSet, NO_PLANE};
use photongrid::grid::PlaneGrids;
use photongrid::photon::{trace_photons, TraceSettings};
use photongrid::scene::Scene;
use photongrid::settings::GridQuantity;
use photongrid::settings::{DirectLighting, Method};
use photongrid::Settings;
use photongrid_testkit::harness::*;
use photongrid_testkit::*;

fn describe(scene: &Scene, set: &PlaneSet) -> String {
    let mut s = String::new();
    for (i, p) in set.planes.iter().enumerate() {
        let mats: std::collections::BTreeSet<&str> = p
            .triangles
            .iter()
            .map(|&t| {
                scene.materials[scene.triangles[t as usize].material as usize]
                    .name
                    .as_str()
            })
            .collect();
        s += &format!(
            "plane {i}: {} triangles, normal {:.3}, {:.3}×{:.3} m, area {:.4} m², {}×{} cells, materials {:?}\n",
            p.triangles.len(),
            p.normal,
            p.size_u,
            p.size_v,
            p.area,
            p.res_u,
            p.res_v,
            mats
        );
    }
    s
}

fn material_name(scene: &Scene, t: usize) -> &str {
    &scene.materials[scene.triangles[t].material as usize].name
}

// ---------------------------------------------------------------------------------------------
// Plane detection on the samples.

#[test]
fn cornell_glass_planes() {
    let scene = load(&sample("cornell_glass.glb"));
    let set = PlaneGrids::detect(&scene.triangles, 128);
    eprintln!("{}", describe(&scene, &set));
    // The sphere (the glass triangles) is never on a plane.
    let glass: Vec<usize> = (0..scene.triangles.len())
        .filter(|&t| scene.materials[scene.triangles[t].material as usize].is_specular())
        .collect();
    assert_eq!(glass.len(), 9024, "the sphere's triangles");
    let on_plane = glass.iter().filter(|&&t| set.plane_of_triangle[t] != NO_PLANE).count();
    assert_eq!(on_plane, 0, "{on_plane} sphere triangles were put on a plane");
    // Every other triangle (floor, ceiling, three walls: 2 each; the box: 12) is on a plane,
    // each plane is one rectangle of two triangles: 5 room planes + 6 box faces (the bottom face,
    // hidden against the floor, is a plane of its own: it faces down, the floor up).
    let rest: Vec<usize> = (0..scene.triangles.len()).filter(|t| !glass.contains(t)).collect();
    assert_eq!(rest.len(), 22);
    for &t in &rest {
        assert_ne!(
            set.plane_of_triangle[t],
            NO_PLANE,
            "triangle {t} ({}) is on no plane",
            material_name(&scene, t)
        );
    }
    assert_eq!(set.planes.len(), 11, "{}", describe(&scene, &set));
    for p in &set.planes {
        assert_eq!(p.triangles.len(), 2, "{}", describe(&scene, &set));
        // A rectangle: the two triangles fill the bounding rectangle.
        assert!(
            (p.area / (p.size_u * p.size_v) - 1.0).abs() < 1e-3,
            "plane of area {} in a {}×{} rectangle",
            p.area,
            p.size_u,
            p.size_v
        );
    }
    // The five room planes are the five large ones (2 m walls): 128 × 128 cells.
    let large = set.planes.iter().filter(|p| p.size_u > 1.9).count();
    assert_eq!(large, 5);
    // The (rotated) box: six planes whose normals are ± three orthogonal axes; its bottom,
    // hidden against the floor, is one of them (it faces down, the floor up).
    let small: Vec<Vec3> = set.planes.iter().filter(|p| p.size_u < 1.9).map(|p| p.normal).collect();
    assert_eq!(small.len(), 6);
    for n in &small {
        assert_eq!(
            small.iter().filter(|m| m.dot(*n) < -0.999).count(),
            1,
            "box face {n} has no opposite"
        );
        assert_eq!(small.iter().filter(|m| m.dot(*n).abs() < 1e-3).count(), 4);
    }
}

#[test]
fn curved_3d_planes() {
    let scene = load(&sample("curved_3d.glb"));
    let set = PlaneGrids::detect(&scene.triangles, 128);
    eprintln!(
        "curved_3d: {} triangles, {} plane(s)\n{}",
        scene.triangles.len(),
        set.planes.len(),
        describe(&scene, &set)
    );
    let on_plane = set.plane_of_triangle.iter().filter(|&&p| p != NO_PLANE).count();
    eprintln!("{on_plane} triangles on planes");
    // Suzanne and the torus: no plane. The trough (a half cylinder, 1536 triangles): only its two
    // rim strips, the outermost row of facets on each side, 4 m × 5 cm, vertical. They are
    // exactly flat (16 coplanar triangles) and half of their boundary is the trough's open rim
    // (sharp), so the smooth share of their boundary is just under the 50 % that rejects facets
    // of a curved surface; every other row of facets borders smooth neighbours on both long
    // sides and is rejected. As planes they get 128 × 2 cells of 3.1 × 2.5 cm: harmless (a flat
    // strip), and they hold 32 of the 23 424 triangles.
    assert!(set.planes.len() <= 2, "{}", describe(&scene, &set));
    for p in &set.planes {
        for &t in &p.triangles {
            assert_eq!(
                material_name(&scene, t as usize),
                "TroughWhite",
                "{}",
                describe(&scene, &set)
            );
        }
        assert!(p.triangles.len() <= 16 && p.size_v < 0.06, "{}", describe(&scene, &set));
        assert!(p.normal.y.abs() < 0.05, "a rim strip is vertical: {}", p.normal);
    }
    assert!(on_plane <= 32);
}

// ---------------------------------------------------------------------------------------------
// The shadow fallback.

/// A 2 m floor, half of it (x > 0.15 m) in the shadow of a white shelf 0.5 m up; the
/// shadowed half gets only light bounced off the floor and the shelf's underside, well under
/// the shadow count per cell. Lit side: the part under the light (x −0.75…0, |z| < 0.5), where
/// cells hold more than the shadow count (farther out, at 500 000 photons, the lit floor's
/// cells drop below 2 photons too and fall back as well).
#[test]
fn shadow_fallback_switches_where_it_should() {
    let view = TopView {
        cx: 0.0,
        cz: 0.0,
        ymag: 0.75,
        height: 0.3,
        w: 64,
        h: 48,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(0.8));
    add_object(&mut g, "Floor", rect_up(-1.0, 1.0, -1.0, 1.0, 0.0), white);
    add_object(&mut g, "Shelf", box_prim([0.0, 0.5, -1.2], [1.2, 0.52, 1.2]), white);
    add_point_light(&mut g, [-0.3, 1.5, 0.0], 2000.0);
    view.add_camera(&mut g);
    let dir = TempDir::new("fallback");
    let scene = load(&g.write_glb(dir.path(), "fallback.glb"));
    view.check_camera(&scene);
    let x_edge = -0.3 + 0.3 * 1.5 / 1.0; // the shelf's edge (0, 0.5) seen from the light
    let settings = Settings {
        photons: 500_000,
        neighbours: 100,
        spp: 1,
        width: Some(view.w),
        height: Some(view.h),
        direct: DirectLighting::Photons,
        caustic_photons: 0,
        gather: 0, // the paper's setting: the photon map shown directly
        method: Method::Adaptive,
        seed: 5,
        // The mechanism under test, at a threshold this photon count exceeds in the lit half.
        shadow_count: 2.0,
        ..Settings::default()
    };
    let prepared = prepare_adaptive(&scene, &settings);
    let grids = prepared.grids.paper.as_ref().and_then(|g| g.planes.as_ref()).unwrap();
    let floor_tri = (0..scene.triangles.len())
        .find(|&t| scene.triangles[t].p.iter().all(|p| p.y == 0.0))
        .unwrap() as u32;
    assert_ne!(grids.set.plane_of_triangle[floor_tri as usize], NO_PLANE);
    let adaptive = render_prepared(&scene, &prepared, &settings);
    let knn = render_prepared(
        &scene,
        &prepared,
        &Settings {
            method: Method::Knn,
            ..settings.clone()
        },
    );
    // Filtered count over each pixel's footprint (5 × 5 points).
    let count_range = |px: u32, py: u32| -> (f32, f32) {
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for i in 0..5 {
            for j in 0..5 {
                let (x, z) = view.film_to_world(px as f64 + i as f64 / 4.0, py as f64 + j as f64 / 4.0);
                let (c, _) = grids.count_at(floor_tri, Vec3::new(x as f32, 0.0, z as f32)).unwrap();
                lo = lo.min(c);
                hi = hi.max(c);
            }
        }
        (lo, hi)
    };
    let (mut shadow_px, mut fallback, mut identical, mut lit_knn) = (0, 0, 0, 0);
    let (mut lit_px, mut lit_grid, mut differ) = (0, 0, 0);
    for py in 0..view.h {
        for px in 0..view.w {
            let i = (py * view.w + px) as usize;
            let (x, z) = view.center(px, py);
            let (lo, hi) = count_range(px, py);
            if x > x_edge + 0.15 {
                shadow_px += 1;
                if hi < settings.shadow_count {
                    fallback += 1;
                    // The code returns the kNN gather: the same bits.
                    assert_eq!(
                        adaptive.color[i], knn.color[i],
                        "pixel ({px}, {py}) at x = {x:.3}: count ≤ {hi} < {} but adaptive ≠ kNN",
                        settings.shadow_count
                    );
                    identical += 1;
                    if knn.color[i].x > 0.0 {
                        lit_knn += 1;
                    }
                }
            } else if x < x_edge - 0.15 && x > -0.75 && z.abs() < 0.5 {
                lit_px += 1;
                if lo >= settings.shadow_count {
                    lit_grid += 1;
                    if adaptive.color[i] != knn.color[i] {
                        differ += 1;
                    }
                }
            }
        }
    }
    eprintln!(
        "shadowed half: {fallback}/{shadow_px} pixels below the shadow count (all identical to kNN: \
         {identical}), {lit_knn} of them with indirect light; lit half: {lit_grid}/{lit_px} above it, \
         {differ} differ from kNN"
    );
    assert!(fallback as f64 >= 0.95 * shadow_px as f64, "{fallback}/{shadow_px}");
    assert!(
        lit_knn as f64 >= 0.9 * fallback as f64,
        "kNN is black in the shadow: the test means nothing"
    );
    assert!(lit_grid as f64 >= 0.95 * lit_px as f64, "{lit_grid}/{lit_px}");
    assert!(differ as f64 >= 0.95 * lit_grid as f64, "{differ}/{lit_grid}");
}

// ---------------------------------------------------------------------------------------------
// No photons; smaller than a cell.

#[test]
fn plane_without_photons_and_tiny_plane() {
    // A lit floor (±5 m) and, 1 m below it, a quad no photon can reach (the floor is opaque and
    // photons bounce upwards; farther than the largest gather radius from the floor's photons).
    let view = TopView {
        cx: 0.0,
        cz: 0.0,
        ymag: 0.375,
        height: -0.5,
        w: 32,
        h: 24,
    };
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(0.5));
    add_object(&mut g, "Floor", rect_up(-5.0, 5.0, -5.0, 5.0, 0.0), white);
    add_object(&mut g, "Dark", rect_up(-0.5, 0.5, -0.5, 0.5, -1.0), white);
    add_point_light(&mut g, [0.0, 1.0, 0.0], 1000.0);
    view.add_camera(&mut g);
    let dir = TempDir::new("dark");
    let scene = load(&g.write_glb(dir.path(), "dark.glb"));
    assert!(
        0.05 * scene.bounds.diagonal() < 1.0,
        "the floor's photons must be out of reach"
    );
    let dark_tri = (0..scene.triangles.len())
        .find(|&t| scene.triangles[t].p[0].y == -1.0)
        .unwrap();
    for shadow_count in [2.0, 0.0] {
        let settings = Settings {
            photons: 100_000,
            spp: 1,
            width: Some(view.w),
            height: Some(view.h),
            direct: DirectLighting::Photons,
            method: Method::Adaptive,
            shadow_count,
            ..Settings::default()
        };
        let prepared = prepare_adaptive(&scene, &settings);
        let grids = prepared.grids.paper.as_ref().and_then(|g| g.planes.as_ref()).unwrap();
        let plane = grids.set.plane_of_triangle[dark_tri];
        assert_ne!(plane, NO_PLANE, "the dark quad should be a plane");
        assert_eq!(grids.raw[plane as usize].sum(), 0.0);
        assert!(grids.filtered[plane as usize].data.iter().all(|&c| c == 0.0));
        let film = render_prepared(&scene, &prepared, &settings);
        assert_eq!(film.nonfinite(), 0);
        assert!(
            film.color.iter().all(|c| *c == Vec3::ZERO),
            "light on a plane no photon reaches (shadow count {shadow_count})"
        );
    }

    // A 1 cm quad floating 1 cm above a 20 cm floor, both detected planes (the quad is 0.25 %
    // of the area); with 8 cells per side the floor's cells (2.5 cm) are larger than the whole
    // quad. The quad catches about 15 of 200 000 photons (0.2 per cell of its own grid): with the
    // shadow fallback (count < 2), without it (shadow count 0; with k = 100 fewer than k photons
    // lie within the largest gather radius, so kNN is used anyway) and with k = 10 (the assumed
    // radius from a count of 0.2 per cell is used).
    let view = TopView {
        cx: 0.05,
        cz: 0.0,
        ymag: 0.0075,
        height: 0.1,
        w: 32,
        h: 24,
    };
    let (qx, qh, half, light, cd) = (0.05, 0.01, 0.005, [0.0, 0.3, 0.0], 300.0);
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(0.5));
    add_object(&mut g, "Floor", rect_up(-0.1, 0.1, -0.1, 0.1, 0.0), white);
    add_object(&mut g, "Tiny", rect_up(qx - half, qx + half, -half, half, qh), white);
    add_point_light(&mut g, light, cd);
    view.add_camera(&mut g);
    let scene = load(&g.write_glb(dir.path(), "tiny.glb"));
    view.check_camera(&scene);
    let tiny_tri = (0..scene.triangles.len())
        .find(|&t| scene.triangles[t].p[0].y > 0.0)
        .unwrap();
    let l = [light[0] as f64, light[1] as f64, light[2] as f64];
    let truth = view.truth(&|x, z| point_radiance(0.5, cd as f64, l, [x, qh as f64, z], [0.0, 1.0, 0.0]));
    let hp = 0.5 * view.pixel_size();
    let on_quad = view.select(&|x, z| (x - qx as f64).abs() + hp <= half as f64 && z.abs() + hp <= half as f64);
    assert!(on_quad.len() > 100);
    for (shadow_count, k) in [(2.0, 100), (0.0, 100), (0.0, 10)] {
        let settings = Settings {
            photons: 200_000,
            neighbours: k,
            spp: 2,
            width: Some(view.w),
            height: Some(view.h),
            direct: DirectLighting::Photons,
            max_photon_depth: 1,
            method: Method::Adaptive,
            grid_res: 8,
            shadow_count,
            ..Settings::default()
        };
        let prepared = prepare_adaptive(&scene, &settings);
        let grids = prepared.grids.paper.as_ref().and_then(|g| g.planes.as_ref()).unwrap();
        assert_eq!(grids.set.planes.len(), 2, "floor and tiny quad");
        let plane = grids.set.plane_of_triangle[tiny_tri];
        assert_ne!(plane, NO_PLANE);
        let floor_plane = &grids.set.planes[1 - plane as usize];
        let floor_cell = floor_plane.size_u / floor_plane.res_u as f32;
        assert!(
            floor_cell > 2.0 * half,
            "a floor cell ({floor_cell} m) larger than the quad"
        );
        let counted = grids.raw[plane as usize].sum();
        let (c, area) = grids.count_at(tiny_tri as u32, Vec3::new(qx, qh, 0.0)).unwrap();
        assert!(c.is_finite() && area > 0.0);
        let film = render_prepared(&scene, &prepared, &settings);
        assert_eq!(film.nonfinite(), 0);
        let ratio = sum_over(&film, &on_quad) / sum_truth(&truth, &on_quad);
        eprintln!(
            "tiny plane (shadow count {shadow_count}, k = {k}): {counted} photons counted on it, count at its \
             centre {c:.3} per cell of {:.2} mm², mean radiance {ratio:.3} × the closed form",
            area * 1e6
        );
        // Sensible: the right order of magnitude (the gather disc is larger than the quad and
        // takes in the floor 1 cm below, so not exact).
        assert!(ratio > 0.3 && ratio < 1.5, "tiny plane: {ratio} × the closed form");
    }
}

// ---------------------------------------------------------------------------------------------
// Continuity of the interpolated counts.

/// A 1 × 1 m floor (x 0…1) meeting a 1 × 1 m wall (x = 0, y 0…1), point light at (d, d, 0):
/// symmetric about the plane x = y, so the photon density on either side of the edge tends to
/// the same value at the edge. Both planes get the same 128 × 128 grid.
#[test]
fn bilinear_counts_continuous_across_cells_and_planes() {
    let mut g = Gltf::new();
    let white = g.material(Material::lambert(0.5));
    add_object(&mut g, "Floor", rect_up(0.0, 1.0, -0.5, 0.5, 0.0), white);
    add_object(&mut g, "Wall", rect_px(0.0, 0.0, 1.0, -0.5, 0.5), white);
    let d = 0.4;
    add_point_light(&mut g, [d, d, 0.0], 1000.0);
    let dir = TempDir::new("continuity");
    let scene = load(&g.write_glb(dir.path(), "corner.glb"));
    let set = PlaneGrids::detect(&scene.triangles, 128);
    assert_eq!(set.planes.len(), 2);
    let accel = Accel::build(&scene.triangles);
    let n_photons = 2_000_000;
    let (photons, tris, _) = trace_photons(
        &scene,
        &accel,
        &TraceSettings {
            photons: n_photons,
            max_depth: 1,
            store_direct: true,
            seed: 3,
            sequences: photongrid::photon::Sequences::starting(3),
            record_triangles: true,
            caustic_photons: 0,
        },
        &|_| {},
    );
    let s = Settings::default();
    let mut grids = PlaneGrids::count(set, &photons, &tris, GridQuantity::Count, |_| true);
    grids.filter(
        photongrid::grid::GridParams::from(&s).wavelet,
        photongrid::grid::GridParams::from(&s).threshold,
        s.wavelet_levels,
    );
    let floor_tri = (0..scene.triangles.len())
        .find(|&t| scene.triangles[t].p.iter().all(|p| p.y == 0.0))
        .unwrap() as u32;
    let wall_tri = (0..scene.triangles.len())
        .find(|&t| scene.triangles[t].p.iter().all(|p| p.x == 0.0))
        .unwrap() as u32;
    let fp = grids.set.plane_for(floor_tri as usize).unwrap().clone();
    let wp = grids.set.plane_for(wall_tri as usize).unwrap().clone();
    assert_eq!((fp.res_u, fp.res_v), (wp.res_u, wp.res_v));
    let cell = fp.size_u / fp.res_u as f32;

    // (a) Across every cell border of the floor, along both axes: no jump.
    let mut worst_jump = 0.0f32;
    let mut max_count = 0.0f32;
    let eps = 1e-4 * cell;
    for j in 0..fp.res_v {
        for i in 1..fp.res_u {
            for (gx, gy, ax) in [(i as f32, j as f32 + 0.5, fp.u), (j as f32 + 0.5, i as f32, fp.v)] {
                let p = fp.grid_to_world(gx, gy);
                let a = grids.count_at(floor_tri, p - ax * eps).unwrap().0;
                let b = grids.count_at(floor_tri, p + ax * eps).unwrap().0;
                worst_jump = worst_jump.max((a - b).abs());
                max_count = max_count.max(a);
            }
        }
    }
    eprintln!("largest jump across a floor cell border: {worst_jump:.2e} (largest count {max_count:.1})");
    assert!(worst_jump < 1e-3 * max_count, "{worst_jump} vs {max_count}");

    // (b) Across the floor/wall edge: mean counts (over the middle 40 cm along z) at distance s
    // from the edge, one sample per cell centre, on both planes.
    let profile = |tri: u32, at: &dyn Fn(f32, f32) -> Vec3| -> Vec<f64> {
        (0..12)
            .map(|k| {
                let s = (k as f32 + 0.5) * cell;
                let zs: Vec<f32> = (0..64).map(|m| -0.2 + 0.4 * (m as f32 + 0.5) / 64.0).collect();
                zs.iter()
                    .map(|&z| grids.count_at(tri, at(s, z)).unwrap().0 as f64)
                    .sum::<f64>()
                    / zs.len() as f64
            })
            .collect()
    };
    let floor = profile(floor_tri, &|s, z| Vec3::new(s, 0.0, z));
    let wall = profile(wall_tri, &|s, z| Vec3::new(0.0, s, z));
    // The exact mean count per cell at those points: N · cell area · (I cosθ / d²) / (4π I).
    let expected: Vec<f64> = (0..12)
        .map(|k| {
            let s = (k as f64 + 0.5) * cell as f64;
            let zs: Vec<f64> = (0..64).map(|m| -0.2 + 0.4 * (m as f64 + 0.5) / 64.0).collect();
            zs.iter()
                .map(|&z| {
                    let dl = [d as f64 - s, d as f64, -z];
                    let d2 = dl.iter().map(|v| v * v).sum::<f64>();
                    n_photons as f64 * (cell as f64).powi(2) * (d as f64 / d2.sqrt() / d2)
                        / (4.0 * std::f64::consts::PI)
                })
                .sum::<f64>()
                / zs.len() as f64
        })
        .collect();
    // The raw texture at the same points.
    let raw_profile = |tri: u32, at: &dyn Fn(f32, f32) -> Vec3| -> Vec<f64> {
        let plane = grids.set.plane_of_triangle[tri as usize] as usize;
        let pl = &grids.set.planes[plane];
        (0..12)
            .map(|k| {
                let s = (k as f32 + 0.5) * cell;
                let zs: Vec<f32> = (0..64).map(|m| -0.2 + 0.4 * (m as f32 + 0.5) / 64.0).collect();
                zs.iter()
                    .map(|&z| grids.raw[plane].data[pl.cell_of(at(s, z), 0.0).unwrap()] as f64)
                    .sum::<f64>()
                    / zs.len() as f64
            })
            .collect()
    };
    let floor_raw = raw_profile(floor_tri, &|s, z| Vec3::new(s, 0.0, z));
    let wall_raw = raw_profile(wall_tri, &|s, z| Vec3::new(0.0, s, z));
    eprintln!("cells from the edge: filtered floor / wall, raw floor / wall, exact mean count");
    for k in 0..12 {
        eprintln!(
            "  {k:2}: {:8.2} {:8.2}   {:8.2} {:8.2}   {:8.2}",
            floor[k], wall[k], floor_raw[k], wall_raw[k], expected[k]
        );
    }
    let gradient = (expected[1] - expected[0]).abs();
    let step = (1..12)
        .map(|k| (floor[k] - floor[k - 1]).abs().max((wall[k] - wall[k - 1]).abs()))
        .fold(0.0, f64::max);
    let jump = (floor[0] - wall[0]).abs();
    eprintln!(
        "jump across the edge {jump:.3}; exact gradient {gradient:.3} per cell; largest step of the \
         filtered profile between neighbouring cells {step:.3} (Haar plateaus)"
    );
    // Symmetric planes: the filtered counts on both sides of the edge agree within the exact
    // change over one cell plus the noise of a 64-cell mean (~1 %, allow 3 %).
    assert!(
        jump <= gradient + 0.03 * expected[0],
        "counts jump by {jump:.2} across the floor/wall edge (exact gradient {gradient:.2} per cell)"
    );
    // Counting loses nothing at the border: the edge cells' raw counts match the exact ones.
    for (name, prof) in [("floor", &floor_raw), ("wall", &wall_raw)] {
        for k in 0..3 {
            let rel = prof[k] / expected[k] - 1.0;
            assert!(
                rel.abs() < 0.06,
                "{name} raw count, cell {k} from the edge: {:+.1} %",
                100.0 * rel
            );
        }
    }
    // The filter's border handling keeps the counts of the cells next to the edge: the filtered
    // mean over the first 8 cells equals the raw one. (Within them the Haar filter flattens the
    // gradient into plateaus: a cell's filtered count is the mean of its 8-cell block, so
    // single cells are off by up to half the gradient across the block.)
    for (name, f, r) in [("floor", &floor, &floor_raw), ("wall", &wall, &wall_raw)] {
        let (fm, rm) = (f[..8].iter().sum::<f64>(), r[..8].iter().sum::<f64>());
        assert!(
            (fm / rm - 1.0).abs() < 0.02,
            "{name}: filtered {fm:.1} vs raw {rm:.1} over the 8 edge cells"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Counts or flux.

/// METHOD.md leaves open whether the textures count photons or flux. With equal-power photons
/// (direct light only) the two are the same up to the plane-independent normalisation; after
/// coloured bounces (cornell_glass: red and green walls) photons carry unequal power and the
/// flux texture is lower where coloured indirect light dominates. Measured here, documented in
/// `docs/grid_method.md` (written with `PHOTONGRID_WRITE_DOCS=1`).
#[test]
fn counts_versus_flux() {
    let scene = load(&sample("cornell_glass.glb"));
    let accel = Accel::build(&scene.triangles);
    // 32 cells along the longer side, so that cells hold enough photons for a per-cell ratio.
    let set = PlaneGrids::detect(&scene.triangles, 32);
    let s = Settings::default();
    let mut doc = String::new();
    for (label, depth) in [("direct only", 1), ("all bounces", 16)] {
        let (photons, tris, _) = trace_photons(
            &scene,
            &accel,
            &TraceSettings {
                photons: 400_000,
                max_depth: depth,
                store_direct: true,
                seed: 1,
                sequences: photongrid::photon::Sequences::starting(1),
                record_triangles: true,
                caustic_photons: 0,
            },
            &|_| {},
        );
        let mut by_count = PlaneGrids::count(set.clone(), &photons, &tris, GridQuantity::Count, |_| true);
        let mut by_flux = PlaneGrids::count(set.clone(), &photons, &tris, GridQuantity::Flux, |_| true);
        by_count.filter(
            photongrid::grid::GridParams::from(&s).wavelet,
            photongrid::grid::GridParams::from(&s).threshold,
            s.wavelet_levels,
        );
        by_flux.filter(
            photongrid::grid::GridParams::from(&s).wavelet,
            photongrid::grid::GridParams::from(&s).threshold,
            s.wavelet_levels,
        );
        doc += &format!("\n{label} (max photon depth {depth}), 400 000 photons, seed 1:\n\n");
        doc += "| plane | triangles' material | photons | Σ flux / Σ count | cells: flux/count 5th–95th percentile | assumed radius flux/count (median) |\n|---|---|---:|---:|---:|---:|\n";
        let mut ratios = Vec::new();
        for (i, p) in by_count.set.planes.iter().enumerate() {
            let rc = &by_count.raw[i];
            let rf = &by_flux.raw[i];
            let name = material_name(&scene, p.triangles[0] as usize).to_string();
            if rc.sum() < 1000.0 {
                doc += &format!("| {i} | {name} | {:.0} | – | – | – |\n", rc.sum());
                continue;
            }
            let total = rf.sum() / rc.sum().max(1e-30);
            // Per cell (cells with at least 20 photons): flux/count of the filtered textures.
            let mut cell: Vec<f64> = (0..rc.data.len())
                .filter(|&c| rc.data[c] >= 20.0)
                .map(|c| by_flux.filtered[i].data[c] as f64 / by_count.filtered[i].data[c] as f64)
                .filter(|r| r.is_finite() && *r > 0.0)
                .collect();
            cell.sort_by(f64::total_cmp);
            if cell.is_empty() {
                // Photons spread so evenly over a dim plane that no cell reaches 20.
                doc += &format!("| {i} | {name} | {:.0} | {total:.3} | – | – |\n", rc.sum());
                continue;
            }
            let q = |f: f64| {
                cell.get(((cell.len() as f64 - 1.0) * f) as usize)
                    .copied()
                    .unwrap_or(f64::NAN)
            };
            // r ∝ 1/√N: radius ratio = √(count/flux).
            doc += &format!(
                "| {i} ({:.2}×{:.2} m, normal {:.0},{:.0},{:.0}) | {name} | {:.0} | {total:.3} | {:.3}–{:.3} | {:.3} |\n",
                p.size_u,
                p.size_v,
                p.normal.x,
                p.normal.y,
                p.normal.z,
                rc.sum(),
                q(0.05),
                q(0.95),
                1.0 / q(0.5).sqrt()
            );
            ratios.push((name, total, q(0.05), q(0.95)));
        }
        if depth == 1 {
            // Equal-power photons: flux = count × (photon power / mean power) = count.
            for (name, total, lo, hi) in &ratios {
                assert!((total - 1.0).abs() < 1e-3, "{name}: {total}");
                assert!((lo - 1.0).abs() < 1e-2 && (hi - 1.0).abs() < 1e-2, "{name}: {lo}–{hi}");
            }
        } else {
            // White planes receive mostly white photons (above the mean power: flux > count)
            // while the red and green walls' own photons keep full power in one channel only.
            for (name, total, _, _) in &ratios {
                assert!(*total > 0.5 && *total < 2.0, "{name}: Σ flux / Σ count = {total}");
            }
            let spread = ratios.iter().map(|r| r.1).fold(f64::NEG_INFINITY, f64::max)
                / ratios.iter().map(|r| r.1).fold(f64::INFINITY, f64::min);
            assert!(
                spread > 1.01,
                "counts and flux agree everywhere even after coloured bounces"
            );
        }
    }

    // What it does to the image: adaptive renders (single map, 128 cells) with either texture
    // from the same photons, against each other and against kNN.
    let settings = Settings {
        photons: 400_000,
        caustic_photons: 0,
        gather: 0, // the paper's setting: the photon map shown directly
        spp: 1,
        width: Some(64),
        height: Some(48),
        direct: DirectLighting::Photons,
        seed: 1,
        ..Settings::default()
    };
    let count_prep = prepare_adaptive(&scene, &settings);
    let flux_settings = Settings {
        grid_quantity: GridQuantity::Flux,
        ..settings.clone()
    };
    let flux_prep = prepare_adaptive(&scene, &flux_settings);
    let adaptive = |prep: &photongrid::Prepared, s: &Settings| {
        render_prepared(
            &scene,
            prep,
            &Settings {
                method: Method::Adaptive,
                ..s.clone()
            },
        )
    };
    let a_count = adaptive(&count_prep, &settings);
    let a_flux = adaptive(&flux_prep, &flux_settings);
    let knn = render_prepared(
        &scene,
        &count_prep,
        &Settings {
            method: Method::Knn,
            ..settings.clone()
        },
    );
    let diff = |a: &photongrid::film::Film, b: &photongrid::film::Film| -> (f64, f64, f64) {
        let (mut d, mut n, mut changed) = (0.0, 0.0, 0usize);
        for i in 0..a.color.len() {
            d += (grey(a, i) - grey(b, i)).abs();
            n += grey(b, i);
            changed += (a.color[i] != b.color[i]) as usize;
        }
        let mean = |f: &photongrid::film::Film| (0..f.color.len()).map(|i| grey(f, i)).sum::<f64>();
        (d / n, mean(a) / mean(b) - 1.0, changed as f64 / a.color.len() as f64)
    };
    let (d_cf, m_cf, c_cf) = diff(&a_flux, &a_count);
    let (d_ck, m_ck, _) = diff(&a_count, &knn);
    let (d_fk, m_fk, _) = diff(&a_flux, &knn);
    doc += &format!(
        "\nImages (camera view, 64×48, 1 spp, single map, 400 000 photons, 128 cells): adaptive with \
         flux vs adaptive with counts: {:.1} % of pixels differ, mean |Δ| / mean {:.2} %, image mean \
         {:+.2} %; adaptive (counts) vs kNN: mean |Δ| / mean {:.2} %, image mean {:+.2} %; adaptive \
         (flux) vs kNN: {:.2} %, {:+.2} %.\n",
        100.0 * c_cf,
        100.0 * d_cf,
        100.0 * m_cf,
        100.0 * d_ck,
        100.0 * m_ck,
        100.0 * d_fk,
        100.0 * m_fk
    );
    assert!(c_cf > 0.1, "flux and count textures give the same image");
    assert!(
        m_cf.abs() < 0.02,
        "flux vs count changes the image mean by {:.2} %",
        100.0 * m_cf
    );
    eprintln!("{doc}");
    if std::env::var("PHOTONGRID_WRITE_DOCS").is_ok_and(|v| v == "1") {
        let path = photongrid_testkit::repo_root().join("docs/grid_method.md");
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(
            &path,
            format!(
                "# Grid textures: photon counts or flux\n\nGenerated by `tests/grid_method.rs` \
                 (`counts_versus_flux`):\n\n```sh\nPHOTONGRID_WRITE_DOCS=1 cargo test --release --test grid_method \
                 -- --nocapture counts_versus_flux\n```\n\nScene `samples/cornell_glass.glb`, global photons \
                 only (no caustic pass), textures of 32 cells along the longer side filtered with the defaults (Haar, universal \
                 threshold, 4 levels). `GridQuantity::Flux` counts each photon as its mean-channel power divided by \
                 the mean over all photons, so both textures are in photons. Per plane: Σ flux / Σ count \
                 over the raw texture, the 5th–95th percentile of filtered flux / filtered count over cells \
                 holding at least 20 photons, and the median assumed-radius ratio r_flux / r_count = \
                 √(count / flux).\n{doc}\n\
                 **Reading.** With direct light only every photon carries the same power and the two \
                 textures are identical. After bounces off the red and green walls a photon keeps full \
                 power in one channel and loses most of the others (Russian roulette on the largest \
                 channel), so its mean-channel flux is well below a white photon's: planes lit mostly \
                 by coloured indirect light (the box's side faces, which see little of the lamp and much \
                 of the coloured walls) get a flux \
                 texture far below their count texture, planes lit by white light a higher one. The \
                 kNN radius r_k depends only on how many photons lie around a point, so eq. (3) with \
                 counts predicts it; with flux the assumed radius r_a is too large where coloured \
                 photons dominate (and too small under white light), so r = r_a + α (r_k − r_a) \
                 blurs more there. The image mean hardly moves (a fixed-radius estimate is unbiased for \
                 any radius on smooth light); the pixels change by about the noise. Counts \
                 (`GridQuantity::Count`, the default) are what the method needs.\n"
            ),
        )
        .unwrap();
    }
}
