//! Progressive rendering: determinism over passes and threads, SPPM against a closed form, the
//! time budget and checkpoints. (The SPPM radius update and the budget rule have unit tests
//! beside their code: `render::sppm`, `render::progressive`.)

use photongrid::film::Film;
use photongrid::pipeline::{prepare, render, render_camera, select_cameras, PhaseTimes, RenderRequest, Rendered};
use photongrid::progress::Progress;
use photongrid::scene::Scene;
use photongrid::settings::{DirectLighting, Method};
use photongrid::Settings;
use photongrid_testkit::*;
use std::f64::consts::PI;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Instant;

const BIN: &str = env!("CARGO_BIN_EXE_photongrid");

fn passes(scene: &Scene, settings: &Settings) -> Rendered {
    let cams = select_cameras(scene, &[]).unwrap();
    let request = RenderRequest {
        scene,
        cameras: &cams[..1],
        settings,
        start: Instant::now(),
    };
    render(&request, &Progress::quiet(), None).unwrap()
}

fn bits(f: &Film) -> Vec<[u32; 3]> {
    f.color.iter().map(|c| c.to_array().map(f32::to_bits)).collect()
}

fn small(method: Method) -> Settings {
    Settings {
        photons: 20_000,
        caustic_photons: 10_000,
        neighbours: 30,
        spp: 1,
        seed: 11,
        width: Some(32),
        height: Some(24),
        method,
        grid_res: 32,
        ..Settings::default()
    }
}

#[test]
fn same_seed_and_passes_same_image_whatever_the_thread_count() {
    let scene = photongrid::load(&sample("cornell_glass.glb")).unwrap();
    for method in [Method::Knn, Method::Adaptive, Method::Sppm] {
        let settings = Settings {
            passes: Some(3),
            ..small(method)
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| passes(&scene, &settings))
        };
        let (a, b) = (run(1), run(2));
        assert_eq!((a.report.passes.count, b.report.passes.count), (3, 3));
        assert_eq!(a.report.photons.emitted, 3 * 20_000);
        assert!(a.films[0].mean().iter().any(|&m| m > 0.0), "{method:?}");
        assert_eq!(a.films[0].nonfinite(), 0, "{method:?}");
        assert!(
            bits(&a.films[0]) == bits(&b.films[0]),
            "{method:?}: 1 and 2 threads differ"
        );
        // More passes change the image (each pass has its own photons and samples).
        let one = passes(
            &scene,
            &Settings {
                passes: Some(1),
                ..small(method)
            },
        );
        assert!(bits(&one.films[0]) != bits(&a.films[0]), "{method:?}");
    }
}

#[test]
fn one_pass_is_the_plain_render() {
    let scene = photongrid::load(&sample("cornell_glass.glb")).unwrap();
    for method in [Method::Knn, Method::Adaptive] {
        let settings = small(method);
        let progressive = passes(&scene, &settings);
        assert_eq!(progressive.report.passes.count, 1);
        let cams = select_cameras(&scene, &[]).unwrap();
        let prepared = prepare(&scene, &settings, &Progress::quiet(), &mut PhaseTimes::default()).unwrap();
        let plain = render_camera(&scene, &prepared, cams[0], &settings, &Progress::quiet());
        assert!(bits(&plain) == bits(&progressive.films[0]), "{method:?}");
    }
}

const ALBEDO: f64 = 0.5;
const W: u32 = 64;
const H: u32 = 48;
const YMAG: f64 = 2.0;
const LIGHT_H: f64 = 3.0;

/// A 40 m Lambert plane (albedo 0.5) at y = 0, a point light 3 m above the origin and an
/// orthographic camera looking straight down (as `tests/analytic.rs`).
fn plane_under_point_light(dir: &TempDir, candela: f32) -> std::path::PathBuf {
    let mut g = Gltf::new();
    let m = g.material(Material::lambert(ALBEDO as f32));
    let mesh = g.mesh(vec![floor_quad(20.0, 0.0).material(m)]);
    g.root(Node {
        name: Some("Plane".into()),
        mesh: Some(mesh),
        ..Default::default()
    });
    let l = g.light(Light::point(candela));
    g.root(Node {
        name: Some("Light".into()),
        transform: Transform::tr([0.0, LIGHT_H as f32, 0.0], [0.0, 0.0, 0.0, 1.0]),
        light: Some(l),
        ..Default::default()
    });
    let c = g.camera(Camera::Orthographic {
        xmag: (YMAG * W as f64 / H as f64) as f32,
        ymag: YMAG as f32,
    });
    g.root(Node {
        name: Some("Top".into()),
        transform: Transform::tr([0.0, 10.0, 0.0], look_down()),
        camera: Some(c),
        ..Default::default()
    });
    g.write_gltf(dir.path(), "plane.gltf")
}

#[test]
fn sppm_plane_under_point_light_matches_closed_form() {
    // All light from photons (--direct photons), so the SPPM estimate is the whole image:
    // L = (albedo/π)(I/683) cos θ / d².
    let dir = TempDir::new("sppm_plane");
    let candela = 500.0;
    let scene = photongrid::load(&plane_under_point_light(&dir, candela as f32)).unwrap();
    let settings = Settings {
        photons: 300_000,
        neighbours: 100,
        spp: 1,
        width: Some(W),
        height: Some(H),
        direct: DirectLighting::Photons,
        method: Method::Sppm,
        passes: Some(6),
        ..Settings::default()
    };
    let result = passes(&scene, &settings);
    assert_eq!(result.report.passes.count, 6);
    let film = &result.films[0];
    let radiance = |x: f64, z: f64| {
        let d2 = x * x + z * z + LIGHT_H * LIGHT_H;
        ALBEDO / PI * (candela / 683.0) * (LIGHT_H / d2.sqrt()) / d2
    };
    // Central region |x|, |z| < 1 m; pixel centres (the closed form barely curves over a pixel).
    let (mut got, mut want, mut n) = (0.0, 0.0, 0);
    for py in 0..H {
        for px in 0..W {
            let x = (2.0 * (px as f64 + 0.5) / W as f64 - 1.0) * YMAG * W as f64 / H as f64;
            let z = -(1.0 - 2.0 * (py as f64 + 0.5) / H as f64) * YMAG;
            if x.abs() < 1.0 && z.abs() < 1.0 {
                got += film.color[(py * W + px) as usize].x as f64;
                want += radiance(x, z);
                n += 1;
            }
        }
    }
    assert!(n > 500, "{n}");
    let rel = got / want - 1.0;
    eprintln!(
        "sppm: region mean {:.5} vs {:.5} ({:+.3} %)",
        got / n as f64,
        want / n as f64,
        100.0 * rel
    );
    assert!(rel.abs() < 0.03, "{:+.2} %", 100.0 * rel);
    // Every visible point got a radius (the PhotonRadius.X pass shows sample 0's).
    assert!(film.aov.iter().all(|a| a.radius > 0.0));
}

fn tiny_scene_args(dir: &TempDir) -> Vec<String> {
    let scene = sample("cornell_glass.glb");
    vec![
        "render".into(),
        scene.display().to_string(),
        "--photons".into(),
        "5000".into(),
        "--caustic-photons".into(),
        "2000".into(),
        "--neighbours".into(),
        "20".into(),
        "--spp".into(),
        "1".into(),
        "--width".into(),
        "24".into(),
        "--height".into(),
        "18".into(),
        "--output".into(),
        dir.join("out.exr").display().to_string(),
    ]
}

#[test]
fn time_budget_runs_at_least_one_pass_and_reports_the_count() {
    let dir = TempDir::new("time_budget");
    for (budget, method) in [("0.000001", "sppm"), ("0.3", "adaptive")] {
        let stats = dir.join("stats.json");
        let out = Command::new(BIN)
            .args(tiny_scene_args(&dir))
            .args(["--time", budget, "--method", method, "--progress", "quiet", "--stats"])
            .arg(&stats)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let s: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
        let count = s["passes"]["count"].as_u64().unwrap();
        assert!(count >= 1, "{s}");
        assert_eq!(s["passes"]["seconds"].as_array().unwrap().len() as u64, count);
        // No pass limit: only the budget can have stopped it.
        assert_eq!(s["passes"]["stopped_by"], "time");
        assert_eq!(s["photons"]["emitted"].as_u64().unwrap(), 5000 * count);
        if budget == "0.000001" {
            assert_eq!(count, 1, "the minimum is one pass");
        }
        let img = photongrid_cli::metrics::read_exr_rgb(&dir.join("out.exr")).unwrap();
        assert_eq!((img.width, img.height), (24, 18));
    }
    // The add-on's spelling, with a unit.
    let out = Command::new(BIN)
        .args(tiny_scene_args(&dir))
        .args(["--time-budget=0.001s", "--progress", "quiet"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bad = Command::new(BIN)
        .args(tiny_scene_args(&dir))
        .args(["--time", "soon"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not a duration"));
}

#[test]
fn checkpoint_leaves_a_readable_image_when_killed() {
    let dir = TempDir::new("checkpoint");
    let out = dir.join("out.exr");
    // Passes without end; a checkpoint after every pass; kill at the first one.
    let mut child = Command::new(BIN)
        .args(tiny_scene_args(&dir))
        .args([
            "--passes",
            "1000000",
            "--checkpoint",
            "0",
            "--method",
            "sppm",
            "--progress",
            "json",
        ])
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let stderr = BufReader::new(child.stderr.take().unwrap());
    let mut seen = None;
    for line in stderr.lines() {
        let line = line.unwrap();
        if let Ok(v) = serde_json::from_str::<serde_json::Value>(&line) {
            if v["event"] == "checkpoint" {
                seen = Some(v);
                break;
            }
        }
    }
    child.kill().unwrap();
    let _ = child.wait();
    let v = seen.expect("a checkpoint event before the end");
    assert_eq!(v["path"].as_str().unwrap(), out.display().to_string());
    assert!(v["passes"].as_u64().unwrap() >= 1);
    let img = photongrid_cli::metrics::read_exr_rgb(&out).unwrap();
    assert_eq!((img.width, img.height), (24, 18));
    assert!(img.data.iter().all(|c| c.iter().all(|v| v.is_finite())));
    assert!(img.data.iter().any(|c| c[0] > 0.0));
}
