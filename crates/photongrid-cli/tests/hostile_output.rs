//! The output side of issue 12, with the real binary: outputs never replace an input, each
//! other or a special file; temporary files are created exclusively and stale ones removed;
//! batch substitutions cannot leave the output folder; renders that cannot fit in memory are
//! refused up front with what to change.

use photongrid_testkit::*;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// The photongrid binary with `args` ([`run_binary`]).
fn run(dir: &TempDir, args: &[&str]) -> Run {
    run_binary(Path::new(env!("CARGO_BIN_EXE_photongrid")), dir, args)
}

/// `render <scene>` at tiny settings plus `extra` (which must give the outputs).
fn render(dir: &TempDir, scene: &Path, extra: &[&str]) -> Run {
    let mut args = vec!["render", scene.to_str().unwrap()];
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

#[track_caller]
fn assert_fails_with(r: &Run, needles: &[&str]) {
    eprintln!("exit {:?}, stderr: {}", r.code, r.stderr.trim_end());
    assert!(
        r.code.is_some() && r.code != Some(0),
        "expected a clean failure, got {:?}",
        r.code
    );
    assert!(!r.stderr.contains("panicked"), "panicked:\n{}", r.stderr);
    for n in needles {
        assert!(r.stderr.contains(n), "stderr lacks {n:?}:\n{}", r.stderr);
    }
}

#[track_caller]
fn assert_ok(r: &Run) {
    assert_eq!(r.code, Some(0), "stderr:\n{}", r.stderr);
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The base scene as `scene.glb` in a fresh folder, and its bytes.
fn scene(tag: &str) -> (TempDir, PathBuf, Vec<u8>) {
    let dir = TempDir::new(tag);
    let p = hostile_base().write_glb(dir.path(), "scene.glb");
    let bytes = std::fs::read(&p).unwrap();
    (dir, p, bytes)
}

/// `.tmp` files left in `dir`.
fn temps(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

#[test]
fn an_output_that_is_the_scene_is_refused_however_spelt() {
    let (dir, p, bytes) = scene("out-is-scene");
    let dotted = dir.path().join(".").join("scene.glb");
    let link = dir.join("link.glb");
    std::os::unix::fs::symlink(&p, &link).unwrap();
    let cwd_relative = format!(
        "{}/../{}/scene.glb",
        s(dir.path()),
        dir.path().file_name().unwrap().to_str().unwrap()
    );
    for (flag, out) in [
        ("-o", s(&p)),
        ("-o", s(&dotted)),
        ("-o", cwd_relative.as_str()),
        ("--png", s(&p)),
        ("--stats", s(&p)),
    ] {
        let other = dir.join("x.exr");
        let mut extra = vec![flag, out];
        if flag != "-o" {
            extra.extend_from_slice(&["-o", s(&other)]);
        }
        assert_fails_with(&render(&dir, &p, &extra), &["is the scene", "choose another file name"]);
        assert_eq!(std::fs::read(&p).unwrap(), bytes, "{flag} {out} changed the scene");
    }
    // The scene read through a link, written by its real name.
    assert_fails_with(&render(&dir, &link, &["-o", s(&p)]), &["is the scene"]);
    assert_eq!(std::fs::read(&p).unwrap(), bytes);
    assert!(temps(dir.path()).is_empty(), "{:?}", temps(dir.path()));
}

#[test]
fn outputs_that_are_the_same_file_are_refused() {
    let (dir, p, _) = scene("out-same");
    let out = dir.join("out.exr");
    std::fs::write(&out, b"old").unwrap();
    for extra in [
        vec!["-o", s(&out), "--png", s(&out)],
        vec!["-o", s(&out), "--stats", s(&out)],
    ] {
        assert_fails_with(&render(&dir, &p, &extra), &["is the same file as --output"]);
        assert_eq!(std::fs::read(&out).unwrap(), b"old");
    }
    // One camera twice.
    assert_fails_with(
        &render(&dir, &p, &["-o", s(&out), "--camera", "0", "--camera", "0"]),
        &["selected twice"],
    );
    assert_eq!(std::fs::read(&out).unwrap(), b"old");
}

#[test]
fn cameras_whose_names_sanitise_alike_are_refused() {
    let dir = TempDir::new("out-cams");
    let mut g = hostile_base();
    for name in ["a b", "a_b"] {
        let c = g.camera(Camera::Perspective {
            yfov: 0.7,
            aspect: Some(4.0 / 3.0),
        });
        g.root(Node {
            name: Some(name.into()),
            transform: Transform::translation([0.0, 1.5, 5.0]),
            camera: Some(c),
            ..Default::default()
        });
    }
    let p = g.write_glb(dir.path(), "scene.glb");
    let out = dir.join("out_{camera}.exr");
    let r = render(&dir, &p, &["-o", s(&out), "--camera", "a b", "--camera", "a_b"]);
    assert_fails_with(&r, &["'a_b'", "is the same file as --output of camera", "'a b'"]);
    assert!(!dir.join("out_a_b.exr").exists());
}

#[test]
fn special_files_are_not_replaced() {
    let (dir, p, _) = scene("out-special");
    let folder = dir.join("folder.exr");
    std::fs::create_dir(&folder).unwrap();
    assert_fails_with(&render(&dir, &p, &["-o", s(&folder)]), &["folder.exr", "a folder"]);
    let fifo = dir.join("fifo.exr");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let out = dir.join("out.exr");
    for extra in [
        vec!["-o", s(&fifo)],
        vec!["-o", s(&out), "--png", s(&fifo)],
        vec!["-o", s(&out), "--stats", s(&fifo)],
    ] {
        assert_fails_with(&render(&dir, &p, &extra), &["fifo.exr", "FIFO", "not a regular file"]);
    }
    use std::os::unix::fs::FileTypeExt;
    assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
    assert!(!out.exists(), "nothing is written when an output is refused");
    let null = Path::new("/dev/null");
    assert_fails_with(&render(&dir, &p, &["-o", s(&out), "--stats", s(null)]), &["a device"]);
}

#[test]
fn temporary_files_are_exclusive_and_stale_ones_removed() {
    let (dir, p, _) = scene("out-temps");
    let out = dir.join("out.exr");
    // Stale temporary files of killed writes (the old name pattern `.<name>.<pid>.tmp`):
    // one older than an hour is removed, a recent one (maybe a live writer's) is kept.
    let stale = dir.join(".out.exr.4000001.tmp");
    std::fs::write(&stale, b"partial").unwrap();
    let old = std::time::SystemTime::now() - Duration::from_secs(2 * 3600);
    std::fs::File::options()
        .write(true)
        .open(&stale)
        .unwrap()
        .set_modified(old)
        .unwrap();
    let fresh = dir.join(".out.exr.4000002.tmp");
    std::fs::write(&fresh, b"live").unwrap();
    // A planted link at a temporary name: never followed, never removed.
    let victim = dir.join("victim.txt");
    std::fs::write(&victim, b"precious").unwrap();
    let planted = dir.join(".out.exr.4000003.tmp");
    std::os::unix::fs::symlink(&victim, &planted).unwrap();
    let old_link = std::fs::File::options().write(true).open(&victim).unwrap();
    drop(old_link);

    assert_ok(&render(&dir, &p, &["-o", s(&out), "--png", s(&dir.join("out.png"))]));
    assert!(out.is_file() && dir.join("out.png").is_file());
    assert!(!stale.exists(), "a stale temporary file was left");
    assert!(fresh.exists(), "a recent temporary file was removed");
    assert!(std::fs::symlink_metadata(&planted).unwrap().file_type().is_symlink());
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    let mut left = temps(dir.path());
    left.sort();
    assert_eq!(left, [".out.exr.4000002.tmp", ".out.exr.4000003.tmp"]);

    // An existing output is replaced whole (a new inode, by rename), and a link at the output
    // is replaced rather than written through.
    let link_out = dir.join("linked.exr");
    std::os::unix::fs::symlink(&victim, &link_out).unwrap();
    assert_ok(&render(&dir, &p, &["-o", s(&link_out)]));
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    assert!(std::fs::symlink_metadata(&link_out).unwrap().is_file());
}

#[test]
fn renders_over_the_memory_limit_are_refused_with_what_to_change() {
    let (dir, p, _) = scene("out-memory");
    let out = dir.join("out.exr");
    let r = render(
        &dir,
        &p,
        &[
            "-o",
            s(&out),
            "--width",
            "8000",
            "--height",
            "6000",
            "--memory-limit",
            "1G",
        ],
    );
    assert_fails_with(
        &r,
        &[
            "images of 1 camera at 8000×6000",
            "memory limit of 1.0 GiB",
            "lower the resolution (--width, --height)",
            "--memory-limit",
        ],
    );
    // SPPM keeps every camera sample: the estimate says so and names --spp.
    let r = render(
        &dir,
        &p,
        &[
            "-o",
            s(&out),
            "--method",
            "sppm",
            "--spp",
            "50000",
            "--width",
            "160",
            "--height",
            "120",
            "--memory-limit",
            "4G",
        ],
    );
    assert_fails_with(&r, &["SPPM state", "lower --spp"]);
    // --spp 4294967295 (the 17 GB when strata were stored) is more than one pass may take.
    let r = render(
        &dir,
        &p,
        &["-o", s(&out), "--spp", "4294967295", "--memory-limit", "8G"],
    );
    assert_fails_with(&r, &["--spp 4294967295", "samples per pixel in one pass", "add passes"]);
    let r = render(&dir, &p, &["-o", s(&out), "--gather", "4294967295"]);
    assert_fails_with(
        &r,
        &["--gather 4294967295", "final-gather rays per camera sample", "spp"],
    );
    let r = render(&dir, &p, &["-o", s(&out), "--memory-limit", "lots"]);
    assert_fails_with(&r, &["--memory-limit", "not a size"]);
    assert!(!out.exists());
    // The same render within the limit goes through.
    assert_ok(&render(&dir, &p, &["-o", s(&out), "--memory-limit", "1G"]));
    assert!(out.is_file());
}

/// A jobs file in `dir` over `scene` with outputs `outputs` (one job each).
fn jobs_file(dir: &Path, scene: &Path, outputs: &[&str]) -> PathBuf {
    let mut t = String::from("[defaults]\nwidth = 16\nheight = 12\nphotons = 1000\nspp = 1\n");
    for o in outputs {
        t += &format!("[[job]]\nscene = \"{}\"\noutput = \"{o}\"\n", s(scene));
    }
    let p = dir.join("jobs.toml");
    std::fs::write(&p, t).unwrap();
    p
}

fn list(dir: &TempDir, jobs: &Path) -> Vec<Value> {
    let r = run(dir, &["batch", s(jobs), "--list"]);
    assert_ok(&r);
    r.stdout.lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

#[test]
fn batch_substitutions_stay_in_the_output_folder() {
    let dir = TempDir::new("batch-dots");
    // A scene named `...glb` has the stem `..`: `out/{scene}.exr` must stay in `out/`.
    let p = hostile_base().write_glb(dir.path(), "...glb");
    std::fs::create_dir(dir.join("out")).unwrap();
    let jobs = jobs_file(dir.path(), &p, &["out/{scene}/x.exr", "out/{scene}.exr"]);
    let units = list(&dir, &jobs);
    assert_eq!(units.len(), 2, "{units:?}");
    for u in &units {
        let o = PathBuf::from(u["output"].as_str().expect("an output"));
        assert!(o.starts_with(dir.join("out")), "{}", o.display());
        assert!(
            !o.components().any(|c| c == std::path::Component::ParentDir),
            "{}",
            o.display()
        );
    }
}

#[test]
fn batch_outputs_that_clash_or_replace_inputs_fail_their_unit() {
    let (dir, p, bytes) = scene("batch-clash");
    std::fs::create_dir(dir.join("out")).unwrap();
    let jobs = jobs_file(
        dir.path(),
        &p,
        &[
            "out/a.exr",
            "./out/../out/a.exr",  // the same file spelt otherwise
            "scene.glb",           // the scene (refused: not an .exr name)
            "jobs.toml",           // the jobs file (likewise)
            "out/b.exr.done.json", // a sidecar's name (likewise)
            "out/b.exr",
        ],
    );
    let jobs_text = std::fs::read(&jobs).unwrap();
    let report = dir.join("report.json");
    let r = run(&dir, &["batch", s(&jobs), "--report", s(&report)]);
    assert!(r.code != Some(0) && r.code.is_some(), "{}", r.stderr);
    assert!(!r.stderr.contains("panicked"), "{}", r.stderr);
    let v: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let units = v["units"].as_array().unwrap();
    let status: Vec<&str> = units.iter().map(|u| u["status"].as_str().unwrap()).collect();
    assert_eq!(status, ["done", "failed", "failed", "failed", "failed", "done"], "{v}");
    let error = |i: usize| units[i]["error"].as_str().unwrap_or_default().to_string();
    assert!(error(1).contains("also the output of unit 0"), "{}", error(1));
    // An output must be named .exr, so the scene, the jobs file and a sidecar are refused by
    // name before anything compares files (the identity checks are tested with --stats and
    // in output.rs).
    for i in 2..5 {
        assert!(error(i).contains("use a name ending in .exr"), "{}", error(i));
    }
    assert_eq!(std::fs::read(&p).unwrap(), bytes);
    assert_eq!(std::fs::read(&jobs).unwrap(), jobs_text);
    // The report may not be the jobs file either.
    let r = run(&dir, &["batch", s(&jobs), "--report", s(&jobs)]);
    assert!(r.code != Some(0) && r.stderr.contains("the jobs file"), "{}", r.stderr);
    assert_eq!(std::fs::read(&jobs).unwrap(), jobs_text);
}

#[test]
fn batch_cameras_that_do_not_fit_together_render_in_turns() {
    let dir = TempDir::new("batch-chunks");
    let mut g = hostile_base();
    let c = g.camera(Camera::Perspective {
        yfov: 0.7,
        aspect: Some(4.0 / 3.0),
    });
    g.root(Node {
        name: Some("Cam2".into()),
        transform: Transform::translation([0.5, 1.5, 5.0]),
        camera: Some(c),
        ..Default::default()
    });
    let p = g.write_glb(dir.path(), "scene.glb");
    // 400×300: one camera's images take about 20 MB, both together about 32 MB.
    let jobs = dir.join("jobs.toml");
    let text = format!(
        "[defaults]\nwidth = 400\nheight = 300\nphotons = 1000\nspp = 1\nmemory_limit = \"26M\"\n\
         [[job]]\nscene = \"{}\"\noutput = \"out/{{camera}}.exr\"\n",
        s(&p)
    );
    std::fs::write(&jobs, text).unwrap();
    let report = dir.join("report.json");
    let r = run(&dir, &["batch", s(&jobs), "--report", s(&report)]);
    assert_ok(&r);
    let v: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let units = v["units"].as_array().unwrap();
    assert_eq!(units.len(), 2, "{v}");
    for u in units {
        assert_eq!(u["status"], "done", "{u}");
        // Each camera rendered on its own (its own photons), not refused.
        assert_eq!(u["stats"]["photon_map_shared_by"], 1, "{u}");
    }
    assert!(dir.join("out/Camera.exr").is_file() && dir.join("out/Cam2.exr").is_file());
    // With room for both, they share one photon map.
    std::fs::write(&jobs, std::fs::read_to_string(&jobs).unwrap().replace("26M", "1G")).unwrap();
    let r = run(&dir, &["batch", s(&jobs), "--report", s(&report), "--force"]);
    assert_ok(&r);
    let v: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    for u in v["units"].as_array().unwrap() {
        assert_eq!(u["stats"]["photon_map_shared_by"], 2, "{u}");
    }
}

/// `photongrid batch JOBS --list` run in `cwd`, so that relative spellings stay relative.
fn list_in(cwd: &Path, jobs: &str) -> Vec<Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_photongrid"))
        .current_dir(cwd)
        .args(["batch", jobs, "--list"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && !stderr.contains("panicked"), "{stderr}");
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn errors(units: &[Value]) -> Vec<String> {
    units
        .iter()
        .map(|u| u["error"].as_str().unwrap_or_default().to_string())
        .collect()
}

#[test]
fn batch_spellings_and_aliases_of_one_output_clash() {
    let (dir, p, _) = scene("batch-alias");
    std::fs::create_dir(dir.join("out")).unwrap();
    // `alias` is another name of the folder `out`.
    std::os::unix::fs::symlink("out", dir.join("alias")).unwrap();
    let absolute = dir.join("out/a.exr");
    let jobs = jobs_file(
        dir.path(),
        &p,
        &["out/a.exr", s(&absolute), "alias/a.exr", "alias/./a.exr", "out/b.exr"],
    );
    assert_eq!(jobs, dir.join("jobs.toml"));
    // The jobs file named relative to the working folder: `out/a.exr` stays relative.
    let units = list_in(dir.path(), "jobs.toml");
    assert_eq!(units.len(), 5, "{units:?}");
    assert_eq!(units[0]["output"], "out/a.exr");
    let e = errors(&units);
    assert!(e[0].is_empty() && e[4].is_empty(), "{e:?}");
    for e in &e[1..4] {
        assert!(e.contains("also the output of unit 0 (job 0)"), "{e}");
    }
}

#[test]
fn batch_outputs_that_lead_to_an_input_fail_their_unit() {
    let (dir, p, bytes) = scene("batch-inputs");
    let out = dir.join("out");
    std::fs::create_dir(&out).unwrap();
    let jobs = jobs_file(
        dir.path(),
        &p,
        &[
            "out/scene.exr",   // a link to the scene
            "out/hard.exr",    // the scene under a second name (a hard link)
            "out/jobs.exr",    // a link to the jobs file
            "out/report.exr",  // the report
            "out/journal.exr", // the journal
            "out/ok.exr",
            "out/linked-sidecar.exr", // a link to unit 5's sidecar
        ],
    );
    std::os::unix::fs::symlink(&p, out.join("scene.exr")).unwrap();
    std::fs::hard_link(&p, out.join("hard.exr")).unwrap();
    std::os::unix::fs::symlink(&jobs, out.join("jobs.exr")).unwrap();
    std::os::unix::fs::symlink("ok.exr.done.json", out.join("linked-sidecar.exr")).unwrap();
    let jobs_text = std::fs::read(&jobs).unwrap();
    let (report, journal) = (out.join("report.exr"), out.join("journal.exr"));
    let args = ["batch", s(&jobs), "--report", s(&report), "--journal", s(&journal)];
    let r = run(&dir, &args);
    assert_fails_with(&r, &["5 of 7 units failed"]);
    let v: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let units = v["units"].as_array().unwrap();
    let status: Vec<&str> = units.iter().map(|u| u["status"].as_str().unwrap()).collect();
    assert_eq!(
        status,
        ["failed", "failed", "failed", "failed", "failed", "done", "done"],
        "{v}"
    );
    let e = errors(units);
    for (i, input) in [
        (0, "is the scene of job 0"),
        (1, "is the scene of job 0"),
        (2, "is the jobs file"),
        (3, "is the report"),
        (4, "is the journal"),
    ] {
        assert!(e[i].contains(input) && e[i].contains("change `output`"), "{}", e[i]);
    }
    assert_eq!(std::fs::read(&p).unwrap(), bytes);
    assert_eq!(std::fs::read(&jobs).unwrap(), jobs_text);
    // The journal is still JSON lines; unit 5's sidecar is its own, not unit 6's image (a link
    // at an output is replaced, never written through), so a rerun skips both.
    let journal_text = std::fs::read_to_string(&journal).unwrap();
    assert!(journal_text.lines().all(|l| serde_json::from_str::<Value>(l).is_ok()));
    assert!(!std::fs::symlink_metadata(out.join("linked-sidecar.exr"))
        .unwrap()
        .is_symlink());
    let r = run(&dir, &args);
    assert_fails_with(&r, &["5 of 7 units failed"]);
    let v: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let status: Vec<&str> = v["units"]
        .as_array()
        .unwrap()
        .iter()
        .map(|u| u["status"].as_str().unwrap())
        .collect();
    assert_eq!(&status[5..], ["skipped", "skipped"], "{v}");
}

#[test]
fn batch_report_or_journal_that_is_a_scene_is_refused() {
    let (dir, p, bytes) = scene("batch-report-scene");
    let jobs = jobs_file(dir.path(), &p, &["out/a.exr"]);
    let report = dir.join("report.json");
    for args in [
        vec!["batch", s(&jobs), "--report", s(&p)],
        vec!["batch", s(&jobs), "--report", s(&report), "--journal", s(&p)],
    ] {
        assert_fails_with(&run(&dir, &args), &["is the scene of job 0"]);
        assert_eq!(std::fs::read(&p).unwrap(), bytes);
    }
    assert!(!dir.join("out/a.exr").exists());
}

#[test]
fn batch_units_over_the_memory_limit_are_refused_up_front() {
    let (dir, p, _) = scene("batch-memory");
    let jobs = dir.join("jobs.toml");
    let text = format!(
        "[defaults]\nwidth = 16\nheight = 12\nphotons = 1000\nspp = 1\n\
         [[job]]\nscene = \"{s}\"\noutput = \"out/ok0.exr\"\n\
         [[job]]\nscene = \"{s}\"\noutput = \"out/huge.exr\"\nwidth = 8000\nheight = 6000\nmemory_limit = \"1G\"\n\
         [[job]]\nscene = \"{s}\"\noutput = \"out/spp.exr\"\nmethod = \"sppm\"\nspp = 50000\nwidth = 160\nheight = 120\nmemory_limit = \"4G\"\n\
         [[job]]\nscene = \"{s}\"\noutput = \"out/ok3.exr\"\n",
        s = s(&p)
    );
    std::fs::write(&jobs, text).unwrap();
    // Listing already shows the refusal: the estimate, the limit and what to change.
    let e = errors(&list(&dir, &jobs));
    assert!(e[0].is_empty() && e[3].is_empty(), "{e:?}");
    for needle in [
        "job 1",
        s(&p),
        "camera 0 'Camera'",
        "refused before rendering",
        "images of 1 camera at 8000×6000",
        "memory limit of 1.0 GiB",
        "lower the resolution (--width, --height)",
        "memory_limit = \"8G\"",
    ] {
        assert!(e[1].contains(needle), "lacks {needle:?}: {}", e[1]);
    }
    assert!(e[2].contains("SPPM state") && e[2].contains("lower --spp"), "{}", e[2]);
    let (report, journal) = (dir.join("report.json"), dir.join("journal.jsonl"));
    let args = ["batch", s(&jobs), "--report", s(&report), "--journal", s(&journal)];
    let statuses = || -> Vec<String> {
        let v: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
        let units = v["units"].as_array().unwrap();
        units
            .iter()
            .map(|u| u["status"].as_str().unwrap().to_string())
            .collect()
    };
    let r = run(&dir, &args);
    let first = format!("failed: {} unit 1 (job 1, camera Camera): job 1", s(&jobs));
    let second = format!("failed: {} unit 2 (job 2, camera Camera)", s(&jobs));
    assert_fails_with(
        &r,
        &[&first, &second, "2 of 4 units failed", "refused before rendering"],
    );
    assert_eq!(statuses(), ["done", "failed", "failed", "done"]);
    assert!(dir.join("out/ok0.exr").is_file() && dir.join("out/ok3.exr").is_file());
    assert!(!dir.join("out/huge.exr").exists() && !dir.join("out/spp.exr").exists());
    // Resumed: the finished units are skipped and the refused ones refused again at once.
    let r = run(&dir, &args);
    assert_fails_with(&r, &[&first, "2 of 4 units failed"]);
    assert_eq!(statuses(), ["skipped", "failed", "failed", "skipped"]);
    // In neither run did a refused unit start rendering.
    let events: Vec<Value> = std::fs::read_to_string(&journal)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for unit in [1, 2] {
        let mine: Vec<&str> = events
            .iter()
            .filter(|e| e["unit"] == unit)
            .map(|e| e["event"].as_str().unwrap())
            .collect();
        assert_eq!(mine, ["failed", "failed"], "unit {unit}: {events:?}");
    }
}
