//! Renders and loads checked against closed forms: direct light from point, spot and sun lights
//! on a Lambert plane, the photon estimate, emission, light units, glTF transforms and
//! primitive modes, glass energy conservation, and thread-count independence.

use glam::{Mat4, Quat, Vec3};
use photongrid::film::Film;
use photongrid::photon::PhotonKind;
use photongrid::pipeline::{prepare, render_camera, select_cameras, PhaseTimes};
use photongrid::progress::Progress;
use photongrid::scene::{Light as SceneLight, Scene};
use photongrid::settings::DirectLighting;
use photongrid::Settings;
use photongrid_testkit::*;
use std::f64::consts::PI;
use std::path::Path;

const ALBEDO: f64 = 0.5;
/// Image size and orthographic half-height of the plane renders (pixels are 1/12 m).
const W: u32 = 64;
const H: u32 = 48;
const YMAG: f64 = 2.0;
/// The top-down camera every test here renders through.
const VIEW: harness::TopView = harness::TopView {
    cx: 0.0,
    cz: 0.0,
    ymag: YMAG,
    height: 10.0,
    w: W,
    h: H,
};
/// Height of the lights above the plane.
const LIGHT_H: f64 = 3.0;

/// Load `path` and render its first camera.
fn render(path: &Path, settings: &Settings) -> (Scene, Film) {
    let scene = photongrid::load(path).unwrap_or_else(|e| panic!("{e}"));
    let film = render_loaded(&scene, settings);
    (scene, film)
}

fn render_loaded(scene: &Scene, settings: &Settings) -> Film {
    let cams = select_cameras(scene, &[]).unwrap();
    let progress = Progress::quiet();
    let mut times = PhaseTimes::default();
    let prepared = prepare(scene, settings, &progress, &mut times).unwrap();
    render_camera(scene, &prepared, cams[0], settings, &progress)
}

fn direct_settings(spp: u32) -> Settings {
    Settings {
        photons: 0,
        spp,
        width: Some(W),
        height: Some(H),
        direct: DirectLighting::ShadowRays,
        ..Settings::default()
    }
}

/// A 40 m Lambert plane (albedo 0.5, metallic 0) at y = 0 facing up, one light node, and an
/// orthographic camera 10 m above the origin looking straight down (image up = world −Z).
fn plane_scene(dir: &TempDir, light: Light, rotation: [f32; 4]) -> std::path::PathBuf {
    let mut g = Gltf::new();
    let m = g.material(Material::lambert(ALBEDO as f32));
    let mesh = g.mesh(vec![floor_quad(20.0, 0.0).material(m)]);
    g.root(Node {
        name: Some("Plane".into()),
        mesh: Some(mesh),
        ..Default::default()
    });
    let l = g.light(light);
    g.root(Node {
        name: Some("Light".into()),
        transform: Transform::tr([0.0, LIGHT_H as f32, 0.0], rotation),
        light: Some(l),
        ..Default::default()
    });
    VIEW.add_camera(&mut g);
    g.write_gltf(dir.path(), "plane.gltf")
}

fn lum(c: glam::Vec3) -> f64 {
    // Grey scenes: all channels agree; check that and return one.
    assert!((c.x - c.y).abs() <= 1e-6 * c.x.abs().max(1e-30) && (c.x - c.z).abs() <= 1e-6 * c.x.abs().max(1e-30));
    c.x as f64
}

/// `L = (albedo/π)·(I/683)·cosθ/d²` for a point light of `candela` at (0, h, 0).
fn point_radiance(candela: f64, x: f64, z: f64) -> f64 {
    let d2 = x * x + z * z + LIGHT_H * LIGHT_H;
    let cos = LIGHT_H / d2.sqrt();
    ALBEDO / PI * (candela / 683.0) * cos / d2
}

#[test]
fn camera_mapping_matches_hand_computation() {
    // The test's own pixel → world mapping must agree with the camera the loader built.
    let dir = TempDir::new("mapping");
    let path = plane_scene(&dir, Light::point(100.0), [0.0, 0.0, 0.0, 1.0]);
    let scene = photongrid::load(&path).unwrap();
    let cam = &scene.cameras[0];
    for (fx, fy) in [(0.5, 0.5), (10.25, 40.75), (63.5, 47.5), (32.0, 24.0)] {
        let (o, d) = cam.generate_ray(glam::Vec2::new(fx as f32, fy as f32), W, H);
        assert!((d - Vec3::NEG_Y).length() < 1e-6, "{d}");
        let (x, z) = VIEW.film_to_world(fx, fy);
        assert!(
            (o.x as f64 - x).abs() < 1e-5 && (o.z as f64 - z).abs() < 1e-5,
            "{o} vs {x} {z}"
        );
    }
}

#[test]
fn point_light_on_lambert_plane_shadow_rays() {
    let dir = TempDir::new("point");
    let candela = 500.0;
    let path = plane_scene(&dir, Light::point(candela as f32), [0.0, 0.0, 0.0, 1.0]);
    let (_, film) = render(&path, &direct_settings(256));
    let mut worst = 0.0f64;
    for py in 0..H {
        for px in 0..W {
            let got = lum(film.color[(py * W + px) as usize]);
            let want = VIEW.pixel_mean(px, py, &|x, z| point_radiance(candela, x, z));
            let rel = (got / want - 1.0).abs();
            worst = worst.max(rel);
            assert!(
                rel < 0.01,
                "pixel ({px}, {py}): {got} vs closed form {want} ({:+.3} %)",
                100.0 * (got / want - 1.0)
            );
        }
    }
    eprintln!("point light: worst pixel {:.4} %", 100.0 * worst);
}

#[test]
fn spot_light_on_lambert_plane_shadow_rays() {
    let dir = TempDir::new("spot");
    let candela = 800.0;
    let (inner, outer) = (10f64.to_radians(), 40f64.to_radians());
    let path = plane_scene(
        &dir,
        Light::spot(candela as f32, inner as f32, outer as f32),
        look_down(),
    );
    let spp = 2048;
    let (scene, film) = render(&path, &direct_settings(spp));
    match &scene.lights[0] {
        SceneLight::Spot { blend, direction, .. } => {
            assert!((*blend as f64 - (1.0 - inner / outer)).abs() < 1e-6);
            assert!((*direction - Vec3::NEG_Y).length() < 1e-6);
        }
        other => panic!("expected a spot, got {other:?}"),
    }
    let cos_outer = outer.cos();
    let blend = 1.0 - inner / outer;
    // Blender's profile: smoothstep((cosθ − cos outer) / ((1 − cos outer)·blend)), 0 outside.
    let mask = |x: f64, z: f64| {
        let c = LIGHT_H / (x * x + z * z + LIGHT_H * LIGHT_H).sqrt();
        if c <= cos_outer {
            return 0.0;
        }
        let t = ((c - cos_outer) / ((1.0 - cos_outer) * blend)).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    };
    let radiance = |x: f64, z: f64| mask(x, z) * point_radiance(candela, x, z);
    let peak = radiance(0.0, 0.0);
    let (mut inside, mut ramp, mut outside) = (0, 0, 0);
    let mut worst = 0.0f64;
    for py in 0..H {
        for px in 0..W {
            let got = lum(film.color[(py * W + px) as usize]);
            let frac_outside = VIEW.pixel_mean(px, py, &|x, z| if mask(x, z) > 0.0 { 0.0 } else { 1.0 });
            // The footprint's point nearest to the spot's axis.
            let (x0, z0) = VIEW.film_to_world(px as f64, py as f64);
            let (x1, z1) = VIEW.film_to_world(px as f64 + 1.0, py as f64 + 1.0);
            let nearest = mask(0f64.clamp(x0.min(x1), x0.max(x1)), 0f64.clamp(z0.min(z1), z0.max(z1)));
            let frac_full = VIEW.pixel_mean(px, py, &|x, z| if mask(x, z) >= 1.0 { 1.0 } else { 0.0 });
            let mask_mean = VIEW.pixel_mean(px, py, &mask);
            let want = VIEW.pixel_mean(px, py, &radiance);
            // The jittered pixel is a mean of `spp` uniform samples over the footprint: its
            // relative standard deviation follows from the footprint's variance.
            let second = VIEW.pixel_mean(px, py, &|x, z| radiance(x, z).powi(2));
            let sigma = if want > 0.0 {
                (second - want * want).max(0.0).sqrt() / want / (spp as f64).sqrt()
            } else {
                0.0
            };
            let rel = if want > 0.0 { got / want - 1.0 } else { 0.0 };
            let msg = || {
                format!(
                    "pixel ({px}, {py}), mask {mask_mean:.3}: {got} vs closed form {want} ({:+.3} %, σ {:.3} %)",
                    100.0 * rel,
                    100.0 * sigma
                )
            };
            if nearest == 0.0 {
                // The whole footprint outside the cone: exactly black.
                outside += 1;
                assert_eq!(got, 0.0, "{}", msg());
            } else if frac_full == 1.0 {
                inside += 1;
                worst = worst.max(rel.abs());
                assert!(rel.abs() < 0.01, "{}", msg());
            } else if frac_outside == 0.0 && mask_mean > 0.1 && mask_mean < 0.9 && 4.0 * sigma <= 0.01 {
                // In the blend ramp, where the sampling noise allows a 1 % test at 4σ.
                ramp += 1;
                worst = worst.max(rel.abs());
                assert!(rel.abs() < 0.01, "{}", msg());
            } else {
                // Pixels across the cone's edge or where the ramp starts, where 8×8 sub-samples
                // do not resolve the footprint: within 1 % of the peak radiance.
                assert!((got - want).abs() <= 0.01 * peak, "{}", msg());
            }
        }
    }
    eprintln!(
        "spot: {inside} inside, {ramp} in the blend ramp, {outside} outside; worst {:.4} %",
        100.0 * worst
    );
    assert!(inside > 300 && ramp > 300 && outside > 50, "{inside} {ramp} {outside}");
}

#[test]
fn sun_at_30_degrees_on_lambert_plane() {
    let dir = TempDir::new("sun");
    let lux = 2000.0;
    // −Z → −Y (down), then tilt 30° about Z: the light travels along (sin 30°, −cos 30°, 0).
    let q = Quat::from_rotation_z(30f32.to_radians()) * Quat::from_array(look_down());
    let path = plane_scene(&dir, Light::directional(lux as f32), q.to_array());
    let (scene, film) = render(&path, &direct_settings(4));
    match &scene.lights[0] {
        SceneLight::Directional { direction, .. } => {
            let want = Vec3::new(0.5, -(3f32.sqrt()) / 2.0, 0.0);
            assert!((*direction - want).length() < 1e-6, "{direction}");
        }
        other => panic!("expected a sun, got {other:?}"),
    }
    let want = ALBEDO / PI * lux / 683.0 * 30f64.to_radians().cos();
    for (i, c) in film.color.iter().enumerate() {
        let got = lum(*c);
        assert!((got / want - 1.0).abs() < 0.01, "pixel {i}: {got} vs {want}");
    }
}

#[test]
fn point_light_from_photons_only() {
    let dir = TempDir::new("photons");
    let candela = 500.0;
    let path = plane_scene(&dir, Light::point(candela as f32), [0.0, 0.0, 0.0, 1.0]);
    let settings = Settings {
        photons: 2_000_000,
        neighbours: 200,
        spp: 1,
        width: Some(W),
        height: Some(H),
        direct: DirectLighting::Photons,
        ..Settings::default()
    };
    let (_, film) = render(&path, &settings);
    // Central region: |x|, |z| < 1 m.
    let (mut got, mut want, mut n) = (0.0, 0.0, 0);
    for py in 0..H {
        for px in 0..W {
            let (x, z) = VIEW.film_to_world(px as f64 + 0.5, py as f64 + 0.5);
            if x.abs() < 1.0 && z.abs() < 1.0 {
                got += lum(film.color[(py * W + px) as usize]);
                want += VIEW.pixel_mean(px, py, &|x, z| point_radiance(candela, x, z));
                n += 1;
            }
        }
    }
    assert!(n > 500, "{n}");
    let rel = got / want - 1.0;
    eprintln!(
        "photons only: region mean {:.5} vs {:.5} ({:+.3} %)",
        got / n as f64,
        want / n as f64,
        100.0 * rel
    );
    assert!(
        rel.abs() < 0.03,
        "region mean {} vs closed form {} ({:+.2} %)",
        got / n as f64,
        want / n as f64,
        100.0 * rel
    );
}

#[test]
fn emissive_quad_seen_directly() {
    let dir = TempDir::new("emissive");
    let mut g = Gltf::new();
    let m = g.material(Material::emitter([1.0, 0.5, 0.25], Some(8.0)));
    let mesh = g.mesh(vec![floor_quad(20.0, 0.0).material(m)]);
    g.root(Node {
        mesh: Some(mesh),
        ..Default::default()
    });
    let c = g.camera(Camera::Orthographic { xmag: 2.0, ymag: 1.5 });
    g.root(Node {
        transform: Transform::tr([0.0, 10.0, 0.0], look_down()),
        camera: Some(c),
        ..Default::default()
    });
    let path = g.write_glb(dir.path(), "emitter.glb");
    let (scene, film) = render(&path, &direct_settings(4));
    assert!(matches!(scene.lights[..], [SceneLight::Emissive { .. }]));
    let want = Vec3::new(8.0, 4.0, 2.0);
    for (i, c) in film.color.iter().enumerate() {
        assert!(
            ((*c - want) / want).abs().max_element() < 1e-3,
            "pixel {i}: {c} vs {want}"
        );
    }
}

#[test]
fn emitter_edges_are_anti_aliased_to_their_coverage() {
    // An emissive square of half-size 0.77 m seen from above: the pixels it partly covers
    // (1/16 m each, its edges not on pixel boundaries) must show emission × covered share. With
    // 4 samples a pixel alone, a covered share comes out in steps of 1/4; the emission-only
    // rays at emitter edges bring it within 4 %.
    let half = 0.77;
    let view = harness::TopView {
        cx: 0.0,
        cz: 0.0,
        ymag: 1.5,
        height: 10.0,
        w: W,
        h: H,
    };
    let dir = TempDir::new("emitter-edges");
    let mut g = Gltf::new();
    let m = g.material(Material::emitter([1.0, 1.0, 1.0], Some(8.0)));
    let mesh = g.mesh(vec![floor_quad(half as f32, 0.0).material(m)]);
    g.root(Node {
        mesh: Some(mesh),
        ..Default::default()
    });
    view.add_camera(&mut g);
    let path = g.write_glb(dir.path(), "square.glb");
    let (_, film) = render(&path, &direct_settings(4));
    let overlap = |a: f64, b: f64| (b.min(half) - a.max(-half)).max(0.0);
    let (mut edge_pixels, mut worst) = (0, 0.0f64);
    for py in 0..H {
        for px in 0..W {
            let (x0, z0) = view.film_to_world(px as f64, py as f64);
            let (x1, z1) = view.film_to_world(px as f64 + 1.0, py as f64 + 1.0);
            let share = overlap(x0.min(x1), x0.max(x1)) * overlap(z0.min(z1), z0.max(z1)) / view.pixel_size().powi(2);
            let got = film.color[(py * W + px) as usize].y as f64 / 8.0;
            if share > 0.0 && share < 1.0 {
                edge_pixels += 1;
            }
            worst = worst.max((got - share).abs());
        }
    }
    assert!(edge_pixels > 80, "{edge_pixels} edge pixels");
    assert!(worst < 0.04, "worst pixel off by {worst:.3} of the emission");
}

/// Load a file holding only a floor and one light.
fn load_with_light(tag: &str, light: Light, rotation: [f32; 4]) -> Scene {
    let dir = TempDir::new(tag);
    let path = plane_scene(&dir, light, rotation);
    photongrid::load(&path).unwrap()
}

#[test]
fn light_units_follow_units_md() {
    // Point: P / (4π) · 683 cd for P = 30 W (the cornell_glass lamp).
    let s = load_with_light("units-point", Light::point(1_630.542_4), [0.0, 0.0, 0.0, 1.0]);
    let p = s.lights[0].power();
    assert!((p - Vec3::splat(30.0)).abs().max_element() < 30.0 * 1e-5, "{p}");

    // Sun: 1366 lux → 2 W/m² on a surface facing it.
    let s = load_with_light("units-sun", Light::directional(1366.0), look_down());
    match &s.lights[0] {
        SceneLight::Directional { irradiance, .. } => {
            assert!(
                (*irradiance - Vec3::splat(2.0)).abs().max_element() < 1e-6,
                "{irradiance}"
            )
        }
        other => panic!("expected a sun, got {other:?}"),
    }

    // Spot: 54351 cd, outer 20°, blend 0.15 (inner = outer · 0.85).
    let outer = 20f64.to_radians();
    let s = load_with_light(
        "units-spot",
        Light::spot(54351.0, (outer * 0.85) as f32, outer as f32),
        look_down(),
    );
    let want = 2.0 * PI * (54351.0 / 683.0) * (1.0 - outer.cos()) * (1.0 - 0.15 / 2.0);
    let got = s.lights[0].power();
    assert!(((got.x as f64) / want - 1.0).abs() < 1e-4, "{got} vs {want}");
    match &s.lights[0] {
        SceneLight::Spot {
            intensity,
            cos_outer,
            blend,
            ..
        } => {
            assert!((intensity.x as f64 / (54351.0 / 683.0) - 1.0).abs() < 1e-6);
            assert!((*cos_outer as f64 - outer.cos()).abs() < 1e-6);
            assert!((*blend as f64 - 0.15).abs() < 1e-5, "{blend}");
        }
        other => panic!("expected a spot, got {other:?}"),
    }

    // Emission carries no 683.
    let mut g = simple_scene(100.0);
    let m = g.material(Material::emitter([1.0, 1.0, 1.0], Some(40.0)));
    let quad = g.mesh(vec![floor_quad(0.5, 2.0).material(m)]);
    g.root(Node {
        mesh: Some(quad),
        ..Default::default()
    });
    let dir = TempDir::new("units-emission");
    let s = photongrid::load(&g.write_gltf(dir.path(), "e.gltf")).unwrap();
    let e = s
        .lights
        .iter()
        .find(|l| matches!(l, SceneLight::Emissive { .. }))
        .unwrap();
    // One face of 1 m² at L = 40: Φ = π L A.
    assert!((e.power().x as f64 / (PI * 40.0) - 1.0).abs() < 1e-5, "{}", e.power());
}

// ---------------------------------------------------------------------------------------------
// Transforms and primitive modes.

/// Triangle (0,0,0), (1,0,0), (0,0,−1): counter-clockwise seen from +Y, normals +Y.
fn up_triangle() -> Prim {
    Prim::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]).normals(vec![[0.0, 1.0, 0.0]; 3])
}

/// A file with `prims` under one node with `transform` (below an optional parent) plus a light.
fn load_mesh(tag: &str, prims: Vec<Prim>, parent: Option<Transform>, transform: Transform) -> Scene {
    let mut g = Gltf::new();
    let m = g.material(Material::lambert(0.5));
    let prims = prims.into_iter().map(|p| p.material(m)).collect();
    let mesh = g.mesh(prims);
    let child = g.node(Node {
        mesh: Some(mesh),
        transform,
        ..Default::default()
    });
    match parent {
        Some(t) => {
            g.root(Node {
                transform: t,
                children: vec![child],
                ..Default::default()
            });
        }
        None => g.add_root(child),
    }
    let l = g.light(Light::point(100.0));
    g.root(Node {
        transform: Transform::translation([0.0, 5.0, 0.0]),
        light: Some(l),
        ..Default::default()
    });
    let dir = TempDir::new(tag);
    photongrid::load(&g.write_glb(dir.path(), "m.glb")).unwrap_or_else(|e| panic!("{e}"))
}

fn assert_vec(got: Vec3, want: [f32; 3], what: &str) {
    let want = Vec3::from(want);
    assert!((got - want).length() < 1e-5, "{what}: {got} vs {want}");
}

#[test]
fn node_hierarchy_translation_rotation_scale() {
    // Parent: translation (1, 2, 3). Child: 90° about +Y, scale (2, 1, 0.5). World = T·R·S.
    let s = load_mesh(
        "hierarchy",
        vec![up_triangle()],
        Some(Transform::translation([1.0, 2.0, 3.0])),
        Transform::Trs {
            t: [0.0; 3],
            r: quat([0.0, 1.0, 0.0], std::f32::consts::FRAC_PI_2),
            s: [2.0, 1.0, 0.5],
        },
    );
    assert_eq!(s.triangles.len(), 1);
    let t = &s.triangles[0];
    // S: (1,0,0) → (2,0,0); R_y(90°): (x,y,z) → (z, y, −x) → (0,0,−2); + T → (1,2,1).
    // (0,0,−1) → (0,0,−0.5) → (−0.5,0,0) → (0.5,2,3).
    assert_vec(t.p[0], [1.0, 2.0, 3.0], "p0");
    assert_vec(t.p[1], [1.0, 2.0, 1.0], "p1");
    assert_vec(t.p[2], [0.5, 2.0, 3.0], "p2");
    for n in t.n {
        assert_vec(n, [0.0, 1.0, 0.0], "normal");
    }
    assert_vec(t.cross().normalize(), [0.0, 1.0, 0.0], "geometric normal");
    assert!((t.area() - 0.5).abs() < 1e-6, "{}", t.area());
}

#[test]
fn negative_scale_keeps_the_authored_side() {
    // Mirror in x: the winding flips, the loader must swap it back so the face still points +Y.
    let s = load_mesh(
        "mirror-x",
        vec![up_triangle()],
        None,
        Transform::Trs {
            t: [0.0, 1.0, 0.0],
            r: [0.0, 0.0, 0.0, 1.0],
            s: [-1.0, 1.0, 1.0],
        },
    );
    let t = &s.triangles[0];
    // Vertices (0,1,0), (−1,1,0), (0,1,−1); with two swapped to keep counter-clockwise from +Y.
    assert_vec(t.p[0], [0.0, 1.0, 0.0], "p0");
    assert_vec(t.p[1], [0.0, 1.0, -1.0], "p1");
    assert_vec(t.p[2], [-1.0, 1.0, 0.0], "p2");
    assert_vec(t.cross().normalize(), [0.0, 1.0, 0.0], "geometric normal");
    for n in t.n {
        assert_vec(n, [0.0, 1.0, 0.0], "shading normal");
    }

    // Mirror in z of a wall facing +Z: the mirrored wall faces −Z (normal by inverse transpose),
    // and so must its winding.
    let wall = Prim::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]).normals(vec![[0.0, 0.0, 1.0]; 3]);
    let s = load_mesh(
        "mirror-z",
        vec![wall],
        None,
        Transform::Trs {
            t: [0.0, 0.0, 2.0],
            r: [0.0, 0.0, 0.0, 1.0],
            s: [1.0, 1.0, -1.0],
        },
    );
    let t = &s.triangles[0];
    assert_vec(t.cross().normalize(), [0.0, 0.0, -1.0], "geometric normal");
    for n in t.n {
        assert_vec(n, [0.0, 0.0, -1.0], "shading normal");
    }
    let mut ps: Vec<[f32; 3]> = t.p.iter().map(|p| p.to_array()).collect();
    ps.sort_by(|a, b| a.partial_cmp(b).unwrap());
    assert_eq!(ps, vec![[0.0, 0.0, 2.0], [0.0, 1.0, 2.0], [1.0, 0.0, 2.0]]);
}

#[test]
fn normals_use_the_inverse_transpose() {
    // A triangle in the plane x + y = 0 with normal (1, 1, 0)/√2, scaled by (2, 1, 1): the
    // normal becomes diag(1/2, 1, 1)·n ∝ (1, 2, 0) (M·n would give (2, 1, 0)).
    let n = [std::f32::consts::FRAC_1_SQRT_2, std::f32::consts::FRAC_1_SQRT_2, 0.0];
    let tri = Prim::new(vec![[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, -1.0, 0.0]]).normals(vec![n; 3]);
    let s = load_mesh(
        "inverse-transpose",
        vec![tri],
        None,
        Transform::Trs {
            t: [0.0; 3],
            r: [0.0, 0.0, 0.0, 1.0],
            s: [2.0, 1.0, 1.0],
        },
    );
    let t = &s.triangles[0];
    let want = Vec3::new(1.0, 2.0, 0.0).normalize().to_array();
    assert_vec(t.p[2], [2.0, -1.0, 0.0], "p2");
    for n in t.n {
        assert_vec(n, want, "shading normal");
    }
    assert_vec(t.cross().normalize(), want, "geometric normal");
}

#[test]
fn missing_normals_give_flat_shading() {
    let tri = Prim::new(vec![[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [0.0, 0.2, -1.0]]);
    let s = load_mesh("flat", vec![tri], None, Transform::None);
    let t = &s.triangles[0];
    let ng = (Vec3::new(1.0, 0.5, 0.0)).cross(Vec3::new(0.0, 0.2, -1.0)).normalize();
    assert!(ng.y > 0.0);
    for n in t.n {
        assert_vec(n, ng.to_array(), "flat normal");
    }
}

/// Triangles as vertex triples, each rotated to start at its smallest vertex (winding kept), sorted.
fn canonical(tris: &[[Vec3; 3]]) -> Vec<[[f32; 3]; 3]> {
    let mut out: Vec<[[f32; 3]; 3]> = tris
        .iter()
        .map(|t| {
            let a = t.map(|p| p.to_array());
            let k = (0..3).min_by(|&i, &j| a[i].partial_cmp(&a[j]).unwrap()).unwrap();
            [a[k], a[(k + 1) % 3], a[(k + 2) % 3]]
        })
        .collect();
    out.sort_by(|a, b| a.partial_cmp(b).unwrap());
    out
}

#[test]
fn triangle_strips_and_fans() {
    // Strip: zig-zag along +x; glTF: triangle i = (i, i+1, i+2) for even i, (i, i+2, i+1) for odd.
    let v: Vec<[f32; 3]> = vec![
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [1.0, 0.0, 1.0],
        [2.0, 0.0, 0.0],
        [2.0, 0.0, 1.0],
    ];
    let strip = Prim::new(v.clone())
        .indices_u16((0..6).collect())
        .mode(mode::TRIANGLE_STRIP);
    let s = load_mesh("strip", vec![strip], None, Transform::None);
    let p = |i: usize| Vec3::from(v[i]);
    let want: Vec<[Vec3; 3]> = (0..4)
        .map(|i| {
            if i % 2 == 0 {
                [p(i), p(i + 1), p(i + 2)]
            } else {
                [p(i), p(i + 2), p(i + 1)]
            }
        })
        .collect();
    let got: Vec<[Vec3; 3]> = s.triangles.iter().map(|t| t.p).collect();
    assert_eq!(canonical(&got), canonical(&want));
    for t in &s.triangles {
        assert_vec(t.cross().normalize(), [0.0, 1.0, 0.0], "strip face");
    }

    // Fan around the origin (non-indexed, then u32-indexed in reverse vertex order):
    // triangle i = (i+1, i+2, 0).
    let f: Vec<[f32; 3]> = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        [-1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
    ];
    let q = |i: usize| Vec3::from(f[i]);
    let want: Vec<[Vec3; 3]> = (0..4).map(|i| [q(i + 1), q(i + 2), q(0)]).collect();
    let fan = Prim::new(f.clone()).mode(mode::TRIANGLE_FAN);
    let s = load_mesh("fan", vec![fan], None, Transform::None);
    let got: Vec<[Vec3; 3]> = s.triangles.iter().map(|t| t.p).collect();
    assert_eq!(canonical(&got), canonical(&want));
    let total: f32 = s.triangles.iter().map(|t| t.area()).sum();
    assert!((total - 2.0).abs() < 1e-6, "{total}");
    for t in &s.triangles {
        assert_vec(t.cross().normalize(), [0.0, 1.0, 0.0], "fan face");
    }
    let reversed: Vec<[f32; 3]> = f.iter().rev().copied().collect();
    let fan = Prim::new(reversed)
        .indices_u32((0..6).rev().collect())
        .mode(mode::TRIANGLE_FAN);
    let s = load_mesh("fan-u32", vec![fan], None, Transform::None);
    let got: Vec<[Vec3; 3]> = s.triangles.iter().map(|t| t.p).collect();
    assert_eq!(canonical(&got), canonical(&want));
}

#[test]
fn matrix_and_trs_nodes_agree() {
    let (t, r, sc) = (
        Vec3::new(1.0, -2.0, 0.5),
        Quat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 0.7),
        Vec3::new(1.5, 0.5, 2.0),
    );
    let tri = || {
        Prim::new(vec![[0.0, 0.0, 0.0], [1.0, 0.3, 0.0], [0.2, 0.1, -1.0]]).normals(vec![
            [0.0, 1.0, 0.0],
            [0.3, 0.9, 0.1],
            [-0.2, 0.95, 0.1],
        ])
    };
    let a = load_mesh(
        "trs",
        vec![tri()],
        None,
        Transform::Trs {
            t: t.to_array(),
            r: r.to_array(),
            s: sc.to_array(),
        },
    );
    let m = Mat4::from_scale_rotation_translation(sc, r, t);
    let b = load_mesh("matrix", vec![tri()], None, Transform::Matrix(m.to_cols_array()));
    let (ta, tb) = (&a.triangles[0], &b.triangles[0]);
    for k in 0..3 {
        assert!((ta.p[k] - tb.p[k]).length() < 1e-5, "p{k}: {} vs {}", ta.p[k], tb.p[k]);
        assert!((ta.n[k] - tb.n[k]).length() < 1e-5, "n{k}: {} vs {}", ta.n[k], tb.n[k]);
        // And both equal the hand-transformed vertex (positive determinant: no winding swap).
        let p = m.transform_point3(Vec3::from(tri().positions[k]));
        assert!((ta.p[k] - p).length() < 1e-5, "p{k}: {} vs {p}", ta.p[k]);
    }
}

#[test]
fn gltf_and_glb_from_the_builder_load_the_same() {
    assert_eq!(base64(b""), "");
    assert_eq!(base64(b"f"), "Zg==");
    assert_eq!(base64(b"fo"), "Zm8=");
    assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    assert_eq!(base64(&[0xff, 0xfe, 0x00, 0x01]), "//4AAQ==");
    let g = simple_scene(100.0);
    let dir = TempDir::new("roundtrip");
    let a = photongrid::load(&g.write_gltf(dir.path(), "a.gltf")).unwrap();
    let b = photongrid::load(&g.write_glb(dir.path(), "b.glb")).unwrap();
    let c = photongrid::load(&g.write_gltf_external(dir.path(), "c.gltf", "c.bin", true)).unwrap();
    for s in [&b, &c] {
        assert_eq!(s.triangles.len(), a.triangles.len());
        for (x, y) in s.triangles.iter().zip(&a.triangles) {
            assert_eq!(x.p, y.p);
            assert_eq!(x.n, y.n);
        }
        assert_eq!(s.cameras.len(), 1);
        assert_eq!(s.lights.len(), 1);
    }
}

// ---------------------------------------------------------------------------------------------
// Energy and determinism.

/// A perspective camera (vertical field of view 1 rad) at `at`, looking down −Z: the scenes
/// that only check photons need one to load.
fn add_perspective_camera(g: &mut Gltf, at: [f32; 3]) {
    let c = g.camera(Camera::Perspective {
        yfov: 1.0,
        aspect: None,
    });
    g.root(Node {
        camera: Some(c),
        transform: Transform::translation(at),
        ..Default::default()
    });
}

#[test]
fn glass_sphere_neither_creates_nor_loses_energy() {
    // A 30 W point light 1 m from a glass sphere (radius 0.8, IOR 1.5), all inside a closed
    // diffuse sphere of radius 5. Every photon ends on the enclosure, straight (direct) or through
    // the glass (caustic): their flux must add up to the light's power, and the caustic share
    // must be the solid angle the glass subtends, (1 − cos asin 0.8)/2 = 20 %.
    let mut g = Gltf::new();
    let wall = g.material(Material::lambert(0.5));
    let glass = g.material(Material::glass(None));
    let enclosure = g.mesh(vec![uv_sphere([0.0; 3], 5.0, 24, 48).material(wall)]);
    let ball = g.mesh(vec![uv_sphere([1.0, 0.0, 0.0], 0.8, 96, 192).material(glass)]);
    g.root(Node {
        mesh: Some(enclosure),
        ..Default::default()
    });
    g.root(Node {
        mesh: Some(ball),
        ..Default::default()
    });
    let l = g.light(Light::point(1_630.542_4));
    g.root(Node {
        light: Some(l),
        ..Default::default()
    });
    add_perspective_camera(&mut g, [0.0, 0.0, 0.0]);
    let dir = TempDir::new("glass");
    let scene = photongrid::load(&g.write_glb(dir.path(), "glass.glb")).unwrap();
    assert!(scene.has_specular());
    let settings = Settings {
        photons: 400_000,
        direct: DirectLighting::Photons,
        ..Settings::default()
    };
    let mut times = PhaseTimes::default();
    let prepared = prepare(&scene, &settings, &Progress::quiet(), &mut times).unwrap();
    let (mut direct, mut caustic) = (0.0f64, 0.0f64);
    for p in prepared.map.photons() {
        match p.kind() {
            PhotonKind::Direct => direct += p.power().x as f64,
            PhotonKind::Caustic => caustic += p.power().x as f64,
            PhotonKind::Indirect => {}
        }
    }
    let total = direct + caustic;
    eprintln!("glass: direct {direct:.3} W + caustic {caustic:.3} W = {total:.3} W of 30 W");
    assert!(
        (total / 30.0 - 1.0).abs() < 0.01,
        "first-hit flux {total} W, light 30 W"
    );
    let share = caustic / total;
    assert!((share / 0.2 - 1.0).abs() < 0.03, "caustic share {share}, expected 0.2");
}

#[test]
fn photons_through_a_glass_slab_land_as_evenly_as_they_left() {
    // A point light 2 m above a clear glass slab (IOR 1.5, 0.2 m thick) over a diffuse floor.
    // Under the slab's centre the caustic photons' density is nearly flat. Emitted from
    // stratified points, they leave the light nearly as evenly as a grid (the counts of cells
    // whose outlines cut the points' strata vary by about 0.03 of their mean). A Fresnel choice
    // by chance at each face keeps 92 % of them like a coin toss and adds about 0.08 (binomial:
    // 1 − 0.92); it gave 0.15. Following the likelier branch with its weight adds nothing.
    let mut g = Gltf::new();
    let floor = g.material(Material::lambert(0.5));
    let glass = g.material(Material::glass(None));
    harness::add_object(&mut g, "floor", harness::rect_up(-3.0, 3.0, -3.0, 3.0, 0.0), floor);
    harness::add_object(
        &mut g,
        "slab",
        harness::box_prim([-1.0, 0.5, -1.0], [1.0, 0.7, 1.0]),
        glass,
    );
    harness::add_point_light(&mut g, [0.0, 2.7, 0.0], 100.0);
    add_perspective_camera(&mut g, [0.0, 1.0, 4.0]);
    let dir = TempDir::new("slab");
    let scene = photongrid::load(&g.write_glb(dir.path(), "slab.glb")).unwrap();
    let settings = Settings {
        photons: 10_000,
        caustic_photons: 400_000,
        ..Settings::default()
    };
    let mut times = PhaseTimes::default();
    let prepared = prepare(&scene, &settings, &Progress::quiet(), &mut times).unwrap();
    // 8 × 8 cells over the central 0.8 m square of the floor.
    const N: usize = 8;
    let (half, mut counts) = (0.4f32, vec![0u32; N * N]);
    for p in prepared.map.photons() {
        let x = p.pos();
        if p.kind() != PhotonKind::Caustic || x.y.abs() > 1e-3 || x.x.abs() >= half || x.z.abs() >= half {
            continue;
        }
        let cell = |v: f32| ((v + half) / (2.0 * half) * N as f32) as usize;
        counts[cell(x.z) * N + cell(x.x)] += 1;
    }
    // The density falls off from the centre (as cos³ of the angle, about 7 % at the corners):
    // the counts' spread is taken about a fit a + b·r² (r the cell centre's distance from the
    // centre), not about their mean.
    let r2: Vec<f64> = (0..N * N)
        .map(|i| {
            let c = |k: usize| ((k as f64 + 0.5) / N as f64 - 0.5) * 2.0 * half as f64;
            c(i % N).powi(2) + c(i / N).powi(2)
        })
        .collect();
    let y: Vec<f64> = counts.iter().map(|&c| c as f64).collect();
    let n = y.len() as f64;
    let (mr, mean) = (r2.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let b = r2.iter().zip(&y).map(|(r, y)| (r - mr) * (y - mean)).sum::<f64>()
        / r2.iter().map(|r| (r - mr).powi(2)).sum::<f64>();
    let var = r2
        .iter()
        .zip(&y)
        .map(|(r, y)| (y - mean - b * (r - mr)).powi(2))
        .sum::<f64>()
        / (n - 2.0);
    eprintln!(
        "slab: {mean:.1} caustic photons per cell, variance / mean {:.4}",
        var / mean
    );
    assert!(mean > 300.0, "{mean} photons per cell");
    assert!(
        var / mean < 0.06,
        "variance / mean {}: thinned by chance at the faces?",
        var / mean
    );
}

#[test]
fn integrating_sphere_photon_flux_and_path_length() {
    // A 30 W point light at the centre of a closed diffuse sphere (albedo 0.7): every photon
    // stays inside until absorbed, so the flux arriving on the walls over n interactions is
    // P (1 − ρⁿ) / (1 − ρ), and the absorbed flux is P when n is unlimited. `max_depth` counts
    // like the references' Mitsuba (12: photons of at most 11 interactions).
    let rho = 0.7f64;
    let mut g = Gltf::new();
    let wall = g.material(Material::lambert(rho as f32));
    let room = g.mesh(vec![uv_sphere([0.0; 3], 2.0, 48, 96).material(wall)]);
    g.root(Node {
        mesh: Some(room),
        ..Default::default()
    });
    let l = g.light(Light::point(1_630.542_4));
    g.root(Node {
        light: Some(l),
        ..Default::default()
    });
    add_perspective_camera(&mut g, [0.0, 0.0, 1.0]);
    let dir = TempDir::new("sphere-room");
    let scene = photongrid::load(&g.write_glb(dir.path(), "room.glb")).unwrap();
    let incident = |settings: &Settings| {
        let mut times = PhaseTimes::default();
        let prepared = prepare(&scene, settings, &Progress::quiet(), &mut times).unwrap();
        let mut sum = 0.0f64;
        let mut deepest = 0;
        for p in prepared.map.photons() {
            sum += p.power().x as f64;
            deepest = deepest.max(p.depth());
        }
        (sum, deepest)
    };
    let base = Settings {
        photons: 200_000,
        direct: DirectLighting::Photons,
        gather: 0,
        caustic_photons: 0,
        ..Settings::default()
    };
    let (got, deepest) = incident(&base);
    let want = 30.0 * (1.0 - rho.powi(11)) / (1.0 - rho);
    eprintln!("max_depth 12: incident {got:.3} W, closed form {want:.3} W, deepest photon {deepest}");
    assert_eq!(deepest, 11);
    assert!((got / want - 1.0).abs() < 0.01, "{got} vs {want}");
    let unlimited = Settings {
        max_depth: 0,
        max_photon_depth: 200,
        ..base
    };
    let (got, _) = incident(&unlimited);
    let absorbed = got * (1.0 - rho);
    eprintln!("unlimited: incident {got:.3} W, absorbed {absorbed:.3} W of 30 W");
    assert!((absorbed / 30.0 - 1.0).abs() < 0.01, "absorbed {absorbed} W of 30 W");
}

#[test]
fn same_seed_same_image_whatever_the_thread_count() {
    let scene = photongrid::load(&sample("cornell_glass.glb")).unwrap();
    let settings = Settings {
        photons: 20_000,
        neighbours: 50,
        spp: 2,
        seed: 7,
        width: Some(40),
        height: Some(30),
        ..Settings::default()
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render_loaded(&scene, &settings))
    };
    let a = run(1);
    let b = run(3);
    assert!(a.mean().iter().any(|&m| m > 0.0));
    let bits = |f: &Film| -> Vec<[u32; 3]> { f.color.iter().map(|c| c.to_array().map(f32::to_bits)).collect() };
    assert!(bits(&a) == bits(&b), "images differ between 1 and 3 threads");
    // A different seed changes the image (so the comparison above means something).
    let c = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| {
            render_loaded(
                &scene,
                &Settings {
                    seed: 8,
                    ..settings.clone()
                },
            )
        });
    assert!(bits(&a) != bits(&c));
}
