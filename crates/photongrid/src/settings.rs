//! Render settings: one struct with defaults and validation, shared by the command line (its
//! flags are derived from it with the `cli` feature), jobs files and stats (serde, same names),
//! the Blender add-on (through `photongrid settings --schema`) and the benchmarks. A new option
//! is added here once.

use serde::{Deserialize, Serialize};

/// Everything that controls a render (except which scene and camera).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Settings {
    /// Photon paths emitted per pass (2M, 500k and 1e6 are accepted). 0: no photons at all, the
    /// caustic pass included (direct light only).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Photons", value_parser = parse_count, default_value_t = Settings::default().photons))]
    #[serde(deserialize_with = "count::deserialize")]
    pub photons: usize,
    /// Extra photon paths aimed at mirrors and glass, for caustics (none are traced when the
    /// scene has no mirror or glass).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Photons", value_parser = parse_count, default_value_t = Settings::default().caustic_photons))]
    #[serde(deserialize_with = "count::deserialize")]
    pub caustic_photons: usize,
    /// Photon bounces before a path stops (a cap on the photon pass alone; max-depth limits
    /// whole light paths).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Photons", default_value_t = Settings::default().max_photon_depth))]
    pub max_photon_depth: u32,
    /// Longest light path, in segments from the light to the camera, counted like Mitsuba's
    /// max_depth (every surface interaction counts, glass and mirrors included; 2: direct light
    /// only). The references use 12, as does Cycles' default. 0: no limit but
    /// max-photon-depth. Mirror and glass bounces between the camera and the visible point
    /// (or on a final-gather ray) are not counted.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", default_value_t = Settings::default().max_depth))]
    pub max_depth: u32,

    /// Image width in pixels (default: the camera's aspect at 480 lines).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Image"))]
    pub width: Option<u32>,
    /// Image height in pixels.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Image"))]
    pub height: Option<u32>,
    /// Camera rays per pixel and pass (jittered, 1-pixel box filter).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Image", default_value_t = Settings::default().spp))]
    pub spp: u32,
    /// Random seed: the same seed and settings give the same image, whatever the thread count.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Image", default_value_t = Settings::default().seed))]
    pub seed: u64,

    /// Radiance estimate from photons.
    #[cfg_attr(feature = "cli", arg(long, value_enum, help_heading = "Estimate", default_value_t = Settings::default().method))]
    pub method: Method,
    /// Photons per radiance estimate (k nearest neighbours; n of the paper; 1k is accepted).
    #[cfg_attr(feature = "cli", arg(long, visible_alias = "neighbors", help_heading = "Estimate", value_parser = parse_count, default_value_t = Settings::default().neighbours))]
    #[serde(deserialize_with = "count::deserialize")]
    pub neighbours: usize,
    /// Direct light from shadow rays, or from photons like the paper's single photon map.
    #[cfg_attr(feature = "cli", arg(long, value_enum, help_heading = "Estimate", default_value_t = Settings::default().direct))]
    pub direct: DirectLighting,
    /// Share of the kNN radius error kept by the paper's method: r = r_a + alpha (r_k − r_a).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Estimate", default_value_t = Settings::default().alpha))]
    pub alpha: f32,
    /// Filtered photons per grid cell below which the kNN radius is used (shadows).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Estimate", default_value_t = Settings::default().shadow_count))]
    pub shadow_count: f32,
    /// Largest kNN search radius, as a fraction of the scene's bounding-box diagonal (searches
    /// also stop at three times the radius that holds k photons at the map's mean density).
    /// Where fewer than k photons lie closer, the estimate uses those within it.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Estimate", default_value_t = Settings::default().max_radius))]
    #[serde(alias = "max_radius_rel")]
    pub max_radius: f32,

    /// Grids of the adaptive estimate: planes where there are planes and voxels where needed
    /// (auto), planes only (the paper), voxels for everything, or none.
    #[cfg_attr(feature = "cli", arg(long, value_enum, help_heading = "Grids", default_value_t = Settings::default().grid))]
    pub grid: GridMode,
    /// Cells along the longer side of each plane's count grid (the paper: 128).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().grid_res))]
    pub grid_res: usize,
    /// Wavelet for the photon-count textures.
    #[cfg_attr(feature = "cli", arg(long, value_enum, help_heading = "Grids", default_value_t = Settings::default().wavelet))]
    pub wavelet: WaveletChoice,
    /// Thresholding of wavelet details: the paper's fixed value, or set from the data.
    #[cfg_attr(feature = "cli", arg(long, value_enum, help_heading = "Grids", default_value_t = Settings::default().threshold))]
    pub threshold: ThresholdChoice,
    /// The threshold (photon counts) of the fixed thresholding.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().threshold_value))]
    pub threshold_value: f32,
    /// Wavelet levels (at most; fewer on small grids).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().wavelet_levels))]
    pub wavelet_levels: usize,
    /// Multiscale estimate: a scale is kept while its estimate stays within this many
    /// standard deviations of every finer one (higher: smoother, more blur). Below 2, kernels
    /// that should hold fewer than 8 photons still use 2: so few photons say too little for a
    /// narrower interval.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().ici_threshold))]
    pub ici_threshold: f32,
    /// Multiscale estimate: the same for caustic photons (lower: caustic filaments stay
    /// sharper, at some grain; the same 8-photon rule).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().caustic_ici_threshold))]
    pub caustic_ici_threshold: f32,
    /// Multiscale estimate: the same for direct photons where every light is a point, spot or
    /// sun. Their photons are emitted from stratified points and land far more evenly than
    /// the Poisson counts the intervals are measured in, so the interval is narrower (an
    /// emitting surface's photons take four numbers each and land nearly as unevenly as
    /// independent ones).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().stratified_ici_threshold))]
    pub stratified_ici_threshold: f32,
    /// Multiscale estimate: the same for caustic photons where every light is a point, spot
    /// or sun (lower: caustic bands keep sharper edges, at some grain).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().stratified_caustic_ici_threshold))]
    pub stratified_caustic_ici_threshold: f32,
    /// Multiscale estimate: photons per finest cell where a plane's photons are densest.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", default_value_t = Settings::default().cell_photons))]
    pub cell_photons: f32,
    /// Multiscale estimate: finest cells over all planes (about 75 bytes each).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Grids", value_parser = parse_count, default_value_t = Settings::default().grid_cells))]
    #[serde(deserialize_with = "count::deserialize")]
    pub grid_cells: usize,
    /// Whether grid cells count photons or flux.
    #[cfg_attr(feature = "cli", arg(long, value_enum, help_heading = "Grids", default_value_t = Settings::default().grid_quantity))]
    pub grid_quantity: GridQuantity,

    /// Shadow rays per emissive-surface light evaluation (point, spot and sun lights take one).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", default_value_t = Settings::default().light_samples))]
    pub light_samples: u32,
    /// Mirror and glass bounces followed from the camera.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", default_value_t = Settings::default().max_specular_depth))]
    pub max_specular_depth: u32,
    /// Depth up to which both glass branches (reflection and refraction) are followed from the
    /// camera; deeper, one is chosen by Fresnel.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", default_value_t = Settings::default().split_depth))]
    pub split_depth: u32,
    /// Final-gather rays per camera sample (0: show the photon map directly, as the paper; at
    /// most 4096).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", default_value_t = Settings::default().gather))]
    pub gather: u32,
    /// Photons per precomputed irradiance estimate (final gathering).
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", value_parser = parse_count, default_value_t = Settings::default().gather_neighbours))]
    #[serde(deserialize_with = "count::deserialize")]
    pub gather_neighbours: usize,
    /// Every how many photons (of those final gathering reads) an irradiance point is
    /// precomputed.
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", value_parser = parse_count, default_value_t = Settings::default().gather_stride))]
    #[serde(deserialize_with = "count::deserialize")]
    pub gather_stride: usize,
    /// Share of the final-gather rays aimed at the brightest surfaces the multiscale grids
    /// know (in proportion to the light they reflect) rather than spread over the hemisphere;
    /// the two kinds are weighted by multiple importance sampling. 0: none
    #[cfg_attr(feature = "cli", arg(long, help_heading = "Light paths", default_value_t = Settings::default().gather_bright))]
    pub gather_bright: f32,

    /// Progressive rendering: at most this many passes, each tracing as many new photons and
    /// adding as many new camera samples per pixel as one pass (neither this nor a time budget:
    /// one pass).
    #[cfg_attr(feature = "cli", arg(long, value_name = "P", help_heading = "Passes and time"))]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub passes: Option<u32>,
    /// Time budget: passes are added while the next one is expected to end within this wall
    /// time, counted from the start (at least one pass runs). Seconds, or 90s, 2.5m, 1h. The
    /// pass count then depends on the machine; the stats report it.
    #[cfg_attr(feature = "cli", arg(long, visible_alias = "time-budget", value_name = "SECONDS", value_parser = parse_seconds, help_heading = "Passes and time"))]
    #[serde(skip_serializing_if = "Option::is_none", alias = "time_budget")]
    pub time: Option<f64>,

    /// Memory limit of a render (8G, 512M, 16GiB or bytes; default half of the RAM): a render
    /// whose estimate (images, per-sample state, photons, grids) is larger is refused up front,
    /// with the estimate and what to change. Also the scene loader's budget.
    #[cfg_attr(feature = "cli", arg(long, value_name = "BYTES", value_parser = parse_bytes, help_heading = "Passes and time"))]
    #[serde(skip_serializing_if = "Option::is_none", deserialize_with = "bytes::deserialize")]
    pub memory_limit: Option<u64>,
}

/// Where direct illumination comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum DirectLighting {
    /// Shadow rays to every light; the photon map gives indirect light and caustics only.
    ShadowRays,
    /// The paper's single map: all light, direct included, from photons.
    Photons,
}

/// The radiance estimate (see `estimate`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Classic k nearest neighbours (Jensen): r = distance to the k-th photon.
    Knn,
    /// The paper's: assumed radius from the filtered grids, blended with r_k.
    Adaptive,
    /// Stochastic progressive photon mapping (Hachisuka & Jensen 2009): a radius per camera
    /// sample that shrinks as passes add photons.
    Sppm,
    /// The grids as the estimator: flux pyramids on the planes, the scale chosen per point
    /// by intersecting confidence intervals (flat light: wide, edges and caustics: narrow),
    /// normalised by the surface actually covered; off the planes the widest of nested kNN
    /// discs that agrees with the narrower ones.
    Multiscale,
}

/// Which grids the adaptive estimate uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum GridMode {
    /// Plane grids for planes; voxels only where enough receiving area is not planar.
    Auto,
    /// Plane grids only (the paper); other surfaces use plain kNN.
    Planes,
    /// One sparse voxel grid for every surface.
    Voxels,
    /// No grid: plain kNN everywhere.
    None,
}

/// What a grid cell accumulates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum GridQuantity {
    /// Number of photons. The kNN radius is set by how many photons lie around a point, so
    /// counts predict it directly, whatever each photon's power.
    Count,
    /// Flux, expressed in "mean photons" (cell flux / mean photon flux of the plane): equals
    /// the count when photons carry equal power, differs after coloured bounces.
    Flux,
}

/// Wavelet for the count textures (`none` skips filtering).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum WaveletChoice {
    /// No filtering: raw counts.
    None,
    /// Haar.
    Haar,
    /// CDF 5/3 (LeGall) lifting.
    Cdf53,
    /// CDF 9/7 lifting.
    Cdf97,
}

/// Thresholding of wavelet detail coefficients.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum ThresholdChoice {
    /// Keep all details (perfect reconstruction).
    None,
    /// The paper's fixed threshold on raw counts (threshold value), hard.
    Fixed,
    /// Anscombe transform, σ from the finest band, hard threshold σ√(2 ln n).
    Universal,
    /// As universal, soft thresholding.
    #[serde(alias = "universalsoft")]
    UniversalSoft,
    /// Anscombe transform, BayesShrink per subband.
    Bayes,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            photons: 2_000_000,
            caustic_photons: 1_000_000,
            max_photon_depth: 16,
            max_depth: 12,
            width: None,
            height: None,
            spp: 4,
            seed: 0,
            method: Method::Multiscale,
            neighbours: 100,
            direct: DirectLighting::ShadowRays,
            alpha: 0.1,
            shadow_count: 8.0,
            max_radius: 0.05,
            grid: GridMode::Auto,
            grid_res: 128,
            wavelet: WaveletChoice::Haar,
            threshold: ThresholdChoice::Universal,
            threshold_value: 4.0,
            wavelet_levels: 4,
            grid_quantity: GridQuantity::Count,
            ici_threshold: 2.0,
            caustic_ici_threshold: 1.0,
            stratified_ici_threshold: 0.5,
            stratified_caustic_ici_threshold: 0.12,
            cell_photons: 2.0,
            grid_cells: 4 << 20,
            light_samples: 4,
            max_specular_depth: 12,
            split_depth: 3,
            gather: 8,
            gather_neighbours: 64,
            gather_stride: 12,
            gather_bright: 0.125,
            passes: None,
            time: None,
            memory_limit: None,
        }
    }
}

/// A setting out of range: which one (its serde key, e.g. `max_radius`) and why.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("`{key}` {message}")]
pub struct SettingsError {
    /// The setting's key as jobs files and stats spell it.
    pub key: &'static str,
    /// What is wrong and what to do, without the setting's name.
    pub message: String,
}

impl SettingsError {
    fn new(key: &'static str, message: impl Into<String>) -> Self {
        SettingsError {
            key,
            message: message.into(),
        }
    }

    /// The command-line flag of the setting (`max_radius` → `--max-radius`).
    pub fn flag(&self) -> String {
        format!("--{}", self.key.replace('_', "-"))
    }

    /// The error in command-line terms: `--max-radius must be …`.
    pub fn for_cli(&self) -> String {
        format!("{} {}", self.flag(), self.message)
    }
}

/// Largest image, in pixels (a film of 2^28 pixels takes several GiB).
pub const MAX_PIXELS: u64 = 1 << 28;

/// Most camera samples per pixel in one pass: beyond this a single pass would run for days on
/// an ordinary image, while passes (`--passes`, `--time`) add samples with a result to look
/// at after each.
pub const MAX_SPP: u32 = 1 << 16;

/// Most final-gather rays per camera sample: beyond this one sample's gathers cost more than
/// many samples would, and samples (`--spp`) spread the same rays over the pixel as well.
pub const MAX_GATHER: u32 = 1 << 12;

impl Settings {
    /// Check values that would make a render meaningless or impossible, with what to do.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let e = |key, message: &str| SettingsError::new(key, message);
        if self.neighbours == 0 {
            return Err(e("neighbours", "must be at least 1"));
        }
        if self.max_depth == 1 {
            return Err(e("max_depth", "must be 0 (no limit) or at least 2 (direct light)"));
        }
        self.validate_sizes()?;
        if !(0.0..1.0).contains(&self.gather_bright) {
            return Err(e(
                "gather_bright",
                "must be at least 0 and below 1 (some gather rays must cover the whole hemisphere)",
            ));
        }
        if !(self.max_radius > 0.0 && self.max_radius.is_finite()) {
            return Err(e("max_radius", "must be a positive fraction of the scene diagonal"));
        }
        if self.grid_res == 0 || self.grid_res > 4096 {
            return Err(e("grid_res", "must be between 1 and 4096"));
        }
        if !(0.0..=1.0).contains(&self.alpha) {
            return Err(e("alpha", "must be between 0 and 1"));
        }
        if !(self.shadow_count >= 0.0 && self.shadow_count.is_finite()) {
            return Err(e("shadow_count", "must be a number ≥ 0"));
        }
        if !(self.ici_threshold > 0.0 && self.ici_threshold.is_finite()) {
            return Err(e("ici_threshold", "must be a positive number"));
        }
        if !(self.caustic_ici_threshold > 0.0 && self.caustic_ici_threshold.is_finite()) {
            return Err(e("caustic_ici_threshold", "must be a positive number"));
        }
        if !(self.stratified_ici_threshold > 0.0 && self.stratified_ici_threshold.is_finite()) {
            return Err(e("stratified_ici_threshold", "must be a positive number"));
        }
        if !(self.stratified_caustic_ici_threshold > 0.0 && self.stratified_caustic_ici_threshold.is_finite()) {
            return Err(e("stratified_caustic_ici_threshold", "must be a positive number"));
        }
        if !(self.cell_photons > 0.0 && self.cell_photons.is_finite()) {
            return Err(e("cell_photons", "must be a positive number"));
        }
        if self.grid_cells == 0 {
            return Err(e("grid_cells", "must be at least 1"));
        }
        if self.passes == Some(0) {
            return Err(e("passes", "must be at least 1"));
        }
        if let Some(t) = self.time {
            if !(t > 0.0 && t.is_finite()) {
                return Err(e("time", "must be a positive number of seconds"));
            }
        }
        Ok(())
    }

    /// [`Settings::validate`]'s checks of the image and the work per pixel.
    fn validate_sizes(&self) -> Result<(), SettingsError> {
        let e = |key, message: &str| SettingsError::new(key, message);
        if self.spp == 0 {
            return Err(e("spp", "must be at least 1"));
        }
        if self.spp > MAX_SPP {
            return Err(e(
                "spp",
                &format!(
                    "{} is more than {MAX_SPP} samples per pixel in one pass: lower it, and add passes (passes) or a time budget (time) instead",
                    self.spp
                ),
            ));
        }
        if self.gather > MAX_GATHER {
            return Err(e(
                "gather",
                &format!(
                    "{} is more than {MAX_GATHER} final-gather rays per camera sample: lower it, and add samples per pixel (spp) instead",
                    self.gather
                ),
            ));
        }
        if self.width == Some(0) {
            return Err(e("width", "must be at least 1"));
        }
        if self.height == Some(0) {
            return Err(e("height", "must be at least 1"));
        }
        let (w, h) = (self.width.unwrap_or(640) as u64, self.height.unwrap_or(480) as u64);
        if w * h > MAX_PIXELS {
            return Err(e(
                "width",
                &format!("× height = {w}×{h} pixels is too large (at most 2^28)"),
            ));
        }
        Ok(())
    }

    /// Surface interactions a photon path may have: `max_photon_depth`, and at most
    /// `max_depth − 1` (light seen at the last one has travelled `max_depth` segments).
    pub fn photon_hits(&self) -> u32 {
        match self.max_depth {
            0 => self.max_photon_depth,
            d => self.max_photon_depth.min(d.saturating_sub(1)),
        }
    }

    /// Whether a photon stored at its `depth`-th interaction may light a visible point through
    /// one final-gather bounce (the path is then `depth + 2` segments long).
    pub fn gathered(&self, depth: u32) -> bool {
        self.max_depth == 0 || depth + 2 <= self.max_depth
    }

    /// Most multiscale fine cells per stored photon of the first pass: cells hold about
    /// `cell_photons` photons where the light is densest, so more would only cost memory (a
    /// small render is not charged the whole `grid_cells` budget).
    pub const MULTISCALE_CELLS_PER_PHOTON: usize = 4;

    /// Fine cells of the multiscale pyramids for a first pass of `stored` photons:
    /// `grid_cells`, or fewer for few photons (at least 64k).
    pub fn multiscale_cells(&self, stored: usize) -> usize {
        self.grid_cells
            .min(stored.saturating_mul(Self::MULTISCALE_CELLS_PER_PHOTON).max(1 << 16))
    }

    /// Final-gather rays actually used: SPPM gathers photons at its visible points itself, so
    /// `gather` does not apply to it.
    pub fn effective_gather(&self) -> u32 {
        if self.method == Method::Sppm {
            0
        } else {
            self.gather
        }
    }
}

/// Seconds from `90`, `90s`, `2.5m` or `1h`; must be positive.
pub fn parse_seconds(v: &str) -> Result<f64, String> {
    let s = parse_seconds_or_zero(v)?;
    if s > 0.0 {
        Ok(s)
    } else {
        Err("must be more than 0 seconds".into())
    }
}

/// As [`parse_seconds`], 0 allowed.
pub fn parse_seconds_or_zero(v: &str) -> Result<f64, String> {
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

/// A count from `2000000`, `2e6`, `2M`, `500k` or `1.5G`: a whole, non-negative number.
pub fn parse_count(v: &str) -> Result<usize, String> {
    let t = v.trim().replace('_', "");
    let (num, unit) = match t.char_indices().last() {
        Some((i, 'k' | 'K')) => (&t[..i], 1e3),
        Some((i, 'M')) => (&t[..i], 1e6),
        Some((i, 'G')) => (&t[..i], 1e9),
        _ => (t.as_str(), 1.0),
    };
    let bad = || format!("`{v}` is not a count: use e.g. 2000000, 2e6, 2M or 500k");
    let x = num.trim().parse::<f64>().map_err(|_| bad())? * unit;
    if !(x >= 0.0 && x.is_finite() && x.fract() == 0.0 && x <= usize::MAX as f64) {
        return Err(bad());
    }
    Ok(x as usize)
}

/// Bytes from `8G`, `512M`, `1.5GiB`, `300k`, `2e9` or `4096` (units of 1024; `B` and `iB`
/// optional).
pub fn parse_bytes(v: &str) -> Result<u64, String> {
    let t = v.trim().replace('_', "");
    let lower = t.to_ascii_lowercase();
    let s = lower.trim_end_matches('b').trim_end_matches('i');
    let (num, unit) = match s.char_indices().last() {
        Some((i, 'k')) => (&s[..i], 1u64 << 10),
        Some((i, 'm')) => (&s[..i], 1 << 20),
        Some((i, 'g')) => (&s[..i], 1 << 30),
        Some((i, 't')) => (&s[..i], 1 << 40),
        _ => (s, 1),
    };
    let bad = || format!("`{v}` is not a size: use e.g. 8G, 512M, 16GiB or a number of bytes");
    let x = num.trim().parse::<f64>().map_err(|_| bad())? * unit as f64;
    if !(x >= 1.0 && x.is_finite() && x < u64::MAX as f64) {
        return Err(bad());
    }
    Ok(x as u64)
}

/// Counts in jobs files: a number, or a string `parse_count` reads (`"2M"`).
mod count {
    use serde::{Deserialize, Deserializer};

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Count {
        Number(usize),
        Text(String),
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
        match Count::deserialize(d)? {
            Count::Number(n) => Ok(n),
            Count::Text(s) => super::parse_count(&s).map_err(serde::de::Error::custom),
        }
    }
}

/// Sizes in jobs files: a number of bytes, or a string `parse_bytes` reads (`"8G"`).
mod bytes {
    use serde::{Deserialize, Deserializer};

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Size {
        Number(u64),
        Text(String),
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<u64>, D::Error> {
        match Option::<Size>::deserialize(d)? {
            None => Ok(None),
            Some(Size::Number(0)) => Err(serde::de::Error::custom("a memory limit must be more than 0 bytes")),
            Some(Size::Number(n)) => Ok(Some(n)),
            Some(Size::Text(s)) => super::parse_bytes(&s).map(Some).map_err(serde::de::Error::custom),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_durations_parse() {
        assert_eq!(parse_count("2M"), Ok(2_000_000));
        assert_eq!(parse_count("500k"), Ok(500_000));
        assert_eq!(parse_count("1e6"), Ok(1_000_000));
        assert_eq!(parse_count("1_000"), Ok(1000));
        assert!(parse_count("1.5").is_err() && parse_count("-3").is_err() && parse_count("x").is_err());
        assert_eq!(parse_seconds("2.5m"), Ok(150.0));
        assert_eq!(parse_seconds("90s"), Ok(90.0));
        assert!(parse_seconds("0").is_err());
        assert_eq!(parse_seconds_or_zero("0"), Ok(0.0));
        assert_eq!(parse_bytes("8G"), Ok(8 << 30));
        assert_eq!(parse_bytes("512MiB"), Ok(512 << 20));
        assert_eq!(parse_bytes("1.5g"), Ok(3 << 29));
        assert_eq!(parse_bytes("4096"), Ok(4096));
        assert_eq!(parse_bytes("2k"), Ok(2048));
        assert!(parse_bytes("x").is_err() && parse_bytes("-1G").is_err() && parse_bytes("0").is_err());
    }

    #[test]
    fn defaults_are_valid_and_errors_name_the_setting() {
        Settings::default().validate().unwrap();
        let s = Settings {
            max_radius: -1.0,
            ..Settings::default()
        };
        let e = s.validate().unwrap_err();
        assert_eq!(e.key, "max_radius");
        assert!(e.for_cli().starts_with("--max-radius "), "{}", e.for_cli());
        assert!(e.to_string().starts_with("`max_radius` "), "{e}");
    }

    #[test]
    fn path_length_counts_like_mitsuba_max_depth() {
        // Mitsuba's max_depth 12 (the references): light paths of at most 11 surface
        // interactions. A photon stored at its 11th is shown directly (11 + 1 segments), one at
        // its 10th is the last that may be read through a final-gather bounce (10 + 2).
        let s = Settings::default();
        assert_eq!(s.max_depth, 12);
        assert_eq!(s.photon_hits(), 11);
        assert!(s.gathered(10) && !s.gathered(11));
        let direct = Settings {
            max_depth: 2,
            ..Settings::default()
        };
        assert_eq!(direct.photon_hits(), 1);
        assert!(!direct.gathered(1));
        let unlimited = Settings {
            max_depth: 0,
            max_photon_depth: 40,
            ..Settings::default()
        };
        assert_eq!(unlimited.photon_hits(), 40);
        assert!(unlimited.gathered(255));
        assert_eq!(
            Settings {
                max_depth: 1,
                ..Settings::default()
            }
            .validate()
            .unwrap_err()
            .key,
            "max_depth"
        );
    }

    #[test]
    fn jobs_files_take_counts_as_text_and_the_old_key() {
        let s: Settings = serde_json::from_str(r#"{"photons": "2M", "max_radius_rel": 0.1}"#).unwrap();
        assert_eq!((s.photons, s.max_radius), (2_000_000, 0.1));
        let round: Settings = serde_json::from_value(serde_json::to_value(&s).unwrap()).unwrap();
        assert_eq!(round, s);
    }
}
