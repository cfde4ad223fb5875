//! Render settings: one struct with defaults, shared by the CLI, batch jobs, the add-on and
//! the benchmarks, so a new option is added once.

use crate::render::DirectLighting;
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
        Ok(())
    }
}
