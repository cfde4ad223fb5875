//! The `photongrid` command line: argument parsing, logging and progress set-up, exit codes.
#![forbid(unsafe_code)]

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use photongrid::film::Film;
use photongrid::output::{self, output_for, AovSelection};
use photongrid::pipeline::{self, RenderRequest, Rendered};
use photongrid::progress::Progress;
use photongrid::scene::gltf::{load_with, LoadOptions};
use photongrid::settings::parse_seconds_or_zero;
use photongrid::Settings;
use photongrid_cli::metrics::read_exr_rgb;
use photongrid_cli::paths::{self, Format};
use photongrid_cli::progress::{emit_json, Display, ProgressMode};
use photongrid_cli::{out, outln};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
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
        /// The scenes (.glb or .gltf), one or more.
        #[arg(required = true, value_name = "SCENE")]
        scenes: Vec<PathBuf>,
        /// Print JSON instead of text: an object for one scene, an array for several.
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
    /// This machine's limits against a render: closest-hit rays/s through the BVH for the
    /// photon pass's own rays, shadow rays/s, kNN queries/s on the photon index, and the same
    /// phases' rates inside a real render of the classic pipeline, with their ratio, and the
    /// render's floor: its phases' seconds with the photon pass at the BVH's rate.
    Throughput(ThroughputArgs),
    /// Print the render settings: their defaults (jobs-file keys), or with --schema a JSON
    /// description of each (flag, heading, help, default, choices) for front ends such as the
    /// Blender add-on.
    Settings {
        /// Print the JSON schema instead of the defaults.
        #[arg(long)]
        schema: bool,
    },
}

#[derive(Args, Debug)]
struct BenchArgs {
    /// Folder with <scene>.glb and refs/<scene>_cam<i>.exr (+ optional .specmask.exr).
    #[arg(default_value = "../shared/scenes")]
    dir: PathBuf,
    /// Output folder: bench.json, error_vs_time_<scene>_cam<i>.svg, time_vs_photons.svg, table.md.
    #[arg(short, long, default_value = "out/bench", help_heading = "Input and output")]
    out: PathBuf,
    /// Matrix preset; the options below override its parts.
    #[arg(long, value_enum, default_value_t = photongrid_cli::bench::Preset::Small, help_heading = "Matrix")]
    preset: photongrid_cli::bench::Preset,
    /// Methods, comma-separated: knn, knn-k500, adaptive, single-map-knn, single-map-adaptive, gather8,
    /// default-knn, default (what each one is: README, Benchmarks).
    #[arg(long, value_delimiter = ',', help_heading = "Matrix")]
    methods: Vec<String>,
    /// Photon counts per pass, comma-separated (e.g. 250k,1M,4M).
    #[arg(long, value_delimiter = ',', value_parser = photongrid::settings::parse_count, help_heading = "Matrix")]
    photons: Vec<usize>,
    /// Wall-time budgets in seconds, comma-separated (e.g. 5,15,60): each run renders with
    /// --time at the method's settings. Combined with --photons, both kinds of runs are made.
    #[arg(long = "time", value_delimiter = ',', value_parser = photongrid::settings::parse_seconds, help_heading = "Matrix")]
    times: Vec<f64>,
    /// Also write every run's images into OUT/images/.
    #[arg(long, help_heading = "Input and output")]
    images: bool,
    /// Number of seeds (0, 1, ... N-1).
    #[arg(long, help_heading = "Matrix")]
    seeds: Option<u64>,
    /// Scenes (file stems), comma-separated. Default: every scene with a reference.
    #[arg(long, value_delimiter = ',', help_heading = "Matrix")]
    scenes: Vec<String>,
    /// Image width (must divide the references' width; the references are box-filtered down).
    #[arg(long, help_heading = "Matrix")]
    width: Option<u32>,
    /// Image height (must divide the references' height).
    #[arg(long, help_heading = "Matrix")]
    height: Option<u32>,
    /// Camera rays per pixel (default: the render default).
    #[arg(long, help_heading = "Matrix")]
    spp: Option<u32>,
    /// Worker threads (default: all cores).
    #[arg(long, help_heading = "Run")]
    threads: Option<usize>,
    /// Keep the runs already in OUT/bench.json and skip them.
    #[arg(long, help_heading = "Input and output")]
    resume: bool,
    /// Replace an existing OUT/bench.json.
    #[arg(long, conflicts_with = "resume", help_heading = "Input and output")]
    overwrite: bool,
    /// Only rewrite the charts and table.md from OUT/bench.json; render nothing.
    #[arg(long, help_heading = "Input and output")]
    report_only: bool,
    /// No per-run lines on stderr.
    #[arg(short, long, help_heading = "Run")]
    quiet: bool,
}

#[derive(Args, Debug)]
struct ThroughputArgs {
    /// The scenes (.glb or .gltf), one or more.
    #[arg(required = true, value_name = "SCENE")]
    scenes: Vec<PathBuf>,
    /// Rays recorded and traced in each ray measurement.
    #[arg(long, default_value = "1M", value_parser = photongrid::settings::parse_count)]
    rays: usize,
    /// Photon paths of the index measurement and of the real render.
    #[arg(long, default_value = "1M", value_parser = photongrid::settings::parse_count)]
    photons: usize,
    /// kNN queries timed.
    #[arg(long, default_value = "200k", value_parser = photongrid::settings::parse_count)]
    queries: usize,
    /// Neighbours per kNN query.
    #[arg(long, default_value_t = photongrid::Settings::default().neighbours)]
    k: usize,
    /// Image width of the real render.
    #[arg(long, default_value_t = 320)]
    width: u32,
    /// Image height of the real render.
    #[arg(long, default_value_t = 240)]
    height: u32,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Print JSON (an array, one object per scene) instead of a Markdown table.
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
struct RenderArgs {
    /// The scene (.glb or .gltf).
    scene: PathBuf,
    /// Camera node name or glTF camera index; repeat for several, or "all". Default: the first camera.
    #[arg(
        short,
        long = "camera",
        value_name = "NAME|INDEX|all",
        help_heading = "Input and output"
    )]
    cameras: Vec<String>,
    /// Output EXR. With several cameras, "{camera}" in the path is replaced by the camera name
    /// (otherwise the name is appended before the extension).
    #[arg(short, long, value_name = "OUT.exr", help_heading = "Input and output")]
    output: PathBuf,
    /// Also write an sRGB PNG preview here (same {camera} rule as --output).
    #[arg(long, value_name = "PREVIEW.png", help_heading = "Input and output")]
    png: Option<PathBuf>,
    /// Exposure of the PNG preview in stops.
    #[arg(long, default_value_t = 0.0, help_heading = "Input and output")]
    exposure: f32,
    /// Add passes to the EXR, named as Blender names them: DiffCol (albedo), Normal, Depth
    /// (along the camera's axis; 1e10 for the background), PhotonDensity and PhotonRadius.
    #[arg(long, help_heading = "Input and output")]
    aovs: bool,
    /// Write settings, phase seconds, photon counts and peak memory as JSON here.
    #[arg(long, value_name = "STATS.json", help_heading = "Input and output")]
    stats: Option<PathBuf>,
    /// Write each plane's textures (one-channel EXR) into this folder. Multiscale (the default), per
    /// layer (caustic, indirect, direct): photons counted per fine cell, the irradiance final
    /// gathering reads, and the reach (m) of the kernel the scale rule chose there — small where
    /// the light changes fast. Adaptive: the count texture before and after the wavelet step.
    #[arg(long, value_name = "DIR", help_heading = "Input and output")]
    dump_grids: Option<PathBuf>,
    /// Write the image so far to the output (atomically) every this many seconds while passes
    /// run, so that a killed render loses little (0: after every pass but the last). Ctrl+C
    /// ends the render after the running pass and writes it.
    #[arg(long, value_name = "SECONDS", value_parser = parse_seconds_or_zero, help_heading = "Input and output")]
    checkpoint: Option<f64>,
    /// Allow buffers and images outside the scene's folder.
    #[arg(long, help_heading = "Input and output")]
    allow_external_uris: bool,
    /// Progress display: bars on a terminal, JSON lines on stderr for programs, or nothing.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto, help_heading = "Run")]
    progress: ProgressMode,
    /// Worker threads (default: all cores).
    #[arg(long, help_heading = "Run")]
    threads: Option<usize>,
    #[command(flatten)]
    settings: Settings,
}

#[derive(Args, Debug)]
struct BatchArgs {
    /// The jobs file: [[job]] tables with scene, output, optional camera and render options,
    /// and an optional [defaults] table (see README.md, "Batch jobs").
    #[arg(value_name = "JOBS.toml")]
    jobs_file: PathBuf,
    /// Write the JSON report here (per unit: status, error, seconds, stats; and totals).
    #[arg(
        long,
        value_name = "REPORT.json",
        required_unless_present = "list",
        help_heading = "Output"
    )]
    report: Option<PathBuf>,
    /// Run only shard I of N (0-based): the units whose index % N == I.
    #[arg(long, value_name = "I/N", help_heading = "Selection")]
    shard: Option<String>,
    /// Run only these units (by index after expansion, as --list prints them); repeatable or comma-separated.
    #[arg(long, value_name = "INDEX", value_delimiter = ',', help_heading = "Selection")]
    only: Vec<usize>,
    /// Jobs rendered at once, each in its own pool of threads/J threads.
    #[arg(long, default_value_t = 1, help_heading = "Run")]
    jobs: usize,
    /// Threads in all (default: all cores).
    #[arg(long, help_heading = "Run")]
    threads: Option<usize>,
    /// Print the expanded units as JSON lines on stdout and exit.
    #[arg(long, help_heading = "Selection")]
    list: bool,
    /// Render even outputs whose sidecar says they are finished.
    #[arg(long, help_heading = "Selection")]
    force: bool,
    /// Append one JSON line per unit event (start, done, skipped, failed) to this file.
    #[arg(long, value_name = "JOURNAL.jsonl", help_heading = "Output")]
    journal: Option<PathBuf>,
    /// No per-unit lines on stderr.
    #[arg(long, short, help_heading = "Output")]
    quiet: bool,
}

fn main() {
    let json_args = std::env::args()
        .collect::<Vec<_>>()
        .windows(2)
        .any(|w| (w[0] == "--progress" && w[1] == "json") || w[1] == "--progress=json");
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        // With --progress json a program reads stderr: a usage error is a JSON event too.
        Err(e) if json_args && e.use_stderr() => {
            let text = e.to_string();
            let message = text.lines().next().unwrap_or_default().trim_start_matches("error: ");
            emit_json(&serde_json::json!({"event": "error", "message": message}));
            std::process::exit(e.exit_code());
        }
        Err(e) => e.exit(),
    };
    let json = matches!(&cli.command, Command::Render(r) if r.progress == ProgressMode::Json);
    init_logging(cli.verbose, json);
    if let Err(e) = run(cli) {
        let message = error_message(&e);
        if json {
            // Only JSON lines on stderr: the message is in the event.
            emit_json(&serde_json::json!({"event": "error", "message": message}));
        } else {
            eprintln!("error: {message}");
        }
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

fn init_logging(verbose: u8, json: bool) {
    let level = match verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    if json {
        use tracing_subscriber::prelude::*;
        let _ = tracing_subscriber::registry()
            .with(filter)
            .with(photongrid_cli::progress::JsonLog)
            .try_init();
        return;
    }
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
        Command::Info { scenes, json } => info(&scenes, json),
        Command::Batch(args) => batch(args),
        Command::Compare {
            image,
            reference,
            mask,
            block,
            json,
        } => compare(&image, &reference, mask.as_deref(), block, json),
        Command::Bench(args) => bench(args),
        Command::Throughput(args) => throughput(args),
        Command::Settings { schema } => settings_command(schema),
    }
}

fn bench(a: BenchArgs) -> Result<()> {
    use photongrid_cli::bench;
    if a.report_only {
        let file = bench::BenchFile::read(&a.out.join("bench.json"))?;
        for p in bench::write_reports(&file, &a.out)? {
            outln!("{}", p.display());
        }
        return Ok(());
    }
    set_threads(a.threads)?;
    let scenes = bench::discover(&a.dir, &a.scenes)?
        .into_iter()
        .map(|s| s.name)
        .collect();
    let mut matrix = bench::Matrix::preset(a.preset, scenes);
    if !a.methods.is_empty() {
        matrix.methods = a.methods.clone();
    }
    if !a.photons.is_empty() || !a.times.is_empty() {
        matrix.budgets = a.photons.iter().map(|&p| bench::Workload::Photons(p)).collect();
        matrix
            .budgets
            .extend(a.times.iter().map(|&t| bench::Workload::Seconds(t)));
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
        images: a.images,
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
        outln!("{}", p.display());
    }
    Ok(())
}

fn throughput(a: ThroughputArgs) -> Result<()> {
    use photongrid_cli::throughput::{measure, table_md, ThroughputOptions};
    set_threads(a.threads)?;
    let opts = ThroughputOptions {
        rays: a.rays,
        photons: a.photons,
        queries: a.queries,
        k: a.k,
        width: a.width,
        height: a.height,
        ..ThroughputOptions::default()
    };
    let mut results = Vec::new();
    for scene in &a.scenes {
        eprintln!("throughput: {}", scene.display());
        results.push(measure(scene, &opts)?);
    }
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&results)?);
    } else {
        out!("{}", table_md(&results));
    }
    Ok(())
}

/// The settings' defaults, or their schema derived from the same clap arguments `render`
/// takes (so front ends never copy names, defaults or choices).
fn settings_command(schema: bool) -> Result<()> {
    let defaults = serde_json::to_value(Settings::default())?;
    if !schema {
        outln!("{}", serde_json::to_string_pretty(&defaults)?);
        return Ok(());
    }
    use clap::Args as _;
    let cmd = Settings::augment_args(clap::Command::new("settings"));
    let items: Vec<serde_json::Value> = cmd
        .get_arguments()
        .filter_map(|a| {
            let key = a.get_id().as_str().to_string();
            let flag = a.get_long()?;
            let choices: Vec<serde_json::Value> = a
                .get_possible_values()
                .iter()
                .filter(|_| a.get_action().takes_values())
                .map(|v| serde_json::json!({"value": v.get_name(), "help": v.get_help().map(|h| h.to_string())}))
                .collect();
            Some(serde_json::json!({
                "key": key,
                "flag": format!("--{flag}"),
                "heading": a.get_help_heading(),
                "help": a.get_long_help().or(a.get_help()).map(|h| h.to_string()),
                "default": defaults.get(&key).cloned().unwrap_or(serde_json::Value::Null),
                "type": settings_type(a, !choices.is_empty()),
                "optional": defaults.get(&key).is_none_or(|v| v.is_null()),
                "choices": choices,
            }))
        })
        .collect();
    let doc = serde_json::json!({"version": env!("CARGO_PKG_VERSION"), "settings": items});
    outln!("{}", serde_json::to_string_pretty(&doc)?);
    Ok(())
}

/// The JSON type of a setting, from the type its flag parses to.
fn settings_type(a: &clap::Arg, choice: bool) -> &'static str {
    use std::any::TypeId;
    let t = a.get_value_parser().type_id();
    if choice {
        "choice"
    } else if [TypeId::of::<f32>(), TypeId::of::<f64>()].iter().any(|id| t == *id) {
        "number"
    } else if [TypeId::of::<u32>(), TypeId::of::<u64>(), TypeId::of::<usize>()]
        .iter()
        .any(|id| t == *id)
    {
        "integer"
    } else if t == TypeId::of::<bool>() {
        "boolean"
    } else {
        "string"
    }
}

fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(t) = threads {
        if t == 0 {
            bail!("--threads must be at least 1");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
            .context("setting up the thread pool")?;
    }
    Ok(())
}

/// Stop after the current pass on the first SIGINT or SIGTERM (Ctrl+C, Esc in Blender), which
/// then writes the image so far and exits 0; quit at once on the second.
fn stop_on_signals() -> Arc<AtomicBool> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let flag = Arc::new(AtomicBool::new(false));
    for (signal, code) in [(SIGINT, 130), (SIGTERM, 143)] {
        // The first registration exits only when the flag is already set (a second signal).
        let ok = signal_hook::flag::register_conditional_shutdown(signal, code, Arc::clone(&flag))
            .and_then(|_| signal_hook::flag::register(signal, Arc::clone(&flag)));
        if let Err(e) = ok {
            tracing::debug!("cannot handle signal {signal}: {e}");
        }
    }
    flag
}

/// Tell the user on the terminal, as soon as it is asked for, that the render will stop after
/// this pass. (With `--progress json` the display says it, between passes.)
fn announce_stop(flag: Arc<AtomicBool>, mode: ProgressMode) {
    if mode != ProgressMode::Auto {
        return;
    }
    std::thread::spawn(move || {
        while !flag.load(Ordering::Relaxed) {
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        eprintln!("photongrid: stopping after this pass; the image so far is kept (Ctrl+C again quits now)");
    });
}

fn render(a: RenderArgs) -> Result<()> {
    let start = Instant::now();
    set_threads(a.threads)?;
    let settings = &a.settings;
    settings.validate().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    check_outputs_before_load(&a)?;
    let stop = stop_on_signals();
    let display = Display::new(a.progress).with_stop(Arc::clone(&stop));
    announce_stop(Arc::clone(&stop), a.progress);
    let progress = Progress::new(&display);

    let phase = progress.phase("load", 0);
    let scene = load_with(
        &a.scene,
        &LoadOptions {
            allow_external_uris: a.allow_external_uris,
            memory_budget_bytes: settings.memory_limit,
        },
    )?;
    let load_seconds = phase.finish();
    for w in scene.report.approximated.iter().chain(&scene.report.ignored) {
        display.warning(&format!("{}: {w}", a.scene.display()));
    }
    let mut cameras = pipeline::select_cameras(&scene, &a.cameras)?;
    if a.cameras.is_empty() {
        cameras.truncate(1);
    }
    let outputs = plan_outputs(&a, Some(&cameras))?;
    for (o, p) in &outputs {
        paths::prepare(o).map_err(anyhow::Error::msg)?;
        if let Some(p) = p {
            paths::prepare(p).map_err(anyhow::Error::msg)?;
        }
    }

    let aovs = if a.aovs {
        AovSelection::all()
    } else {
        AovSelection::default()
    };
    let json_progress = a.progress == ProgressMode::Json;
    let mut write_checkpoint = |films: &[Film], passes: u32| -> Result<(), String> {
        for ((film, (out, _)), camera) in films.iter().zip(&outputs).zip(&cameras) {
            output::write_exr(out, film, aovs).map_err(|e| e.to_string())?;
            if json_progress {
                emit_json(
                    &serde_json::json!({"event": "checkpoint", "camera": camera.name, "path": out, "passes": passes}),
                );
            }
        }
        Ok(())
    };
    let checkpoint = a.checkpoint.map(|every| pipeline::Checkpoint {
        every,
        write: &mut write_checkpoint,
    });
    let request = RenderRequest {
        scene: &scene,
        cameras: &cameras,
        settings,
        start,
    };
    let Rendered {
        films,
        mut report,
        grids,
    } = pipeline::render(&request, &progress, checkpoint)?;
    report.seconds.load = load_seconds;
    if let Some(dir) = &a.dump_grids {
        dump_grids(dir, &grids)?;
    }
    write_films(&a, &mut report, &outputs, &films, aovs)?;
    report.seconds.total = start.elapsed().as_secs_f64();
    report.cpu_seconds = pipeline::cpu_seconds();
    print_render_summary(&a, &report);
    if let Some(path) = &a.stats {
        output::write_atomic(path, serde_json::to_string_pretty(&report)?.as_bytes())?;
    }
    Ok(())
}

/// The checks on the output paths that need no scene, before any work: none replaces an
/// input or another output, the right extensions, folders created, writable.
fn check_outputs_before_load(a: &RenderArgs) -> Result<()> {
    plan_outputs(a, None)?;
    paths::check_extension(&a.output, Format::Exr, "--output").map_err(anyhow::Error::msg)?;
    if let Some(p) = &a.png {
        paths::check_extension(p, Format::Png, "--png").map_err(anyhow::Error::msg)?;
    }
    let patterns = [Some(&a.output), a.png.as_ref(), a.stats.as_ref()];
    for p in patterns.into_iter().flatten() {
        // A {camera} in a folder name is known only once the scene is loaded.
        if !p.parent().is_some_and(|d| d.to_string_lossy().contains("{camera}")) {
            paths::prepare(&output_for(p, "camera", false)).map_err(anyhow::Error::msg)?;
        }
    }
    if let Some(dir) = &a.dump_grids {
        paths::prepare(&dir.join("plane000_counts.exr")).map_err(anyhow::Error::msg)?;
    }
    Ok(())
}

/// `--dump-grids`: the textures of the grids the estimate built.
fn dump_grids(dir: &Path, grids: &photongrid::pipeline::GridState) -> Result<()> {
    if let Some(g) = grids.paper.as_ref().and_then(|g| g.planes.as_ref()) {
        dump_plane_grids(dir, g)?;
    }
    if let Some(g) = grids.multiscale.as_ref() {
        dump_multiscale(dir, g)?;
    }
    Ok(())
}

/// `--dump-grids`: each plane's count texture before and after the wavelet step.
fn dump_plane_grids(dir: &Path, g: &photongrid::grid::PlaneGrids) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create folder", dir.display()))?;
    for (i, (raw, filtered)) in g.raw.iter().zip(&g.filtered).enumerate() {
        output::write_field_exr(&dir.join(format!("plane{i:03}_counts.exr")), raw)?;
        output::write_field_exr(&dir.join(format!("plane{i:03}_filtered.exr")), filtered)?;
    }
    Ok(())
}

/// `--dump-grids` with the multiscale estimate: per plane and layer, the photons per fine cell,
/// and (when final gathering resolved them) the irradiance gather rays read and the reach of
/// the kernel chosen at each of its texels.
fn dump_multiscale(dir: &Path, g: &photongrid::grid::multiscale::MultiscaleGrids) -> Result<()> {
    use photongrid::grid::multiscale::{CAUSTIC, DIRECT, INDIRECT, TAIL};
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create folder", dir.display()))?;
    // Each plane's frame, to place its textures in the scene: texel (x, y) of a field of
    // w × h covers origin + u·(x/w)·size_u + v·(y/h)·size_v (row y of the image).
    let frames: Vec<_> = g
        .textures
        .iter()
        .map(|tex| {
            let p = &tex[INDIRECT].plane;
            serde_json::json!({"origin": p.origin.to_array(), "u": p.u.to_array(), "v": p.v.to_array(),
                "size_u": p.size_u, "size_v": p.size_v, "normal": p.normal.to_array()})
        })
        .collect();
    let path = dir.join("planes.json");
    std::fs::write(&path, serde_json::to_string_pretty(&frames)?)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    for (i, tex) in g.textures.iter().enumerate() {
        for (layer, name) in [
            (CAUSTIC, "caustic"),
            (INDIRECT, "indirect"),
            (DIRECT, "direct"),
            (TAIL, "tail"),
        ] {
            let t = &tex[layer];
            output::write_field_exr(&dir.join(format!("plane{i:03}_{name}_counts.exr")), &t.count_field())?;
            if let Some((irradiance, reach)) = t.resolved_fields() {
                output::write_field_exr(&dir.join(format!("plane{i:03}_{name}_irradiance.exr")), &irradiance)?;
                output::write_field_exr(&dir.join(format!("plane{i:03}_{name}_kernel_reach.exr")), &reach)?;
            }
        }
    }
    Ok(())
}

/// Writes each camera's EXR (and PNG) and records the paths and the writing time in the report.
fn write_films(
    a: &RenderArgs,
    report: &mut pipeline::RenderReport,
    outputs: &[(PathBuf, Option<PathBuf>)],
    films: &[Film],
    aovs: AovSelection,
) -> Result<()> {
    for ((camera, (out, png)), film) in report.cameras.iter_mut().zip(outputs).zip(films) {
        let t = Instant::now();
        output::write_exr(out, film, aovs)?;
        if let Some(p) = png {
            output::write_png(p, film, a.exposure)?;
        }
        report.seconds.write += t.elapsed().as_secs_f64();
        if camera.nonfinite_pixels > 0 {
            tracing::warn!(
                "{}: {} pixels were not finite (NaN or infinite) and were written as 0",
                out.display(),
                camera.nonfinite_pixels
            );
        }
        camera.output = Some(out.clone());
        camera.png = png.clone();
        if a.progress == ProgressMode::Json {
            emit_json(
                &serde_json::json!({"event": "output", "camera": camera.camera, "path": out, "passes": report.passes.count}),
            );
        }
    }
    Ok(())
}

/// The closing line on the terminal, or the `done` event with `--progress json`.
fn print_render_summary(a: &RenderArgs, report: &pipeline::RenderReport) {
    let n = report.passes.count;
    match a.progress {
        ProgressMode::Auto => {
            let phases: Vec<String> = report
                .seconds
                .phases()
                .iter()
                .map(|(name, s)| format!("{name} {s:.2} s"))
                .collect();
            let stopped = if report.passes.stopped_by == Some(photongrid::render::progressive::Stop::Requested) {
                " (stopped on request)"
            } else {
                ""
            };
            eprintln!(
                "{}: {n} pass{}{stopped} · {} · total {:.2} s",
                a.scene.display(),
                if n == 1 { "" } else { "es" },
                phases.join(" · "),
                report.seconds.total
            );
            if let Some(b) = &report.budget {
                eprintln!("time budget {:.1} s: {}", b.time, b.plan.reason);
            }
        }
        ProgressMode::Json => {
            let seconds: serde_json::Map<String, serde_json::Value> = report
                .seconds
                .phases()
                .into_iter()
                .map(|(name, s)| (name.to_string(), serde_json::json!(s)))
                .collect();
            emit_json(&serde_json::json!({
                "event": "done", "passes": n, "stopped_by": report.passes.stopped_by,
                "seconds": seconds, "total": report.seconds.total,
            }));
        }
        ProgressMode::Quiet => {}
    }
}

/// The files `render` writes — per camera the EXR and the PNG, and the stats — checked before
/// any work (issue 12): each a regular-file path in an existing folder, none of them the
/// scene (however spelt, through links too), none the same file as another, and no camera
/// selected twice. Without `cameras` (before the scene is loaded) the paths are checked as
/// given, those with `{camera}` left for later.
fn plan_outputs(
    a: &RenderArgs,
    cameras: Option<&[&photongrid::scene::Camera]>,
) -> Result<Vec<(PathBuf, Option<PathBuf>)>> {
    let mut plan = output::OutputPlan::new();
    plan.input("the scene", &a.scene);
    let Some(cameras) = cameras else {
        for (what, p) in [
            ("--output", Some(&a.output)),
            ("--png", a.png.as_ref()),
            ("--stats", a.stats.as_ref()),
        ] {
            if let Some(p) = p.filter(|p| !p.to_string_lossy().contains("{camera}")) {
                plan.output(what, p)?;
            }
        }
        return Ok(Vec::new());
    };
    let mut seen = std::collections::HashMap::new();
    for c in cameras {
        if let Some(first) = seen.insert(c.index, c.name.as_str()) {
            bail!(
                "camera {} '{first}' is selected twice by --camera; select each camera once",
                c.index
            );
        }
    }
    let several = cameras.len() > 1;
    let of = |flag: &str, c: &photongrid::scene::Camera| {
        if several {
            format!("{flag} of camera {} '{}'", c.index, c.name)
        } else {
            flag.to_string()
        }
    };
    let mut outputs = Vec::new();
    for c in cameras {
        let exr = output_for(&a.output, &c.name, several);
        plan.output(of("--output", c), &exr)?;
        let png = a.png.as_ref().map(|p| output_for(p, &c.name, several));
        if let Some(p) = &png {
            plan.output(of("--png", c), p)?;
        }
        outputs.push((exr, png));
    }
    if let Some(s) = &a.stats {
        plan.output("--stats", s)?;
    }
    Ok(outputs)
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
    batch_refusals(&a, &mut units)?;
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
        return list_units(&units);
    }
    let report_path = a.report.as_deref().context("--report is required")?;
    // Its folder is created (as the images' are), and it must be writable before any render.
    paths::prepare(report_path).map_err(anyhow::Error::msg)?;
    if let Some(j) = &a.journal {
        paths::prepare(j).map_err(anyhow::Error::msg)?;
    }
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
    batch_summary(&a.jobs_file, report_path, &doc, &reports, start)
}

/// `--list`: one JSON line per unit.
fn list_units(units: &[photongrid_cli::batch::Unit]) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    for u in units {
        writeln!(out, "{}", serde_json::to_string(u)?)?;
    }
    out.flush()?;
    Ok(())
}

/// The totals, then each failed unit with the jobs file, its job and camera; an error when
/// any failed.
fn batch_summary(
    jobs_file: &Path,
    report_path: &Path,
    doc: &serde_json::Value,
    reports: &[photongrid_cli::batch::UnitReport],
    start: Instant,
) -> Result<()> {
    let t = &doc["totals"];
    eprintln!(
        "{}: {} units: {} done, {} skipped, {} failed in {:.2} s; report {}",
        jobs_file.display(),
        t["units"],
        t["done"],
        t["skipped"],
        t["failed"],
        start.elapsed().as_secs_f64(),
        report_path.display()
    );
    let failed: Vec<_> = reports
        .iter()
        .filter(|r| r.status == photongrid_cli::batch::Status::Failed)
        .collect();
    if !failed.is_empty() {
        for r in &failed {
            eprintln!(
                "failed: {} unit {} (job {}{}): {}",
                jobs_file.display(),
                r.index,
                r.job,
                r.camera.as_deref().map(|c| format!(", camera {c}")).unwrap_or_default(),
                r.error.as_deref().unwrap_or("")
            );
        }
        bail!(
            "{}: {} of {} units failed (see {})",
            jobs_file.display(),
            failed.len(),
            reports.len(),
            report_path.display()
        );
    }
    Ok(())
}

/// The files a batch reads and writes besides the units' outputs, checked before any work:
/// the report and the journal must be regular-file paths in existing folders, neither the
/// jobs file, a scene nor each other; a unit whose output or sidecar would replace the jobs
/// file, the report or the journal fails (the scenes are protected by `batch::expand` itself).
fn batch_refusals(a: &BatchArgs, units: &mut [photongrid_cli::batch::Unit]) -> Result<()> {
    let mut plan = output::OutputPlan::new();
    plan.input("the jobs file", &a.jobs_file);
    if a.report.is_some() || a.journal.is_some() {
        let mut seen = std::collections::HashSet::new();
        for u in units.iter().filter(|u| !u.scene.as_os_str().is_empty()) {
            if seen.insert(u.scene.as_path()) {
                plan.input(format!("the scene of job {}", u.job), &u.scene);
            }
        }
    }
    let mut inputs = vec![("the jobs file".to_string(), a.jobs_file.clone())];
    if let Some(r) = &a.report {
        plan.output("--report", r)?;
        inputs.push(("the report".into(), r.clone()));
    }
    if let Some(j) = &a.journal {
        plan.output("--journal", j)?;
        inputs.push(("the journal".into(), j.clone()));
    }
    photongrid_cli::batch::protect(units, &inputs);
    Ok(())
}

/// Describe each scene; with several, one that fails to load is reported and the others still
/// are (the exit status is then 1).
fn info(paths: &[PathBuf], json: bool) -> Result<()> {
    if let [path] = paths {
        let doc = info_one(path, json)?;
        if json {
            outln!("{}", serde_json::to_string_pretty(&doc)?);
        }
        return Ok(());
    }
    let mut docs = Vec::new();
    let mut failed = Vec::new();
    for path in paths {
        match info_one(path, json) {
            Ok(doc) => docs.push(doc),
            Err(e) => {
                let message = error_message(&e);
                if json {
                    docs.push(serde_json::json!({"scene": path, "error": message}));
                } else {
                    eprintln!("error: {message}");
                }
                failed.push(path.display().to_string());
            }
        }
        if !json {
            outln!();
        }
    }
    if json {
        outln!("{}", serde_json::to_string_pretty(&serde_json::Value::Array(docs))?);
    }
    if !failed.is_empty() {
        bail!(
            "{} of {} scenes could not be read: {}",
            failed.len(),
            paths.len(),
            failed.join(", ")
        );
    }
    Ok(())
}

/// One scene: printed as text, or returned as JSON (`Value::Null` when printed).
fn info_one(path: &Path, json: bool) -> Result<serde_json::Value> {
    use photongrid_cli::info::{camera_json, describe};
    let scene = photongrid::load(path)?;
    let r = &scene.report;
    if json {
        let mut report = serde_json::to_value(r)?;
        report["cameras"] = scene.cameras.iter().map(camera_json).collect();
        return Ok(serde_json::json!({
            "scene": path,
            "triangles": scene.triangles.len(),
            "surface_area_m2": scene.surface_area(),
            "bounds": scene.bounds,
            "has_specular": scene.has_specular(),
            "report": report,
        }));
    }
    outln!("{}", path.display());
    outln!(
        "  triangles: {} ({} degenerate skipped), surface {:.3} m²",
        scene.triangles.len(),
        r.degenerate_triangles,
        scene.surface_area()
    );
    outln!(
        "  bounds: {:.3?} – {:.3?}",
        scene.bounds.min.to_array(),
        scene.bounds.max.to_array()
    );
    let section = |title: &str, items: &[String]| {
        outln!("  {title}: {}", if items.is_empty() { "none" } else { "" });
        for i in items {
            outln!("    - {i}");
        }
    };
    section("materials", &r.materials);
    section("lights", &r.lights);
    let cameras: Vec<String> = scene
        .cameras
        .iter()
        .map(|c| format!("{} '{}': {}", c.index, c.name, describe(c)))
        .collect();
    section("cameras", &cameras);
    section("approximated", &r.approximated);
    section("ignored", &r.ignored);
    outln!(
        "  caustics possible (glass or mirror present): {}",
        if scene.has_specular() { "yes" } else { "no" }
    );
    info_grids(&scene);
    Ok(serde_json::Value::Null)
}

/// `info`'s grids: the planes the adaptive method's grids and the multiscale textures get.
fn info_grids(scene: &photongrid::scene::Scene) {
    let set = photongrid::grid::PlaneGrids::detect(&scene.triangles, Settings::default().grid_res);
    let on_plane = set
        .plane_of_triangle
        .iter()
        .filter(|p| **p != photongrid::grid::planes::NO_PLANE)
        .count();
    outln!(
        "  planes (grids for --method adaptive): {} ({} of {} triangles; the rest use kNN or voxels)",
        set.planes.len(),
        on_plane,
        scene.triangles.len()
    );
    let receivers = photongrid::grid::PlaneGrids::detect_receivers(scene, Settings::default().grid_res);
    outln!(
        "  multiscale textures (--method multiscale, the default): {} planes (mirrors and glass excluded); \
         each gets four (caustic, indirect and direct light, and indirect light too deep for final gathering) with fine cells sized from the first pass's photons \
         (about --cell-photons photons per cell where that light is densest, 8 to 2048 cells along a side, within \
         --grid-cells) and a pyramid of coarser kernels, from which each point takes the widest that agrees with \
         every finer one; the sizes and the kernels chosen are known after the first pass: --stats (grids.choice) \
         and --dump-grids. Surfaces on no plane use nested kNN discs of the photon map, each divided by the \
         receiving surface inside it where the map holds global light (no final gathering).",
        receivers.planes.len()
    );
    let grids = photongrid::grid::Grids::build(scene, &[], &[], &(&Settings::default()).into());
    outln!("  grids chosen by --grid auto (the default):");
    for c in &grids.choice {
        outln!("    - {c}");
    }
    for (i, p) in set.planes.iter().enumerate() {
        outln!(
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
        outln!("{}", serde_json::to_string(&s)?);
    } else {
        let f = |v: Option<f64>| v.map(|v| format!("{v:.4}")).unwrap_or_else(|| "n/a".into());
        outln!("mean_lum_ratio        {}", f(s.mean_lum_ratio));
        outln!(
            "rgb_mean_ratio        {:.4} {:.4} {:.4}",
            s.rgb_mean_ratio[0],
            s.rgb_mean_ratio[1],
            s.rgb_mean_ratio[2]
        );
        outln!("rel_rmse              {}", f(s.rel_rmse));
        outln!("block_rel_rmse        {}  (block {})", f(s.block_rel_rmse), s.block);
        outln!("block_frac_off_10pct  {}", f(s.block_frac_off_10pct));
        outln!("nonfinite_pixels      {}", s.nonfinite_pixels);
        outln!("pixels_scored         {}", s.pixels_scored);
    }
    Ok(())
}
