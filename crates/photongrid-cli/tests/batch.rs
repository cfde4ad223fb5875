//! `photongrid batch` end to end, with the real binary and the sample scenes at tiny settings.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_photongrid");
const TINY: &str = "width = 48\nheight = 36\nphotons = 20000\nspp = 1\n";

fn samples() -> PathBuf {
    photongrid_testkit::repo_root().join("samples")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pg-batch-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A jobs file in `dir`: scenes by absolute path, outputs relative to the file.
fn write_jobs(dir: &Path, jobs: &[(&str, &str, &str)]) -> PathBuf {
    let mut s = format!("[defaults]\n{TINY}\n");
    for (scene, output, extra) in jobs {
        let scene = if scene.starts_with('/') {
            scene.to_string()
        } else {
            samples().join(scene).display().to_string()
        };
        s += &format!("[[job]]\nscene = \"{scene}\"\noutput = \"{output}\"\n{extra}\n");
    }
    let p = dir.join("jobs.toml");
    std::fs::write(&p, s).unwrap();
    p
}

fn batch(jobs: &Path, report: &Path, extra: &[&str]) -> (Output, Value) {
    let out = Command::new(BIN)
        .arg("batch")
        .arg(jobs)
        .arg("--report")
        .arg(report)
        .args(extra)
        .output()
        .unwrap();
    let v: Value = serde_json::from_slice(&std::fs::read(report).unwrap_or_default()).unwrap_or(Value::Null);
    (out, v)
}

fn statuses(report: &Value) -> Vec<String> {
    report["units"]
        .as_array()
        .unwrap()
        .iter()
        .map(|u| u["status"].as_str().unwrap().to_string())
        .collect()
}

fn list(jobs: &Path, extra: &[&str]) -> Vec<Value> {
    let out = Command::new(BIN)
        .arg("batch")
        .arg(jobs)
        .arg("--list")
        .args(extra)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn failure_resume_and_corrupt_output() {
    let dir = tmp("resume");
    let jobs = write_jobs(
        &dir,
        &[
            ("cornell_glass.glb", "out/{scene}.exr", ""),
            ("ring_caustic.glb", "out/{scene}_{camera}.exr", ""),
            ("/nonexistent/missing.glb", "out/{scene}.exr", ""),
            ("shadow_edges.glb", "out/{scene}-{camera}.exr", "camera = 0\nseed = 3"),
        ],
    );
    let report = dir.join("report.json");
    let (out, r) = batch(&jobs, &report, &["--jobs", "2"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a failed unit must fail the batch");
    assert!(
        stderr.contains("unit 3 (job 2)") && stderr.contains("missing.glb"),
        "{stderr}"
    );
    assert_eq!(statuses(&r), ["done", "done", "done", "failed", "done"]);
    let u = &r["units"];
    assert!(u[3]["error"].as_str().unwrap().contains("does not exist"), "{}", u[3]);
    assert_eq!(u[3]["job"], 2);
    assert_eq!(r["totals"]["done"], 4);
    assert_eq!(r["totals"]["failed"], 1);
    assert!(u[0]["stats"]["photons"]["stored"].as_u64().unwrap() > 0);
    assert!(u[0]["stats"]["seconds"]["photons"].as_f64().is_some());
    // The two ring_caustic cameras share one photon map.
    assert_eq!(u[1]["stats"]["photon_map_shared_by"], 2);
    let outputs = [
        "out/cornell_glass.exr",
        "out/ring_caustic_CamWide.exr",
        "out/ring_caustic_CamClose.exr",
        "out/shadow_edges-Camera.exr",
    ];
    for o in outputs {
        assert!(dir.join(o).is_file(), "{o} missing");
        assert!(dir.join(format!("{o}.done.json")).is_file(), "{o} has no sidecar");
    }
    for (i, o) in [0, 1, 2, 4].iter().zip(outputs) {
        assert_eq!(u[*i]["output"].as_str().unwrap(), dir.join(o).to_str().unwrap());
    }
    let bytes: Vec<Vec<u8>> = outputs.iter().map(|o| std::fs::read(dir.join(o)).unwrap()).collect();

    // Rerun: every good unit is skipped, the bad one still fails.
    let (out, r) = batch(&jobs, &report, &[]);
    assert!(!out.status.success());
    assert_eq!(statuses(&r), ["skipped", "skipped", "skipped", "failed", "skipped"]);

    // A truncated EXR is rendered again, and only it.
    let p = dir.join(outputs[2]);
    let len = std::fs::metadata(&p).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)
        .unwrap()
        .set_len(len / 2)
        .unwrap();
    let (_, r) = batch(&jobs, &report, &[]);
    assert_eq!(statuses(&r), ["skipped", "skipped", "done", "failed", "skipped"]);
    // Same seed and settings, one job at a time instead of two: the same bytes.
    assert_eq!(std::fs::read(&p).unwrap(), bytes[2]);

    // An EXR present but without a sidecar is not trusted either.
    std::fs::remove_file(dir.join(format!("{}.done.json", outputs[0]))).unwrap();
    // Changed settings for one job: only its unit is rendered again.
    let text = std::fs::read_to_string(&jobs)
        .unwrap()
        .replace("camera = 0\nseed = 3", "camera = 0\nseed = 4");
    std::fs::write(&jobs, text).unwrap();
    let (_, r) = batch(&jobs, &report, &[]);
    assert_eq!(statuses(&r), ["done", "skipped", "skipped", "failed", "done"]);
    assert_eq!(std::fs::read(dir.join(outputs[0])).unwrap(), bytes[0]);
    assert_ne!(std::fs::read(dir.join(outputs[3])).unwrap(), bytes[3]);

    // --force renders everything again.
    let (_, r) = batch(&jobs, &report, &["--force"]);
    assert_eq!(statuses(&r), ["done", "done", "done", "failed", "done"]);
    // No temporary files are left beside the outputs.
    for e in std::fs::read_dir(dir.join("out")).unwrap() {
        let n = e.unwrap().file_name().to_string_lossy().to_string();
        assert!(!n.ends_with(".tmp"), "{n}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn shards_cover_every_unit_once() {
    let dir = tmp("shard");
    let jobs = write_jobs(
        &dir,
        &[
            ("cornell_glass.glb", "{scene}.exr", ""),
            ("ring_caustic.glb", "{scene}_{camera}.exr", "camera = \"all\""),
            ("cornell_area.glb", "{scene}.exr", ""),
            ("curved_3d.glb", "{scene}.exr", ""),
            ("shadow_edges.glb", "{scene}.exr", ""),
        ],
    );
    let all: Vec<u64> = list(&jobs, &[]).iter().map(|u| u["index"].as_u64().unwrap()).collect();
    assert_eq!(all, (0..6).collect::<Vec<u64>>());
    let mut seen = Vec::new();
    for s in ["0/2", "1/2"] {
        let listed: Vec<u64> = list(&jobs, &["--shard", s])
            .iter()
            .map(|u| u["index"].as_u64().unwrap())
            .collect();
        let (out, r) = batch(&jobs, &dir.join(format!("report{}.json", &s[..1])), &["--shard", s]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let ran: Vec<u64> = r["units"]
            .as_array()
            .unwrap()
            .iter()
            .map(|u| u["index"].as_u64().unwrap())
            .collect();
        assert_eq!(ran, listed);
        assert!(statuses(&r).iter().all(|s| s == "done"));
        seen.extend(ran);
    }
    seen.sort();
    assert_eq!(seen, all);
    // --only runs just that unit.
    let (out, r) = batch(&jobs, &dir.join("only.json"), &["--only", "2", "--force"]);
    assert!(out.status.success());
    assert_eq!(r["units"].as_array().unwrap().len(), 1);
    assert_eq!(r["units"][0]["camera"], "CamClose");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn unknown_option_names_job_and_key() {
    let dir = tmp("unknown");
    let jobs = write_jobs(
        &dir,
        &[
            ("cornell_glass.glb", "a.exr", ""),
            ("cornell_glass.glb", "b.exr", "photon = 5000"),
            ("cornell_glass.glb", "c.exr", "camera = \"NoSuchCamera\""),
            ("cornell_glass.glb", "d.exr", "spp = 0"),
        ],
    );
    let (out, r) = batch(&jobs, &dir.join("r.json"), &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert_eq!(statuses(&r), ["done", "failed", "failed", "failed"]);
    let e1 = r["units"][1]["error"].as_str().unwrap();
    assert!(e1.contains("job 1") && e1.contains("unknown key `photon`"), "{e1}");
    assert!(stderr.contains("unknown key `photon`"), "{stderr}");
    let e2 = r["units"][2]["error"].as_str().unwrap();
    assert!(e2.contains("job 2") && e2.contains("NoSuchCamera"), "{e2}");
    let e3 = r["units"][3]["error"].as_str().unwrap();
    assert!(e3.contains("job 3") && e3.contains("`spp` must be at least 1"), "{e3}");

    // A bad [defaults] key is an error for the whole file, before anything runs.
    std::fs::write(
        &jobs,
        "[defaults]\nbogus = 1\n[[job]]\nscene = \"x.glb\"\noutput = \"x.exr\"\n",
    )
    .unwrap();
    let (out, _) = batch(&jobs, &dir.join("r2.json"), &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("[defaults]") && stderr.contains("bogus"), "{stderr}");
    assert!(!dir.join("r2.json").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn clashing_outputs_are_refused() {
    let dir = tmp("clash");
    let jobs = write_jobs(
        &dir,
        &[
            ("cornell_glass.glb", "same.exr", ""),
            ("cornell_area.glb", "same.exr", ""),
        ],
    );
    let units = list(&jobs, &[]);
    assert!(units[0]["error"].is_null());
    let e = units[1]["error"].as_str().unwrap();
    assert!(e.contains("job 1") && e.contains("also the output of unit 0"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
