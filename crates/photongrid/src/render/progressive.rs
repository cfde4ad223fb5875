//! Progressive rendering: the image of each camera accumulates passes, each with new photons
//! and new camera samples, and the [`Budget`] says when to stop. The loop itself, which traces
//! each pass's photons, is [`crate::pipeline::render`].

use super::emitter_edges::EmitterEdges;
use super::sppm::SppmFilm;
use super::{render_until, CameraPass, Cut};
use crate::estimate::Accumulation;
use crate::film::{Aov, Film};
use crate::Rgb;

pub use super::budget::{Budget, Stop};

/// One camera's image across passes.
pub enum Accumulator {
    /// kNN and adaptive: the mean of the passes' images (each a complete render with the
    /// pass's photons and camera samples). AOVs are the first pass's.
    Average {
        /// Sum of the passes' radiance.
        sum: Vec<Rgb>,
        /// AOVs of the first pass.
        aov: Vec<Aov>,
        /// Width, height.
        size: (u32, u32),
        /// Passes added.
        passes: u32,
        /// Sum of the passes' weights.
        weight: f32,
        /// Samples per pixel added.
        samples: u32,
        /// The camera's emitter edges, found at the first pass (`Some(None)`: none).
        edges: Option<Option<EmitterEdges>>,
    },
    /// SPPM: per-sample radius, count and flux.
    Sppm(SppmFilm),
}

impl Accumulator {
    /// An empty image that accumulates passes as `accumulation` says.
    pub fn new(accumulation: Accumulation, width: u32, height: u32, spp: u32) -> Self {
        match accumulation {
            Accumulation::PerSample => Accumulator::Sppm(SppmFilm::new(width, height, spp)),
            Accumulation::Average => Accumulator::Average {
                sum: vec![Rgb::ZERO; width as usize * height as usize],
                aov: Vec::new(),
                size: (width, height),
                passes: 0,
                weight: 0.0,
                samples: 0,
                edges: None,
            },
        }
    }

    /// Render one more pass of `camera` with this pass's photons (`settings.seed` and
    /// `settings.pass` are the pass's), weighted by `weight` in the average (a smaller last pass
    /// of a time budget counts less). A pass cut at `cut`'s deadline keeps the samples per pixel
    /// it completed, its weight scaled by their share (spare sweeps, [`Cut::spare`], add none);
    /// returns the samples per pixel added (0 when the pass is given up; SPPM's passes update
    /// every sample in place and always complete).
    pub fn add_pass(&mut self, pass: CameraPass<'_>, progress: &(dyn Fn(usize) + Sync), cut: Cut, weight: f32) -> u32 {
        let spp = pass.settings.spp.max(1);
        match self {
            Accumulator::Sppm(s) => {
                s.add_pass(pass, progress);
                spp
            }
            Accumulator::Average {
                sum,
                aov,
                passes,
                weight: total,
                samples,
                edges,
                ..
            } => {
                let edges = edges.get_or_insert_with(|| EmitterEdges::find(&pass));
                let Some(swept) = render_until(pass, progress, cut, edges.as_ref()) else {
                    return 0;
                };
                // Spare sweeps beyond the pass's samples lower its pixels' noise but not its
                // photons': its weight stays that of the pass.
                let weight = weight * swept.samples.min(spp) as f32 / spp as f32;
                for (s, c) in sum.iter_mut().zip(&swept.film.color) {
                    *s += *c * weight;
                }
                *total += weight;
                if *passes == 0 {
                    *aov = swept.film.aov;
                }
                *passes += 1;
                *samples = samples.wrapping_add(swept.samples);
                swept.samples
            }
        }
    }

    /// Passes added so far.
    pub fn passes(&self) -> u32 {
        match self {
            Accumulator::Sppm(s) => s.passes(),
            Accumulator::Average { passes, .. } => *passes,
        }
    }

    /// Samples per pixel added so far (modulo 2³²): where the next pass continues each pixel's
    /// sequence of sample positions.
    pub fn samples(&self) -> u32 {
        match self {
            Accumulator::Sppm(s) => s.passes().wrapping_mul(s.spp()),
            Accumulator::Average { samples, .. } => *samples,
        }
    }

    /// Pixels at the outline of an emitter in view (0 before the first pass, and for SPPM).
    pub fn emitter_edge_pixels(&self) -> usize {
        match self {
            Accumulator::Average {
                edges: Some(Some(e)), ..
            } => e.count(),
            _ => 0,
        }
    }

    /// The image so far.
    pub fn film(&self) -> Film {
        match self {
            Accumulator::Sppm(s) => s.film(),
            Accumulator::Average {
                sum, aov, size, weight, ..
            } => {
                let mut film = Film::new(size.0, size.1);
                let p = if *weight > 0.0 { *weight } else { 1.0 };
                for (c, s) in film.color.iter_mut().zip(sum) {
                    *c = *s / p;
                }
                if aov.len() == film.aov.len() {
                    film.aov.clone_from(aov);
                }
                film
            }
        }
    }
}
