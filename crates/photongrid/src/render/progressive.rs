//! Progressive rendering: the image of each camera accumulates passes, each with new photons
//! and new camera samples, and the [`Budget`] says when to stop. The loop itself, which traces
//! each pass's photons, is [`crate::pipeline::render_passes`].

use super::sppm::SppmFilm;
use super::{render, PhotonData, RenderSettings};
use crate::accel::Accel;
use crate::estimate::Accumulation;
use crate::film::{Aov, Film};
use crate::scene::{Camera, Scene};
use crate::Rgb;

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
            },
        }
    }

    /// Render one more pass of `camera` with this pass's photons (`settings.seed` and
    /// `settings.pass` are the pass's).
    #[allow(clippy::too_many_arguments)]
    pub fn add_pass(
        &mut self,
        scene: &Scene,
        accel: &Accel,
        photons: PhotonData<'_>,
        camera: &Camera,
        settings: &RenderSettings,
        progress: &(dyn Fn(usize) + Sync),
    ) {
        match self {
            Accumulator::Sppm(s) => s.add_pass(scene, accel, photons, camera, settings, progress),
            Accumulator::Average { sum, aov, passes, .. } => {
                let film = render(scene, accel, photons, camera, settings, progress);
                for (s, c) in sum.iter_mut().zip(&film.color) {
                    *s += *c;
                }
                if *passes == 0 {
                    *aov = film.aov;
                }
                *passes += 1;
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

    /// The image so far.
    pub fn film(&self) -> Film {
        match self {
            Accumulator::Sppm(s) => s.film(),
            Accumulator::Average { sum, aov, size, passes } => {
                let mut film = Film::new(size.0, size.1);
                let p = (*passes).max(1) as f32;
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

/// Why the passes stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stop {
    /// The pass count was reached (one pass when neither count nor time is given).
    Passes,
    /// The next pass would have overrun the time budget.
    Time,
    /// The caller asked to stop (Esc in Blender, Ctrl+C): the passes done so far are kept.
    Requested,
}

/// When a progressive render stops.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Budget {
    /// At most this many passes (none: unlimited if `time` is set, else one).
    pub passes: Option<u32>,
    /// Wall-time budget in seconds, counted from the caller's start.
    pub time: Option<f64>,
}

impl Budget {
    /// Whether to start another pass after `done` passes, `elapsed` seconds into the budget,
    /// when the last pass took `last_pass` seconds. The first pass always runs. A pass is
    /// started only if it is expected to end within the budget, the estimate being the previous
    /// pass: after the first pass that is the first pass (which also pays one-off work: plane
    /// detection, SPPM's initial kNN radii, so it errs on the safe side); later it follows the
    /// actual cost per pass (SPPM's passes get cheaper as radii shrink) and the machine's load.
    /// A pass slower than the one before (load rising) overruns the budget by the difference.
    pub fn next(&self, done: u32, elapsed: f64, last_pass: f64) -> Result<(), Stop> {
        if done == 0 {
            return Ok(());
        }
        let max = self.passes.unwrap_or(if self.time.is_some() { u32::MAX } else { 1 });
        if done >= max {
            return Err(Stop::Passes);
        }
        match self.time {
            Some(t) if elapsed + last_pass > t => Err(Stop::Time),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budget_rules() {
        let one = Budget::default();
        assert_eq!(one.next(0, 100.0, 0.0), Ok(()));
        assert_eq!(one.next(1, 0.0, 0.0), Err(Stop::Passes));
        let three = Budget {
            passes: Some(3),
            time: None,
        };
        assert_eq!(three.next(2, 1e9, 1e9), Ok(()));
        assert_eq!(three.next(3, 0.0, 0.0), Err(Stop::Passes));
        let timed = Budget {
            passes: None,
            time: Some(10.0),
        };
        assert_eq!(timed.next(0, 50.0, 0.0), Ok(()), "the minimum is one pass");
        assert_eq!(timed.next(5, 7.0, 3.0), Ok(()));
        assert_eq!(timed.next(5, 7.5, 3.0), Err(Stop::Time));
        let both = Budget {
            passes: Some(4),
            time: Some(10.0),
        };
        assert_eq!(both.next(4, 1.0, 1.0), Err(Stop::Passes));
        assert_eq!(both.next(2, 9.5, 1.0), Err(Stop::Time));
    }
}
