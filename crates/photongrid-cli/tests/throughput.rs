//! `photongrid throughput` on a sample scene: the figures exist, are positive and consistent
//! with each other (never their values: they depend on the machine).

use photongrid_cli::throughput::{measure, table_md, SceneThroughput, ThroughputOptions};
use std::path::{Path, PathBuf};
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_photongrid");

fn sample(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../samples").join(name)
}

fn small() -> ThroughputOptions {
    ThroughputOptions {
        rays: 20_000,
        photons: 20_000,
        queries: 2_000,
        k: 50,
        width: 32,
        height: 24,
        seed: 1,
    }
}

fn check(r: &SceneThroughput, opts: &ThroughputOptions) {
    assert!(r.triangles > 0 && r.threads > 0, "{r:?}");
    for (name, rate) in [("closest hit", r.closest_hit), ("shadow", r.shadow), ("knn", r.knn)] {
        assert!(rate.one_thread > 0.0 && rate.one_thread.is_finite(), "{name}: {rate:?}");
        assert!(
            rate.per_thread_all > 0.0 && rate.per_thread_all.is_finite(),
            "{name}: {rate:?}"
        );
    }
    assert!(r.indexed > 0, "{r:?}");
    let g = &r.render;
    assert_eq!(g.paths, opts.photons);
    // Every stored photon ends a ray, every path starts with one.
    assert!(g.photon_rays >= g.stored && g.photon_rays >= g.paths, "{g:?}");
    assert!(
        g.photons_seconds > 0.0 && g.build_seconds > 0.0 && g.render_seconds > 0.0,
        "{g:?}"
    );
    assert!(g.photon_rays_per_thread > 0.0 && g.samples_per_thread > 0.0, "{g:?}");
    assert!(r.photon_pass_ratio > 0.0 && r.photon_pass_ratio.is_finite(), "{r:?}");
}

#[test]
fn measures_rays_knn_and_render_phases() {
    let opts = small();
    let r = measure(&sample("cornell_glass.glb"), &opts).expect("measured");
    check(&r, &opts);
    let table = table_md(&[r.clone(), r]);
    assert_eq!(table.lines().count(), 4, "{table}");
    assert!(
        table.lines().nth(2).unwrap().starts_with("| cornell_glass | "),
        "{table}"
    );
}

#[test]
fn command_prints_one_json_object_per_scene() {
    let scenes = [sample("cornell_area.glb"), sample("shadow_edges.glb")];
    let out = Command::new(BIN)
        .args([
            "throughput",
            "--json",
            "--rays",
            "5k",
            "--photons",
            "5k",
            "--queries",
            "500",
        ])
        .args(["--width", "16", "--height", "12"])
        .args(&scenes)
        .output()
        .expect("photongrid runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: Vec<SceneThroughput> = serde_json::from_slice(&out.stdout).expect("JSON array");
    assert_eq!(v.len(), 2);
    let opts = ThroughputOptions {
        photons: 5_000,
        ..small()
    };
    for (r, s) in v.iter().zip(&scenes) {
        assert_eq!(Path::new(&r.scene), s.as_path());
        check(r, &opts);
    }
}

#[test]
fn a_missing_scene_is_an_error_naming_it() {
    let out = Command::new(BIN)
        .args(["throughput", "no_such_scene.glb"])
        .output()
        .expect("photongrid runs");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no_such_scene.glb"));
}
