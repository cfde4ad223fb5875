//! The real binary on broken files and bad options: a non-zero exit, no panic, and a message
//! naming the file and the element (or the option). Also the help texts and one real render.

use photongrid_testkit::*;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// The photongrid binary with `args` ([`run_binary`]).
fn run(dir: &TempDir, args: &[&str]) -> Run {
    run_binary(Path::new(env!("CARGO_BIN_EXE_photongrid")), dir, args)
}

/// `render <scene> -o <dir>/out.exr` at tiny settings, plus `extra`.
fn render(dir: &TempDir, scene: &Path, extra: &[&str]) -> Run {
    let out = dir.join("out.exr");
    let mut args = vec!["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap()];
    for (option, value) in [
        ("--width", "16"),
        ("--height", "12"),
        ("--photons", "1000"),
        ("--spp", "1"),
    ] {
        if !extra.contains(&option) {
            args.extend_from_slice(&[option, value]);
        }
    }
    args.extend_from_slice(extra);
    run(dir, &args)
}

/// The run failed cleanly and stderr contains every one of `needles`.
#[track_caller]
fn assert_fails_with(r: &Run, needles: &[&str]) {
    eprintln!("exit {:?}, stderr: {}", r.code, r.stderr.trim_end());
    assert!(
        !r.ok(),
        "expected a failure, got exit {:?}; stderr:\n{}",
        r.code,
        r.stderr
    );
    assert!(r.code.is_some(), "killed by a signal; stderr:\n{}", r.stderr);
    assert!(!r.stderr.contains("panicked"), "panicked:\n{}", r.stderr);
    for n in needles {
        assert!(r.stderr.contains(n), "stderr lacks {n:?}:\n{}", r.stderr);
    }
}

fn write_json(dir: &TempDir, name: &str, doc: &Value) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, serde_json::to_string_pretty(doc).unwrap()).unwrap();
    p
}

#[test]
fn truncated_glb() {
    let dir = TempDir::new("case-a");
    let bytes = std::fs::read(sample("cornell_glass.glb")).unwrap();
    let p = dir.join("half.glb");
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["half.glb", "truncated"]);
    let r = run(&dir, &["info", p.to_str().unwrap()]);
    assert_fails_with(&r, &["half.glb", "truncated"]);
    // Cut inside the 12-byte header.
    std::fs::write(&p, &bytes[..7]).unwrap();
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["half.glb", "GLB header", "truncated"]);
}

#[test]
fn invalid_json() {
    let dir = TempDir::new("badjson");
    let p = dir.join("bad.gltf");
    std::fs::write(&p, "{ \"asset\": { \"version\": \"2.0\" }, \"nodes\": [ }").unwrap();
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["bad.gltf", "not a valid glTF", "line 1"]);
}

#[test]
fn dangling_mesh_index() {
    let dir = TempDir::new("dangling");
    let mut doc = simple_scene(100.0).json(&BufferMode::Embedded);
    doc["nodes"][0]["mesh"] = json!(99);
    let p = write_json(&dir, "dangling.gltf", &doc);
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["dangling.gltf", "nodes[0].mesh"]);
}

#[test]
fn index_out_of_range() {
    let dir = TempDir::new("index");
    let mut g = Gltf::new();
    // 900 vertices on a 30 × 30 grid, one index 912 among valid ones.
    let positions: Vec<[f32; 3]> = (0..900)
        .map(|i| [(i % 30) as f32 * 0.1, 0.0, (i / 30) as f32 * 0.1])
        .collect();
    let idx: Vec<u32> = vec![0, 30, 1, 1, 30, 31, 2, 32, 912];
    let mesh = g.mesh(vec![Prim::new(positions).indices_u32(idx)]);
    assert_eq!(mesh, 0);
    g.root(Node {
        mesh: Some(mesh),
        ..Default::default()
    });
    let l = g.light(Light::point(100.0));
    g.root(Node {
        transform: Transform::translation([0.0, 2.0, 0.0]),
        light: Some(l),
        ..Default::default()
    });
    let p = g.write_glb(dir.path(), "index.glb");
    let r = render(&dir, &p, &[]);
    assert_fails_with(
        &r,
        &["index.glb", "meshes[0].primitives[0]: index 912", ">= vertex count 900"],
    );
}

#[test]
fn non_finite_positions() {
    for (tag, bad) in [("nan", f32::NAN), ("inf", f32::INFINITY)] {
        let dir = TempDir::new(tag);
        let mut g = simple_scene(100.0);
        let mesh = g.mesh(vec![Prim::new(vec![
            [0.0, 1.0, 0.0],
            [1.0, bad, 0.0],
            [0.0, 1.0, -1.0],
        ])]);
        g.root(Node {
            mesh: Some(mesh),
            ..Default::default()
        });
        let p = g.write_gltf(dir.path(), &format!("{tag}.gltf"));
        let r = render(&dir, &p, &[]);
        let element = format!("meshes[{mesh}].primitives[0]");
        assert_fails_with(&r, &[&format!("{tag}.gltf"), &element, "POSITION[1]", "not finite"]);
    }
}

#[test]
fn degenerate_triangles_are_skipped_and_reported() {
    let dir = TempDir::new("case-b");
    let mut g = simple_scene(100.0);
    // One good triangle, two of zero area (repeated vertex, collinear).
    let mesh = g.mesh(vec![Prim::new(vec![
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, -1.0],
        [0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [2.0, 1.0, 0.0],
    ])]);
    g.root(Node {
        mesh: Some(mesh),
        ..Default::default()
    });
    let p = g.write_glb(dir.path(), "za.glb");
    let r = render(&dir, &p, &[]);
    assert!(r.ok(), "degenerate triangles must not be an error:\n{}", r.stderr);
    assert!(r.stderr.contains("degenerate"), "not reported:\n{}", r.stderr);
    assert!(
        r.stderr.contains(&format!("meshes[{mesh}].primitives[0]")),
        "{}",
        r.stderr
    );
    assert!(dir.join("out.exr").is_file());

    let scene = photongrid::load(&p).unwrap();
    assert_eq!(scene.report.degenerate_triangles, 2);
    assert_eq!(scene.triangles.len(), 3);

    // All degenerate: nothing to render.
    let mut g = Gltf::new();
    let m = g.mesh(vec![Prim::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])]);
    g.root(Node {
        mesh: Some(m),
        ..Default::default()
    });
    let l = g.light(Light::point(100.0));
    g.root(Node {
        light: Some(l),
        ..Default::default()
    });
    let p = g.write_glb(dir.path(), "flat.glb");
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["flat.glb", "no triangles", "degenerate"]);
}

#[test]
fn missing_external_buffer() {
    let dir = TempDir::new("nobin");
    let p = simple_scene(100.0).write_gltf_external(dir.path(), "ext.gltf", "ext.bin", false);
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["ext.gltf", "buffers[0]", "ext.bin", "not found"]);
}

#[test]
fn missing_image() {
    let dir = TempDir::new("noimage");
    let mut doc = simple_scene(100.0).json(&BufferMode::Embedded);
    doc["images"] = json!([{ "uri": "wood.png" }]);
    doc["textures"] = json!([{ "source": 0 }]);
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = json!({ "index": 0 });
    let p = write_json(&dir, "tex.gltf", &doc);
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["tex.gltf", "images[0]", "wood.png", "not found"]);
}

#[test]
fn no_lights() {
    let dir = TempDir::new("nolights");
    let mut doc = simple_scene(100.0).json(&BufferMode::Embedded);
    // Drop the lamp node from the scene and the extension.
    doc["scenes"][0]["nodes"] = json!([0, 2]);
    doc["nodes"][1] = json!({ "name": "Empty" });
    doc.as_object_mut().unwrap().remove("extensions");
    doc.as_object_mut().unwrap().remove("extensionsUsed");
    doc.as_object_mut().unwrap().remove("extensionsRequired");
    let p = write_json(&dir, "dark.gltf", &doc);
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["dark.gltf", "no lights", "Punctual Lights", "emission strength"]);
}

#[test]
fn no_camera() {
    let dir = TempDir::new("nocamera");
    let mut doc = simple_scene(100.0).json(&BufferMode::Embedded);
    doc["scenes"][0]["nodes"] = json!([0, 1]);
    doc["nodes"][2] = json!({ "name": "NotACamera" });
    doc.as_object_mut().unwrap().remove("cameras");
    let p = write_json(&dir, "blind.gltf", &doc);
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["blind.gltf", "no camera", "Include > Cameras"]);
}

#[test]
fn unknown_camera_lists_the_available_ones() {
    let dir = TempDir::new("camname");
    let p = simple_scene(100.0).write_glb(dir.path(), "cams.glb");
    let r = render(&dir, &p, &["--camera", "Nope"]);
    assert_fails_with(&r, &["cams.glb", "no camera 'Nope'", "available", "0 (Camera)"]);
    let r = render(&dir, &p, &["--camera", "7"]);
    assert_fails_with(&r, &["no camera '7'", "0 (Camera)"]);
}

#[test]
fn absurd_photon_count_is_refused_quickly() {
    let dir = TempDir::new("photons");
    let p = simple_scene(100.0).write_glb(dir.path(), "s.glb");
    let r = render(&dir, &p, &["--photons", "100000000000"]);
    assert_fails_with(&r, &["100000000000 photons", "GiB", "--photons"]);
    assert!(r.seconds < 10.0, "took {} s", r.seconds);
    assert!(!dir.join("out.exr").exists());
}

#[test]
fn output_folder_in_an_unwritable_place_is_refused() {
    // A missing folder is created (issue 11); one that cannot be created is an error naming it.
    let dir = TempDir::new("outdir");
    let p = simple_scene(100.0).write_glb(dir.path(), "s.glb");
    std::fs::write(dir.join("file"), b"not a folder").unwrap();
    let out = dir.join("file/sub/out.exr");
    let r = run(
        &dir,
        &[
            "render",
            p.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--photons",
            "1000",
            "--width",
            "8",
            "--height",
            "6",
        ],
    );
    assert_fails_with(&r, &["file/sub/out.exr", "cannot create the folder"]);
}

#[test]
fn uri_leaving_the_scene_folder() {
    let dir = TempDir::new("escape");
    let g = simple_scene(100.0);
    std::fs::create_dir_all(dir.join("scene")).unwrap();
    // The buffer exists, but one folder up.
    std::fs::write(dir.join("outside.bin"), g.bin()).unwrap();
    let doc = g.json(&BufferMode::External("../outside.bin".into()));
    let p = write_json(&dir, "scene/escape.gltf", &doc);
    let r = render(&dir, &p, &[]);
    assert_fails_with(
        &r,
        &[
            "escape.gltf",
            "buffers[0]",
            "../outside.bin",
            "leaves the scene's folder",
        ],
    );
    // Also when percent-encoded.
    let doc = g.json(&BufferMode::External("%2E%2E/outside.bin".into()));
    let p = write_json(&dir, "scene/escape2.gltf", &doc);
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["escape2.gltf", "buffers[0]", "leaves the scene's folder"]);
    // A percent sign before a multi-byte character is not an escape (and must not panic).
    let doc = g.json(&BufferMode::External("%€/../../outside.bin".into()));
    let p = write_json(&dir, "scene/escape3.gltf", &doc);
    let r = render(&dir, &p, &[]);
    assert_fails_with(&r, &["escape3.gltf", "buffers[0]", "leaves the scene's folder"]);
    // With the opt-in it loads.
    let r = render(&dir, &dir.join("scene/escape.gltf"), &["--allow-external-uris"]);
    assert!(r.ok(), "{}", r.stderr);
}

#[test]
fn zero_neighbours_and_zero_spp() {
    let dir = TempDir::new("zeros");
    let p = simple_scene(100.0).write_glb(dir.path(), "s.glb");
    let r = render(&dir, &p, &["--neighbours", "0"]);
    assert_fails_with(&r, &["--neighbours must be at least 1"]);
    let r = render(&dir, &p, &["--spp", "0"]);
    assert_fails_with(&r, &["--spp must be at least 1"]);
}

#[test]
fn empty_file() {
    let dir = TempDir::new("case-c");
    for name in ["zero.glb", "zero.gltf"] {
        let p = dir.join(name);
        std::fs::write(&p, b"").unwrap();
        let r = render(&dir, &p, &[]);
        assert_fails_with(&r, &[name, "empty"]);
    }
}

#[test]
fn directory_as_scene() {
    let dir = TempDir::new("dirscene");
    std::fs::create_dir_all(dir.join("scene.glb")).unwrap();
    let r = render(&dir, &dir.join("scene.glb"), &[]);
    assert_fails_with(&r, &["scene.glb", "folder"]);
}

#[test]
fn missing_scene_file() {
    let dir = TempDir::new("missing");
    let r = render(&dir, &dir.join("nothere.glb"), &[]);
    assert_fails_with(&r, &["nothere.glb", "cannot read"]);
}

#[test]
fn help_mentions_every_option() {
    let dir = TempDir::new("help");
    let r = run(&dir, &["render", "--help"]);
    assert!(r.ok(), "{}", r.stderr);
    for opt in [
        "--camera",
        "--output",
        "--photons",
        "--neighbours",
        "--spp",
        "--seed",
        "--threads",
        "--width",
        "--height",
        "--direct",
        "--light-samples",
        "--max-photon-depth",
        "--max-specular-depth",
        "--max-radius",
        "--aovs",
        "--png",
        "--exposure",
        "--stats",
        "--progress",
        "--allow-external-uris",
        "--verbose",
        "--help",
        "shadow-rays",
        "photons",
    ] {
        assert!(r.stdout.contains(opt), "render --help lacks {opt}:\n{}", r.stdout);
    }
    let r = run(&dir, &["--help"]);
    assert!(r.ok(), "{}", r.stderr);
    for word in ["render", "info", "compare", "--verbose", "--help", "--version"] {
        assert!(r.stdout.contains(word), "--help lacks {word}:\n{}", r.stdout);
    }
    for sub in ["info", "compare"] {
        let r = run(&dir, &[sub, "--help"]);
        assert!(r.ok() && r.stdout.contains("--json"), "{sub} --help:\n{}", r.stdout);
    }
}

#[test]
fn readme_render_of_cornell_glass() {
    let dir = TempDir::new("readme");
    let out = dir.join("cornell.exr");
    let stats = dir.join("stats.json");
    let scene = sample("cornell_glass.glb");
    let r = run(
        &dir,
        &[
            "render",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--width",
            "64",
            "--height",
            "48",
            "--photons",
            "20000",
            "--spp",
            "1",
            "--stats",
            stats.to_str().unwrap(),
        ],
    );
    assert!(r.ok(), "exit {:?}:\n{}", r.code, r.stderr);
    assert!(!r.stderr.contains("panicked"));
    let img = photongrid_cli::metrics::read_exr_rgb(&out).unwrap();
    assert_eq!((img.width, img.height), (64, 48));
    assert_eq!(img.data.len(), 64 * 48);
    assert!(
        img.data.iter().all(|p| p.iter().all(|v| v.is_finite())),
        "non-finite pixels"
    );
    let mean_lum: f64 = img
        .data
        .iter()
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .sum::<f64>()
        / img.data.len() as f64;
    assert!(mean_lum > 0.0, "black image");
    let s: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    for key in ["load", "bvh", "photons", "build", "render", "write", "total"] {
        let v = &s["seconds"][key];
        assert!(v.as_f64().is_some_and(|x| x >= 0.0), "stats.seconds.{key} = {v}");
    }
    assert_eq!(s["settings"]["photons"], json!(20000));
    assert_eq!(s["cameras"][0]["width"], json!(64));
    assert_eq!(s["photons"]["emitted"], json!(20000));
    // A point light: no emitter outline in view.
    assert_eq!(s["cameras"][0]["emitter_edge_pixels"], json!(0));
}

#[test]
fn stats_count_the_pixels_at_an_emitter_outline() {
    let dir = TempDir::new("emitter-edges");
    let (out, stats) = (dir.join("area.exr"), dir.join("stats.json"));
    let scene = sample("cornell_area.glb");
    let args = ["--width", "64", "--height", "48", "--photons", "20000", "--spp", "1"];
    let mut all = vec!["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap()];
    all.extend(args);
    all.extend(["--stats", stats.to_str().unwrap()]);
    let r = run(&dir, &all);
    assert!(r.ok(), "exit {:?}:\n{}", r.code, r.stderr);
    let s: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    // The ceiling's emissive quad seen from below: its outline, a few pixels wide.
    let n = s["cameras"][0]["emitter_edge_pixels"].as_u64().unwrap();
    assert!((8..400).contains(&n), "{n} pixels");
}
