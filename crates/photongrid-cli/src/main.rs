//! The `photongrid` command line: argument parsing, logging and progress set-up, exit codes.
#![forbid(unsafe_code)]

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use photongrid::film::Film;
use photongrid::grid::{GridMode, GridQuantity};
use photongrid::output::{self, output_for, AovSelection};
use photongrid_cli::metrics::read_exr_rgb;
use photongrid_cli::progress::{emit_json, Display, ProgressMode};
use photongrid::pipeline::{self, PhaseTimes};
use photongrid::progress::Progress;
use photongrid::render::{DirectLighting, Method};
use photongrid::scene::gltf::{load_with, LoadOptions};
use photongrid::settings::{ThresholdChoice, WaveletChoice};
use photongrid::Settings;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Photon-mapping renderer for Blender-exported glTF scenes, caustics included.
#[derive(Parser, Debug)]
#[command(name = "photongrid", version, about, long_about = None)]
struct Cli {
    /// More log output on stderr (-v: info, -vv: debug). RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render one or more cameras of a .glb/.gltf scene to EXR.
    Render(RenderArgs),
    /// Show what was loaded from a scene: materials, lights, cameras, and what was approximated or ignored.
    Info {
        /// The scene (.glb or .gltf).
        scene: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Render the jobs of a JOBS.toml: parallel, resumable, shardable, with a JSON report.
    Batch(BatchArgs),
    /// Compare an image with a reference (same metrics as shared/tools/score.py).
    Compare {
        /// The rendered image (EXR).
        image: PathBuf,
        /// The reference image (EXR).
        reference: PathBuf,
        /// Leave out pixels where this EXR's luminance is > 0.5 (e.g. a specular mask).
        #[arg(long)]
        mask: Option<PathBuf>,
        /// Block size for the block metrics.
        #[arg(long, default_value_t = 8)]
        block: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Error against time: render methods × photon counts × scenes × seeds against references;
    /// write bench.json, SVG charts and table.md.
    Bench(BenchArgs),
}

#[derive(Args, Debug)]
struct BenchArgs {
    /// Folder with <scene>.glb and refs/<scene>_cam<i>.exr (+ optional .specmask.exr).
    #[arg(default_value = "../shared/scenes")]
    dir: PathBuf,
    /// Output folder: bench.json, error_vs_time_<scene>_cam<i>.svg, time_vs_photons.svg, table.md.
    #[arg(short, long, default_value = "out/bench")]
    out: PathBuf,
    /// Matrix preset; the options below override its parts.
    #[arg(long, value_enum, default_value_t = photongrid_cli::bench::Preset::Small)]
    preset: photongrid_cli::bench::Preset,
    /// Methods, comma-separated: knn, knn-k500, adaptive, single-map-knn, single-map-adaptive, gather8.
    #[arg(long, value_delimiter = ',')]
    methods: Vec<String>,
    /// Photon counts, comma-separated (e.g. 250000,1000000,4000000).
    #[arg(long, value_delimiter = ',')]
    photons: Vec<usize>,
    /// Number of seeds (0, 1, ... N-1).
    #[arg(long)]
    seeds: Option<u64>,
    /// Scenes (file stems), comma-separated. Default: every scene with a reference.
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// Image width (must divide the references' width; the references are box-filtered down).
    #[arg(long)]
    width: Option<u32>,
    /// Image height (must divide the references' height).
    #[arg(long)]
    height: Option<u32>,
    /// Camera rays per pixel (default: the render default).
    #[arg(long)]
    spp: Option<u32>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Keep the runs already in OUT/bench.json and skip them.
    #[arg(long)]
    resume: bool,
    /// Replace an existing OUT/bench.json.
    #[arg(long, conflicts_with = "resume")]
    overwrite: bool,
    /// Only rewrite the charts and table.md from OUT/bench.json; render nothing.
    #[arg(long)]
    report_only: bool,
    /// No per-run lines on stderr.
    #[arg(short, long)]
    quiet: bool,
}

#[derive(Args, Debug)]
struct RenderArgs {
    /// The scene (.glb or .gltf).
    scene: PathBuf,
    /// Camera node name or glTF camera index; repeat for several, or "all". Default: the first camera.
    #[arg(short, long = "camera", value_name = "NAME|INDEX|all")]
    cameras: Vec<String>,
    /// Output EXR. With several cameras, "{camera}" in the path is replaced by the camera name
    /// (otherwise the name is appended before the extension).
    #[arg(short, long, value_name = "OUT.exr")]
    output: PathBuf,
    /// Photon paths to emit.
    #[arg(long, default_value_t = Settings::default().photons)]
    photons: usize,
    /// Photons per radiance estimate (k nearest neighbours).
    #[arg(long, visible_alias = "neighbors", default_value_t = Settings::default().neighbours)]
    neighbours: usize,
    /// Camera rays per pixel (jittered, 1-pixel box filter).
    #[arg(long, default_value_t = Settings::default().spp)]
    spp: u32,
    /// Random seed: the same seed and settings give the same image.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Image width (default: the camera's aspect at 480 lines).
    #[arg(long)]
    width: Option<u32>,
    /// Image height.
    #[arg(long)]
    height: Option<u32>,
    /// Direct light from shadow rays, or from photons like the paper's single photon map.
    #[arg(long, value_enum, default_value_t = DirectLighting::ShadowRays)]
    direct: DirectLighting,
    /// Shadow rays per emissive-surface light evaluation.
    #[arg(long, default_value_t = Settings::default().light_samples)]
    light_samples: u32,
    /// Photon bounces before a path stops.
    #[arg(long, default_value_t = Settings::default().max_photon_depth)]
    max_photon_depth: u32,
    /// Mirror/glass bounces followed from the camera.
    #[arg(long, default_value_t = Settings::default().max_specular_depth)]
    max_specular_depth: u32,
    /// Largest photon gather radius, as a fraction of the scene diagonal.
    #[arg(long, default_value_t = Settings::default().max_radius_rel)]
    max_radius: f32,
    /// Radiance estimate: plain k nearest neighbours, or the paper's grid-adaptive radius.
    #[arg(long, value_enum, default_value_t = Settings::default().method)]
    method: Method,
    /// Grids for the adaptive method: planes where there are planes and voxels where needed
    /// (auto), planes only (the paper), voxels for everything, or none.
    #[arg(long, value_enum, default_value_t = Settings::default().grid)]
    grid: GridMode,
    /// Cells along the longer side of each plane's count grid.
    #[arg(long, default_value_t = Settings::default().grid_res)]
    grid_res: usize,
    /// Wavelet for the photon-count textures.
    #[arg(long, value_enum, default_value_t = Settings::default().wavelet)]
    wavelet: WaveletChoice,
    /// Thresholding of wavelet details: the paper's fixed value, or set from the data.
    #[arg(long, value_enum, default_value_t = Settings::default().threshold)]
    threshold: ThresholdChoice,
    /// The fixed threshold (photon counts) for --threshold fixed.
    #[arg(long, default_value_t = Settings::default().threshold_value)]
    threshold_value: f32,
    /// Wavelet levels (at most).
    #[arg(long, default_value_t = Settings::default().wavelet_levels)]
    wavelet_levels: usize,
    /// Share of the kNN radius error kept: r = r_a + alpha (r_k − r_a).
    #[arg(long, default_value_t = Settings::default().alpha)]
    alpha: f32,
    /// Filtered photons per cell below which the kNN radius is used (shadows).
    #[arg(long, default_value_t = Settings::default().shadow_count)]
    shadow_count: f32,
    /// Whether grid cells count photons or flux.
    #[arg(long, value_enum, default_value_t = Settings::default().grid_quantity)]
    grid_quantity: GridQuantity,
    /// Extra photon paths aimed at mirrors and glass, for caustics (ignored when there are none).
    #[arg(long, default_value_t = Settings::default().caustic_photons)]
    caustic_photons: usize,
    /// Final-gather rays per camera sample (0: show the photon map directly, as the paper).
    #[arg(long, default_value_t = Settings::default().gather)]
    gather: u32,
    /// Progressive rendering: passes of new photons (--photons each) and new camera samples
    /// (--spp each), averaged. With --time, at most this many.
    #[arg(long, value_name = "P")]
    passes: Option<u32>,
    /// Progressive rendering with a time budget: add passes while the next one is expected to
    /// end within this wall time, counted from the start (at least one pass runs). Seconds, or
    /// with a unit: 90s, 2.5m, 1h. The pass count then depends on the machine; --stats reports it.
    #[arg(long, visible_alias = "time-budget", value_name = "SECONDS", value_parser = parse_seconds)]
    time: Option<f64>,
    /// Write the image so far to the output (atomically) every this many seconds while passes
    /// run, so that a killed render loses little (0: after every pass).
    #[arg(long, value_name = "SECONDS", value_parser = parse_seconds_or_zero)]
    checkpoint: Option<f64>,
    /// Write each plane's count texture before and after the wavelet step (EXR) into this folder.
    #[arg(long, value_name = "DIR")]
    dump_grids: Option<PathBuf>,
    /// Add AOV layers to the EXR: albedo, N, depth, photons (density and radius).
    #[arg(long)]
    aovs: bool,
    /// Also write an sRGB PNG preview here (same {camera} rule as --output).
    #[arg(long, value_name = "PREVIEW.png")]
    png: Option<PathBuf>,
    /// Exposure of the PNG preview in stops.
    #[arg(long, default_value_t = 0.0)]
    exposure: f32,
    /// Write settings, phase seconds, photon counts and peak memory as JSON here.
    #[arg(long, value_name = "STATS.json")]
    stats: Option<PathBuf>,
    /// Progress display: bars on a terminal, JSON lines on stderr for programs, or nothing.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    progress: ProgressMode,
    /// Allow buffers and images outside the scene's folder.
    #[arg(long)]
    allow_external_uris: bool,
}

#[derive(Args, Debug)]
struct BatchArgs {
    /// The jobs file: [[job]] tables with scene, output, optional camera and render options,
    /// and an optional [defaults] table (see README.md, "Batch jobs").
    #[arg(value_name = "JOBS.toml")]
    jobs_file: PathBuf,
    /// Write the JSON report here (per unit: status, error, seconds, stats; and totals).
    #[arg(long, value_name = "REPORT.json", required_unless_present = "list")]
    report: Option<PathBuf>,
    /// Run only shard I of N (0-based): the units whose index % N == I.
    #[arg(long, value_name = "I/N")]
    shard: Option<String>,
    /// Run only these units (by index after expansion, as `--list` prints them); repeatable or comma-separated.
    #[arg(long, value_name = "INDEX", value_delimiter = ',')]
    only: Vec<usize>,
    /// Jobs rendered at once, each in its own pool of threads/J threads.
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Threads in all (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Print the expanded units as JSON lines on stdout and exit.
    #[arg(long)]
    list: bool,
    /// Render even outputs whose sidecar says they are finished.
    #[arg(long)]
    force: bool,
    /// Append one JSON line per unit event (start, done, skipped, failed) to this file.
    #[arg(long, value_name = "JOURNAL.jsonl")]
    journal: Option<PathBuf>,
    /// No per-unit lines on stderr.
    #[arg(long, short)]
    quiet: bool,
}

fn main() {
    let cli = Cli::parse();
    let json = matches!(&cli.command, Command::Render(r) if r.progress == ProgressMode::Json);
    init_logging(cli.verbose);
    if let Err(e) = run(cli) {
        let message = error_message(&e);
        if json {
            emit_json(&serde_json::json!({"event": "error", "message": message}));
        }
        eprintln!("error: {message}");
        std::process::exit(1);
    }
}

/// The error and its causes, leaving out a cause the message already quotes (the loader's and
/// writer's errors print their I/O cause themselves; `{e:#}` would repeat it).
fn error_message(e: &anyhow::Error) -> String {
    let mut message = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !message.contains(&c) {
            message.push_str(": ");
            message.push_str(&c);
        }
    }
    message
}

fn init_logging(verbose: u8) {
    let level = match verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    use std::io::IsTerminal;
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .try_init();
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render(args) => render(args),
        Command::Info { scene, json } => info(&scene, json),
        Command::Batch(args) => batch(args),
        Command::Compare {
            image,
            reference,
            mask,
            block,
            json,
        } => compare(&image, &reference, mask.as_deref(), block, json),
        Command::Bench(args) => bench(args),
    }
}

fn bench(a: BenchArgs) -> Result<()> {
    use photongrid_cli::bench;
    if a.report_only {
        let file = bench::BenchFile::read(&a.out.join("bench.json"))?;
        for p in bench::write_reports(&file, &a.out)? {
            println!("{}", p.display());
        }
        return Ok(());
    }
    if let Some(t) = a.threads {
        if t == 0 {
            bail!("--threads must be at least 1");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
            .context("setting up the thread pool")?;
    }
    let scenes = bench::discover(&a.dir, &a.scenes)?
        .into_iter()
        .map(|s| s.name)
        .collect();
    let mut matrix = bench::Matrix::preset(a.preset, scenes);
    if !a.methods.is_empty() {
        matrix.methods = a.methods.clone();
    }
    if !a.photons.is_empty() {
        matrix.budgets = a.photons.iter().map(|&p| bench::Budget::Photons(p)).collect();
    }
    if let Some(n) = a.seeds {
        matrix.seeds = (0..n).collect();
    }
    matrix.width = a.width.unwrap_or(matrix.width);
    matrix.height = a.height.unwrap_or(matrix.height);
    matrix.spp = a.spp.or(matrix.spp);
    let command = std::env::args()
        .map(|s| {
            if s.is_empty() || s.contains(|c: char| c.is_whitespace() || "'\"$\\".contains(c)) {
                format!("'{}'", s.replace('\'', "'\\''"))
            } else {
                s
            }
        })
        .collect::<Vec<_>>()
        .join(" ");
    let opts = bench::BenchOptions {
        dir: a.dir.clone(),
        out: a.out.clone(),
        matrix,
        resume: a.resume,
        overwrite: a.overwrite,
        command,
    };
    let quiet = a.quiet;
    let summary = bench::run(&opts, &mut |line| {
        if !quiet {
            eprintln!("{line}");
        }
    })?;
    eprintln!(
        "bench: {} runs rendered, {} skipped, {:.1} s",
        summary.ran, summary.skipped, summary.seconds
    );
    for p in &summary.outputs {
        println!("{}", p.display());
    }
    Ok(())
}

fn settings_of(a: &RenderArgs) -> Settings {
    Settings {
        photons: a.photons,
        neighbours: a.neighbours,
        spp: a.spp,
        seed: a.seed,
        width: a.width,
        height: a.height,
        direct: a.direct,
        light_samples: a.light_samples,
        max_photon_depth: a.max_photon_depth,
        max_specular_depth: a.max_specular_depth,
        max_radius_rel: a.max_radius,
        method: a.method,
        grid: a.grid,
        grid_res: a.grid_res,
        wavelet: a.wavelet,
        threshold: a.threshold,
        threshold_value: a.threshold_value,
        wavelet_levels: a.wavelet_levels,
        alpha: a.alpha,
        shadow_count: a.shadow_count,
        grid_quantity: a.grid_quantity,
        gather: a.gather,
        caustic_photons: a.caustic_photons,
        passes: a.passes,
        time: a.time,
        ..Settings::default()
    }
}

/// Seconds from "90", "90s", "2.5m" or "1h"; must be positive.
fn parse_seconds(v: &str) -> Result<f64, String> {
    let s = parse_seconds_or_zero(v)?;
    if s > 0.0 {
        Ok(s)
    } else {
        Err("must be more than 0 seconds".into())
    }
}

/// As [`parse_seconds`], 0 allowed.
fn parse_seconds_or_zero(v: &str) -> Result<f64, String> {
    let t = v.trim();
    let (num, unit) = match t.char_indices().last() {
        Some((i, 's')) => (&t[..i], 1.0),
        Some((i, 'm')) => (&t[..i], 60.0),
        Some((i, 'h')) => (&t[..i], 3600.0),
        _ => (t, 1.0),
    };
    match num.trim().parse::<f64>() {
        Ok(x) if x >= 0.0 && x.is_finite() => Ok(x * unit),
        _ => Err(format!("`{v}` is not a duration: use seconds (30, 30s) or 2.5m, 1h")),
    }
}

fn check_writable(path: &Path) -> Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        bail!(
            "{}: the folder {} does not exist; create it first",
            path.display(),
            dir.display()
        );
    }
    if path.is_dir() {
        bail!("{}: is a folder, not a file name", path.display());
    }
    Ok(())
}

fn render(a: RenderArgs) -> Result<()> {
    let start = Instant::now();
    if let Some(t) = a.threads {
        if t == 0 {
            bail!("--threads must be at least 1");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
            .context("setting up the thread pool")?;
    }
    let settings = settings_of(&a);
    settings.validate().map_err(|e| anyhow::anyhow!(e))?;
    let display = Display::new(a.progress);
    let progress = Progress::new(&display);
    let mut times = PhaseTimes::default();

    let phase = progress.phase("load", 0);
    let scene = load_with(
        &a.scene,
        &LoadOptions {
            allow_external_uris: a.allow_external_uris,
            ..Default::default()
        },
    )?;
    times.load = phase.finish();
    for w in scene.report.approximated.iter().chain(&scene.report.ignored) {
        tracing::warn!("{}: {w}", a.scene.display());
    }
    let keys = if a.cameras.is_empty() {
        vec![]
    } else {
        a.cameras.clone()
    };
    let mut cameras = pipeline::select_cameras(&scene, &keys)?;
    if a.cameras.is_empty() {
        cameras.truncate(1);
    }
    let several = cameras.len() > 1;
    let outputs: Vec<(PathBuf, Option<PathBuf>)> = cameras
        .iter()
        .map(|c| {
            (
                output_for(&a.output, &c.name, several),
                a.png.as_ref().map(|p| output_for(p, &c.name, several)),
            )
        })
        .collect();
    for (o, p) in &outputs {
        check_writable(o)?;
        if let Some(p) = p {
            check_writable(p)?;
        }
    }
    if let Some(s) = &a.stats {
        check_writable(s)?;
    }

    let aovs = if a.aovs {
        AovSelection::all()
    } else {
        AovSelection::default()
    };
    let json_progress = a.progress == ProgressMode::Json;
    let mut write_checkpoint = |films: &[Film], passes: u32| -> Result<(), String> {
        for (film, (out, _)) in films.iter().zip(&outputs) {
            output::write_exr(out, film, aovs).map_err(|e| e.to_string())?;
            if json_progress {
                emit_json(&serde_json::json!({"event": "checkpoint", "path": out, "passes": passes}));
            }
        }
        Ok(())
    };
    let checkpoint = a.checkpoint.map(|every| pipeline::Checkpoint {
        every,
        write: &mut write_checkpoint,
    });
    let result = pipeline::render_passes(&scene, &cameras, &settings, start, &progress, &mut times, checkpoint)?;
    if let (Some(dir), Some(g)) = (&a.dump_grids, result.grids.as_ref().and_then(|g| g.planes.as_ref())) {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create folder", dir.display()))?;
        for (i, (raw, filtered)) in g.raw.iter().zip(&g.filtered).enumerate() {
            output::write_field_exr(&dir.join(format!("plane{i:03}_counts.exr")), raw)?;
            output::write_field_exr(&dir.join(format!("plane{i:03}_filtered.exr")), filtered)?;
        }
    }
    let mut camera_stats = Vec::new();
    for ((camera, (out, png)), film) in cameras.iter().zip(&outputs).zip(&result.films) {
        let t = Instant::now();
        output::write_exr(out, film, aovs)?;
        if let Some(p) = png {
            output::write_png(p, film, a.exposure)?;
        }
        times.write += t.elapsed().as_secs_f64();
        let nonfinite = film.nonfinite();
        if nonfinite > 0 {
            tracing::warn!("{}: {nonfinite} pixels are not finite", out.display());
        }
        camera_stats.push(serde_json::json!({
            "camera": camera.name, "index": camera.index, "output": out, "png": png,
            "width": film.width, "height": film.height,
            "mean_rgb": film.mean().to_array(), "nonfinite_pixels": nonfinite,
        }));
        if a.progress == ProgressMode::Json {
            emit_json(&serde_json::json!({"event": "output", "camera": camera.name, "path": out}));
        }
    }
    times.total = start.elapsed().as_secs_f64();
    if a.progress != ProgressMode::Quiet {
        eprintln!(
            "{}: {} pass{} · load {:.2} s · bvh {:.2} s · photons {:.2} s · build {:.2} s · render {:.2} s · write {:.2} s · total {:.2} s",
            a.scene.display(),
            result.passes,
            if result.passes == 1 { "" } else { "es" },
            times.load,
            times.bvh,
            times.photons,
            times.build,
            times.render,
            times.write,
            times.total
        );
    }
    if let Some(path) = &a.stats {
        let stats = serde_json::json!({
            "scene": a.scene,
            "version": env!("CARGO_PKG_VERSION"),
            "settings": settings,
            "threads": rayon::current_num_threads(),
            "seconds": times,
            "photons": result.photon_stats,
            "passes": {
                "count": result.passes,
                "stopped_by": result.stop,
                "seconds": result.pass_seconds,
                "checkpoints": result.checkpoints,
            },
            "cpu_seconds": pipeline::cpu_seconds(),
            "memory": {
                "peak_bytes": pipeline::peak_memory_bytes(),
                "photon_map_bytes": result.photon_map_bytes,
                "bvh_bytes": result.bvh_bytes,
            },
            "cameras": camera_stats,
            "grids": result.grids.as_ref().map(|g| serde_json::json!({
                "choice": g.choice,
                "memory_bytes": g.memory_bytes(),
                // Per plane: does the wavelet step change the photon total (the paper's
                // "brightening")? mean_after/mean_before should stay 1.
                "planes": g.planes.as_ref().map(|p| p.reports.iter().zip(&p.set.planes).map(|(r, pl)| serde_json::json!({
                    "cells": [pl.res_u, pl.res_v], "mean_before": r.mean_before, "mean_after": r.mean_after,
                    "sigma": r.sigma, "kept_fraction": r.kept_fraction,
                })).collect::<Vec<_>>()),
            })),
        });
        output::write_atomic(path, serde_json::to_string_pretty(&stats)?.as_bytes())?;
    }
    Ok(())
}

fn batch(a: BatchArgs) -> Result<()> {
    use photongrid_cli::batch;
    let start = Instant::now();
    if a.jobs == 0 {
        bail!("--jobs must be at least 1");
    }
    if a.threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    let shard = a
        .shard
        .as_deref()
        .map(batch::parse_shard)
        .transpose()
        .map_err(|e| anyhow::anyhow!(e))?;
    let text =
        std::fs::read_to_string(&a.jobs_file).with_context(|| format!("{}: cannot read", a.jobs_file.display()))?;
    let base = a
        .jobs_file
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let jobs = batch::parse_jobs(&text, base).map_err(|e| anyhow::anyhow!("{}: {e}", a.jobs_file.display()))?;
    let mut units = batch::expand(&jobs);
    let all = units.len();
    if let Some(&i) = a.only.iter().find(|&&i| i >= all) {
        bail!("--only {i}: {} has {all} units (0..{all})", a.jobs_file.display());
    }
    if let Some((i, n)) = shard {
        units = batch::shard(units, i, n);
    }
    if !a.only.is_empty() {
        units.retain(|u| a.only.contains(&u.index));
    }
    if a.list {
        let mut out = std::io::stdout().lock();
        for u in &units {
            use std::io::Write;
            writeln!(out, "{}", serde_json::to_string(u)?)?;
        }
        return Ok(());
    }
    let report_path = a.report.as_deref().context("--report is required")?;
    check_writable(report_path)?;
    let mut opts = batch::RunOptions {
        jobs: a.jobs,
        force: a.force,
        journal: a.journal.clone(),
        verbose: !a.quiet,
        ..Default::default()
    };
    if let Some(t) = a.threads {
        opts.threads = t;
    }
    let (jobs, threads) = opts.layout();
    if jobs < a.jobs {
        tracing::warn!(
            "--jobs {} with {} threads: running {jobs} at once",
            a.jobs,
            opts.threads
        );
    }
    let reports = batch::run(&units, &opts);
    let run = serde_json::json!({
        "shard": shard.map(|(i, n)| serde_json::json!({"index": i, "count": n})),
        "only": if a.only.is_empty() { None } else { Some(&a.only) },
        "units_in_file": all,
        "jobs": jobs,
        "threads_per_job": threads,
        "force": a.force,
    });
    let doc = batch::report(&a.jobs_file, &reports, run, start.elapsed().as_secs_f64());
    output::write_atomic(report_path, serde_json::to_string_pretty(&doc)?.as_bytes())?;
    let t = &doc["totals"];
    eprintln!(
        "{}: {} units: {} done, {} skipped, {} failed in {:.2} s; report {}",
        a.jobs_file.display(),
        t["units"],
        t["done"],
        t["skipped"],
        t["failed"],
        start.elapsed().as_secs_f64(),
        report_path.display()
    );
    let failed: Vec<_> = reports.iter().filter(|r| r.status == batch::Status::Failed).collect();
    if !failed.is_empty() {
        for r in &failed {
            eprintln!(
                "failed: unit {} (job {}{}): {}",
                r.index,
                r.job,
                r.camera.as_deref().map(|c| format!(", camera {c}")).unwrap_or_default(),
                r.error.as_deref().unwrap_or("")
            );
        }
        bail!("{} of {} units failed", failed.len(), reports.len());
    }
    Ok(())
}

fn info(path: &Path, json: bool) -> Result<()> {
    let scene = photongrid::load(path)?;
    let r = &scene.report;
    if json {
        let v = serde_json::json!({
            "scene": path,
            "triangles": scene.triangles.len(),
            "surface_area_m2": scene.surface_area(),
            "bounds": scene.bounds,
            "has_specular": scene.has_specular(),
            "report": r,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("{}", path.display());
    println!(
        "  triangles: {} ({} degenerate skipped), surface {:.3} m²",
        scene.triangles.len(),
        r.degenerate_triangles,
        scene.surface_area()
    );
    println!(
        "  bounds: {:.3?} – {:.3?}",
        scene.bounds.min.to_array(),
        scene.bounds.max.to_array()
    );
    let section = |title: &str, items: &[String]| {
        println!("  {title}: {}", if items.is_empty() { "none" } else { "" });
        for i in items {
            println!("    - {i}");
        }
    };
    section("materials", &r.materials);
    section("lights", &r.lights);
    section("cameras", &r.cameras);
    section("approximated", &r.approximated);
    section("ignored", &r.ignored);
    println!(
        "  caustics possible (glass or mirror present): {}",
        if scene.has_specular() { "yes" } else { "no" }
    );
    let set = photongrid::grid::PlaneGrids::detect(&scene.triangles, Settings::default().grid_res);
    let on_plane = set
        .plane_of_triangle
        .iter()
        .filter(|p| **p != photongrid::grid::planes::NO_PLANE)
        .count();
    println!(
        "  planes (grids for --method adaptive): {} ({} of {} triangles; the rest use kNN or voxels)",
        set.planes.len(),
        on_plane,
        scene.triangles.len()
    );
    let grids = photongrid::grid::Grids::build(&scene, &[], &[], &Settings::default());
    println!("  grids chosen by --grid auto (the default):");
    for c in &grids.choice {
        println!("    - {c}");
    }
    for (i, p) in set.planes.iter().enumerate() {
        println!(
            "    - plane {i}: {:.3} × {:.3} m, normal {:.3?}, {} triangles, {}×{} cells of {:.2} mm²",
            p.size_u,
            p.size_v,
            p.normal.to_array(),
            p.triangles.len(),
            p.res_u,
            p.res_v,
            p.cell_area() * 1e6
        );
    }
    Ok(())
}

fn compare(image: &Path, reference: &Path, mask: Option<&Path>, block: usize, json: bool) -> Result<()> {
    let img = read_exr_rgb(image)?;
    let r = read_exr_rgb(reference)?;
    let m = match mask {
        Some(m) => Some(photongrid_cli::metrics::mask_from_rgb(&read_exr_rgb(m)?)),
        None => None,
    };
    let s = photongrid_cli::metrics::score(&img, &r, m.as_deref(), block)
        .map_err(|e| anyhow::anyhow!("{}: {e}", image.display()))?;
    if json {
        println!("{}", serde_json::to_string(&s)?);
    } else {
        let f = |v: Option<f64>| v.map(|v| format!("{v:.4}")).unwrap_or_else(|| "n/a".into());
        println!("mean_lum_ratio        {}", f(s.mean_lum_ratio));
        println!(
            "rgb_mean_ratio        {:.4} {:.4} {:.4}",
            s.rgb_mean_ratio[0], s.rgb_mean_ratio[1], s.rgb_mean_ratio[2]
        );
        println!("rel_rmse              {}", f(s.rel_rmse));
        println!("block_rel_rmse        {}  (block {})", f(s.block_rel_rmse), s.block);
        println!("block_frac_off_10pct  {}", f(s.block_frac_off_10pct));
        println!("nonfinite_pixels      {}", s.nonfinite_pixels);
        println!("pixels_scored         {}", s.pixels_scored);
    }
    Ok(())
}
