//! The memory of a render, estimated before anything large is allocated, and the limit it is
//! checked against. [`crate::pipeline::render`] calls [`check_render`] first, so every front
//! end (command line, batch, bench, add-on) refuses a render that cannot fit with the same
//! message: the estimate item by item, the limit, and what to change.
//!
//! The estimate adds up what stays allocated for the whole render and the largest transient
//! peak on top of it:
//! - the scene (triangles, textures) and its BVH;
//! - per camera, its image across passes: 97 bytes a pixel (sum, AOVs, emitter-edge flags,
//!   the final film), or with `--method sppm` 20 bytes per camera *sample* (radius, count, flux
//!   of each of the `spp` samples of each pixel, kept across passes) plus 97 a pixel;
//! - while one camera renders and is written: its pass film and the encoded image (72 bytes
//!   a pixel);
//! - one pass's photons: stored photons per emitted path from the scene's mean albedo
//!   (1 + ρ + ρ² + … up to `Settings::photon_hits()` bounces), about 48 bytes each while traced and
//!   indexed, 44 more when final gathering indexes all of them again;
//! - the grids the estimate needs: at least one plane of `grid_res²` cells (16 bytes each),
//!   or the multiscale pyramids' `grid_cells` (72 bytes each with the coarser levels).
//!
//! The limit is [`Settings::memory_limit`] when set, else half of the machine's RAM (the
//! loader's default budget, `MemTotal` of `/proc/meminfo`), else 8 GiB.

use crate::estimate::Accumulation;
use crate::render::budget::{PassSize, CAUSTIC_BOOST};
use crate::scene::{Camera, Scene, Surface, Triangle};
use crate::settings::Settings;

/// Bytes a pixel of a camera's image costs across passes (accumulated sum 12, AOVs 36, the
/// emitter-edge flag 1, the final film 48).
const BYTES_PER_PIXEL: u64 = 97;
/// Bytes a pixel costs while one camera renders a pass and is written (the pass's film 48,
/// the channels and encoded bytes of the EXR 24).
const TRANSIENT_BYTES_PER_PIXEL: u64 = 72;
/// Bytes per camera sample kept by SPPM (`SppmPixel`: r², N, τ).
const SPPM_BYTES_PER_SAMPLE: u64 = 20;
/// Bytes per stored photon while a pass traces and indexes it (photon 24, held once: the index
/// sorts it in place; its triangle 4; the sort's input index 4; cell offsets up to 16).
const BYTES_PER_PHOTON: u64 = 48;
/// More bytes per stored photon when final gathering indexes all photons a second time (a
/// copy of the photons 24, its sort's input index 4 and cell offsets up to 16).
const GATHER_BYTES_PER_PHOTON: u64 = 44;
/// Bytes per triangle: the scene's copy and the BVH built over it.
const BYTES_PER_TRIANGLE: u64 = std::mem::size_of::<Triangle>() as u64 + 200;
/// Bytes per plane-grid cell (counts, filtered counts, wavelet scratch).
const BYTES_PER_GRID_CELL: u64 = 16;
/// Bytes per multiscale finest cell, coarser levels included.
const BYTES_PER_MULTISCALE_CELL: u64 = 72;
/// The limit when the RAM cannot be read.
const FALLBACK_LIMIT: u64 = 8 << 30;

/// One part of the estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct Item {
    /// What it is, with the numbers it comes from.
    pub what: String,
    /// Bytes.
    pub bytes: u64,
    /// What to change to make it smaller.
    pub change: String,
}

/// The memory a render is expected to need, against its limit.
#[derive(Clone, Debug, PartialEq)]
pub struct MemoryEstimate {
    /// The parts, largest first.
    pub items: Vec<Item>,
    /// The limit in bytes.
    pub limit: u64,
    /// Where the limit comes from, for messages.
    pub limit_origin: String,
}

impl MemoryEstimate {
    /// Sum of the parts (saturating).
    pub fn total(&self) -> u64 {
        self.items.iter().fold(0u64, |s, i| s.saturating_add(i.bytes))
    }

    /// Whether the render fits its limit.
    pub fn fits(&self) -> bool {
        self.total() <= self.limit
    }
}

/// A render refused because its estimate is over the limit.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct MemoryError {
    /// The estimate.
    pub needed: u64,
    /// The limit.
    pub limit: u64,
    /// The estimate item by item, the limit and what to change.
    pub message: String,
}

/// The memory limit of a render under `settings`, and where it comes from.
pub fn memory_limit(settings: &Settings) -> (u64, String) {
    match settings.memory_limit {
        Some(b) => (b, "set by --memory-limit (jobs files: memory_limit)".to_string()),
        None => match physical_ram() {
            Some(ram) => (ram / 2, format!("half of the {} of RAM", human(ram))),
            None => (FALLBACK_LIMIT, "the default when the RAM size is unknown".to_string()),
        },
    }
}

/// `MemTotal` of `/proc/meminfo`, in bytes, read once (a batch checks every unit).
fn physical_ram() -> Option<u64> {
    static RAM: std::sync::OnceLock<Option<u64>> = std::sync::OnceLock::new();
    *RAM.get_or_init(read_physical_ram)
}

fn read_physical_ram() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// Bytes for people: `3.2 GiB`, `640.0 MiB`, `12.0 KiB`, `100 bytes`.
pub fn human(bytes: u64) -> String {
    const UNITS: [(&str, u64); 5] = [
        ("PiB", 1 << 50),
        ("TiB", 1 << 40),
        ("GiB", 1 << 30),
        ("MiB", 1 << 20),
        ("KiB", 1 << 10),
    ];
    for (unit, size) in UNITS {
        if bytes >= size {
            return format!("{:.1} {unit}", bytes as f64 / size as f64);
        }
    }
    format!("{bytes} bytes")
}

/// Mean diffuse albedo (largest channel) of the scene's surfaces, weighted by area: the share
/// of a photon's paths that goes on after a diffuse bounce.
fn mean_albedo(scene: &Scene) -> f64 {
    let (mut sum, mut area) = (0.0f64, 0.0f64);
    for t in &scene.triangles {
        let a = t.area() as f64;
        if !a.is_finite() {
            continue;
        }
        let rho = match &scene.materials.get(t.material as usize).map(|m| &m.surface) {
            Some(Surface::Lambert { albedo, .. }) => albedo.max_element().clamp(0.0, 1.0) as f64,
            // Mirrors and glass pass photons on without storing them.
            Some(_) => 1.0,
            None => 0.0,
        };
        sum += rho * a;
        area += a;
    }
    if area > 0.0 {
        (sum / area).clamp(0.0, 0.95)
    } else {
        0.5
    }
}

/// What the estimate needs of a scene, so that a front end which drops the scene once its
/// cameras are known (batch expansion) can still check each unit before rendering it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneFootprint {
    /// Triangles (the scene's copy and the BVH).
    pub triangles: u64,
    /// Texels of all textures.
    pub texels: u64,
    /// Whether a material is specular (caustic photons are then traced).
    pub specular: bool,
    /// Mean diffuse albedo, weighted by area ([`mean_albedo`]).
    pub mean_albedo: f64,
}

impl SceneFootprint {
    /// The footprint of `scene`.
    pub fn of(scene: &Scene) -> Self {
        SceneFootprint {
            triangles: scene.triangles.len() as u64,
            texels: scene
                .textures
                .iter()
                .map(|t| (t.width as u64).saturating_mul(t.height as u64))
                .fold(0u64, u64::saturating_add),
            specular: scene.has_specular(),
            mean_albedo: mean_albedo(scene),
        }
    }
}

/// Estimate the memory of rendering `cameras` of `scene` with `settings` in the current
/// thread pool (its size sets the per-thread part). Items are sorted largest first.
pub fn estimate_render(scene: &Scene, cameras: &[&Camera], settings: &Settings) -> MemoryEstimate {
    estimate_footprint(&SceneFootprint::of(scene), cameras, settings)
}

/// [`estimate_render`] from a scene's [`SceneFootprint`].
pub fn estimate_footprint(scene: &SceneFootprint, cameras: &[&Camera], settings: &Settings) -> MemoryEstimate {
    let (limit, limit_origin) = memory_limit(settings);
    let mut items = Items::default();
    // The scene and its BVH.
    let (tris, texels) = (scene.triangles, scene.texels);
    items.add(
        format!("the scene and its BVH ({tris} triangles, {texels} texels)"),
        tris.saturating_mul(BYTES_PER_TRIANGLE)
            .saturating_add(texels.saturating_mul(12)),
        "render a smaller scene",
    );
    image_items(&mut items, cameras, settings);
    let stored = photon_items(&mut items, scene, settings);
    grid_items(&mut items, settings, stored);
    let mut items = items.0;
    items.sort_by_key(|i| std::cmp::Reverse(i.bytes));
    MemoryEstimate {
        items,
        limit,
        limit_origin,
    }
}

/// The parts of an estimate; empty ones are left out.
#[derive(Default)]
struct Items(Vec<Item>);

impl Items {
    fn add(&mut self, what: String, bytes: u64, change: &str) {
        if bytes > 0 {
            self.0.push(Item {
                what,
                bytes,
                change: change.to_string(),
            })
        }
    }
}

/// The cameras' images and the pass being rendered and written.
fn image_items(items: &mut Items, cameras: &[&Camera], settings: &Settings) {
    let needs = settings.method.needs();
    let spp = settings.spp.max(1) as u64;
    let sizes: Vec<(u64, u32, u32)> = cameras
        .iter()
        .map(|c| {
            let (w, h) = c.resolution(settings.width, settings.height);
            ((w as u64) * (h as u64), w, h)
        })
        .collect();
    let pixels: u64 = sizes.iter().map(|s| s.0).sum();
    let largest = sizes.iter().max_by_key(|s| s.0).copied().unwrap_or((0, 0, 0));
    let several = if cameras.len() == 1 {
        format!("1 camera at {}×{}", largest.1, largest.2)
    } else {
        format!("{} cameras, {} pixels in all", cameras.len(), pixels)
    };
    let film_change = if cameras.len() > 1 {
        "render fewer cameras at once (--camera NAME|INDEX) or at a lower resolution (--width, --height)"
    } else {
        "lower the resolution (--width, --height)"
    };
    items.add(
        format!("images of {several}: {BYTES_PER_PIXEL} bytes a pixel across passes"),
        pixels.saturating_mul(BYTES_PER_PIXEL),
        film_change,
    );
    if needs.accumulation == Accumulation::PerSample {
        items.add(
            format!("SPPM state of every camera sample ({several} × --spp {spp} × {SPPM_BYTES_PER_SAMPLE} bytes)"),
            pixels.saturating_mul(spp).saturating_mul(SPPM_BYTES_PER_SAMPLE),
            "lower --spp (SPPM keeps each sample's radius and flux across passes; add passes with --passes instead) or use another --method",
        );
    }
    items.add(
        format!(
            "one camera's pass and output while it renders and is written ({}×{})",
            largest.1, largest.2
        ),
        largest.0.saturating_mul(TRANSIENT_BYTES_PER_PIXEL),
        "lower the resolution (--width, --height)",
    );
}

/// One pass's photons; returns how many are stored.
fn photon_items(items: &mut Items, scene: &SceneFootprint, settings: &Settings) -> u64 {
    // A time budget may ask for more caustic photons where caustics carry much of the light
    // (more global photons only as far as the limit allows: `photons_within_limit`).
    let boost = if settings.time.is_some() { CAUSTIC_BOOST } else { 1 };
    let paths = settings.photons as u64;
    let caustic = if scene.specular && settings.photons > 0 {
        settings.caustic_photons.saturating_mul(boost) as u64
    } else {
        0
    };
    let rho = scene.mean_albedo;
    let depth = settings.photon_hits().max(1) as i32;
    let per_path = if rho < 1.0 {
        (1.0 - rho.powi(depth)) / (1.0 - rho)
    } else {
        depth as f64
    };
    let gather = settings.effective_gather() > 0;
    let stored = (paths as f64 * per_path + caustic as f64).min(u64::MAX as f64 / 1024.0) as u64;
    let per_photon = BYTES_PER_PHOTON + if gather { GATHER_BYTES_PER_PHOTON } else { 0 };
    items.add(
        format!(
            "one pass's photons (about {stored} stored: {paths} paths × {per_path:.1} bounces at mean albedo {rho:.2}{}, {per_photon} bytes each)",
            if caustic > 0 && boost > 1 {
                format!(", plus {caustic} caustic paths: {boost}× --caustic-photons, as a time budget asks where caustics carry much of the light")
            } else if caustic > 0 {
                format!(", plus {caustic} caustic paths")
            } else {
                String::new()
            }
        ),
        stored.saturating_mul(per_photon),
        "lower --photons (and --caustic-photons); add passes with --passes instead",
    );
    stored
}

/// The grids the estimate needs, for `stored` photons a pass.
fn grid_items(items: &mut Items, settings: &Settings, stored: u64) {
    let needs = settings.method.needs();
    if needs.grids && settings.grid != crate::settings::GridMode::None {
        let cells = (settings.grid_res as u64).saturating_pow(2);
        items.add(
            format!(
                "plane grids (at least one plane of --grid-res {}² cells)",
                settings.grid_res
            ),
            cells.saturating_mul(BYTES_PER_GRID_CELL),
            "lower --grid-res",
        );
    }
    if needs.multiscale {
        let cells = settings.multiscale_cells(stored as usize);
        items.add(
            format!(
                "multiscale grids ({cells} cells: --grid-cells {}, at most {} a stored photon)",
                settings.grid_cells,
                Settings::MULTISCALE_CELLS_PER_PHOTON
            ),
            (cells as u64).saturating_mul(BYTES_PER_MULTISCALE_CELL),
            "lower --grid-cells",
        );
    }
}

/// How many of `cameras`, from the first, can render together within the limit (at least 1:
/// a single camera that does not fit is refused by [`check_render`] with its own message).
pub fn cameras_that_fit(scene: &Scene, cameras: &[&Camera], settings: &Settings) -> usize {
    cameras_that_fit_footprint(&SceneFootprint::of(scene), cameras, settings)
}

/// [`cameras_that_fit`] from a scene's [`SceneFootprint`].
fn cameras_that_fit_footprint(scene: &SceneFootprint, cameras: &[&Camera], settings: &Settings) -> usize {
    if cameras.len() <= 1 || estimate_footprint(scene, cameras, settings).fits() {
        return cameras.len();
    }
    // The estimate grows with the cameras: bisect.
    let (mut lo, mut hi) = (1usize, cameras.len());
    while lo + 1 < hi {
        let mid = lo + (hi - lo) / 2;
        if estimate_footprint(scene, &cameras[..mid], settings).fits() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// `size` (a time-budgeted pass, its counts final) with its global photons lowered, not below
/// the settings' own, until one pass of it fits the memory limit: a budget buys photons beyond
/// those asked for only as far as memory allows.
pub fn photons_within_limit(scene: &Scene, cameras: &[&Camera], settings: &Settings, size: PassSize) -> PassSize {
    let footprint = SceneFootprint::of(scene);
    photons_within_footprint(&footprint, cameras, settings, size)
}

fn photons_within_footprint(
    scene: &SceneFootprint,
    cameras: &[&Camera],
    settings: &Settings,
    size: PassSize,
) -> PassSize {
    let fits = |photons: usize| {
        // The counts are the pass's own: no boost on top (`time` unset).
        let pass = Settings {
            time: None,
            ..PassSize { photons, ..size }.apply(settings)
        };
        estimate_footprint(scene, cameras, &pass).fits()
    };
    let mut photons = size.photons;
    while photons > settings.photons && !fits(photons) {
        photons = (photons / 4 * 3).max(settings.photons);
    }
    if photons < size.photons {
        tracing::info!(
            "the time budget would buy {} global photons per pass; {photons} fit the memory limit",
            size.photons
        );
    }
    PassSize { photons, ..size }
}

/// Refuse a render whose estimate is over the limit, before anything large is allocated.
pub fn check_render(scene: &Scene, cameras: &[&Camera], settings: &Settings) -> Result<MemoryEstimate, MemoryError> {
    check_footprint(&SceneFootprint::of(scene), cameras, settings)
}

/// [`check_render`] from a scene's [`SceneFootprint`].
pub fn check_footprint(
    scene: &SceneFootprint,
    cameras: &[&Camera],
    settings: &Settings,
) -> Result<MemoryEstimate, MemoryError> {
    let estimate = estimate_footprint(scene, cameras, settings);
    if estimate.fits() {
        tracing::debug!(
            "memory estimate {} of {} ({})",
            human(estimate.total()),
            human(estimate.limit),
            estimate.limit_origin
        );
        return Ok(estimate);
    }
    let needed = estimate.total();
    let parts: Vec<String> = estimate
        .items
        .iter()
        .map(|i| format!("{}: {}", i.what, human(i.bytes)))
        .collect();
    let mut change = estimate.items[0].change.clone();
    if cameras.len() > 1 {
        let n = cameras_that_fit_footprint(scene, cameras, settings);
        if estimate_footprint(scene, &cameras[..n], settings).fits() {
            change = format!("{change}; {n} of the {} cameras fit at once", cameras.len());
        }
    }
    Err(MemoryError {
        needed,
        limit: estimate.limit,
        message: format!(
            "the render would need about {} ({}), more than the memory limit of {} ({}); {change}, or raise the limit with --memory-limit",
            human(needed),
            parts.join("; "),
            human(estimate.limit),
            estimate.limit_origin,
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_budget_buys_photons_only_as_far_as_memory_allows() {
        let scene = SceneFootprint {
            triangles: 10_000,
            texels: 0,
            specular: true,
            mean_albedo: 0.5,
        };
        let settings = Settings {
            photons: 1_000_000,
            caustic_photons: 100_000,
            width: Some(64),
            height: Some(48),
            time: Some(10.0),
            ..Settings::default()
        };
        let size = PassSize {
            photons: 8_000_000,
            caustic_photons: 300_000,
            spp: 4,
            gather: 8,
        };
        let pass = |photons: usize, limit: u64| Settings {
            memory_limit: Some(limit),
            time: None,
            ..PassSize { photons, ..size }.apply(&settings)
        };
        let bytes = |photons: usize| estimate_footprint(&scene, &[], &pass(photons, u64::MAX)).total();
        assert!(bytes(8_000_000) > bytes(4_000_000) + (1 << 20));
        let within = |limit: u64| {
            let s = Settings {
                memory_limit: Some(limit),
                ..settings.clone()
            };
            photons_within_footprint(&scene, &[], &s, size).photons
        };
        // Room for all of them: unchanged.
        assert_eq!(within(bytes(8_000_000)), 8_000_000);
        // Room for about half: fewer, and the pass fits.
        let half = within(bytes(4_000_000));
        assert!((1_000_000..=4_000_000).contains(&half), "{half}");
        assert!(estimate_footprint(&scene, &[], &pass(half, bytes(4_000_000))).fits());
        // No room at all: never below what the settings ask for (the render's own check
        // refuses it with its message).
        assert_eq!(within(1), 1_000_000);
    }

    #[test]
    fn sizes_print() {
        assert_eq!(human(3 << 29), "1.5 GiB");
    }

    #[test]
    fn default_limit_is_half_the_ram() {
        let (limit, origin) = memory_limit(&Settings::default());
        match physical_ram() {
            Some(ram) => assert_eq!(limit, ram / 2, "{origin}"),
            None => assert_eq!(limit, FALLBACK_LIMIT),
        }
        let set = Settings {
            memory_limit: Some(1 << 20),
            ..Settings::default()
        };
        assert_eq!(memory_limit(&set).0, 1 << 20);
    }
}
