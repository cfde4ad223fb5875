//! The pipeline in order: scene → BVH → photons → photon index → camera pass. Each phase is
//! timed and reported; the result of the first three is shared by every camera rendered.

use crate::accel::Accel;
use crate::estimate::{IrradianceCache, PhotonMap};
use crate::film::Film;
use crate::grid::Grids;
use crate::photon::{trace_photons, PhotonStats, TraceSettings};
use crate::photon::{Photon, PhotonKind};
use crate::progress::Progress;
use crate::render::{self, DirectLighting, Method, RenderSettings};
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
    #[error("{photons} photons (with the caustic pass's) need at least {needed_gib:.1} GiB but only {available_gib:.1} GiB is available; use --photons {suggest} or fewer")]
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

/// Refuse photon counts that cannot fit, before spending minutes finding out.
pub fn check_photon_memory(photons: usize, caustic_photons: usize) -> Result<(), RenderError> {
    let total = photons.saturating_add(caustic_photons);
    let needed = total as f64 * MIN_BYTES_PER_PHOTON;
    let available = available_memory_bytes()
        .unwrap_or(f64::INFINITY)
        .min(u32::MAX as f64 * MIN_BYTES_PER_PHOTON);
    if total > u32::MAX as usize / 2 || needed > available {
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
    // The caustic pass only runs when the scene has a mirror or glass.
    let caustic_photons = if scene.has_specular() {
        settings.caustic_photons
    } else {
        0
    };
    check_photon_memory(settings.photons, caustic_photons)?;

    let max_radius = settings.max_radius_rel * scene.bounds.diagonal();
    let phase = progress.phase("bvh", 0);
    let accel = {
        let _s = tracing::info_span!("bvh", triangles = scene.triangles.len()).entered();
        Accel::build(&scene.triangles)
    };
    times.bvh = phase.finish();

    let trace = TraceSettings {
        photons: settings.photons,
        max_depth: settings.max_photon_depth,
        store_direct: settings.direct == DirectLighting::Photons || settings.gather > 0,
        seed: settings.seed,
        record_triangles: settings.method == Method::Adaptive,
        caustic_photons: settings.caustic_photons,
    };
    let phase = progress.phase("photons", settings.photons as u64);
    let (photons, photon_triangles, photon_stats) = {
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

    // Final gathering reads irradiance from all photons at the gather rays' hits; the camera
    // then sees only what gathering cannot give: caustics (and direct light in single-map mode).
    let irradiance = (settings.gather > 0).then(|| {
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
        times.irradiance = phase.finish();
        cache
    });
    let direct_photons = settings.direct == DirectLighting::Photons;
    let shown = |k: PhotonKind| match k {
        PhotonKind::Caustic => true,
        PhotonKind::Direct => direct_photons,
        PhotonKind::Indirect => settings.gather == 0,
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

    let grids = (settings.method == Method::Adaptive).then(|| {
        let phase = progress.phase("grids", 0);
        let _s = tracing::info_span!("grids").entered();
        let g = Grids::build(scene, &photons, &photon_triangles, settings);
        times.grids = phase.finish();
        for c in &g.choice {
            tracing::info!("{c}");
        }
        g
    });
    drop(photon_triangles);

    let phase = progress.phase("build", 0);
    let map = {
        let _s = tracing::info_span!("build", photons = photons.len()).entered();
        PhotonMap::build(photons, settings.neighbours, scene.surface_area(), max_radius)
    };
    times.build = phase.finish();
    Ok(Prepared {
        accel,
        map,
        photon_stats,
        grids,
        irradiance,
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
        method: settings.method,
        alpha: settings.alpha,
        shadow_count: settings.shadow_count,
        gather: settings.gather,
    };
    let phase = progress.phase("render", height as u64);
    let film = {
        let _s = tracing::info_span!("render", camera = camera.name.as_str(), width, height).entered();
        render::render(
            scene,
            &prepared.accel,
            &prepared.map,
            prepared.grids.as_ref(),
            prepared.irradiance.as_ref(),
            camera,
            &rs,
            &|n| phase.inc(n as u64),
        )
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
