//! Scene scale (issue 12): ray offsets are relative to the scene, so one small scene scaled by
//! 10⁻³ or 10⁴ (its point light's intensity by the square, so that the irradiance stays the
//! same) renders the same image within noise. With the old absolute offsets (10⁻⁴ m plus a
//! share of the coordinates) the small scene leaked light through the box's contact with the
//! floor and lost its shadows.

use photongrid::film::Film;
use photongrid::pipeline::{render, select_cameras, RenderRequest};
use photongrid::progress::Progress;
use photongrid::Settings;
use photongrid_testkit::harness::box_prim;
use photongrid_testkit::*;
use std::time::Instant;

/// A floor, a back wall and a box standing on the floor, lit by a point light, seen by one
/// camera — every length multiplied by `s`.
fn scene_at(s: f32) -> Gltf {
    let mut g = Gltf::new();
    let m = g.material(Material::lambert(0.7));
    let scaled = |mut p: Prim| {
        for v in &mut p.positions {
            *v = v.map(|c| c * s);
        }
        p
    };
    let floor = Prim::new(vec![
        [-3.0, 0.0, 3.0],
        [3.0, 0.0, 3.0],
        [3.0, 0.0, -3.0],
        [-3.0, 0.0, -3.0],
    ])
    .normals(vec![[0.0, 1.0, 0.0]; 4])
    .indices_u16(vec![0, 1, 2, 0, 2, 3]);
    let wall = Prim::new(vec![
        [-3.0, 0.0, -2.0],
        [3.0, 0.0, -2.0],
        [3.0, 3.0, -2.0],
        [-3.0, 3.0, -2.0],
    ])
    .normals(vec![[0.0, 0.0, 1.0]; 4])
    .indices_u16(vec![0, 1, 2, 0, 2, 3]);
    let cube = box_prim([-0.6, 0.0, -0.6], [0.6, 1.0, 0.6]);
    let mesh = g.mesh(vec![
        scaled(floor).material(m),
        scaled(wall).material(m),
        scaled(cube).material(m),
    ]);
    g.root(Node {
        name: Some("Room".into()),
        mesh: Some(mesh),
        ..Default::default()
    });
    let l = g.light(Light::point(2000.0 * s * s));
    g.root(Node {
        name: Some("Lamp".into()),
        transform: Transform::translation([0.8 * s, 2.5 * s, 1.2 * s]),
        light: Some(l),
        ..Default::default()
    });
    let c = g.camera(Camera::Perspective {
        yfov: 0.7,
        aspect: Some(4.0 / 3.0),
    });
    g.root(Node {
        name: Some("Camera".into()),
        transform: Transform::translation([0.0, 1.5 * s, 5.0 * s]),
        camera: Some(c),
        ..Default::default()
    });
    g
}

fn render_at(s: f32) -> Film {
    let dir = TempDir::new("scale");
    let path = scene_at(s).write_glb(dir.path(), "scene.glb");
    let scene = photongrid::load(&path).unwrap_or_else(|e| panic!("scale {s}: {e}"));
    let settings = Settings {
        photons: 100_000,
        spp: 2,
        seed: 5,
        width: Some(160),
        height: Some(120),
        ..Settings::default()
    };
    let cams = select_cameras(&scene, &[]).unwrap();
    let request = RenderRequest {
        scene: &scene,
        cameras: &cams,
        settings: &settings,
        start: Instant::now(),
    };
    let mut r = render(&request, &Progress::quiet(), None).unwrap_or_else(|e| panic!("scale {s}: {e}"));
    let film = r.films.remove(0);
    assert_eq!(film.nonfinite(), 0, "scale {s}");
    film
}

/// Mean grey of each 10×10 block of a 160×120 film.
fn blocks(f: &Film) -> Vec<f64> {
    let (w, h) = (f.width as usize, f.height as usize);
    let mut out = Vec::new();
    for by in 0..h / 10 {
        for bx in 0..w / 10 {
            let mut sum = 0.0;
            for y in by * 10..by * 10 + 10 {
                for x in bx * 10..bx * 10 + 10 {
                    let c = f.color[y * w + x];
                    sum += ((c.x + c.y + c.z) / 3.0) as f64;
                }
            }
            out.push(sum / 100.0);
        }
    }
    out
}

/// `b` is `a` within noise: the same mean within 3 %, and every block within 2 % of the
/// brightest block's level plus 15 % of its own (photon noise at 100k photons is a few %).
#[track_caller]
fn same_image(a: &Film, b: &Film, what: &str) {
    let (ba, bb) = (blocks(a), blocks(b));
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (ma, mb) = (mean(&ba), mean(&bb));
    assert!(ma > 0.0, "{what}: the reference is black");
    assert!((mb / ma - 1.0).abs() < 0.03, "{what}: mean {mb} vs {ma}");
    let top = ba.iter().cloned().fold(0.0, f64::max);
    for (i, (x, y)) in ba.iter().zip(&bb).enumerate() {
        assert!(
            (x - y).abs() <= 0.02 * top + 0.15 * x,
            "{what}: block {i} ({}, {}) is {y}, the reference {x}",
            i % 16,
            i / 16
        );
    }
}

#[test]
fn a_scene_scaled_by_1e_minus_3_and_1e4_renders_the_same() {
    let reference = render_at(1.0);
    // The box's shadow exists: the darkest floor blocks are well below the mean.
    let b = blocks(&reference);
    let mean = b.iter().sum::<f64>() / b.len() as f64;
    assert!(b.iter().any(|&x| x < 0.3 * mean), "no shadow in the reference: {b:?}");
    for s in [1e-3, 1e4] {
        same_image(&reference, &render_at(s), &format!("scale {s}"));
    }
}

#[test]
fn extreme_scales_render_the_same() {
    let reference = render_at(1.0);
    for s in [1e-6, 1e8] {
        same_image(&reference, &render_at(s), &format!("scale {s}"));
    }
}
