//! The orchestrator: one [`RenderRequest`] in, films and one typed [`RenderReport`] out. It
//! runs the stages in order — BVH → photons (with grids and precomputed irradiance where the
//! estimate needs them) → photon index → camera pass — for as many progressive passes as the
//! settings' budget allows, timing each phase. The command line, batch jobs and the bench all
//! render through [`render`], so what is measured is what users run.

use crate::accel::Accel;
use crate::estimate::{Accumulation, Estimator, Gammas, IrradianceCache, PassGrids, PhotonMap, Surfaces};
use crate::film::Film;
use crate::grid::multiscale::{Emitted, MultiscaleGrids, MultiscaleParams, Probes, DIRECT, INDIRECT};
use crate::grid::PlaneGrids;
use crate::grid::{GridParams, Grids};
use crate::photon::{trace_photons, Photon, PhotonKind, PhotonStats, Sequences, TraceSettings};
use crate::progress::Progress;
use crate::render::budget::{corrected, plan, Costs, PassSize, Plan, Stage, GATHER_LADDER};
use crate::render::progressive::{Accumulator, Budget, Stop};
use crate::render::{CameraPass, Cut, PhotonData, RenderSettings, Spare};
use crate::sampling::pass_seed;
use crate::scene::{Camera, Scene};
use crate::settings::{DirectLighting, Settings, SettingsError};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::atomic::AtomicU64;
use std::time::{Duration, Instant};

/// Why a render could not run.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// A setting is out of range.
    #[error("invalid settings: {0}")]
    Settings(#[from] SettingsError),
    /// The photon count would not fit in memory.
    #[error("{photons} photons (plus {caustic} caustic-pass paths) need at least {needed_gib:.1} GiB but only {available_gib:.1} GiB is available; use --photons {suggest} or fewer")]
    TooManyPhotons {
        /// Requested photons.
        photons: usize,
        /// Requested caustic-pass paths.
        caustic: usize,
        /// Lower bound of the memory needed.
        needed_gib: f64,
        /// Memory available.
        available_gib: f64,
        /// A count that fits.
        suggest: usize,
    },
    /// The render's memory estimate is over the limit ([`crate::memory`]).
    #[error("{0}")]
    Memory(#[from] crate::memory::MemoryError),
    /// The scene has no camera.
    #[error("{0}: the scene has no camera: export one (Blender: Include > Cameras)")]
    NoCamera(String),
    /// The requested camera does not exist.
    #[error("{0}")]
    UnknownCamera(String),
    /// Writing a checkpoint image failed.
    #[error("checkpoint: {0}")]
    Checkpoint(String),
}

/// Seconds spent in each phase.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PhaseTimes {
    /// Reading and validating the file.
    pub load: f64,
    /// Building the BVH.
    pub bvh: f64,
    /// Measuring the scene's costs to size the passes of a time budget.
    pub probe: f64,
    /// Tracing photons.
    pub photons: f64,
    /// Plane detection, counting and wavelet filtering (adaptive method).
    pub grids: f64,
    /// Precomputing irradiance for final gathering.
    pub irradiance: f64,
    /// Building the photon index.
    pub build: f64,
    /// Camera pass (all cameras).
    pub render: f64,
    /// Writing outputs.
    pub write: f64,
    /// Wall time of everything.
    pub total: f64,
}

impl PhaseTimes {
    /// The phases that took time, in pipeline order, with their seconds (for summaries).
    pub fn phases(&self) -> Vec<(&'static str, f64)> {
        [
            ("load", self.load),
            ("bvh", self.bvh),
            ("probe", self.probe),
            ("photons", self.photons),
            ("grids", self.grids),
            ("irradiance", self.irradiance),
            ("build", self.build),
            ("render", self.render),
            ("write", self.write),
        ]
        .into_iter()
        .filter(|(_, s)| *s > 0.0)
        .collect()
    }
}

/// What to render: cameras of a loaded scene with settings. The budget's clock (`--time`)
/// runs from `start`.
pub struct RenderRequest<'a> {
    /// The scene.
    pub scene: &'a Scene,
    /// The cameras, in output order; every pass's photons serve all of them.
    pub cameras: &'a [&'a Camera],
    /// The settings.
    pub settings: &'a Settings,
    /// When the time budget started (the process start for the command line).
    pub start: Instant,
}

/// How the passes went.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PassReport {
    /// Passes that ran.
    pub count: u32,
    /// Why they stopped.
    pub stopped_by: Option<Stop>,
    /// Seconds of each pass (photons and every camera).
    pub seconds: Vec<f64>,
    /// Checkpoint images written between passes.
    pub checkpoints: u32,
    /// Passes given up at the time budget's deadline (their work is lost).
    #[serde(default)]
    pub dropped: u32,
    /// Samples per pixel a pass cut at the deadline gave up (it keeps the ones it completed),
    /// summed over cameras.
    #[serde(default)]
    pub samples_cut: u32,
    /// Samples per pixel the last pass added beyond its own in the time before the deadline
    /// that no further pass would use ([`crate::render::Spare`]).
    #[serde(default)]
    pub samples_spare: u32,
}

/// Memory use.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MemoryReport {
    /// Peak resident memory of the process (Linux), if known.
    pub peak_bytes: Option<u64>,
    /// The largest pass's photon map.
    pub photon_map_bytes: usize,
    /// The BVH.
    pub bvh_bytes: usize,
    /// The grids.
    pub grids_bytes: usize,
    /// The estimate checked against the memory limit before any work ([`crate::memory`]).
    #[serde(default)]
    pub estimated_bytes: u64,
}

/// One camera's image.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraReport {
    /// Camera name.
    pub camera: String,
    /// glTF camera index.
    pub index: usize,
    /// Resolution.
    pub width: u32,
    /// Resolution.
    pub height: u32,
    /// Seconds of this camera's passes.
    pub render_seconds: f64,
    /// Mean radiance per channel.
    pub mean_rgb: [f64; 3],
    /// Pixels that are NaN or infinite.
    pub nonfinite_pixels: usize,
    /// Pixels at the outline of an emitter in view, whose directly seen emission took
    /// `render::emitter_edges::EDGE_RAYS` emission-only rays per sample (0 under SPPM).
    #[serde(default)]
    pub emitter_edge_pixels: usize,
    /// Where the caller wrote the image.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub output: Option<PathBuf>,
    /// Where the caller wrote a preview.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub png: Option<PathBuf>,
}

/// What the wavelet step did on one plane.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PlaneReport {
    /// Cells along u and v.
    pub cells: [usize; 2],
    /// Mean count before filtering.
    pub mean_before: f64,
    /// Mean count after filtering (the paper's "brightening" if it differs).
    pub mean_after: f64,
    /// Noise σ estimated from the finest band.
    pub sigma: f64,
    /// Share of detail coefficients kept.
    pub kept_fraction: f64,
}

/// The grids chosen and what their filtering did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GridReport {
    /// What was chosen and why.
    pub choice: Vec<String>,
    /// Memory of the grids.
    pub memory_bytes: usize,
    /// Per plane (when plane grids were built).
    pub planes: Option<Vec<PlaneReport>>,
}

impl GridReport {
    fn of(state: &GridState) -> Option<Self> {
        let mut report = state.paper.as_ref().map(GridReport::of_paper).unwrap_or_default();
        if let Some(m) = &state.multiscale {
            report.choice.push(format!(
                "multiscale: {} planes (mirrors and glass excluded), {:.1} MB; {}",
                m.textures.len(),
                m.memory_bytes() as f64 / 1e6,
                if m.stratified {
                    "every light is a point, spot or sun: direct and caustic photons land from stratified points (--stratified-ici-threshold, --stratified-caustic-ici-threshold)"
                } else {
                    "a light has area: direct and caustic photons land about as unevenly as independent ones (--ici-threshold, --caustic-ici-threshold)"
                }
            ));
            report.choice.extend(m.describe());
            report.choice.extend(m.bright.as_ref().map(|b| b.describe()));
            report.memory_bytes += m.memory_bytes();
        }
        (state.paper.is_some() || state.multiscale.is_some()).then_some(report)
    }

    fn of_paper(g: &Grids) -> Self {
        GridReport {
            choice: g.choice.clone(),
            memory_bytes: g.memory_bytes(),
            planes: g.planes.as_ref().map(|p| {
                p.reports
                    .iter()
                    .zip(&p.set.planes)
                    .map(|(r, pl)| PlaneReport {
                        cells: [pl.res_u, pl.res_v],
                        mean_before: r.mean_before,
                        mean_after: r.mean_after,
                        sigma: r.sigma as f64,
                        kept_fraction: r.kept_fraction as f64,
                    })
                    .collect()
            }),
        }
    }
}

/// Everything a render reports: the stats file of `--stats`, batch sidecars and bench records.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RenderReport {
    /// The scene file.
    pub scene: PathBuf,
    /// Renderer version.
    pub version: String,
    /// The settings used.
    pub settings: Settings,
    /// Worker threads.
    pub threads: usize,
    /// Seconds per phase (`load`, `write` and `total` are set by the caller).
    pub seconds: PhaseTimes,
    /// Photon counts, summed over passes.
    pub photons: PhotonStats,
    /// Passes.
    pub passes: PassReport,
    /// CPU seconds of the process so far (Linux), if known.
    pub cpu_seconds: Option<f64>,
    /// Memory.
    pub memory: MemoryReport,
    /// One entry per camera, in request order.
    pub cameras: Vec<CameraReport>,
    /// The grids, when the estimate used them.
    pub grids: Option<GridReport>,
    /// What the loader approximated, one entry per material or light and feature
    /// (`materials[i] 'Name': what`), so that a stats reader sees what the image is not.
    #[serde(default)]
    pub approximations: Vec<String>,
    /// How a time budget sized the passes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub budget: Option<BudgetReport>,
}

impl RenderReport {
    fn started(scene: &Scene, settings: &Settings) -> Self {
        RenderReport {
            scene: scene.source.clone(),
            version: env!("CARGO_PKG_VERSION").to_string(),
            settings: settings.clone(),
            threads: rayon::current_num_threads(),
            approximations: scene.report.approximated.clone(),
            ..RenderReport::default()
        }
    }
}

/// The images and the report of a render, and the grids for inspection (`--dump-grids`).
pub struct Rendered {
    /// One image per camera, in request order.
    pub films: Vec<Film>,
    /// The report.
    pub report: RenderReport,
    /// The accumulated grids, those the estimate built.
    pub grids: GridState,
}

/// Writes the images so far while passes run (`--checkpoint`).
pub struct Checkpoint<'a> {
    /// Seconds between writes (0: after every pass but the last).
    pub every: f64,
    /// Write the films (one per camera, in order) after `passes` passes.
    pub write: &'a mut WriteFilms<'a>,
}

/// [`Checkpoint::write`]: writes the films (one per camera, in order) after a number of
/// passes, or says why it could not.
pub type WriteFilms<'a> = dyn FnMut(&[Film], u32) -> Result<(), String> + 'a;

/// Stored photons per emitted path is at least about one in a closed scene; 24 bytes each,
/// held once (the index sorts them in place), plus the sort's 4-byte input index and the cell
/// offsets.
const MIN_BYTES_PER_PHOTON: f64 = 32.0;

fn available_memory_bytes() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = s.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// Peak resident memory of this process in bytes (Linux), if known.
pub fn peak_memory_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// CPU seconds (user + system, all threads) this process has used so far (Linux), if known.
/// Less sensitive than wall time to other work on a shared machine.
pub fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may contain spaces) start after the last ')'.
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = f.get(11)?.parse().ok()?;
    let stime: f64 = f.get(12)?.parse().ok()?;
    Some((utime + stime) / 100.0) // USER_HZ is 100 on Linux
}

/// Refuse photon counts (global paths plus caustic-pass paths) that cannot fit, before
/// spending minutes finding out.
pub fn check_photon_memory(photons: usize, caustic: usize) -> Result<(), RenderError> {
    let total = photons.saturating_add(caustic);
    let needed = total as f64 * MIN_BYTES_PER_PHOTON;
    let available = available_memory_bytes()
        .unwrap_or(f64::INFINITY)
        .min(u32::MAX as f64 * MIN_BYTES_PER_PHOTON);
    if total > u32::MAX as usize / 2 || needed > available {
        let gib = (1u64 << 30) as f64;
        return Err(RenderError::TooManyPhotons {
            photons,
            caustic,
            needed_gib: needed / gib,
            available_gib: available / gib,
            suggest: ((available / MIN_BYTES_PER_PHOTON) as usize / 4)
                .min(u32::MAX as usize / 2)
                .saturating_sub(caustic)
                .max(1),
        });
    }
    Ok(())
}

/// Caustic-pass paths for `scene`: none when it has no mirror or glass to aim at, or when no
/// photons at all are asked for.
fn caustic_photons(scene: &Scene, settings: &Settings) -> usize {
    if scene.has_specular() && settings.photons > 0 {
        settings.caustic_photons
    } else {
        0
    }
}

/// Render the request's cameras progressively: passes of `settings.photons` new photons (seed
/// [`pass_seed`] of the pass) and `settings.spp` new samples per pixel, accumulated per camera,
/// until `settings.passes` passes ran or the next pass would end after `settings.time` seconds
/// counted from `request.start` ([`Budget`]; neither given: one pass), or the progress observer
/// asks to stop ([`Progress::should_stop`], polled between passes). With a time budget the
/// passes are sized by a probe first ([`plan_passes`]) and a camera pass still running at the
/// deadline keeps the sweeps it completed (none: dropped; the first always keeps one). The same seed and pass count give the same images whatever the thread
/// count. Each pass's photons serve every camera, then are dropped. `checkpoint` writes the
/// images so far every `every` seconds, except after the last pass (the caller writes the
/// final images).
pub fn render(
    request: &RenderRequest<'_>,
    progress: &Progress<'_>,
    mut checkpoint: Option<Checkpoint<'_>>,
) -> Result<Rendered, RenderError> {
    let RenderRequest {
        scene,
        cameras,
        settings,
        start,
    } = *request;
    settings.validate()?;
    check_photon_memory(settings.photons, caustic_photons(scene, settings))?;
    let estimate = crate::memory::check_render(scene, cameras, settings)?;
    let mut report = RenderReport::started(scene, settings);
    let accel = build_accel(scene, progress, &mut report.seconds);
    let deadline = settings
        .time
        .map(|t| start + Duration::from_secs_f64(deadline_seconds(t)));
    let pass_settings = match settings.time {
        Some(t) => {
            let left = deadline_seconds(t) - start.elapsed().as_secs_f64();
            let plan = plan_passes(scene, &accel, cameras, settings, left, progress, &mut report.seconds);
            report.budget.insert(plan).plan.size.apply(settings)
        }
        None => settings.clone(),
    };
    let budget = Budget {
        passes: settings.passes,
        time: settings.time.map(deadline_seconds),
    };
    let mut run = PassLoop::new(scene, &accel, cameras, pass_settings, deadline);
    let (mut last, mut last_checkpoint) = (0.0f64, Instant::now());
    let stop = loop {
        let done = report.passes.count;
        if done > 0 && progress.should_stop() {
            break Stop::Requested;
        }
        if let Err(stop) = budget.next(done, start.elapsed().as_secs_f64(), last) {
            let left = budget.time.unwrap_or(0.0) - start.elapsed().as_secs_f64();
            if stop != Stop::Time || run.fill(report.budget.as_mut(), left, last).is_none() {
                break stop;
            }
        }
        let t = Instant::now();
        let before = report.seconds.clone();
        let complete = run.pass(done, progress, &mut report);
        last = t.elapsed().as_secs_f64();
        if report.passes.dropped == 0 {
            report.passes.seconds.push(last);
            report.passes.count += 1;
        }
        if !complete || run.filled {
            break Stop::Time;
        }
        if let (0, Some(b)) = (done, report.budget.as_mut()) {
            let left = budget.time.unwrap_or(0.0) - start.elapsed().as_secs_f64();
            if let Some(next) = run.replan(b, left, &before, &report.seconds) {
                last = next;
            }
        }
        tracing::info!(pass = done + 1, seconds = format!("{last:.3}"), "pass done");
        if let Some(cp) = checkpoint.as_mut() {
            let more = !progress.should_stop() && budget.next(done + 1, start.elapsed().as_secs_f64(), last).is_ok();
            if more && last_checkpoint.elapsed().as_secs_f64() >= cp.every {
                let tw = Instant::now();
                (cp.write)(&run.films(), done + 1).map_err(RenderError::Checkpoint)?;
                report.seconds.write += tw.elapsed().as_secs_f64();
                report.passes.checkpoints += 1;
                last_checkpoint = Instant::now();
            }
        }
    };
    report.passes.stopped_by = Some(stop);
    report.memory.estimated_bytes = estimate.total();
    Ok(run.finish(report))
}

/// Seconds after the start by which the passes of a `time`-second budget must end: what is
/// left is for writing the images.
pub fn deadline_seconds(time: f64) -> f64 {
    time - (WRITE_RESERVE_SECONDS + WRITE_RESERVE_SHARE * time).min(0.5 * time)
}

/// Time kept for writing outputs after the last pass: a fixed part and a share of the budget.
const WRITE_RESERVE_SECONDS: f64 = 0.15;
const WRITE_RESERVE_SHARE: f64 = 0.01;

/// The passes of one render: every camera's accumulated image and the grids, for one pass
/// size.
struct PassLoop<'a> {
    scene: &'a Scene,
    accel: &'a Accel,
    cameras: &'a [&'a Camera],
    settings: Settings,
    deadline: Option<Instant>,
    /// Weight of the next pass in each camera's average (1 for a regular pass).
    weight: f32,
    /// The next pass is the smaller last one of a time budget.
    filled: bool,
    accs: Vec<Accumulator>,
    render_seconds: Vec<f64>,
    grids: GridState,
    /// The surfaces under the estimate's discs (their measurements kept over passes).
    surfaces: Surfaces<'a>,
    /// Final-gather rays per pixel over the passes so far.
    gather_rays: f32,
    /// Where the next pass's photons start in the emitting sequences.
    sequences: Sequences,
}

impl<'a> PassLoop<'a> {
    fn new(
        scene: &'a Scene,
        accel: &'a Accel,
        cameras: &'a [&'a Camera],
        settings: Settings,
        deadline: Option<Instant>,
    ) -> Self {
        let accumulation = settings.method.needs().accumulation;
        let accs = cameras
            .iter()
            .map(|c| {
                let (w, h) = resolution(c, &settings);
                Accumulator::new(accumulation, w, h, settings.spp)
            })
            .collect();
        let surfaces = Surfaces::new(scene, accel, &settings);
        PassLoop {
            scene,
            accel,
            cameras,
            deadline,
            weight: 1.0,
            filled: false,
            accs,
            render_seconds: vec![0.0; cameras.len()],
            grids: GridState::default(),
            surfaces,
            gather_rays: 0.0,
            sequences: Sequences::starting(settings.seed),
            settings,
        }
    }

    /// Trace pass `done`'s photons and add the pass to every camera. False when a camera's
    /// pass ran into the deadline: cut after its first sweeps (`samples_cut`) or dropped
    /// (`dropped`; never the first pass's first sweep: it is the image).
    fn pass(&mut self, done: u32, progress: &Progress<'_>, report: &mut RenderReport) -> bool {
        let started = Instant::now();
        let (scene, accel, settings) = (self.scene, self.accel, &self.settings);
        let times = &mut report.seconds;
        let at = (done, self.sequences);
        let photons = trace_pass(scene, accel, settings, at, &mut self.grids, progress, times);
        self.sequences = self.sequences.after(&photons.stats);
        report.memory.photon_map_bytes = report.memory.photon_map_bytes.max(photons.map.memory_bytes());
        self.gather_rays += settings.spp as f32 * settings.effective_gather() as f32;
        let input = PhotonData {
            estimator: Estimator::for_pass(settings, done, &photons.map, self.grids.view(), &self.surfaces)
                .with_gather_rays(self.gather_rays),
            irradiance: photons.irradiance.as_ref(),
        };
        // After the first pass (whose successors are sized for the time it leaves) and without
        // a pass count (which asks for that many passes, no more), the last camera takes spare
        // sweeps where no pass of this size fits in the time left: a smaller last pass of one
        // sample per pixel made the image worse on some scenes (docs/time_budget.md).
        let spare = (done > 0 && settings.passes.is_none()).then_some(Spare {
            since: started,
            max: settings.spp.max(1),
        });
        let last = self.cameras.len().saturating_sub(1);
        let mut complete = true;
        for (i, (camera, acc)) in self.cameras.iter().zip(&mut self.accs).enumerate() {
            let cut = Cut {
                deadline: self.deadline,
                required: u32::from(done == 0),
                spare: spare.filter(|_| i == last),
            };
            let job = PassJob {
                pass: done,
                cut,
                weight: self.weight,
            };
            let (seconds, samples) = render_pass(scene, accel, input, job, camera, settings, acc, progress);
            self.render_seconds[i] += seconds;
            times.render += seconds;
            let spp = settings.spp.max(1);
            if samples == 0 {
                // A dropped pass's photons are in no image: not reported as emitted.
                report.passes.dropped = 1;
                return false;
            }
            if samples < spp {
                report.passes.samples_cut += spp - samples;
                complete = false;
            }
            report.passes.samples_spare += samples.saturating_sub(spp);
        }
        report.photons.add(&photons.stats);
        complete
    }

    /// Make the next pass a smaller last one that fits in the `left` seconds, when the regular
    /// pass (which took `last` seconds) does not ([`crate::render::budget::fill`]); its weight
    /// in the averages is its predicted share of a regular pass. Not for SPPM, whose passes
    /// must all have the same samples.
    fn fill(&mut self, budget: Option<&mut BudgetReport>, left: f64, last: f64) -> Option<()> {
        let budget = budget?;
        if self.settings.method.needs().accumulation != Accumulation::Average {
            return None;
        }
        let (costs, regular) = budget.current();
        let predicted = costs.pass_seconds(&regular);
        let size = crate::render::budget::fill(costs, left, regular, predicted, last)?;
        self.weight *= (costs.pass_seconds(&size) / predicted) as f32;
        self.settings = size.apply(&self.settings);
        self.filled = true;
        budget.fill = Some(size);
        Some(())
    }

    /// After the first pass of a time budget: size the next passes for the `left` seconds with
    /// the costs the first pass measured (phase times `before` and `after` it); their weight in
    /// the averages is their predicted share of the first. Returns the next pass's predicted
    /// seconds. Not for SPPM, whose passes must all have the same samples.
    fn replan(&mut self, budget: &mut BudgetReport, left: f64, before: &PhaseTimes, after: &PhaseTimes) -> Option<f64> {
        if self.settings.method.needs().accumulation != Accumulation::Average {
            return None;
        }
        let photon_side = |s: &PhaseTimes| s.photons + s.grids + s.irradiance + s.build;
        let photon_seconds = photon_side(after) - photon_side(before);
        let first = budget.plan.size;
        let costs = corrected(&budget.costs, &first, photon_seconds, after.render - before.render);
        let stage = Stage::After {
            gather: first.gather,
            spp: first.spp,
        };
        let plan = plan(&costs, left, budget.requested, stage);
        self.weight = (costs.pass_seconds(&plan.size) / costs.pass_seconds(&first)) as f32;
        self.settings = plan.size.apply(&self.settings);
        let next = plan.predicted_pass_seconds;
        budget.replan = Some(Replan { costs, plan });
        Some(next)
    }

    fn films(&self) -> Vec<Film> {
        self.accs.iter().map(Accumulator::film).collect()
    }

    /// The images and the report's per-camera, memory and grid parts.
    fn finish(self, mut report: RenderReport) -> Rendered {
        let films = self.films();
        report.cameras = self
            .cameras
            .iter()
            .zip(&films)
            .zip(self.render_seconds)
            .zip(&self.accs)
            .map(|(((c, f), render_seconds), acc)| CameraReport {
                camera: c.name.clone(),
                index: c.index,
                width: f.width,
                height: f.height,
                render_seconds,
                mean_rgb: f.mean(),
                nonfinite_pixels: f.nonfinite(),
                emitter_edge_pixels: acc.emitter_edge_pixels(),
                output: None,
                png: None,
            })
            .collect();
        report.memory.bvh_bytes = self.accel.memory_bytes();
        report.memory.grids_bytes = self.grids.memory_bytes();
        report.memory.peak_bytes = peak_memory_bytes();
        report.grids = GridReport::of(&self.grids);
        report.cpu_seconds = cpu_seconds();
        Rendered {
            films,
            report,
            grids: self.grids,
        }
    }
}

/// Photon paths of a probe pass: this share of the requested ones, at least [`PROBE_MIN_PATHS`].
const PROBE_SHARE: usize = 32;
const PROBE_MIN_PATHS: usize = 10_000;
/// A camera sample costs more with a pass's full photon map than with the probe's sparse one
/// (larger maps miss the caches): the first pass's measured camera seconds over the probe's
/// prediction, median over the public cameras (docs/time_budget.md).
const PROBE_CAMERA_BIAS: f64 = 1.3;
/// The probe's camera pass renders this many times fewer pixels along each axis.
const PROBE_SHRINK: u32 = 8;
/// Timed runs of the probe's camera pass (after a warm-up), of which the median is taken.
const PROBE_CAMERA_RUNS: usize = 3;

/// The median of a few measurements.
fn median_of<const N: usize>(mut v: [f64; N]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[N / 2]
}

/// What the time budget decided: the probe's measurements, the plan, and the deadline.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BudgetReport {
    /// The budget asked for.
    pub time: f64,
    /// When passes must have ended (the rest is for writing images).
    pub deadline: f64,
    /// Costs the probe measured.
    pub costs: Costs,
    /// The pass the settings ask for.
    pub requested: PassSize,
    /// Size of the first pass and why.
    pub plan: Plan,
    /// The passes after the first, sized with the costs it measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replan: Option<Replan>,
    /// The smaller last pass that filled the time a regular one would have overrun.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fill: Option<PassSize>,
}

/// The passes after the first of a time budget.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Replan {
    /// The probe's costs corrected by the first pass's photon and camera seconds.
    pub costs: Costs,
    /// Their size and why.
    pub plan: Plan,
}

impl BudgetReport {
    /// The costs and pass size in force now.
    fn current(&self) -> (&Costs, PassSize) {
        match &self.replan {
            Some(r) => (&r.costs, r.plan.size),
            None => (&self.costs, self.plan.size),
        }
    }
}

/// Measure this scene's costs with a small pass (few photons, a low-resolution camera pass
/// with and without final gathering, grids and images thrown away), then size the passes for
/// the `left` seconds ([`plan`]).
pub fn plan_passes(
    scene: &Scene,
    accel: &Accel,
    cameras: &[&Camera],
    settings: &Settings,
    left: f64,
    progress: &Progress<'_>,
    times: &mut PhaseTimes,
) -> BudgetReport {
    let requested = PassSize::of(settings, caustic_photons(scene, settings));
    let costs = probe_costs(scene, accel, cameras, settings, requested, progress);
    let requested = requested.for_budget(&costs, left - costs.probe_seconds);
    let requested = crate::memory::photons_within_limit(scene, cameras, settings, requested);
    times.probe += costs.probe_seconds;
    let plan = plan(&costs, left - costs.probe_seconds, requested, Stage::First);
    tracing::info!(reason = plan.reason.as_str(), "pass size");
    let time = settings.time.unwrap_or(0.0);
    if plan.over_budget {
        tracing::warn!(
            "a time budget of {time:.1} s is too short for this scene: one pass of the smallest size is predicted to \
             take {:.1} s, so the render will end late; give --time {:.0} or more, or fewer pixels (--width/--height)",
            plan.predicted_pass_seconds,
            (time - left + costs.probe_seconds + plan.predicted_pass_seconds).ceil()
        );
    }
    BudgetReport {
        time,
        deadline: deadline_seconds(time),
        requested,
        costs,
        plan,
        replan: None,
        fill: None,
    }
}

/// Wall seconds per global and per caustic photon path, from a probe pass: each kind's
/// tracing time, plus the time after tracing (irradiance, index) shared by stored photons.
fn path_costs(stats: &PhotonStats, times: &PhaseTimes, probe: &PassSize) -> (f64, f64) {
    let traced = stats.global_seconds + stats.caustic_seconds;
    let rest = (times.photons - traced).max(0.0) + times.irradiance + times.build;
    let caustic_share = stats.caustic as f64 / stats.stored.max(1) as f64;
    let per = |seconds: f64, paths: usize| if paths > 0 { seconds / paths as f64 } else { 0.0 };
    (
        per(stats.global_seconds + rest * (1.0 - caustic_share), probe.photons),
        per(stats.caustic_seconds + rest * caustic_share, probe.caustic_photons),
    )
}

/// The probe's pass: a [`PROBE_SHARE`]th of the `requested` photons (at least
/// [`PROBE_MIN_PATHS`]), one sample per pixel, the requested gather rays.
fn probe_size(requested: PassSize) -> PassSize {
    let small = |n: usize| {
        if n == 0 {
            0
        } else {
            (n / PROBE_SHARE).max(PROBE_MIN_PATHS.min(n))
        }
    };
    PassSize {
        photons: small(requested.photons),
        caustic_photons: small(requested.caustic_photons),
        spp: 1,
        gather: requested.gather,
    }
}

/// The gather rays per pixel the `probe` pass is read with: the `requested` pass's, scaled by
/// the probe's share of its photons. With its few photons at its own rays the probe would
/// gather almost everywhere; so it gathers where the pass it times will
/// ([`crate::estimate::multiscale::photons_suffice`]).
fn probe_gather_rays(probe: PassSize, requested: PassSize) -> f32 {
    let share = probe.photons as f32 / requested.photons.max(1) as f32;
    requested.spp as f32 * requested.gather as f32 * share
}

/// The probe of [`plan_passes`]: a pass of a small share of the `requested` photons, then each
/// camera at a reduced resolution without and with final gathering, each timed.
fn probe_costs(
    scene: &Scene,
    accel: &Accel,
    cameras: &[&Camera],
    settings: &Settings,
    requested: PassSize,
    progress: &Progress<'_>,
) -> Costs {
    let t0 = Instant::now();
    let probe = probe_size(requested);
    let probe_settings = probe.apply(settings);
    let (mut scratch, mut grids) = (PhaseTimes::default(), GridState::default());
    let photons = trace_pass(
        scene,
        accel,
        &probe_settings,
        (u32::MAX, Sequences::starting(pass_seed(settings.seed, u32::MAX))),
        &mut grids,
        progress,
        &mut scratch,
    );
    let surfaces = Surfaces::new(scene, accel, &probe_settings);
    let input = PhotonData {
        estimator: Estimator::for_pass(&probe_settings, 0, &photons.map, grids.view(), &surfaces),
        irradiance: photons.irradiance.as_ref(),
    };
    let camera = CameraProbe::run(
        scene,
        accel,
        cameras,
        &probe_settings,
        input,
        probe_gather_rays(probe, requested),
    );
    let per_ray = camera.per_gather_ray();
    let (per_path, per_caustic_path) = path_costs(&photons.stats, &scratch, &probe);
    Costs {
        per_pass: scratch.grids,
        per_path,
        per_caustic_path,
        caustic_share: photons.stats.caustic_power / photons.stats.stored_power.max(f64::MIN_POSITIVE),
        plane_share: grids.multiscale.as_ref().map_or(0.0, |g| {
            let global = (photons.stats.direct + photons.stats.indirect).max(1) as f64;
            (g.photons_counted(DIRECT) + g.photons_counted(INDIRECT)) / global
        }),
        per_sample: PROBE_CAMERA_BIAS * camera.plain / camera.samples.max(1) as f64,
        per_gather_ray: per_ray[0],
        per_gather_ray_sparser: std::array::from_fn(|i| per_ray[i + 1]),
        photons_per_gather_ray: if camera.ladder {
            requested.photons as f64 / (requested.spp * requested.gather) as f64
        } else {
            0.0
        },
        prior_photons: 0.0,
        prior_gather_rays: 0.0,
        pixels: camera.pixels,
        probe_seconds: t0.elapsed().as_secs_f64(),
    }
}

/// What the probe's camera passes measured, over all cameras.
struct CameraProbe {
    /// Pixels of the full-size cameras.
    pixels: u64,
    /// Camera samples of a timed pass.
    samples: u64,
    /// Gather rays per sample.
    gather: u32,
    /// Seconds without gathering and with it, the estimate read at the fewest photons per
    /// gather ray both times (their difference is gathering's).
    plain: f64,
    gathered: f64,
    /// Whether the points that gather depend on the photons per gather ray; if so, how many
    /// asked for gathering at each rung of [`GATHER_LADDER`].
    ladder: bool,
    points: [u64; GATHER_LADDER + 1],
}

impl CameraProbe {
    /// Time each camera at a reduced resolution without final gathering and with it where the
    /// photons per gather ray are fewest (the most points gather, the steadiest cost per
    /// point), and count the points that ask for it at each rung (without gathering: cheap).
    /// The `input` estimator is read with `base_rays` gather rays per pixel at the first rung.
    fn run(
        scene: &Scene,
        accel: &Accel,
        cameras: &[&Camera],
        settings: &Settings,
        input: PhotonData<'_>,
        base_rays: f32,
    ) -> Self {
        let gather = settings.effective_gather();
        let rays_at = |rung: usize| base_rays * (1u32 << rung) as f32;
        let ladder = gather > 0 && input.estimator.weighs_gather_rays();
        let (mut samples, mut plain, mut gathered, mut pixels) = (0u64, 0.0, 0.0, 0u64);
        let points: [AtomicU64; GATHER_LADDER + 1] = Default::default();
        for camera in cameras {
            let mut rs = render_settings(camera, settings, u32::MAX);
            pixels += rs.width as u64 * rs.height as u64;
            rs.width = (rs.width / PROBE_SHRINK).max(4);
            rs.height = (rs.height / PROBE_SHRINK).max(3);
            samples += rs.width as u64 * rs.height as u64;
            // The points are counted at a quarter of the timed pixels: a share needs fewer.
            let counted_rs = RenderSettings {
                width: (rs.width / 2).max(4),
                height: (rs.height / 2).max(3),
                ..rs.clone()
            };
            let run = |rs: &RenderSettings, gather: u32, rays: f32, counted: Option<&AtomicU64>| {
                let t = Instant::now();
                let rs = RenderSettings { gather, ..rs.clone() };
                let photons = PhotonData {
                    estimator: input.estimator.with_gather_rays(rays),
                    ..input
                };
                let pass = CameraPass {
                    scene,
                    accel,
                    photons,
                    camera,
                    settings: &rs,
                    gathering_points: counted,
                };
                drop(crate::render::render(pass, &|_| {}));
                t.elapsed().as_secs_f64()
            };
            // A few milliseconds each: the first run pays for cold caches and idle threads,
            // and single runs varied twofold; a warm-up, then the median of three.
            let time = |gather: u32| run(&rs, gather, rays_at(GATHER_LADDER), None);
            time(0);
            let mut runs: [[f64; 2]; PROBE_CAMERA_RUNS] = [[0.0; 2]; PROBE_CAMERA_RUNS];
            for r in &mut runs {
                *r = [time(0), time(gather)];
            }
            plain += median_of(runs.map(|r| r[0]));
            gathered += median_of(runs.map(|r| r[1]));
            if ladder {
                for (rung, n) in points.iter().enumerate() {
                    run(&counted_rs, 0, rays_at(rung), Some(n));
                }
            }
        }
        CameraProbe {
            pixels,
            samples,
            gather,
            plain,
            gathered,
            ladder,
            points: points.map(AtomicU64::into_inner),
        }
    }

    /// Seconds per gather ray at each rung: at the sparsest as timed, at the others by their
    /// share of its gathering points (the same camera points, so the share grows with the
    /// rung).
    fn per_gather_ray(&self) -> [f64; GATHER_LADDER + 1] {
        let rays = (self.samples.max(1) * u64::from(self.gather.max(1))) as f64;
        let sparsest = PROBE_CAMERA_BIAS * (self.gathered - self.plain).max(0.0) / rays;
        let most = self.points[GATHER_LADDER];
        std::array::from_fn(|rung| {
            if self.ladder && most > 0 {
                sparsest * self.points[rung] as f64 / most as f64
            } else {
                sparsest
            }
        })
    }
}

fn build_accel(scene: &Scene, progress: &Progress<'_>, times: &mut PhaseTimes) -> Accel {
    let phase = progress.phase("bvh", 0);
    let accel = {
        let _s = tracing::info_span!("bvh", triangles = scene.triangles.len()).entered();
        Accel::for_scene(scene)
    };
    times.bvh += phase.finish();
    accel
}

/// The grids accumulated over passes, those the estimate needs.
#[derive(Default)]
pub struct GridState {
    /// The paper's count textures and voxels.
    pub paper: Option<Grids>,
    /// The multiscale flux pyramids.
    pub multiscale: Option<MultiscaleGrids>,
}

impl GridState {
    /// The grids as an estimator reads them.
    pub fn view(&self) -> PassGrids<'_> {
        PassGrids {
            paper: self.paper.as_ref(),
            multiscale: self.multiscale.as_ref(),
        }
    }

    /// Add a pass's shown photons to the paper's count textures (building them at pass 0).
    fn add_paper(&mut self, scene: &Scene, settings: &Settings, photons: &[Photon], triangles: &[u32]) {
        if settings.method.needs().grids {
            let params = GridParams::from(settings);
            match self.paper.as_mut() {
                Some(g) => g.add(scene, photons, triangles, &params),
                None => {
                    let g = Grids::build(scene, photons, triangles, &params);
                    for c in &g.choice {
                        tracing::info!("{c}");
                    }
                    self.paper = Some(g);
                }
            }
        }
    }

    /// Add all of a pass's photons, each kind to its layer, to the multiscale pyramids
    /// (building them at pass 0): the camera reads the layers it shows, final-gather rays
    /// read them all.
    fn add_multiscale(
        &mut self,
        scene: &Scene,
        accel: &Accel,
        settings: &Settings,
        photons: &[Photon],
        triangles: &[u32],
    ) {
        if settings.method.needs().multiscale {
            let emitted = Some(Emitted {
                global: settings.photons,
                caustic: caustic_photons(scene, settings),
            });
            let g = match self.multiscale.as_mut() {
                Some(g) => {
                    g.add(photons, triangles, emitted);
                    g
                }
                None => {
                    let set = PlaneGrids::detect_receivers(scene, settings.grid_res);
                    let tris: Vec<[glam::Vec3; 3]> = scene.triangles.iter().map(|t| t.p).collect();
                    let params = MultiscaleParams {
                        cell_budget: settings.multiscale_cells(photons.len()),
                        photons_per_cell: settings.cell_photons,
                        max_radius: settings.max_radius * scene.bounds.diagonal(),
                        max_depth: settings.max_depth,
                        stratified: scene.lights.iter().all(|l| l.is_delta()),
                        ..MultiscaleParams::default()
                    };
                    let probes = Probes {
                        buried: &|p, n| inside_solid(scene, accel, p, n),
                        clearance: &|p, n, counts| clearance(scene, accel, p, n, params.max_radius, counts),
                    };
                    let g = MultiscaleGrids::build(set, &tris, photons, triangles, &params, &probes, emitted);
                    for line in g.describe() {
                        tracing::info!("{line}");
                    }
                    self.multiscale.insert(g)
                }
            };
            if settings.effective_gather() > 0 {
                g.resolve_for_gathering(Gammas::of_settings(settings, g.stratified));
            }
        }
    }

    fn memory_bytes(&self) -> usize {
        self.paper.as_ref().map(Grids::memory_bytes).unwrap_or(0)
            + self.multiscale.as_ref().map(MultiscaleGrids::memory_bytes).unwrap_or(0)
    }
}

/// The open space in front of a surface point `p` with front normal `n`, up to `reach`: the
/// nearest surface along the normal and four directions 45° off it (a shelf board standing
/// out of a wall above the point is met by the ray leaning up) met at a point `counts` accepts.
fn clearance(
    scene: &Scene,
    accel: &Accel,
    p: glam::Vec3,
    n: glam::Vec3,
    reach: f32,
    counts: &dyn Fn(glam::Vec3) -> bool,
) -> f32 {
    let eps = crate::surface::offset_eps(p.abs().max_element(), scene.bounds.diagonal());
    let (u, v) = crate::sampling::basis(n);
    let o = p + n * eps;
    [n, n + u, n - u, n + v, n - v]
        .iter()
        .filter_map(|&d| {
            let d = d.normalize();
            accel.intersect(o, d, reach).filter(|hit| counts(o + d * hit.t))
        })
        .map(|hit| hit.t)
        .fold(f32::INFINITY, f32::min)
}

/// Whether a point of a surface with front normal `n` lies inside a closed opaque solid
/// resting on its front (under a box on the floor): the first surface met along the normal and
/// along both in-plane axes is hit from its back, and is not glass (light reaches the table
/// under a glass through it, and is seen through it). (Only the front: every face of a solid
/// has the solid itself behind it.) Directions lean slightly off the axes (a ray through the shared
/// edge of two triangles, where cell centres often lie, can slip between them) and towards
/// the front (so they do not cross the surface).
fn inside_solid(scene: &Scene, accel: &Accel, p: glam::Vec3, n: glam::Vec3) -> bool {
    let eps = crate::surface::offset_eps(p.abs().max_element(), scene.bounds.diagonal());
    let (u, v) = crate::sampling::basis(n);
    [n].iter().any(|&side| {
        let o = p + side * eps;
        let exits = |d: glam::Vec3| {
            let d = (d + 0.013 * side + 0.007 * u + 0.003 * v).normalize();
            accel.intersect(o, d, f32::INFINITY).is_some_and(|hit| {
                let t = &scene.triangles[hit.triangle as usize];
                d.dot(t.cross()) > 0.0 && !scene.materials[t.material as usize].transmits()
            })
        };
        [side, u, -u, v, -v].iter().all(|&d| exits(d))
    })
}

/// The photons of one pass, reduced to the kinds the camera pass shows and indexed.
struct PassPhotons {
    map: PhotonMap,
    stats: PhotonStats,
    irradiance: Option<IrradianceCache>,
}

/// Trace pass `pass`'s photons (seed [`pass_seed`], from where `sequences` says) and index
/// them. When the estimate needs grids, their counts are added to `grids` (created at pass 0),
/// which is then refiltered: the textures hold every pass's photons so far. Phase times are
/// added to `times`.
fn trace_pass(
    scene: &Scene,
    accel: &Accel,
    settings: &Settings,
    (pass, sequences): (u32, Sequences),
    grids: &mut GridState,
    progress: &Progress<'_>,
    times: &mut PhaseTimes,
) -> PassPhotons {
    let needs = settings.method.needs();
    let max_radius = settings.max_radius * scene.bounds.diagonal();
    let gather = settings.effective_gather();
    let trace = TraceSettings {
        photons: settings.photons,
        max_depth: settings.photon_hits(),
        store_direct: settings.direct == DirectLighting::Photons || gather > 0,
        seed: pass_seed(settings.seed, pass),
        sequences,
        // Gathering's irradiance points measure the surface under their discs on the photon's
        // triangle.
        record_triangles: needs.photon_triangles || gather > 0,
        caustic_photons: caustic_photons(scene, settings),
    };
    let phase = progress.phase("photons", settings.photons as u64);
    let (photons, photon_triangles, stats) = {
        let _s = tracing::info_span!("photons", n = settings.photons, pass).entered();
        trace_photons(scene, accel, &trace, &|n| phase.inc(n as u64))
    };
    times.photons += phase.finish();
    tracing::info!(
        pass,
        stored = stats.stored,
        caustic = stats.caustic,
        indirect = stats.indirect,
        direct = stats.direct,
        "photons stored"
    );
    if needs.multiscale {
        let phase = progress.phase("grids", 0);
        let _s = tracing::info_span!("grids", pass).entered();
        grids.add_multiscale(scene, accel, settings, &photons, &photon_triangles);
        times.grids += phase.finish();
    }
    // Final gathering reads irradiance from all photons at the gather rays' hits; the camera
    // then sees only what gathering cannot give: caustics (and direct light in single-map mode).
    let irradiance = (gather > 0).then(|| {
        let phase = progress.phase("irradiance", 0);
        let _s = tracing::info_span!("irradiance").entered();
        let cache = irradiance_cache(
            scene,
            accel,
            settings,
            &photons,
            &photon_triangles,
            grids.multiscale.as_ref(),
            max_radius,
        );
        times.irradiance += phase.finish();
        cache
    });
    let (photons, photon_triangles) = shown_photons(settings, photons, photon_triangles);
    if needs.grids {
        let phase = progress.phase("grids", 0);
        let _s = tracing::info_span!("grids", pass).entered();
        grids.add_paper(scene, settings, &photons, &photon_triangles);
        times.grids += phase.finish();
    }
    drop(photon_triangles);
    let phase = progress.phase("build", 0);
    let map = {
        let _s = tracing::info_span!("build", photons = photons.len()).entered();
        PhotonMap::build(photons, settings.neighbours, scene.surface_area(), max_radius)
    };
    times.build += phase.finish();
    PassPhotons { map, stats, irradiance }
}

/// The irradiance that final gathering reads, precomputed from all photons of the pass that
/// gathering may show.
fn irradiance_cache(
    scene: &Scene,
    accel: &Accel,
    settings: &Settings,
    photons: &[Photon],
    photon_triangles: &[u32],
    multiscale: Option<&MultiscaleGrids>,
    max_radius: f32,
) -> IrradianceCache {
    // A gathered photon's light reaches the camera one bounce later than a photon shown
    // directly: keep the paths within `max_depth` segments (`Settings::gathered`). Gather
    // rays that land on a multiscale plane's lit side read the pyramids, so only the other
    // photons are indexed and turned into irradiance points.
    let stride = settings.gather_stride.max(1);
    let (mut gathered, mut sites) = (Vec::new(), Vec::new());
    for (p, &t) in photons.iter().zip(photon_triangles) {
        if settings.gathered(p.depth()) && multiscale.is_none_or(|g| g.texture_facing(t, p.normal()).is_none()) {
            if gathered.len() % stride == 0 {
                sites.push((*p, t));
            }
            gathered.push(*p);
        }
    }
    let k = settings.gather_neighbours;
    let all = PhotonMap::build(gathered, k, scene.surface_area(), max_radius);
    let surfaces = Surfaces::new(scene, accel, settings);
    IrradianceCache::build(&all, &sites, k, &surfaces, scene.surface_area())
}

/// The photons the camera reads, with their triangles: caustics always, direct light in the
/// single-map mode, indirect light only without final gathering (which reads it from the
/// precomputed irradiance instead).
fn shown_photons(settings: &Settings, photons: Vec<Photon>, triangles: Vec<u32>) -> (Vec<Photon>, Vec<u32>) {
    let direct_photons = settings.direct == DirectLighting::Photons;
    let gather = settings.effective_gather() > 0;
    let shown = |k: PhotonKind| match k {
        PhotonKind::Caustic => true,
        PhotonKind::Direct => direct_photons,
        PhotonKind::Indirect => !gather,
    };
    if triangles.is_empty() {
        (photons.into_iter().filter(|p| shown(p.kind())).collect(), Vec::new())
    } else {
        photons
            .into_iter()
            .zip(triangles)
            .filter(|(p, _)| shown(p.kind()))
            .unzip()
    }
}

/// The resolution a camera renders at under `settings`.
pub fn resolution(camera: &Camera, settings: &Settings) -> (u32, u32) {
    camera.resolution(settings.width, settings.height)
}

/// The camera pass's settings for `camera` in pass `pass`.
fn render_settings(camera: &Camera, settings: &Settings, pass: u32) -> RenderSettings {
    let (width, height) = resolution(camera, settings);
    RenderSettings {
        width,
        height,
        spp: settings.spp,
        direct: settings.direct,
        light_samples: settings.light_samples,
        max_specular_depth: settings.max_specular_depth,
        split_depth: settings.split_depth,
        seed: pass_seed(settings.seed, pass),
        sequence_seed: settings.seed,
        first_sample: 0,
        gather: settings.effective_gather(),
        gather_bright: settings.gather_bright,
    }
}

/// Which pass a camera pass is, when it must have ended, and its weight in the average.
#[derive(Clone, Copy)]
struct PassJob {
    pass: u32,
    cut: Cut,
    weight: f32,
}

/// Add pass `pass` of `camera` to `acc` (cut at `job.cut`); returns its seconds and the
/// samples per pixel added (0: dropped).
#[allow(clippy::too_many_arguments)]
fn render_pass(
    scene: &Scene,
    accel: &Accel,
    photons: PhotonData<'_>,
    job: PassJob,
    camera: &Camera,
    settings: &Settings,
    acc: &mut Accumulator,
    progress: &Progress<'_>,
) -> (f64, u32) {
    let PassJob { pass, cut, weight } = job;
    let rs = RenderSettings {
        first_sample: acc.samples(),
        ..render_settings(camera, settings, pass)
    };
    progress.camera(&camera.name);
    let phase = progress.phase("render", rs.height as u64 * rs.spp.max(1) as u64);
    let added = {
        let _s = tracing::info_span!(
            "render",
            camera = camera.name.as_str(),
            width = rs.width,
            height = rs.height,
            pass
        )
        .entered();
        let camera_pass = CameraPass {
            scene,
            accel,
            photons,
            camera,
            settings: &rs,
            gathering_points: None,
        };
        acc.add_pass(camera_pass, &|n| phase.inc(n as u64), cut, weight)
    };
    (phase.finish(), added)
}

/// The photon data of pass 0, for rendering cameras one at a time with [`render_camera`]
/// (tests that compare estimates on the same photons).
pub struct Prepared {
    /// The BVH.
    pub accel: Accel,
    /// The photon map.
    pub map: PhotonMap,
    /// Photon counts.
    pub photon_stats: PhotonStats,
    /// The grids the estimate needs.
    pub grids: GridState,
    /// Precomputed irradiance for final gathering.
    pub irradiance: Option<IrradianceCache>,
}

/// Build the BVH and trace pass 0's photons, as [`render`] does for its first pass.
pub fn prepare(
    scene: &Scene,
    settings: &Settings,
    progress: &Progress<'_>,
    times: &mut PhaseTimes,
) -> Result<Prepared, RenderError> {
    settings.validate()?;
    check_photon_memory(settings.photons, caustic_photons(scene, settings))?;
    let accel = build_accel(scene, progress, times);
    let mut grids = GridState::default();
    let at = (0, Sequences::starting(settings.seed));
    let pass = trace_pass(scene, &accel, settings, at, &mut grids, progress, times);
    Ok(Prepared {
        accel,
        map: pass.map,
        photon_stats: pass.stats,
        grids,
        irradiance: pass.irradiance,
    })
}

/// Render one camera from prepared data as [`render`]'s first pass would, with the estimate
/// `settings` asks for (which may differ from the one the data was prepared for, as long as
/// it needs nothing more).
pub fn render_camera(
    scene: &Scene,
    prepared: &Prepared,
    camera: &Camera,
    settings: &Settings,
    progress: &Progress<'_>,
) -> Film {
    let (w, h) = resolution(camera, settings);
    let mut acc = Accumulator::new(settings.method.needs().accumulation, w, h, settings.spp);
    let surfaces = Surfaces::new(scene, &prepared.accel, settings);
    let input = PhotonData {
        estimator: Estimator::for_pass(settings, 0, &prepared.map, prepared.grids.view(), &surfaces),
        irradiance: prepared.irradiance.as_ref(),
    };
    let job = PassJob {
        pass: 0,
        cut: Cut::NONE,
        weight: 1.0,
    };
    render_pass(scene, &prepared.accel, input, job, camera, settings, &mut acc, progress);
    acc.film()
}

/// Pick cameras by name or index; "all" (or an empty list) means every camera.
pub fn select_cameras<'a>(scene: &'a Scene, keys: &[String]) -> Result<Vec<&'a Camera>, RenderError> {
    if scene.cameras.is_empty() {
        return Err(RenderError::NoCamera(scene.source.display().to_string()));
    }
    if keys.is_empty() || keys.iter().any(|k| k == "all") {
        return Ok(scene.cameras.iter().collect());
    }
    if keys.len() <= 8 {
        return keys
            .iter()
            .map(|k| scene.camera(k).map_err(RenderError::UnknownCamera))
            .collect();
    }
    // Many keys (a jobs file listing thousands of cameras): look them up in maps, not one
    // scan of the cameras per key; the first camera of a name or index wins, as in
    // `Scene::camera`.
    let mut by_name = std::collections::HashMap::new();
    let mut by_index = std::collections::HashMap::new();
    for c in &scene.cameras {
        by_name.entry(c.name.as_str()).or_insert(c);
        by_index.entry(c.index).or_insert(c);
    }
    keys.iter()
        .map(|k| {
            by_name
                .get(k.as_str())
                .or_else(|| k.parse::<usize>().ok().and_then(|i| by_index.get(&i)))
                .copied()
                .ok_or_else(|| RenderError::UnknownCamera(scene.camera(k).err().unwrap_or_default()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn many_camera_keys_select_as_few_do() {
        let camera = |name: &str, index: usize| Camera {
            name: name.into(),
            index,
            to_world: glam::Mat4::IDENTITY,
            projection: crate::scene::Projection::Perspective {
                yfov: 1.0,
                aspect: None,
            },
        };
        // Names that repeat, a name that is another camera's index, two nodes of one camera.
        let mut cameras: Vec<Camera> = (0..30).map(|i| camera(&format!("c{}", i % 25), i)).collect();
        cameras.push(camera("3", 40));
        cameras.push(camera("twin", 7));
        let scene = Scene {
            source: PathBuf::from("s.glb"),
            triangles: vec![],
            materials: vec![],
            textures: vec![],
            tangents: vec![],
            glossy_roughness: 0.0,
            lights: vec![],
            cameras,
            bounds: crate::scene::Bounds::empty(),
            report: Default::default(),
        };
        let keys: Vec<String> = ["c3", "c2", "3", "7", "twin", "29", "c0", "c24", "0", "40", "c1"]
            .iter()
            .map(|k| k.to_string())
            .collect();
        let picked: Vec<(String, usize)> = select_cameras(&scene, &keys)
            .unwrap()
            .iter()
            .map(|c| (c.name.clone(), c.index))
            .collect();
        let one_by_one: Vec<(String, usize)> = keys
            .iter()
            .map(|k| scene.camera(k).map(|c| (c.name.clone(), c.index)).unwrap())
            .collect();
        assert_eq!(picked, one_by_one);
        let mut bad = keys.clone();
        bad.push("nope".into());
        let e = select_cameras(&scene, &bad).unwrap_err().to_string();
        assert!(e.contains("nope") && e.contains("c24"), "{e}");
    }

    #[test]
    fn summary_lists_the_phases_that_ran_in_order() {
        let t = PhaseTimes {
            load: 0.1,
            photons: 2.0,
            irradiance: 1.5,
            render: 0.7,
            total: 4.3,
            ..PhaseTimes::default()
        };
        let names: Vec<&str> = t.phases().iter().map(|p| p.0).collect();
        assert_eq!(names, ["load", "photons", "irradiance", "render"]);
    }
}
