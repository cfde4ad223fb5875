//! The pipeline in order: scene → BVH → photons → photon index → camera pass. Each phase is
//! timed and reported; the result of the first three is shared by every camera rendered.

use crate::accel::Accel;
use crate::estimate::{IrradianceCache, PhotonMap};
use crate::film::Film;
use crate::grid::Grids;
use crate::photon::{trace_photons, PhotonStats, TraceSettings};
use crate::photon::{Photon, PhotonKind};
use crate::progress::Progress;
use crate::render::progressive::{Accumulator, Budget, Stop};
use crate::render::{DirectLighting, Method, PhotonData, RenderSettings};
use crate::sampling::pass_seed;
use crate::scene::{Camera, Scene};
use crate::settings::Settings;
use serde::Serialize;
use std::time::Instant;

/// Why a render could not run.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// A setting is out of range.
    #[error("invalid settings: {0}")]
    Settings(String),
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
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PhaseTimes {
    /// Reading and validating the file.
    pub load: f64,
    /// Building the BVH.
    pub bvh: f64,
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

/// Everything the camera pass needs that does not depend on the camera.
pub struct Prepared {
    /// The BVH.
    pub accel: Accel,
    /// The photon map.
    pub map: PhotonMap,
    /// Photon counts.
    pub photon_stats: PhotonStats,
    /// The grids (adaptive method only).
    pub grids: Option<Grids>,
    /// Precomputed irradiance for final gathering.
    pub irradiance: Option<IrradianceCache>,
}

/// Stored photons per emitted path is at least about one in a closed scene; 24 bytes each,
/// held twice while the index is sorted.
const MIN_BYTES_PER_PHOTON: f64 = 48.0;

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

/// Build the BVH, trace photons and index them (one pass: the photons of pass 0).
pub fn prepare(
    scene: &Scene,
    settings: &Settings,
    progress: &Progress<'_>,
    times: &mut PhaseTimes,
) -> Result<Prepared, RenderError> {
    settings.validate().map_err(RenderError::Settings)?;
    // The caustic pass only runs when the scene has a mirror or glass.
    let caustic_photons = if scene.has_specular() {
        settings.caustic_photons
    } else {
        0
    };
    check_photon_memory(settings.photons, caustic_photons)?;
    let accel = build_accel(scene, progress, times);
    let mut grids = None;
    let pass = trace_pass(scene, &accel, settings, 0, &mut grids, progress, times);
    Ok(Prepared {
        accel,
        map: pass.map,
        photon_stats: pass.stats,
        grids,
        irradiance: pass.irradiance,
    })
}

fn build_accel(scene: &Scene, progress: &Progress<'_>, times: &mut PhaseTimes) -> Accel {
    let phase = progress.phase("bvh", 0);
    let accel = {
        let _s = tracing::info_span!("bvh", triangles = scene.triangles.len()).entered();
        Accel::build(&scene.triangles)
    };
    times.bvh += phase.finish();
    accel
}

/// The photons of one pass, reduced to the kinds the camera pass shows and indexed.
struct PassPhotons {
    map: PhotonMap,
    stats: PhotonStats,
    irradiance: Option<IrradianceCache>,
}

/// Trace pass `pass`'s photons (seed [`pass_seed`]) and index them. For the adaptive method
/// their plane counts are added to `grids` (created at pass 0), which is then refiltered: the
/// textures hold every pass's photons so far. Phase times are added to `times`.
#[allow(clippy::too_many_arguments)]
fn trace_pass(
    scene: &Scene,
    accel: &Accel,
    settings: &Settings,
    pass: u32,
    grids: &mut Option<Grids>,
    progress: &Progress<'_>,
    times: &mut PhaseTimes,
) -> PassPhotons {
    let max_radius = settings.max_radius_rel * scene.bounds.diagonal();
    let trace = TraceSettings {
        photons: settings.photons,
        max_depth: settings.max_photon_depth,
        store_direct: settings.direct == DirectLighting::Photons || settings.effective_gather() > 0,
        seed: pass_seed(settings.seed, pass),
        record_triangles: settings.method == Method::Adaptive,
        caustic_photons: settings.caustic_photons,
    };
    let phase = progress.phase("photons", settings.photons as u64);
    let (photons, photon_triangles, photon_stats) = {
        let _s = tracing::info_span!("photons", n = settings.photons, pass).entered();
        trace_photons(scene, accel, &trace, &|n| phase.inc(n as u64))
    };
    times.photons += phase.finish();
    tracing::info!(
        pass,
        stored = photon_stats.stored,
        caustic = photon_stats.caustic,
        indirect = photon_stats.indirect,
        direct = photon_stats.direct,
        "photons stored"
    );

    // Final gathering reads irradiance from all photons at the gather rays' hits; the camera
    // then sees only what gathering cannot give: caustics (and direct light in single-map mode).
    let irradiance = (settings.effective_gather() > 0).then(|| {
        let phase = progress.phase("irradiance", 0);
        let _s = tracing::info_span!("irradiance").entered();
        let all = PhotonMap::build(
            photons.clone(),
            settings.gather_neighbours,
            scene.surface_area(),
            max_radius,
        );
        let cache = IrradianceCache::build(
            &all,
            settings.gather_neighbours,
            settings.gather_stride,
            scene.surface_area(),
        );
        times.irradiance += phase.finish();
        cache
    });
    let direct_photons = settings.direct == DirectLighting::Photons;
    let shown = |k: PhotonKind| match k {
        PhotonKind::Caustic => true,
        PhotonKind::Direct => direct_photons,
        PhotonKind::Indirect => settings.effective_gather() == 0,
    };
    let (photons, photon_triangles): (Vec<Photon>, Vec<u32>) = if photon_triangles.is_empty() {
        (photons.into_iter().filter(|p| shown(p.kind())).collect(), Vec::new())
    } else {
        photons
            .into_iter()
            .zip(photon_triangles)
            .filter(|(p, _)| shown(p.kind()))
            .unzip()
    };

    if settings.method == Method::Adaptive {
        let phase = progress.phase("grids", 0);
        let _s = tracing::info_span!("grids", pass).entered();
        match grids.as_mut() {
            Some(g) => g.add(scene, &photons, &photon_triangles, settings),
            None => {
                let g = Grids::build(scene, &photons, &photon_triangles, settings);
                for c in &g.choice {
                    tracing::info!("{c}");
                }
                *grids = Some(g);
            }
        }
        times.grids += phase.finish();
    }
    drop(photon_triangles);

    let phase = progress.phase("build", 0);
    let map = {
        let _s = tracing::info_span!("build", photons = photons.len()).entered();
        PhotonMap::build(photons, settings.neighbours, scene.surface_area(), max_radius)
    };
    times.build += phase.finish();
    PassPhotons {
        map,
        stats: photon_stats,
        irradiance,
    }
}

/// The resolution a camera renders at under `settings`.
pub fn resolution(camera: &Camera, settings: &Settings) -> (u32, u32) {
    let (dw, dh) = camera.default_resolution();
    match (settings.width, settings.height) {
        (Some(w), Some(h)) => (w, h),
        (Some(w), None) => (w, ((w as f32 * dh as f32 / dw as f32).round() as u32).max(1)),
        (None, Some(h)) => (((h as f32 * dw as f32 / dh as f32).round() as u32).max(1), h),
        (None, None) => (dw, dh),
    }
}

/// The camera pass's settings for `camera` in pass `pass`.
fn render_settings(camera: &Camera, settings: &Settings, pass: u32) -> RenderSettings {
    let (width, height) = resolution(camera, settings);
    RenderSettings {
        width,
        height,
        spp: settings.spp,
        neighbours: settings.neighbours,
        direct: settings.direct,
        light_samples: settings.light_samples,
        max_specular_depth: settings.max_specular_depth,
        split_depth: settings.split_depth,
        seed: pass_seed(settings.seed, pass),
        pass,
        method: settings.method,
        alpha: settings.alpha,
        shadow_count: settings.shadow_count,
        gather: settings.effective_gather(),
    }
}

/// The photon data a camera pass reads.
struct PassInputs<'a> {
    pass: u32,
    photons: PhotonData<'a>,
}

/// Add pass `input.pass` of `camera` to `acc`.
fn render_pass(
    scene: &Scene,
    accel: &Accel,
    input: &PassInputs<'_>,
    camera: &Camera,
    settings: &Settings,
    acc: &mut Accumulator,
    progress: &Progress<'_>,
) {
    let rs = render_settings(camera, settings, input.pass);
    let phase = progress.phase("render", rs.height as u64);
    {
        let _s = tracing::info_span!(
            "render",
            camera = camera.name.as_str(),
            width = rs.width,
            height = rs.height,
            pass = input.pass
        )
        .entered();
        acc.add_pass(scene, accel, input.photons, camera, &rs, &|n| phase.inc(n as u64));
    }
    phase.finish();
}

/// Render one camera with prepared data (one pass).
pub fn render_camera(
    scene: &Scene,
    prepared: &Prepared,
    camera: &Camera,
    settings: &Settings,
    progress: &Progress<'_>,
) -> Film {
    let (w, h) = resolution(camera, settings);
    let mut acc = Accumulator::new(settings.method, w, h, settings.spp);
    let input = PassInputs {
        pass: 0,
        photons: PhotonData {
            map: &prepared.map,
            grids: prepared.grids.as_ref(),
            irradiance: prepared.irradiance.as_ref(),
        },
    };
    render_pass(scene, &prepared.accel, &input, camera, settings, &mut acc, progress);
    acc.film()
}

/// Writes the images so far while passes run (`--checkpoint`).
pub struct Checkpoint<'a> {
    /// Seconds between writes.
    pub every: f64,
    /// Write the films (one per camera, in order) after `passes` passes.
    pub write: &'a mut dyn FnMut(&[Film], u32) -> Result<(), String>,
}

/// What a progressive render produced.
pub struct Passes {
    /// One image per camera, in the order given.
    pub films: Vec<Film>,
    /// Passes that ran.
    pub passes: u32,
    /// Seconds of each pass (photons and every camera).
    pub pass_seconds: Vec<f64>,
    /// Why the passes stopped.
    pub stop: Stop,
    /// Photon counts summed over passes.
    pub photon_stats: PhotonStats,
    /// The accumulated, filtered plane grids (adaptive method).
    pub grids: Option<Grids>,
    /// Checkpoints written.
    pub checkpoints: u32,
    /// Memory of the largest pass's photon map.
    pub photon_map_bytes: usize,
    /// Memory of the BVH.
    pub bvh_bytes: usize,
}

/// Render `cameras` progressively: passes of `settings.photons` new photons (seed
/// [`pass_seed`] of the pass) and `settings.spp` new samples per pixel, accumulated per camera,
/// until `settings.passes` passes ran or the next pass would end after `settings.time`
/// seconds counted from `start` ([`Budget`]); neither given: one pass, the plain render. The
/// same seed and pass count give the same images whatever the thread count. Each pass's
/// photons serve every camera, then are dropped. `checkpoint` writes the images so far every
/// `every` seconds, except after the last pass (the caller writes the final images).
pub fn render_passes(
    scene: &Scene,
    cameras: &[&Camera],
    settings: &Settings,
    start: Instant,
    progress: &Progress<'_>,
    times: &mut PhaseTimes,
    mut checkpoint: Option<Checkpoint<'_>>,
) -> Result<Passes, RenderError> {
    settings.validate().map_err(RenderError::Settings)?;
    check_photon_memory(settings.photons, settings.caustic_photons)?;
    let accel = build_accel(scene, progress, times);
    let budget = Budget {
        passes: settings.passes,
        time: settings.time,
    };
    let mut accs: Vec<Accumulator> = cameras
        .iter()
        .map(|c| {
            let (w, h) = resolution(c, settings);
            Accumulator::new(settings.method, w, h, settings.spp)
        })
        .collect();
    let mut grids = None;
    let mut photon_stats = PhotonStats::default();
    let (mut pass_seconds, mut last, mut map_bytes, mut checkpoints) = (Vec::new(), 0.0f64, 0, 0);
    let mut last_checkpoint = Instant::now();
    let mut done = 0u32;
    let stop = loop {
        if let Err(stop) = budget.next(done, start.elapsed().as_secs_f64(), last) {
            break stop;
        }
        let t = Instant::now();
        let photons = trace_pass(scene, &accel, settings, done, &mut grids, progress, times);
        photon_stats.add(&photons.stats);
        map_bytes = map_bytes.max(photons.map.memory_bytes());
        let tr = Instant::now();
        let input = PassInputs {
            pass: done,
            photons: PhotonData {
                map: &photons.map,
                grids: grids.as_ref(),
                irradiance: photons.irradiance.as_ref(),
            },
        };
        for (camera, acc) in cameras.iter().zip(&mut accs) {
            render_pass(scene, &accel, &input, camera, settings, acc, progress);
        }
        times.render += tr.elapsed().as_secs_f64();
        drop(photons);
        let seconds = t.elapsed().as_secs_f64();
        pass_seconds.push(seconds);
        last = seconds;
        done += 1;
        tracing::info!(pass = done, seconds = format!("{seconds:.3}"), "pass done");
        if let Some(cp) = checkpoint.as_mut() {
            let more = budget.next(done, start.elapsed().as_secs_f64(), last).is_ok();
            if more && last_checkpoint.elapsed().as_secs_f64() >= cp.every {
                let tw = Instant::now();
                let films: Vec<Film> = accs.iter().map(Accumulator::film).collect();
                (cp.write)(&films, done).map_err(RenderError::Checkpoint)?;
                times.write += tw.elapsed().as_secs_f64();
                checkpoints += 1;
                last_checkpoint = Instant::now();
            }
        }
    };
    Ok(Passes {
        films: accs.iter().map(Accumulator::film).collect(),
        passes: done,
        pass_seconds,
        stop,
        photon_stats,
        grids,
        checkpoints,
        photon_map_bytes: map_bytes,
        bvh_bytes: accel.memory_bytes(),
    })
}

/// Pick cameras by name or index; "all" (or an empty list) means every camera.
pub fn select_cameras<'a>(scene: &'a Scene, keys: &[String]) -> Result<Vec<&'a Camera>, RenderError> {
    if scene.cameras.is_empty() {
        return Err(RenderError::NoCamera(scene.source.display().to_string()));
    }
    if keys.is_empty() || keys.iter().any(|k| k == "all") {
        return Ok(scene.cameras.iter().collect());
    }
    keys.iter()
        .map(|k| scene.camera(k).map_err(RenderError::UnknownCamera))
        .collect()
}
