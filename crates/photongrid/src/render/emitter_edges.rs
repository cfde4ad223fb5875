//! Pixels where the camera sees the edge of an emitter. An emitter seen directly is often tens of
//! times brighter than the surfaces around it, so at its outline the share of the pixel it
//! covers can be the largest noise in the image (measured: docs/architecture.md, "Camera
//! samples"). There, each sample's emission is replaced by the mean of [`EDGE_RAYS`]
//! emission-only camera rays (a ray and a material lookup each, no shading): an unbiased
//! estimate of the same integral with many more positions, for almost nothing. The flags are
//! found once per camera, at the first pass, with one ray per pixel; SPPM does not use them.

use super::{seen_emission, CameraPass};
use crate::sampling::{self, stream};
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::Vec2;
use rayon::prelude::*;

/// Emission-only rays per camera sample at an edge pixel.
pub const EDGE_RAYS: u32 = 16;

/// The pixels of one camera (at one resolution) whose 3×3 neighbourhood has both centre rays
/// that see emission and centre rays that do not.
#[derive(Clone, Debug)]
pub struct EmitterEdges {
    width: usize,
    flagged: Vec<bool>,
    count: usize,
}

impl EmitterEdges {
    /// Find the edges from one ray through each pixel's centre; `None` when the scene has no
    /// emissive material or none is at an edge in view. The flags depend on the camera only, not
    /// on any sample, so the estimate stays unbiased wherever they fall.
    pub fn find(pass: &CameraPass<'_>) -> Option<Self> {
        if !pass.scene.materials.iter().any(|m| m.is_emissive()) {
            return None;
        }
        let (w, h) = (pass.settings.width as usize, pass.settings.height as usize);
        let lit: Vec<bool> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let film = Vec2::new((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                emission_along(pass, film).max_element() > 0.0
            })
            .collect();
        let flagged: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let mut around = (y.saturating_sub(1)..(y + 2).min(h))
                    .flat_map(|v| (x.saturating_sub(1)..(x + 2).min(w)).map(move |u| v * w + u));
                around.any(|j| lit[j] != lit[i])
            })
            .collect();
        let count = flagged.iter().filter(|&&f| f).count();
        (count > 0).then_some(EmitterEdges {
            width: w,
            flagged,
            count,
        })
    }

    /// Whether pixel (x, y) is at an edge.
    pub fn contains(&self, x: usize, y: usize) -> bool {
        self.flagged.get(y * self.width + x).copied().unwrap_or(false)
    }

    /// Pixels at an edge.
    pub fn count(&self) -> usize {
        self.count
    }
}

/// The emission a camera ray through film position `film` sees first (zero for none).
fn emission_along(pass: &CameraPass<'_>, film: Vec2) -> Rgb {
    let (o, d) = pass
        .camera
        .generate_ray(film, pass.settings.width, pass.settings.height);
    match pass.accel.intersect(o, d, f32::INFINITY) {
        Some(hit) => seen_emission(pass.scene, &SurfacePoint::new(pass.scene, o, d, hit)),
        None => Rgb::ZERO,
    }
}

/// The mean emission seen by [`EDGE_RAYS`] camera rays through pixel (x, y) for sample `index`
/// of its sequence: positions from their own scrambled sequence, continued across samples and
/// passes as the samples' own ([`sampling::owen_sobol`]).
pub fn edge_emission(pass: &CameraPass<'_>, x: usize, y: usize, index: u32) -> Rgb {
    let pixel = (y * pass.settings.width as usize + x) as u64;
    let scramble = sampling::pixel_scramble(pass.settings.sequence_seed, stream::EDGE_RAYS, pixel);
    let first = index.wrapping_mul(EDGE_RAYS);
    let sum = (0..EDGE_RAYS).fold(Rgb::ZERO, |s, k| {
        let film = Vec2::new(x as f32, y as f32) + sampling::owen_sobol(first.wrapping_add(k), scramble);
        s + emission_along(pass, film)
    });
    sum / EDGE_RAYS as f32
}
