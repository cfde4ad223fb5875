//! Issue 11's command line, through the real binary: outputs checked before any work, folders
//! created, the summary listing every phase, `--progress json` carrying only JSON (with the
//! camera of each render event and warnings), `info` on many files, counts as `2M`/`1e6`,
//! `--photons 0`, grouped help without doc syntax, a stop on SIGINT that keeps the passes done,
//! and the EXR's alpha and Blender-named passes.

use photongrid_testkit::*;
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_photongrid");

fn run(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .output()
        .expect("photongrid runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[track_caller]
fn ok(o: &Output) {
    assert!(o.status.success(), "exit {:?}:\n{}", o.status.code(), stderr(o));
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The floor of `simple_scene` under its top camera, a ball of a metallic 0.3 material (which
/// the loader approximates) and a second camera, "Side", looking along the floor: it sees the
/// sky above the horizon.
fn scene(dir: &TempDir) -> PathBuf {
    let mut g = simple_scene(100.0);
    let m = g.material(Material {
        name: Some("Brushed".into()),
        base_color: [0.8, 0.6, 0.3, 1.0],
        metallic: 0.3,
        roughness: 0.5,
        ..Default::default()
    });
    let mesh = g.mesh(vec![uv_sphere([0.0, 0.5, 0.0], 0.5, 8, 16).material(m)]);
    g.root(Node {
        name: Some("Ball".into()),
        mesh: Some(mesh),
        ..Default::default()
    });
    let c = g.camera(photongrid_testkit::Camera::Perspective {
        yfov: 0.7,
        aspect: Some(4.0 / 3.0),
    });
    g.root(Node {
        name: Some("Side".into()),
        transform: Transform::translation([0.0, 1.0, 6.0]),
        camera: Some(c),
        ..Default::default()
    });
    g.write_glb(dir.path(), "scene.glb")
}

const SMALL: [&str; 10] = [
    "--width",
    "32",
    "--height",
    "24",
    "--photons",
    "5000",
    "--caustic-photons",
    "2000",
    "--spp",
    "1",
];

/// `render SCENE -o OUT`, the small settings, then `extra`, whose options replace the small
/// settings' (clap refuses an option given twice).
fn render_args<'a>(scene: &'a Path, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["render", s(scene), "-o", s(out)];
    for pair in SMALL.chunks(2) {
        if !extra.contains(&pair[0]) {
            a.extend_from_slice(pair);
        }
    }
    a.extend_from_slice(extra);
    a
}

/// Channel name → values of an EXR's first layer.
fn exr_channels(path: &Path) -> std::collections::HashMap<String, Vec<f32>> {
    use exr::prelude::*;
    let image = read_all_flat_layers_from_file(path).unwrap();
    let layer = &image.layer_data[0];
    layer
        .channel_data
        .list
        .iter()
        .map(|c| {
            let v = match &c.sample_data {
                FlatSamples::F32(v) => v.clone(),
                FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
                FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
            };
            (c.name.to_string(), v)
        })
        .collect()
}

#[test]
fn unwritable_output_and_wrong_extension_are_refused_before_any_work() {
    let dir = TempDir::new("early-output");
    let scene = scene(&dir);
    // A folder no file can be created in: refused before the scene is even loaded (no phase
    // starts), not after the render.
    let o = run(&render_args(&scene, Path::new("/proc/x.exr"), &["--progress", "json"]));
    assert!(!o.status.success());
    let events: Vec<Value> = stderr(&o).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(events.len(), 1, "{events:?}");
    let message = events[0]["message"].as_str().unwrap();
    assert!(
        message.contains("/proc/x.exr") && message.contains("cannot write"),
        "{message}"
    );
    // -o x.png would be an EXR named .png: refused, saying why and what to do.
    let png = dir.join("x.png");
    let o = run(&render_args(&scene, &png, &[]));
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("x.png") && e.contains("OpenEXR") && e.contains(".exr") && e.contains("--png"),
        "{e}"
    );
    assert!(!png.exists());
    // --png takes a .png.
    let o = run(&render_args(
        &scene,
        &dir.join("a.exr"),
        &["--png", s(&dir.join("p.exr"))],
    ));
    assert!(!o.status.success() && stderr(&o).contains("PNG"), "{}", stderr(&o));
    // A folder named as the output.
    std::fs::create_dir_all(dir.join("taken.exr")).unwrap();
    let o = run(&render_args(&scene, &dir.join("taken.exr"), &[]));
    assert!(
        !o.status.success() && stderr(&o).contains("is a folder"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn output_stats_and_report_folders_are_created() {
    let dir = TempDir::new("folders");
    let scene = scene(&dir);
    let out = dir.join("new/deeper/out.exr");
    let png = dir.join("previews/out.png");
    let stats = dir.join("stats/run/stats.json");
    let o = run(&render_args(
        &scene,
        &out,
        &["--png", s(&png), "--stats", s(&stats), "--progress", "quiet"],
    ));
    ok(&o);
    assert!(out.is_file() && png.is_file() && stats.is_file());
    // The README's batch command on a fresh clone: the report's folder does not exist yet.
    let jobs = dir.join("jobs.toml");
    std::fs::write(
        &jobs,
        format!(
            "[defaults]\nphotons = \"5k\"\ncaustic_photons = 2000\nspp = 1\nwidth = 16\nheight = 12\n\
             output = \"out/jobs/{{scene}}-{{camera}}.exr\"\n\n[[job]]\nscene = \"{}\"\ncamera = \"Camera\"\n",
            scene.display()
        ),
    )
    .unwrap();
    let report = dir.join("out/jobs/report.json");
    let o = run(&["batch", s(&jobs), "--report", s(&report), "--quiet"]);
    ok(&o);
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(r["totals"]["done"], 1, "{r}");
    // A job whose output is not an EXR fails alone, saying why.
    std::fs::write(
        &jobs,
        format!(
            "[[job]]\nscene = \"{}\"\noutput = \"out/x.png\"\nphotons = 1000\nwidth = 8\nheight = 6\n",
            scene.display()
        ),
    )
    .unwrap();
    let o = run(&["batch", s(&jobs), "--report", s(&report), "--quiet"]);
    assert!(!o.status.success());
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert!(r["units"][0]["error"].as_str().unwrap().contains(".exr"), "{r}");
}

#[test]
fn summary_lists_every_phase_that_ran() {
    let dir = TempDir::new("summary");
    let stats = dir.join("stats.json");
    // The defaults gather (irradiance) and use grids (adaptive).
    let o = run(&render_args(
        &sample("cornell_glass.glb"),
        &dir.join("out.exr"),
        &["--stats", s(&stats), "--progress", "auto"],
    ));
    ok(&o);
    let e = stderr(&o);
    let line = e.lines().find(|l| l.contains("total")).expect("a summary line");
    let st: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let seconds = st["seconds"].as_object().unwrap();
    let mut ran = 0;
    for (phase, v) in seconds {
        if phase != "total" && v.as_f64().unwrap() > 0.0 {
            assert!(line.contains(&format!("{phase} ")), "{phase} missing from: {line}");
            ran += 1;
        }
    }
    for phase in ["irradiance", "grids", "photons", "build", "render", "write"] {
        assert!(line.contains(phase), "{phase} missing from: {line}");
    }
    assert!(ran >= 7, "{seconds:?}");
}

#[test]
fn json_progress_is_json_only_and_render_events_name_their_camera() {
    let dir = TempDir::new("json");
    let scene = scene(&dir);
    let out = dir.join("out_{camera}.exr");
    let o = run(&render_args(
        &scene,
        &out,
        &["--camera", "all", "--passes", "2", "--progress", "json", "-v"],
    ));
    ok(&o);
    let events: Vec<Value> = stderr(&o)
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| serde_json::from_str::<Value>(l).unwrap_or_else(|_| panic!("not JSON: {l:?}")))
        .collect();
    assert!(events.iter().all(|e| e["event"].is_string()));
    let kinds: Vec<&str> = events.iter().map(|e| e["event"].as_str().unwrap()).collect();
    // The approximated material is a warning event; -v's log lines are JSON too.
    assert!(
        events
            .iter()
            .any(|e| e["event"] == "warning" && e["message"].as_str().unwrap().contains("Brushed")),
        "{kinds:?}"
    );
    assert!(kinds.contains(&"log"), "{kinds:?}");
    // Every render event carries its camera; a camera event comes before each render phase.
    let mut cameras = Vec::new();
    for (i, e) in events.iter().enumerate() {
        if e["phase"] == "render" {
            let c = e["camera"].as_str().expect("render event without camera");
            assert!(["Camera", "Side"].contains(&c));
            if e["event"] == "start" {
                assert_eq!(events[i - 1]["event"], "camera");
                assert_eq!(events[i - 1]["camera"], c);
                cameras.push(c.to_string());
            }
        }
    }
    assert_eq!(
        cameras,
        ["Camera", "Side", "Camera", "Side"],
        "two passes of two cameras"
    );
    let outputs: Vec<&Value> = events.iter().filter(|e| e["event"] == "output").collect();
    assert_eq!(outputs.len(), 2);
    let done = events.last().unwrap();
    assert_eq!(
        (done["event"].as_str(), done["passes"].as_u64()),
        (Some("done"), Some(2))
    );
    // A failure is a JSON error event and nothing else.
    let o = run(&render_args(
        &dir.join("missing.glb"),
        &dir.join("o.exr"),
        &["--progress", "json"],
    ));
    assert!(!o.status.success());
    let lines: Vec<Value> = stderr(&o)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|_| panic!("not JSON: {l:?}")))
        .collect();
    let errors: Vec<&Value> = lines.iter().filter(|e| e["event"] == "error").collect();
    assert_eq!(errors.len(), 1, "{lines:?}");
    assert_eq!(lines.last().unwrap()["event"], "error");
    assert!(errors[0]["message"].as_str().unwrap().contains("missing.glb"));
    // So is a usage error.
    let o = run(&[
        "render",
        s(&scene),
        "-o",
        s(&dir.join("o.exr")),
        "--progress",
        "json",
        "--bogus",
    ]);
    assert!(!o.status.success());
    let v: Value = serde_json::from_str(stderr(&o).trim()).unwrap_or_else(|_| panic!("{}", stderr(&o)));
    assert_eq!(v["event"], "error");
    assert!(v["message"].as_str().unwrap().contains("--bogus"));
}

#[test]
fn info_takes_many_files_and_describes_cameras() {
    let dir = TempDir::new("info");
    let scene = scene(&dir);
    let glass = sample("cornell_glass.glb");
    let o = run(&["info", s(&scene), s(&glass)]);
    ok(&o);
    let text = stdout(&o);
    assert!(
        text.contains("scene.glb") && text.contains("cornell_glass.glb"),
        "{text}"
    );
    assert!(
        text.contains("0 'Camera': perspective, yfov 45.8°, aspect 4:3"),
        "{text}"
    );
    assert!(!text.contains("Perspective {") && !text.contains("Some("), "{text}");
    let o = run(&["info", "--json", s(&scene), s(&glass)]);
    ok(&o);
    let v: Value = serde_json::from_str(&stdout(&o)).unwrap();
    let all = v.as_array().expect("an array for several scenes");
    assert_eq!(all.len(), 2);
    let cam = &all[0]["report"]["cameras"][0];
    assert_eq!(cam["projection"], "perspective");
    assert_eq!(cam["name"], "Camera");
    assert!((cam["yfov_degrees"].as_f64().unwrap() - 45.8366).abs() < 1e-3, "{cam}");
    assert_eq!(cam["aspect_ratio"], "4:3");
    assert!(!stdout(&o).contains("Perspective {"));
    // One file: one object, as before.
    let o = run(&["info", "--json", s(&scene)]);
    ok(&o);
    assert!(serde_json::from_str::<Value>(&stdout(&o)).unwrap().is_object());
    // A missing file among others: the others are still described, the exit status says it.
    let o = run(&["info", s(&dir.join("nope.glb")), s(&scene)]);
    assert!(!o.status.success());
    assert!(stdout(&o).contains("scene.glb") && stderr(&o).contains("nope.glb"));
}

#[test]
fn counts_accept_suffixes_and_exponents() {
    let dir = TempDir::new("counts");
    let scene = scene(&dir);
    let stats = dir.join("stats.json");
    let o = run(&[
        "render",
        s(&scene),
        "-o",
        s(&dir.join("o.exr")),
        "--width",
        "16",
        "--height",
        "12",
        "--spp",
        "1",
        "--photons",
        "1e4",
        "--caustic-photons",
        "2k",
        "--neighbours",
        "5e1",
        "--gather-neighbours",
        "4e1",
        "--grid-cells",
        "1M",
        "--progress",
        "quiet",
        "--stats",
        s(&stats),
    ]);
    ok(&o);
    let st: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let set = &st["settings"];
    assert_eq!(
        (
            &set["photons"],
            &set["caustic_photons"],
            &set["neighbours"],
            &set["gather_neighbours"],
            &set["grid_cells"]
        ),
        (
            &Value::from(10_000),
            &Value::from(2000),
            &Value::from(50),
            &Value::from(40),
            &Value::from(1_000_000)
        )
    );
    let o = run(&["render", s(&scene), "-o", s(&dir.join("o.exr")), "--photons", "2.5"]);
    assert!(
        !o.status.success() && stderr(&o).contains("not a count"),
        "{}",
        stderr(&o)
    );
    // The bench's counts too: parsed (then the missing folder is the error).
    let o = run(&[
        "bench",
        s(&dir.join("no-scenes")),
        "--photons",
        "2M,500k,1e6",
        "--out",
        s(&dir.join("b")),
    ]);
    assert!(!o.status.success());
    assert!(
        !stderr(&o).contains("not a count") && !stderr(&o).contains("invalid value"),
        "{}",
        stderr(&o)
    );
    let o = run(&["bench", s(&dir.join("no-scenes")), "--photons", "lots"]);
    assert!(stderr(&o).contains("not a count"), "{}", stderr(&o));
}

#[test]
fn zero_photons_means_none_at_all() {
    let dir = TempDir::new("zero");
    let stats = dir.join("stats.json");
    let out = dir.join("o.exr");
    // cornell_glass has glass: without the rule the caustic pass would still trace 2000 paths.
    let o = run(&render_args(
        &sample("cornell_glass.glb"),
        &out,
        &["--photons", "0", "--stats", s(&stats), "--progress", "quiet"],
    ));
    ok(&o);
    let st: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!(st["photons"]["emitted"], 0, "{}", st["photons"]);
    assert_eq!(st["photons"]["stored"], 0, "{}", st["photons"]);
    assert_eq!(st["photons"]["caustic"], 0, "{}", st["photons"]);
    let img = photongrid_cli::metrics::read_exr_rgb(&out).unwrap();
    assert!(img.data.iter().all(|p| p.iter().all(|v| v.is_finite())));
    assert!(img.data.iter().any(|p| p[0] > 0.0), "direct light still shows");
}

/// `--dump-grids` with the default (multiscale) estimate: per plane and layer the photons per
/// fine cell and, with final gathering on, the irradiance gather rays read and the reach of
/// the kernel chosen at each texel — narrow in the ring's bright caustic, wide where there is
/// none;
/// `--stats` says why each layer's cells have their size and which kernels were chosen.
#[test]
fn dump_grids_shows_the_multiscale_textures_and_the_kernels_chosen() {
    let dir = TempDir::new("dump_grids");
    let (out, grids, stats) = (dir.join("out.exr"), dir.join("grids"), dir.join("stats.json"));
    let scene = sample("ring_caustic.glb");
    let extra = [
        "--photons",
        "100000",
        "--caustic-photons",
        "200000",
        "--dump-grids",
        s(&grids),
        "--stats",
        s(&stats),
    ];
    ok(&run(&render_args(&scene, &out, &extra)));
    let field = |name: &str| exr_channels(&grids.join(format!("plane000_caustic_{name}.exr")))["Y"].clone();
    let (counts, irradiance, reach) = (field("counts"), field("irradiance"), field("kernel_reach"));
    let report: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let stored = report["photons"]["caustic"].as_f64().unwrap();
    let counted: f64 = counts.iter().map(|&c| c as f64).sum();
    assert!(
        counted > 0.5 * stored && counted <= stored,
        "{counted} of {stored} caustic photons counted"
    );
    assert_eq!(irradiance.len(), reach.len());
    let median = |mut v: Vec<f32>| {
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    // The bright caustic (a tenth of the peak irradiance and more) is resolved at least one
    // pyramid level finer than where there is no caustic (four times finer in this run).
    let bright = 0.1 * irradiance.iter().copied().fold(0.0f32, f32::max);
    let lit: Vec<f32> = irradiance
        .iter()
        .zip(&reach)
        .filter(|(&e, _)| e >= bright)
        .map(|(_, &r)| r)
        .collect();
    let dark: Vec<f32> = irradiance
        .iter()
        .zip(&reach)
        .filter(|(&e, &r)| e == 0.0 && r > 0.0)
        .map(|(_, &r)| r)
        .collect();
    assert!(
        lit.len() > 20 && dark.len() > 20,
        "{} lit, {} dark texels",
        lit.len(),
        dark.len()
    );
    let (lit, dark) = (median(lit), median(dark));
    assert!(
        lit <= 0.5 * dark,
        "kernels chosen in the bright caustic reach {lit} m, where there is none {dark} m"
    );
    let plane = report["grids"]["choice"][1].as_str().unwrap();
    assert!(
        plane.contains("caustic layer") && plane.contains("kernels chosen there reach") && plane.contains("cells of"),
        "{plane}"
    );
}

#[test]
fn help_is_grouped_and_free_of_doc_syntax() {
    for args in [
        vec!["--help"],
        vec!["render", "--help"],
        vec!["render", "-h"],
        vec!["info", "--help"],
        vec!["batch", "--help"],
        vec!["compare", "--help"],
        vec!["bench", "--help"],
        vec!["settings", "--help"],
    ] {
        let o = run(&args);
        ok(&o);
        let h = stdout(&o);
        assert!(!h.contains('`') && !h.contains("[`"), "{args:?} leaks doc syntax:\n{h}");
        assert!(!h.contains("](") && !h.contains("\\["), "{args:?}:\n{h}");
    }
    let o = run(&["render", "--help"]);
    let h = stdout(&o);
    // Every option sits under a heading; "Options:" keeps only the generic ones.
    let mut heading = "";
    let mut headings = Vec::new();
    for line in h.lines() {
        if !line.starts_with(' ') && line.ends_with(':') {
            heading = line.trim_end_matches(':');
            headings.push(heading.to_string());
        } else if line.trim_start().starts_with('-') && line.starts_with("  ") && heading == "Options" {
            assert!(
                ["-v, --verbose", "-h, --help"]
                    .iter()
                    .any(|o| line.trim_start().starts_with(o)),
                "ungrouped option: {line}"
            );
        }
    }
    for want in [
        "Input and output",
        "Run",
        "Photons",
        "Image",
        "Estimate",
        "Grids",
        "Light paths",
        "Passes and time",
    ] {
        assert!(headings.iter().any(|h| h == want), "no heading {want}: {headings:?}");
    }
    for sub in ["batch", "bench"] {
        let h = stdout(&run(&[sub, "--help"]));
        let options = h.split("\nOptions:\n").nth(1).unwrap_or("");
        let options = options.split("\n\n").next().unwrap_or("");
        assert!(
            options.lines().filter(|l| l.trim_start().starts_with('-')).count() <= 2,
            "{sub}: ungrouped options:\n{h}"
        );
    }
}

#[test]
fn sigint_stops_after_the_pass_and_keeps_it() {
    let dir = TempDir::new("sigint");
    let scene = scene(&dir);
    let out = dir.join("out.exr");
    let stats = dir.join("stats.json");
    let mut child = Command::new(BIN)
        .args(render_args(
            &scene,
            &out,
            &[
                "--passes",
                "100000",
                "--checkpoint",
                "0",
                "--progress",
                "json",
                "--stats",
                s(&stats),
            ],
        ))
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let mut events = Vec::new();
    let mut signalled = false;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        let v: Value = serde_json::from_str(&line.unwrap()).expect("JSON only");
        if v["event"] == "checkpoint" && !signalled {
            let kill = Command::new("kill")
                .args(["-INT", &child.id().to_string()])
                .status()
                .unwrap();
            assert!(kill.success());
            signalled = true;
        }
        events.push(v);
    }
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(0), "{events:?}");
    let output = events
        .iter()
        .find(|e| e["event"] == "output")
        .expect("the image so far is written");
    let n = output["passes"].as_u64().unwrap();
    assert!((1..100_000).contains(&n), "{n}");
    assert!(events.iter().any(|e| e["event"] == "stopping"));
    let st: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!(st["passes"]["stopped_by"], "requested");
    assert_eq!(st["passes"]["count"].as_u64(), Some(n));
    let img = photongrid_cli::metrics::read_exr_rgb(&out).unwrap();
    assert_eq!((img.width, img.height), (32, 24));
    assert!(img.data.iter().any(|c| c[0] > 0.0));
}

#[test]
fn exr_has_alpha_and_blender_named_passes() {
    let dir = TempDir::new("passes");
    let scene = scene(&dir);
    let side = dir.join("side.exr");
    ok(&run(&render_args(
        &scene,
        &side,
        &["--camera", "Side", "--aovs", "--progress", "quiet"],
    )));
    let ch = exr_channels(&side);
    let mut names: Vec<&String> = ch.keys().collect();
    names.sort();
    assert_eq!(
        names,
        [
            "A",
            "B",
            "Depth.Z",
            "DiffCol.B",
            "DiffCol.G",
            "DiffCol.R",
            "G",
            "Normal.X",
            "Normal.Y",
            "Normal.Z",
            "PhotonDensity.X",
            "PhotonRadius.X",
            "R"
        ]
    );
    let (a, z) = (&ch["A"], &ch["Depth.Z"]);
    let sky = a.iter().filter(|&&v| v == 0.0).count();
    assert!(
        sky > 50 && a.iter().all(|&v| v == 0.0 || v == 1.0),
        "the side camera sees the sky"
    );
    for (a, z) in a.iter().zip(z) {
        if *a == 0.0 {
            assert_eq!(*z, 1e10, "background depth as Blender's");
        } else {
            assert!(*z > 0.0 && *z < 100.0);
        }
    }
    // Depth along the camera's axis (Blender's Z pass): the floor seen straight down from 5 m
    // is 5 m deep at every pixel, not farther at the corners.
    let top = dir.join("top.exr");
    ok(&run(&render_args(
        &scene,
        &top,
        &["--camera", "Camera", "--aovs", "--progress", "quiet"],
    )));
    let ch = exr_channels(&top);
    let floor: Vec<f32> = ch["Depth.Z"]
        .iter()
        .zip(&ch["Normal.Y"])
        .filter(|(_, n)| **n > 0.999)
        .map(|(z, _)| *z)
        .collect();
    assert!(floor.len() > 300 && floor.iter().filter(|z| (**z - 5.0).abs() < 1e-3).count() > 300);
    assert!(ch["A"].iter().all(|&v| v == 1.0), "the floor fills the top view");
}

#[test]
fn irradiance_shows_a_spinner_on_a_terminal() {
    // Bars are drawn only on a terminal: `script` (util-linux) gives the render one.
    let dir = TempDir::new("tty");
    let out = dir.join("out.exr");
    let quote = |a: &str| format!("'{}'", a.replace('\'', "'\\''"));
    let mut cmd = vec![quote(BIN)];
    for a in render_args(&sample("cornell_glass.glb"), &out, &["--photons", "20000"]) {
        cmd.push(quote(a));
    }
    let o = Command::new("script")
        .args(["-qec", &cmd.join(" "), "/dev/null"])
        .stdin(Stdio::null())
        .output()
        .expect("`script` (util-linux) runs the render on a pseudo-terminal");
    ok(&o);
    let screen = String::from_utf8_lossy(&o.stdout);
    // The irradiance phase reports no progress of its own: a spinner and its elapsed time,
    // where there used to be nothing.
    let spinner = screen
        .split(['\r', '\n'])
        .any(|l| l.contains("irradiance ") && l.contains("00:00:") && !l.contains('%'));
    assert!(spinner, "no irradiance spinner in:\n{screen}");
    assert!(out.is_file());
}

#[test]
fn a_reader_that_stops_early_ends_the_command_quietly() {
    // `photongrid info … | head -1`: the pipe closes before the output is written. The
    // command must end with success and no panic message, as other command-line tools do.
    let samples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../samples");
    let scenes: Vec<PathBuf> = ["cornell_glass.glb", "ring_caustic.glb", "curved_3d.glb"]
        .iter()
        .map(|f| samples.join(f))
        .collect();
    let mut child = Command::new(BIN)
        .arg("info")
        .args(&scenes)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "status {:?}: {err}", out.status);
    assert!(!err.contains("panicked"), "{err}");
}
