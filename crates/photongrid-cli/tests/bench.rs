//! `photongrid bench` end to end on a tiny folder: one scene, a fake reference rendered by
//! photongrid itself, a 2 methods × 2 photon counts matrix at 32×24.

use photongrid::film::Film;
use photongrid::output::{write_exr, AovSelection};
use photongrid::Rgb;
use std::path::Path;
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_photongrid");

fn run(args: &[&str]) -> Output {
    let out = Command::new(BIN).args(args).output().expect("photongrid runs");
    out
}

fn ok(args: &[&str]) -> Output {
    let out = run(args);
    assert!(
        out.status.success(),
        "photongrid {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Polylines drawn with the data-line stroke (axes and ticks are 1 px).
fn data_lines(svg: &str) -> usize {
    let w = format!("stroke-width=\"{}\"", photongrid_cli::bench::DATA_STROKE);
    svg.split('<')
        .filter(|t| t.starts_with("polyline") && t.contains(&w))
        .count()
}

/// The contents of the SVG's text elements, trimmed.
fn svg_texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| Some(t.split_once('>')?.1.split_once("</text>")?.0.trim().to_string()))
        .collect()
}

#[test]
fn bench_runs_a_matrix_and_writes_json_charts_and_table() {
    let tmp = photongrid_testkit::TempDir::new("bench-it");
    let root = tmp.path().to_path_buf();
    let scenes = root.join("scenes");
    let refs = scenes.join("refs");
    std::fs::create_dir_all(&refs).unwrap();
    let sample = photongrid_testkit::repo_root().join("samples/cornell_glass.glb");
    std::fs::copy(&sample, scenes.join("cornell_glass.glb")).unwrap();

    // The "reference": photongrid at 32×24 with more photons and another seed.
    let reference = refs.join("cornell_glass_cam0.exr");
    ok(&[
        "render",
        s(&scenes.join("cornell_glass.glb")),
        "--camera",
        "0",
        "--output",
        s(&reference),
        "--width",
        "32",
        "--height",
        "24",
        "--photons",
        "200000",
        "--seed",
        "99",
        "--progress",
        "quiet",
    ]);
    // A specular mask leaving out the top-left 8×8 block, and a file that is not a reference.
    let mut mask = Film::new(32, 24);
    for y in 0..8 {
        for x in 0..8 {
            mask.color[y * 32 + x] = Rgb::ONE;
        }
    }
    write_exr(
        &refs.join("cornell_glass_cam0.specmask.exr"),
        &mask,
        AovSelection::default(),
    )
    .unwrap();
    std::fs::copy(&reference, refs.join("cornell_glass_cam0.stderr.exr")).unwrap();

    let out = root.join("out");
    let args = [
        "bench",
        s(&scenes),
        "--out",
        s(&out),
        "--methods",
        "knn,adaptive",
        "--photons",
        "20000,40000",
        "--seeds",
        "1",
        "--width",
        "32",
        "--height",
        "24",
        "--spp",
        "1",
    ];
    ok(&args);

    // bench.json: 4 runs, one camera each, scored with and without the mask.
    let text = std::fs::read_to_string(out.join("bench.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).expect("bench.json parses");
    let runs = v["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    let mut keys: Vec<(String, u64)> = Vec::new();
    for r in runs {
        assert_eq!(r["key"]["scene"], "cornell_glass");
        assert_eq!(
            (r["key"]["width"].as_u64(), r["key"]["height"].as_u64()),
            (Some(32), Some(24))
        );
        keys.push((
            r["key"]["method"].as_str().unwrap().to_string(),
            r["key"]["budget"]["photons"].as_u64().unwrap(),
        ));
        assert_eq!(r["settings"]["photons"], r["key"]["budget"]["photons"]);
        assert!(r["seconds"]["total"].as_f64().unwrap() > 0.0);
        assert!(r["seconds"]["photons"].as_f64().unwrap() > 0.0);
        assert!(r["peak_memory_bytes"].as_u64().unwrap() > 0);
        let cams = r["cameras"].as_array().unwrap();
        assert_eq!(cams.len(), 1);
        let c = &cams[0];
        assert_eq!(c["index"], 0);
        let e = c["masked"]["block_rel_rmse"].as_f64().unwrap();
        assert!(e.is_finite() && e > 0.0 && e < 1.0, "masked block error {e}");
        let ratio = c["masked"]["mean_lum_ratio"].as_f64().unwrap();
        assert!((0.5..1.5).contains(&ratio), "mean ratio {ratio}");
        assert_eq!(c["masked"]["pixels_scored"], 32 * 24 - 64);
        assert_eq!(c["unmasked"]["pixels_scored"], 32 * 24);
    }
    keys.sort();
    assert_eq!(
        keys,
        [
            ("adaptive".to_string(), 20000),
            ("adaptive".to_string(), 40000),
            ("knn".to_string(), 20000),
            ("knn".to_string(), 40000)
        ]
    );
    photongrid_cli::bench::BenchFile::read(&out.join("bench.json")).expect("typed read");

    // Charts: one data line per method.
    for chart in ["error_vs_time_cornell_glass_cam0.svg", "time_vs_photons.svg"] {
        let svg = std::fs::read_to_string(out.join(chart)).unwrap();
        assert!(svg.contains("<svg") && svg.trim_end().ends_with("</svg>"), "{chart}");
        assert_eq!(data_lines(&svg), 2, "{chart}: one polyline per method");
        let texts = svg_texts(&svg);
        assert!(
            texts.iter().any(|t| t == "knn") && texts.iter().any(|t| t == "adaptive"),
            "{chart}: legend"
        );
    }

    // table.md: a table per photon count, one row per camera.
    let table = std::fs::read_to_string(out.join("table.md")).unwrap();
    assert_eq!(table.matches("| camera | knn | adaptive |").count(), 2, "{table}");
    assert_eq!(table.matches("\n| cornell_glass cam0 |").count(), 2, "{table}");
    for section in table.split("\n### ").skip(1) {
        let rows = section
            .lines()
            .filter(|l| l.starts_with("| ") && !l.starts_with("| camera"))
            .count();
        assert_eq!(rows, 1, "{section}");
    }

    // Resume skips every run; without --resume the file is not overwritten.
    let mut resume = args.to_vec();
    resume.push("--resume");
    let o = ok(&resume);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("0 runs rendered, 4 skipped"), "{err}");
    let again: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap();
    assert_eq!(again["runs"], v["runs"]);
    let o = run(&args);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--resume"));

    // Report-only rewrites the outputs from bench.json.
    std::fs::remove_file(out.join("table.md")).unwrap();
    ok(&["bench", "--out", s(&out), "--report-only"]);
    assert_eq!(std::fs::read_to_string(out.join("table.md")).unwrap(), table);

    // A size that does not divide the reference is refused before rendering.
    let o = run(&[
        "bench",
        s(&scenes),
        "--out",
        s(&root.join("out2")),
        "--width",
        "20",
        "--height",
        "15",
        "--photons",
        "1000",
        "--seeds",
        "1",
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("must divide"));
}

#[test]
fn bench_help_lists_every_method() {
    // The --methods help is written by hand beside the METHODS table: keep them in step.
    let out = ok(&["bench", "--help"]);
    let help = String::from_utf8_lossy(&out.stdout);
    let text: String = help.split_whitespace().collect::<Vec<_>>().join(" ");
    let start = text.find("Methods, comma-separated:").expect("a --methods help line");
    let list = &text[start + "Methods, comma-separated:".len()..];
    let listed: Vec<&str> = list[..list.find('(').unwrap_or(list.len())]
        .split(',')
        .map(|m| m.trim().trim_end_matches('.'))
        .collect();
    for m in photongrid_cli::bench::METHODS {
        assert!(
            listed.contains(&m.name),
            "bench --help lists {listed:?}, lacks {}",
            m.name
        );
    }
}
