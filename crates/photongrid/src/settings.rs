//! Render settings: one struct with defaults, shared by the CLI, batch jobs, the add-on and
//! the benchmarks, so a new option is added once.

use crate::grid::wavelet::{Threshold, Wavelet};
use crate::grid::{GridMode, GridQuantity};
use crate::render::{DirectLighting, Method};
use serde::{Deserialize, Serialize};

/// Everything that controls a render (except which scene and camera).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    /// Photon paths emitted.
    pub photons: usize,
    /// Photons per radiance estimate (k).
    pub neighbours: usize,
    /// Camera rays per pixel.
    pub spp: u32,
    /// Random seed (same seed and settings → same image, whatever the thread count).
    pub seed: u64,
    /// Image width (default: from the camera's aspect at 480 lines).
    pub width: Option<u32>,
    /// Image height.
    pub height: Option<u32>,
    /// Direct light from shadow rays or from photons (the paper's single map).
    pub direct: DirectLighting,
    /// Shadow rays per emissive-light evaluation.
    pub light_samples: u32,
    /// Photon bounces before a path stops.
    pub max_photon_depth: u32,
    /// Mirror/glass bounces followed from the camera.
    pub max_specular_depth: u32,
    /// Depth up to which both glass branches are followed from the camera.
    pub split_depth: u32,
    /// Largest gather radius, as a fraction of the scene's bounding-box diagonal (CLI and
    /// jobs files: `max_radius`).
    #[serde(alias = "max_radius")]
    pub max_radius_rel: f32,
    /// Radiance estimate: plain kNN, or the paper's grid-adaptive radius.
    pub method: Method,
    /// Which grids the adaptive method uses (planes, voxels, both, none).
    pub grid: GridMode,
    /// Cells along the longer side of each plane's grid (the paper: 128).
    pub grid_res: usize,
    /// Wavelet for the count textures.
    pub wavelet: WaveletChoice,
    /// Thresholding of the wavelet details.
    pub threshold: ThresholdChoice,
    /// Value of the fixed threshold (photon counts), for `threshold = fixed`.
    pub threshold_value: f32,
    /// Wavelet levels (at most; fewer on small grids).
    pub wavelet_levels: usize,
    /// Share of the kNN radius error kept: `r = r_a + α (r_k − r_a)` (the paper: 0.1).
    pub alpha: f32,
    /// Below this filtered count per cell (shadows, dark corners) the kNN radius is used.
    pub shadow_count: f32,
    /// Whether the textures count photons or flux.
    pub grid_quantity: GridQuantity,
    /// Extra photon paths aimed at mirrors and glass for caustics (skipped when the scene has
    /// none).
    pub caustic_photons: usize,
    /// Final-gather rays per camera sample (0: show the photon map directly, as the paper).
    pub gather: u32,
    /// Photons per precomputed irradiance estimate (final gathering).
    pub gather_neighbours: usize,
    /// Every how many photons an irradiance point is precomputed.
    pub gather_stride: usize,
    /// Progressive rendering: at most this many passes, each tracing `photons` new photons and
    /// adding `spp` camera samples per pixel (none and no `time`: one pass).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub passes: Option<u32>,
    /// Progressive rendering: wall-time budget in seconds; passes are added while the next one
    /// is expected to finish within it (at least one pass runs). Makes the image depend on the
    /// machine's speed; the stats report the passes that ran.
    #[serde(skip_serializing_if = "Option::is_none", alias = "time_budget")]
    pub time: Option<f64>,
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
#[serde(rename_all = "lowercase")]
pub enum ThresholdChoice {
    /// Keep all details (perfect reconstruction).
    None,
    /// The paper's fixed threshold on raw counts (`threshold_value`), hard.
    Fixed,
    /// Anscombe transform, σ from the finest band, hard threshold σ√(2 ln n).
    Universal,
    /// As universal, soft thresholding.
    UniversalSoft,
    /// Anscombe transform, BayesShrink per subband.
    Bayes,
}

impl Settings {
    /// The wavelet, or None for no filtering.
    pub fn wavelet(&self) -> Option<Wavelet> {
        match self.wavelet {
            WaveletChoice::None => None,
            WaveletChoice::Haar => Some(Wavelet::Haar),
            WaveletChoice::Cdf53 => Some(Wavelet::Cdf53),
            WaveletChoice::Cdf97 => Some(Wavelet::Cdf97),
        }
    }

    /// The threshold rule.
    pub fn threshold(&self) -> Threshold {
        match self.threshold {
            ThresholdChoice::None => Threshold::None,
            ThresholdChoice::Fixed => Threshold::Fixed {
                value: self.threshold_value,
                soft: false,
            },
            ThresholdChoice::Universal => Threshold::Universal { soft: false },
            ThresholdChoice::UniversalSoft => Threshold::Universal { soft: true },
            ThresholdChoice::Bayes => Threshold::BayesShrink,
        }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            photons: 2_000_000,
            neighbours: 100,
            spp: 4,
            seed: 0,
            width: None,
            height: None,
            direct: DirectLighting::ShadowRays,
            light_samples: 4,
            max_photon_depth: 16,
            max_specular_depth: 12,
            split_depth: 2,
            max_radius_rel: 0.05,
            method: Method::Adaptive,
            grid: GridMode::Auto,
            grid_res: 128,
            wavelet: WaveletChoice::Haar,
            threshold: ThresholdChoice::Universal,
            threshold_value: 4.0,
            wavelet_levels: 4,
            alpha: 0.1,
            shadow_count: 8.0,
            grid_quantity: GridQuantity::Count,
            caustic_photons: 1_000_000,
            gather: 8,
            gather_neighbours: 64,
            gather_stride: 4,
            passes: None,
            time: None,
        }
    }
}

impl Settings {
    /// Check values that would make a render meaningless, with what to do instead.
    pub fn validate(&self) -> Result<(), String> {
        if self.neighbours == 0 {
            return Err("--neighbours must be at least 1".into());
        }
        if self.spp == 0 {
            return Err("--spp must be at least 1".into());
        }
        if matches!(self.width, Some(0)) || matches!(self.height, Some(0)) {
            return Err("--width and --height must be at least 1".into());
        }
        let (w, h) = (self.width.unwrap_or(640) as u64, self.height.unwrap_or(480) as u64);
        if w * h > 1 << 28 {
            return Err(format!("{w}×{h} pixels is too large (at most 2^28 pixels)"));
        }
        if !(self.max_radius_rel > 0.0 && self.max_radius_rel.is_finite()) {
            return Err("max_radius_rel must be a positive number".into());
        }
        if self.grid_res == 0 || self.grid_res > 4096 {
            return Err("--grid-res must be between 1 and 4096".into());
        }
        if !(0.0..=1.0).contains(&self.alpha) {
            return Err("--alpha must be between 0 and 1".into());
        }
        if !(self.shadow_count >= 0.0) {
            return Err("--shadow-count must be ≥ 0".into());
        }
        if self.passes == Some(0) {
            return Err("--passes must be at least 1".into());
        }
        if let Some(t) = self.time {
            if !(t > 0.0 && t.is_finite()) {
                return Err("--time must be a positive number of seconds".into());
            }
        }
        Ok(())
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
