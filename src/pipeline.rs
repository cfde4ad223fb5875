//! The pipeline in order: scene → BVH → photons → photon index → camera pass. Each phase is
//! timed and reported; the result of the first three is shared by every camera rendered.

use crate::accel::Accel;
use crate::estimate::PhotonMap;
use crate::film::Film;
use crate::photon::{trace_photons, PhotonStats, TraceSettings};
use crate::progress::Progress;
use crate::render::{self, DirectLighting, RenderSettings};
use crate::scene::{Camera, Scene};
use crate::settings::Settings;
use serde::Serialize;

/// Why a render could not run.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// A setting is out of range.
    #[error("invalid settings: {0}")]
    Settings(String),
    /// The photon count would not fit in memory.
    #[error("{photons} photons need at least {needed_gib:.1} GiB but only {available_gib:.1} GiB is available; use --photons {suggest} or fewer")]
    TooManyPhotons {
        /// Requested photons.
        photons: usize,
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
}

/// Seconds spent in each phase.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PhaseTimes {
    /// Reading and validating the file.
    pub load: f64,
    /// Building the BVH.
    pub bvh: f64,
    /// Tracing photons.
    pub photons: f64,
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

/// Refuse photon counts that cannot fit, before spending minutes finding out.
pub fn check_photon_memory(photons: usize) -> Result<(), RenderError> {
    let needed = photons as f64 * MIN_BYTES_PER_PHOTON;
    let available = available_memory_bytes()
        .unwrap_or(f64::INFINITY)
        .min(u32::MAX as f64 * MIN_BYTES_PER_PHOTON);
    if photons > u32::MAX as usize / 2 || needed > available {
        let gib = (1u64 << 30) as f64;
        return Err(RenderError::TooManyPhotons {
            photons,
            needed_gib: needed / gib,
            available_gib: available / gib,
            suggest: ((available / MIN_BYTES_PER_PHOTON) as usize / 4).min(u32::MAX as usize / 2),
        });
    }
    Ok(())
}

/// Build the BVH, trace photons and index them.
pub fn prepare(
    scene: &Scene,
    settings: &Settings,
    progress: &Progress,
    times: &mut PhaseTimes,
) -> Result<Prepared, RenderError> {
    settings.validate().map_err(RenderError::Settings)?;
    check_photon_memory(settings.photons)?;

    let phase = progress.phase("bvh", 0);
    let accel = {
        let _s = tracing::info_span!("bvh", triangles = scene.triangles.len()).entered();
        Accel::build(&scene.triangles)
    };
    times.bvh = phase.finish();

    let trace = TraceSettings {
        photons: settings.photons,
        max_depth: settings.max_photon_depth,
        store_direct: settings.direct == DirectLighting::Photons,
        seed: settings.seed,
    };
    let phase = progress.phase("photons", settings.photons as u64);
    let (photons, photon_stats) = {
        let _s = tracing::info_span!("photons", n = settings.photons).entered();
        trace_photons(scene, &accel, &trace, &|n| phase.inc(n as u64))
    };
    times.photons = phase.finish();
    tracing::info!(
        stored = photon_stats.stored,
        caustic = photon_stats.caustic,
        indirect = photon_stats.indirect,
        direct = photon_stats.direct,
        "photons stored"
    );

    let phase = progress.phase("build", 0);
    let map = {
        let _s = tracing::info_span!("build", photons = photons.len()).entered();
        let max_radius = settings.max_radius_rel * scene.bounds.diagonal();
        PhotonMap::build(
            photons,
            settings.neighbours,
            scene.surface_area(),
            max_radius,
            trace.store_direct,
        )
    };
    times.build = phase.finish();
    Ok(Prepared {
        accel,
        map,
        photon_stats,
    })
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

/// Render one camera with prepared data.
pub fn render_camera(
    scene: &Scene,
    prepared: &Prepared,
    camera: &Camera,
    settings: &Settings,
    progress: &Progress,
) -> Film {
    let (width, height) = resolution(camera, settings);
    let rs = RenderSettings {
        width,
        height,
        spp: settings.spp,
        neighbours: settings.neighbours,
        direct: settings.direct,
        light_samples: settings.light_samples,
        max_specular_depth: settings.max_specular_depth,
        split_depth: settings.split_depth,
        seed: settings.seed,
    };
    let phase = progress.phase("render", height as u64);
    let film = {
        let _s = tracing::info_span!("render", camera = camera.name.as_str(), width, height).entered();
        render::render(scene, &prepared.accel, &prepared.map, camera, &rs, &|n| {
            phase.inc(n as u64)
        })
    };
    phase.finish();
    film
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
