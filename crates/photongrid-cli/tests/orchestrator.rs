//! One orchestrator, settings defined once: a bench run and a `render` with the same settings
//! give identical images, and the settings schema lists every setting with its flag.

use photongrid::output::{write_exr, AovSelection};
use photongrid::Settings;
use photongrid_cli::metrics::read_exr_rgb;
use photongrid_testkit::TempDir;
use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_photongrid");

fn ok(args: &[String]) -> std::process::Output {
    let out = Command::new(BIN).args(args).output().expect("photongrid runs");
    assert!(
        out.status.success(),
        "photongrid {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

/// `--key value` flags for every setting in a settings JSON object (the jobs-file/stats form).
fn flags(settings: &serde_json::Value) -> Vec<String> {
    let mut out = Vec::new();
    for (k, v) in settings.as_object().unwrap() {
        let value = match v {
            serde_json::Value::Null => continue,
            serde_json::Value::String(s) => s.clone(),
            v => v.to_string(),
        };
        out.push(format!("--{}", k.replace('_', "-")));
        out.push(value);
    }
    out
}

#[test]
fn bench_and_render_give_identical_images() {
    let dir = TempDir::new("orchestrator");
    let scenes = dir.path().join("scenes");
    std::fs::create_dir_all(scenes.join("refs")).unwrap();
    let scene = scenes.join("cornell_glass.glb");
    std::fs::copy(photongrid_testkit::sample("cornell_glass.glb"), &scene).unwrap();
    // Any image of the right size serves as the reference: only the images are compared here.
    let film = photongrid::film::Film::new(40, 30);
    write_exr(
        &scenes.join("refs/cornell_glass_cam0.exr"),
        &film,
        AovSelection::default(),
    )
    .unwrap();
    let out = dir.path().join("out");
    ok(&[
        "bench".into(),
        s(&scenes),
        "--out".into(),
        s(&out),
        "--methods".into(),
        "default".into(),
        "--photons".into(),
        "30000".into(),
        "--seeds".into(),
        "1".into(),
        "--width".into(),
        "40".into(),
        "--height".into(),
        "30".into(),
        "--images".into(),
        "--quiet".into(),
    ]);
    let bench: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap();
    let run = &bench["runs"][0];
    let key: photongrid_cli::bench::RunKey = serde_json::from_value(run["key"].clone()).unwrap();
    let bench_image = out.join("images").join(photongrid_cli::bench::image_name(&key, 0));

    let rendered = dir.path().join("render.exr");
    let mut args = vec![
        "render".into(),
        s(&scene),
        "--camera".into(),
        "0".into(),
        "--output".into(),
        s(&rendered),
    ];
    args.extend(flags(&run["settings"]));
    args.extend(["--progress".into(), "quiet".into()]);
    ok(&args);
    let (a, b) = (read_exr_rgb(&bench_image).unwrap(), read_exr_rgb(&rendered).unwrap());
    assert_eq!((a.width, a.height), (40, 30));
    assert!(a.data.iter().any(|p| p[0] > 0.0), "the image is not black");
    let bits = |i: &photongrid_cli::metrics::Image| i.data.iter().map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
    assert!(bits(&a) == bits(&b), "bench and render images differ");
}

#[test]
fn settings_schema_lists_every_setting_with_its_flag_and_default() {
    let out = ok(&["settings".into(), "--schema".into()]);
    let schema: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let defaults = serde_json::to_value(Settings::default()).unwrap();
    // The schema is read back from text, whose floats serde_json parses to within an ulp.
    let same = |a: &serde_json::Value, b: &serde_json::Value| match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => (x - y).abs() <= 1e-12 * y.abs(),
        _ => a == b,
    };
    let items = schema["settings"].as_array().unwrap();
    let keys: Vec<&str> = items.iter().map(|i| i["key"].as_str().unwrap()).collect();
    // Every serialised setting (optional ones are absent from the defaults) is in the schema.
    for k in defaults.as_object().unwrap().keys() {
        assert!(keys.contains(&k.as_str()), "{k} missing from the schema");
    }
    for i in items {
        let key = i["key"].as_str().unwrap();
        assert_eq!(i["flag"], format!("--{}", key.replace('_', "-")));
        assert!(i["heading"].is_string() && i["help"].is_string(), "{key}");
        let default = defaults.get(key).cloned().unwrap_or_default();
        assert!(same(&i["default"], &default), "{key}: {} vs {default}", i["default"]);
    }
    let method = items.iter().find(|i| i["key"] == "method").unwrap();
    let choices: Vec<&str> = method["choices"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["value"].as_str().unwrap())
        .collect();
    assert_eq!(choices, ["knn", "adaptive", "sppm", "multiscale"]);
    // The defaults form parses back as settings (the jobs-file form).
    let out = ok(&["settings".into()]);
    let back: Settings = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(back, Settings::default());
}
