//! The time budget: when passes stop, and how large each pass is so that `--time T` ends at T.
//!
//! With a time budget, a short probe (a few photons, a low-resolution camera pass) measures
//! what a photon and a camera sample cost on this scene and machine ([`Costs`]); [`plan`] then
//! sizes the passes so that several fit in what is left, and [`Budget`] starts a pass only if
//! the last one's duration says it will end in time. All passes after the probe have the same
//! size: the progressive estimates (the adaptive method's shrinking k, the multiscale grids'
//! per-pass mean, SPPM) assume it.

use crate::settings::Settings;
use serde::{Deserialize, Serialize};

/// Why the passes stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
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
    /// Seconds, counted from the caller's start, by which the last pass must have ended.
    pub time: Option<f64>,
}

impl Budget {
    /// Whether to start another pass after `done` passes, `elapsed` seconds into the budget,
    /// when the last pass took `last_pass` seconds. The first pass always runs. A pass is
    /// started only if it is expected to end within the budget, the estimate being the previous
    /// pass (same size; it follows the machine's load). A pass slower than the one before (load
    /// rising) would overrun: the camera pass is then cut at the deadline and dropped.
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

/// What a pass is made of: the knobs the planner turns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PassSize {
    /// Global photon paths.
    pub photons: usize,
    /// Caustic-pass photon paths.
    pub caustic_photons: usize,
    /// Camera samples per pixel.
    pub spp: u32,
    /// Final-gather rays per camera sample.
    pub gather: u32,
}

impl PassSize {
    /// The pass `settings` ask for.
    pub fn of(settings: &Settings, caustic_photons: usize) -> Self {
        PassSize {
            photons: settings.photons,
            caustic_photons,
            spp: settings.spp.max(1),
            gather: settings.effective_gather(),
        }
    }

    /// `settings` with this pass size (the caustic count only if the scene has a caustic pass).
    pub fn apply(&self, settings: &Settings) -> Settings {
        let mut s = settings.clone();
        s.photons = self.photons;
        if settings.caustic_photons > 0 && self.caustic_photons > 0 {
            s.caustic_photons = self.caustic_photons;
        }
        s.spp = self.spp;
        s.gather = self.gather;
        s
    }

    /// Photon paths, both passes.
    pub fn paths(&self) -> usize {
        self.photons + self.caustic_photons
    }
}

/// What the probe measured: wall seconds per unit of work on this scene and machine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Costs {
    /// Per pass, whatever its size (the grids' filtering).
    pub per_pass: f64,
    /// Per global photon path (tracing, irradiance precomputation, index).
    pub per_path: f64,
    /// Per caustic photon path (aimed at glass and mirrors; most store one photon).
    #[serde(default)]
    pub per_caustic_path: f64,
    /// Per camera sample without final gathering (all cameras' pixels counted).
    pub per_sample: f64,
    /// Per final-gather ray, at the requested pass's [`Costs::photons_per_gather_ray`].
    pub per_gather_ray: f64,
    /// Per final-gather ray at 2, 4, 8 and 16 times fewer global photons per gather ray than
    /// `per_gather_ray`: the fewer they are, the more points final gathering supplies instead
    /// of the photons ([`crate::estimate::multiscale::photons_suffice`]), and where a scene's
    /// kernels hold alike counts the camera's cost jumps. The probe times gathering at the
    /// fewest and prices each rung by the points that ask for it there (docs/time_budget.md,
    /// "A camera pass priced by its photons per gather ray").
    #[serde(default)]
    pub per_gather_ray_sparser: [f64; GATHER_LADDER],
    /// Global photon paths per gather ray per pixel (of a pass) at which `per_gather_ray` was
    /// measured; 0: the same cost at any (an estimate that gathers wherever a pass has rays).
    #[serde(default)]
    pub photons_per_gather_ray: f64,
    /// Global photon paths and gather rays per pixel of the passes already made: the next
    /// passes' join them in the estimate.
    #[serde(default)]
    pub prior_photons: f64,
    /// See `prior_photons`.
    #[serde(default)]
    pub prior_gather_rays: f64,
    /// Share of the stored photon power that caustic photons carry.
    #[serde(default)]
    pub caustic_share: f64,
    /// Share of the stored global photons that the multiscale planes count: there the
    /// estimate widens its kernels where light is flat, so more photons lower the noise
    /// (a k-nearest-neighbour estimate only narrows its radius).
    #[serde(default)]
    pub plane_share: f64,
    /// Camera pixels per pass, all cameras.
    pub pixels: u64,
    /// Wall seconds the probe took.
    pub probe_seconds: f64,
}

impl Costs {
    /// Predicted wall seconds of the photon paths of a pass of `size` (without `per_pass`).
    pub fn photon_seconds(&self, size: &PassSize) -> f64 {
        size.photons as f64 * self.per_path + size.caustic_photons as f64 * self.per_caustic_path
    }

    /// These costs with the photons' side scaled by `photons` and the camera's by `camera`.
    fn scaled(&self, photons: f64, camera: f64) -> Costs {
        Costs {
            per_pass: self.per_pass * photons,
            per_path: self.per_path * photons,
            per_caustic_path: self.per_caustic_path * photons,
            per_sample: self.per_sample * camera,
            per_gather_ray: self.per_gather_ray * camera,
            per_gather_ray_sparser: self.per_gather_ray_sparser.map(|c| c * camera),
            ..*self
        }
    }

    /// Predicted wall seconds of the camera samples and gather rays of a pass of `size`.
    pub fn camera_seconds(&self, size: &PassSize) -> f64 {
        let samples = self.pixels as f64 * size.spp as f64;
        samples * (self.per_sample + size.gather as f64 * self.gather_ray_seconds(size))
    }

    /// Predicted wall seconds of a final-gather ray in a pass of `size`: between the measured
    /// rungs, linear in the logarithm of the photons per gather ray (the passes already made
    /// counted), held beyond the ends.
    pub fn gather_ray_seconds(&self, size: &PassSize) -> f64 {
        let rays = self.prior_gather_rays + (size.spp * size.gather) as f64;
        if !(self.photons_per_gather_ray > 0.0 && rays > 0.0) {
            return self.per_gather_ray;
        }
        let share = (self.prior_photons + size.photons as f64) / rays / self.photons_per_gather_ray;
        let rung = (-share.log2()).clamp(0.0, GATHER_LADDER as f64);
        let cost = |i: usize| {
            if i == 0 {
                self.per_gather_ray
            } else {
                self.per_gather_ray_sparser[i - 1]
            }
        };
        let i = (rung.floor() as usize).min(GATHER_LADDER - 1);
        let t = rung - i as f64;
        cost(i) + t * (cost(i + 1) - cost(i))
    }

    /// Predicted wall seconds of a pass of `size`.
    pub fn pass_seconds(&self, size: &PassSize) -> f64 {
        self.per_pass + self.photon_seconds(size) + self.camera_seconds(size)
    }
}

/// Rungs the probe prices final gathering at beyond the requested pass's photons per gather
/// ray, each with half the photons per ray of the one before ([`Costs::per_gather_ray_sparser`]):
/// down to 1/16, the floor of a shrunk pass's global photons ([`PHOTON_FLOOR_SHARE`]).
pub const GATHER_LADDER: usize = 4;

/// Fewest photon paths a planned pass keeps (below this a photon map is mostly noise).
pub const MIN_PATHS: usize = 20_000;
/// With less time than this many requested passes, the first pass is made smaller so that
/// about this many fit: its prediction comes from the probe, whose sparse photons make the
/// camera's costs the least certain (it may be off by this factor and still end in time).
pub const PLANNED_PASSES: f64 = 1.6;
/// After the first pass, the costs it measured size the passes for the time left so that
/// about this many fit: little more than one, as those costs are the pass's own and a camera
/// pass that overruns is cut at the deadline (a small fill pass used the rest less well).
pub const REPLANNED_PASSES: f64 = 1.1;

/// Which passes a plan sizes: they differ in how many must fit and in what they give up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The first pass, sized from the probe's costs ([`PLANNED_PASSES`]).
    First,
    /// The passes after the first, sized from its measured costs ([`REPLANNED_PASSES`]). They
    /// keep the first pass's `gather` rays per sample as long as fewer photons can make room:
    /// the images average with weights by time, which suits fewer samples but not fewer gather
    /// rays per sample (each sample is then noisier than its weight says), while their photons
    /// join grids that already hold the first pass's. They also keep [`AFTER_SPP_FLOOR`]
    /// samples per pixel where the first pass had them, while their gather rays and photons
    /// are cut down to their floors: one sample leaves bright edges unresolved.
    After {
        /// The first pass's gather rays per sample.
        gather: u32,
        /// The first pass's samples per pixel.
        spp: u32,
    },
}

impl Stage {
    /// How many passes of the plan's size should fit in the time left.
    pub fn passes(self) -> f64 {
        match self {
            Stage::First => PLANNED_PASSES,
            Stage::After { .. } => REPLANNED_PASSES,
        }
    }

    /// Fewest gather rays a pass keeps before its photons go below their floor.
    fn gather_floor(self) -> u32 {
        match self {
            Stage::First => 1,
            Stage::After { gather, .. } => gather.max(1),
        }
    }

    /// Fewest samples per pixel a pass keeps while its photons and gather rays are cut to their
    /// floors (below them, samples go first).
    fn spp_floor(self) -> u32 {
        match self {
            Stage::First => 1,
            Stage::After { spp, .. } => spp.clamp(1, AFTER_SPP_FLOOR),
        }
    }
}

/// Samples per pixel a pass after the first keeps (where the first had as many) while its
/// photons and gather rays are cut to their floors. One sample per pixel leaves bright edges
/// (caustic cusps, a spot's border) unresolved within the pixel: such a pass had about three
/// times the block error of one of two at equal photons and gather rays per pixel, and averaged
/// by its time it made a render worse than its first pass alone (docs/time_budget.md, "One
/// sample per pixel after the first pass").
pub const AFTER_SPP_FLOOR: u32 = 2;

/// How the passes of a time-budgeted render are sized, and why.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// The size of every pass.
    pub size: PassSize,
    /// Predicted seconds of one pass.
    pub predicted_pass_seconds: f64,
    /// Seconds left for passes when the plan was made.
    pub seconds_left: f64,
    /// Why this size.
    pub reason: String,
    /// The budget is too short for even the smallest pass: the render ends late.
    pub over_budget: bool,
}

/// Size the passes of `stage` for `left` seconds: the requested pass when the stage's number of
/// them fit; otherwise a pass of `left / passes` made as [`shrink`] says.
pub fn plan(costs: &Costs, left: f64, requested: PassSize, stage: Stage) -> Plan {
    let passes = stage.passes();
    let full = costs.pass_seconds(&requested);
    if full <= left / passes {
        let n = (left / full.max(1e-9)).floor();
        return Plan {
            size: requested,
            predicted_pass_seconds: full,
            seconds_left: left,
            reason: format!("the requested pass ({full:.2} s predicted) fits about {n} times"),
            over_budget: false,
        };
    }
    let size = shrink(costs, left / passes, requested, stage);
    let predicted = costs.pass_seconds(&size);
    let share = |n: usize, of: usize| 100.0 * n as f64 / of.max(1) as f64;
    Plan {
        size,
        predicted_pass_seconds: predicted,
        seconds_left: left,
        reason: format!(
            "the requested pass ({full:.2} s predicted) does not fit {passes} times in {left:.2} s: \
             {} spp, {} gather rays, {:.1} % of the global and {:.1} % of the caustic photons",
            size.spp,
            size.gather,
            share(size.photons, requested.photons),
            share(size.caustic_photons, requested.caustic_photons),
        ),
        over_budget: predicted > left,
    }
}

/// `costs` corrected by what a pass of `size` measured: the photons' side (`photon_seconds`)
/// and the camera's side (`camera_seconds`) each by its measured/predicted ratio. The pass's
/// photons and gather rays join those the next passes' gathering is priced with.
pub fn corrected(costs: &Costs, size: &PassSize, photon_seconds: f64, camera_seconds: f64) -> Costs {
    let camera = costs.camera_seconds(size);
    let photons = costs.per_pass + costs.photon_seconds(size);
    let ratio = |measured: f64, predicted: f64| {
        if predicted > 0.0 && measured > 0.0 {
            measured / predicted
        } else {
            1.0
        }
    };
    Costs {
        prior_photons: costs.prior_photons + size.photons as f64,
        prior_gather_rays: costs.prior_gather_rays + (size.spp * size.gather) as f64,
        ..costs.scaled(ratio(photon_seconds, photons), ratio(camera_seconds, camera))
    }
}

/// Share of the time left that a last, smaller pass may be planned to take.
pub const FILL_SHARE: f64 = 0.8;
/// A last pass shorter than this share of a regular one is not worth its overhead.
pub const MIN_FILL: f64 = 0.25;

/// A last, smaller pass for the `left` seconds after which a regular pass (of `size`, predicted
/// `predicted`, measured `measured` seconds) no longer fits: the costs are corrected by the
/// measured/predicted ratio. `None` when even a small pass would not pay.
pub fn fill(costs: &Costs, left: f64, size: PassSize, predicted: f64, measured: f64) -> Option<PassSize> {
    if left < MIN_FILL * measured || predicted <= 0.0 {
        return None;
    }
    let k = measured / predicted;
    let corrected = costs.scaled(k, k);
    let fill = shrink(&corrected, FILL_SHARE * left, size, Stage::First);
    let kept = |n: usize, of: usize| of == 0 || n as f64 >= FILL_MIN_PHOTON_SHARE * of as f64;
    if !kept(fill.photons, size.photons) || !kept(fill.caustic_photons, size.caustic_photons) {
        return None;
    }
    // The images average with weights by time, which suits fewer samples but not fewer
    // gather rays per sample: those make each sample noisier than its weight says.
    if fill.gather < size.gather {
        return None;
    }
    // Photons and samples have floors; a pass cut at the deadline is dropped, so allow some.
    (corrected.pass_seconds(&fill) <= left).then_some(fill)
}

/// Fewest photons (of each kind, as a share of a regular pass's) a last, smaller pass may
/// trace. The multiscale grids weigh each pass by its photons, so any such pass smooths them;
/// below this share a pass adds little and its own photon-map reads (surfaces off the planes)
/// are noisier than its weight in the image average says.
pub const FILL_MIN_PHOTON_SHARE: f64 = 0.1;

/// Global photon paths a shrunk pass keeps before it gives up camera samples: this share of
/// the requested ones (at least their share of [`MIN_PATHS`]). Measured on cornell_glass at
/// equal time, camera samples and gather rays lower the error more than global photons beyond
/// this (docs/time_budget.md): final gathering smooths what they carry.
pub const PHOTON_FLOOR_SHARE: f64 = 1.0 / 16.0;

/// [`PHOTON_FLOOR_SHARE`] where the planes count at least [`GLOBAL_BOOST_PLANE_SHARE`] of the
/// global photons and caustics carry little light: there the multiscale estimate shows the
/// global photons' light directly, and a pass cut to 1/8 of them for a second sample per pixel
/// had twice the block error of one with half of them (shelf_objects, cornell_glass at equal
/// time: docs/time_budget.md). Where caustics carry much light the time goes to caustic
/// photons first: a higher floor took it from them (pool_caustic).
pub const PHOTON_FLOOR_SHARE_PLANES: f64 = 0.5;

/// Caustic photons are kept before camera samples when caustics carry at least this share of
/// the stored photon power (pool_caustic 0.17, ring_caustic 0.19; cornell_glass 0.007,
/// shelf_objects 0.004): measured at equal time (docs/time_budget.md).
pub const CAUSTICS_FIRST_SHARE: f64 = 0.1;

/// Where caustics carry at least [`CAUSTICS_FIRST_SHARE`] of the stored photon power, a
/// time-budgeted pass asks for up to this many times the caustic photons the settings give
/// ([`CAUSTIC_TIME_SHARE`] sets how many): a caustic's noise and sharpness depend on them
/// alone, and they cost little beside the camera pass (docs/time_budget.md).
pub const CAUSTIC_BOOST: usize = 12;

/// Share of a budgeted pass's planned seconds that its caustic photons may take where caustics
/// carry much of the light ([`CAUSTICS_FIRST_SHARE`]; never fewer photons than the settings
/// give, never more than [`CAUSTIC_BOOST`] times them). A fixed multiple either starved long
/// budgets of caustic photons or took short ones' samples and global photons
/// (docs/time_budget.md).
pub const CAUSTIC_TIME_SHARE: f64 = 0.5;

/// Most a time budget multiplies the global photons of a pass by ([`PassSize::for_budget`];
/// memory permitting: `memory::photons_within_limit`; measured in docs/time_budget.md).
pub const GLOBAL_BOOST_MAX: f64 = 8.0;
/// Most a time budget multiplies the camera samples of a pass by where the planes count less
/// than [`GLOBAL_BOOST_PLANE_SHARE`] of the global photons ([`PassSize::for_budget`]): there
/// gather rays carry the indirect light and more photons barely lower the noise, so fewer,
/// larger passes spend less on each pass's photons and grids (measured in docs/time_budget.md).
pub const SAMPLE_BOOST_MAX: u32 = 2;
/// Share of the global photons the planes must count for a budget to buy more of them.
pub const GLOBAL_BOOST_PLANE_SHARE: f64 = 0.5;

impl PassSize {
    /// The pass a time budget asks for, given what the probe measured: more caustic photons
    /// where caustics carry much of the light ([`Costs::caustic_boost`]), and more global photons
    /// where the planes estimate most of them and they cost less than half the camera's
    /// side of the pass — up to half of it, at most [`GLOBAL_BOOST_MAX`] times: there photons
    /// lowered the error more per second than samples (measured in docs/time_budget.md).
    /// The global photons are added only as far as the pass still fits [`PLANNED_PASSES`]
    /// times in `left` seconds: a shorter budget shrinks the pass, photons first.
    pub fn for_budget(self, costs: &Costs, left: f64) -> Self {
        let target = left / PLANNED_PASSES;
        let size = PassSize {
            caustic_photons: costs.caustic_boost(self.caustic_photons, target),
            ..self
        };
        let size = PassSize {
            spp: costs.sample_boost(&size, target),
            ..size
        };
        let size = PassSize {
            spp: costs.samples_for_photons(&size, target),
            ..size
        };
        PassSize {
            // Rounded down: the boosted pass must still fit.
            photons: (self.photons as f64 * costs.global_boost(&size, target)).floor() as usize,
            ..size
        }
    }
}

impl Costs {
    /// The caustic photons [`PassSize::for_budget`] asks for instead of `requested`, for a pass
    /// of at most `target` seconds: [`CAUSTIC_TIME_SHARE`] of it where caustics carry much of
    /// the light, between `requested` and [`CAUSTIC_BOOST`] times it.
    pub fn caustic_boost(&self, requested: usize, target: f64) -> usize {
        if self.caustic_share < CAUSTICS_FIRST_SHARE || !(self.per_caustic_path > 0.0) {
            return requested;
        }
        let by_time = CAUSTIC_TIME_SHARE * target / self.per_caustic_path;
        let most = requested.saturating_mul(CAUSTIC_BOOST);
        if by_time.is_nan() {
            return requested;
        }
        (by_time.min(most as f64).floor() as usize).max(requested)
    }

    /// The share of the requested global photons a shrunk pass keeps before it gives up camera
    /// samples ([`PHOTON_FLOOR_SHARE`], [`PHOTON_FLOOR_SHARE_PLANES`]).
    pub fn photon_floor_share(&self) -> f64 {
        if self.planes_count_photons() && self.caustic_share < CAUSTICS_FIRST_SHARE {
            PHOTON_FLOOR_SHARE_PLANES
        } else {
            PHOTON_FLOOR_SHARE
        }
    }

    /// Whether the multiscale planes count at least [`GLOBAL_BOOST_PLANE_SHARE`] of the global
    /// photons: there more photons lower the noise, elsewhere more samples do.
    pub fn planes_count_photons(&self) -> bool {
        self.plane_share >= GLOBAL_BOOST_PLANE_SHARE
    }

    /// The camera samples per pixel [`PassSize::for_budget`] asks for, for a pass of at most
    /// `target` seconds: up to [`SAMPLE_BOOST_MAX`] times `size`'s where the planes count few of
    /// the global photons and gather rays carry the indirect light, never fewer than `size`'s.
    /// (Without final gathering the camera shows the photons: more samples would not help.)
    pub fn sample_boost(&self, size: &PassSize, target: f64) -> u32 {
        let per_spp = self.camera_seconds(size) / size.spp.max(1) as f64;
        if self.planes_count_photons() || size.gather == 0 || !(per_spp > 0.0) {
            return size.spp;
        }
        let fits = ((target - self.pass_seconds(size)) / per_spp).floor();
        let extra = fits.clamp(0.0, ((SAMPLE_BOOST_MAX - 1) * size.spp) as f64);
        size.spp + extra as u32
    }

    /// The camera samples per pixel [`PassSize::for_budget`] asks for where the planes count
    /// the global photons and caustics carry little light, when `size` does not fit in `target`
    /// seconds but would with at most half of its samples: the fewest samples given up for
    /// that, before any photon, so that the photons (cheap beside the camera there, and what
    /// the planes show) can be boosted
    /// ([`Costs::global_boost`]) instead of cut to their floor. On shelf_objects CamShelf,
    /// whose 4 samples per pixel take most of a 15 s budget, the photons were the rest and
    /// swung between 1 and 5 M with the probe's noise (docs/time_budget.md).
    pub fn samples_for_photons(&self, size: &PassSize, target: f64) -> u32 {
        if !self.planes_count_photons() || self.caustic_share >= CAUSTICS_FIRST_SHARE {
            return size.spp;
        }
        let least = size.spp.div_ceil(2).max(1);
        let fits = |spp: u32| self.pass_seconds(&PassSize { spp, ..*size }) <= target;
        // A short budget where even half the samples do not fit shrinks as before ([`shrink`]):
        // there the photons would get no boost, and a first pass of 1 spp with all the
        // photons left no time for a second (cornell_glass at --time 5: 1.84 -> 3.17 %).
        if fits(size.spp) || !fits(least) {
            return size.spp;
        }
        (least..size.spp).rev().find(|&s| fits(s)).unwrap_or(least)
    }

    /// The factor [`PassSize::for_budget`] multiplies the global photons of `size` by, for a
    /// pass of at most `target` seconds.
    pub fn global_boost(&self, size: &PassSize, target: f64) -> f64 {
        let global = size.photons as f64 * self.per_path;
        let camera = self.camera_seconds(size);
        if !self.planes_count_photons() || !(global > 0.0) {
            return 1.0;
        }
        let fits = 1.0 + (target - self.pass_seconds(size)) / global;
        let boost = (camera / (2.0 * global)).min(fits);
        if boost.is_nan() {
            return 1.0;
        }
        boost.clamp(1.0, GLOBAL_BOOST_MAX)
    }
}

/// A pass of `requested`'s shape that takes `target` seconds, giving up first what lowers the
/// error least: photons down to [`Costs::photon_floor_share`], then samples per pixel (down to 1,
/// or to [`AFTER_SPP_FLOOR`] for the passes after the first), then gather rays (down to 1, or to
/// the first pass's for the passes after it, [`Stage`]), then the samples a later pass kept,
/// then photons down to [`MIN_PATHS`], then the gather rays a later pass kept. Where caustics
/// carry much of the light ([`CAUSTICS_FIRST_SHARE`]) the caustic photons are given up only after
/// the samples (for a later pass, the samples above its floor): a caustic's sharpness depends
/// on them alone (passes average images, they do not narrow the kernels), and they are cheap
/// (most paths store one photon and need no irradiance); time freed then goes to caustic
/// photons first. Elsewhere both kinds of photon shrink alike: the multiscale estimate shows
/// global photons' light directly, and caustic photons bought at their expense darkened a scene
/// whose caustics carry 0.4 % of the light.
pub fn shrink(costs: &Costs, target: f64, requested: PassSize, stage: Stage) -> PassSize {
    let paths = requested.paths().max(1) as f64;
    let floor =
        |n: usize, share: f64| ((n as f64 * share).max(MIN_PATHS as f64 * n as f64 / paths).round() as usize).min(n);
    let fit = Fit {
        costs,
        target,
        requested,
        // Photon counts are rounded: a pass that fills the target exactly may be over it by a
        // photon.
        slack: 2.0 * costs.per_path.max(costs.per_caustic_path) + 1e-9 * target,
        caustic_heavy: costs.caustic_share >= CAUSTICS_FIRST_SHARE,
    };
    let g_lo = floor(requested.photons, costs.photon_floor_share());
    let c_lo = floor(requested.caustic_photons, PHOTON_FLOOR_SHARE);
    let c_first = if fit.caustic_heavy {
        requested.caustic_photons
    } else {
        c_lo
    };
    let mut size = fit.refill(requested, g_lo, c_first);
    let spp_floor = stage.spp_floor().min(requested.spp);
    while size.spp > spp_floor && fit.over(&size) {
        size.spp -= 1;
        size = fit.refill(size, g_lo, c_first);
    }
    size = fit.refill(size, g_lo, c_lo);
    let (g_min, c_min) = (floor(requested.photons, 0.0), floor(requested.caustic_photons, 0.0));
    let gather_floor = stage.gather_floor().min(requested.gather);
    while size.gather > gather_floor && fit.over(&size) {
        size.gather -= 1;
        size = fit.refill(size, g_lo, c_lo);
    }
    while size.spp > 1 && fit.over(&size) {
        size.spp -= 1;
        size = fit.refill(size, g_lo, c_lo);
    }
    if fit.over(&size) {
        size = fit.refill(size, g_min, c_min);
    }
    while size.gather > 1 && fit.over(&size) {
        size.gather -= 1;
        size = fit.refill(size, g_min, c_min);
    }
    size
}

/// The photon counts of a pass fitted into `target` seconds ([`shrink`]'s steps).
struct Fit<'a> {
    costs: &'a Costs,
    target: f64,
    requested: PassSize,
    slack: f64,
    caustic_heavy: bool,
}

impl Fit<'_> {
    fn over(&self, size: &PassSize) -> bool {
        self.costs.pass_seconds(size) > self.target + self.slack
    }

    /// The most photons of one kind, within [lo, hi], that fit beside `rest` seconds.
    fn most(&self, rest: f64, per: f64, lo: usize, hi: usize) -> usize {
        (((self.target - rest) / per.max(1e-12)).floor().max(0.0).min(hi as f64) as usize).max(lo)
    }

    /// The most photons, neither kind below its floor (`g_lo`, `c_lo`), beside `size`'s
    /// samples and gather rays.
    fn refill(&self, size: PassSize, g_lo: usize, c_lo: usize) -> PassSize {
        if self.caustic_heavy {
            self.caustics_first(size, g_lo, c_lo)
        } else {
            self.alike(size, g_lo, c_lo)
        }
    }

    /// Caustic photons first (down to `c_lo`) beside the global photons (at least `g_lo`) that
    /// cost least with the camera's side, then the global ones in what is left. Not always
    /// `g_lo`: fewer global photons make the camera's side dearer ([`Costs::gather_ray_seconds`]).
    fn caustics_first(&self, size: PassSize, g_lo: usize, c_lo: usize) -> PassSize {
        let hi = self.requested.photons;
        let global = |x: f64| PassSize {
            photons: ((hi as f64 * x).round() as usize).clamp(g_lo, hi.max(g_lo)),
            caustic_photons: 0,
            ..size
        };
        let x_lo = g_lo as f64 / hi.max(1) as f64;
        let cheapest = shares_down_to(x_lo)
            .map(|x| self.costs.pass_seconds(&global(x)))
            .fold(f64::INFINITY, f64::min);
        let caustic_photons = self.most(
            cheapest,
            self.costs.per_caustic_path,
            c_lo,
            self.requested.caustic_photons,
        );
        // Without the slack, as `most` fits the caustic photons.
        let x = largest_fitting(x_lo, |x| {
            let size = PassSize {
                caustic_photons,
                ..global(x)
            };
            self.costs.pass_seconds(&size) <= self.target
        });
        PassSize {
            caustic_photons,
            ..global(x)
        }
    }

    /// Both kinds scaled alike from the requested ones, neither below its floor.
    fn alike(&self, size: PassSize, g_lo: usize, c_lo: usize) -> PassSize {
        let r = self.requested;
        let at = |s: f64| PassSize {
            photons: ((r.photons as f64 * s).round() as usize).clamp(g_lo, r.photons.max(g_lo)),
            caustic_photons: ((r.caustic_photons as f64 * s).round() as usize).clamp(c_lo, r.caustic_photons.max(c_lo)),
            ..size
        };
        at(largest_fitting(LEAST_SHARE, |s| !self.over(&at(s))))
    }
}

/// Least share of the requested photons a pass is fitted at ([`shares_down_to`]): the floors
/// lie above it ([`MIN_PATHS`] is a larger share of any pass with photons to shrink).
const LEAST_SHARE: f64 = 1.0 / (1u64 << 24) as f64;

/// Steps per halving of [`shares_down_to`].
const SHARE_STEPS: f64 = 16.0;

/// Shares of a pass's photons from 1 down to `lo` (at least [`LEAST_SHARE`]), in steps of
/// 2^(−1/[`SHARE_STEPS`]), then `lo`.
fn shares_down_to(lo: f64) -> impl Iterator<Item = f64> {
    let lo = lo.clamp(LEAST_SHARE, 1.0);
    (0..)
        .map(|j| (-(j as f64) / SHARE_STEPS).exp2())
        .take_while(move |&x| x > lo)
        .chain(std::iter::once(lo))
}

/// The largest share in [`lo`, 1] for which `fits`, `lo` if none: the pass's seconds do not
/// fall steadily with its photons (fewer make the camera's side dearer, [`Costs::gather_ray_seconds`]),
/// so [`shares_down_to`] are tried from the top, then bisection between the first that fits and
/// the one above it.
fn largest_fitting(lo: f64, fits: impl Fn(f64) -> bool) -> f64 {
    let mut above: Option<f64> = None;
    for x in shares_down_to(lo) {
        if fits(x) {
            let Some(mut hi) = above else { return x };
            let mut lo = x;
            for _ in 0..48 {
                let mid = 0.5 * (lo + hi);
                if fits(mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return lo;
        }
        above = Some(x);
    }
    lo.clamp(LEAST_SHARE, 1.0)
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

    fn costs() -> Costs {
        Costs {
            per_pass: 0.05,
            per_path: 1e-6,
            per_caustic_path: 0.4e-6,
            caustic_share: 0.2,
            plane_share: 0.0,
            per_sample: 2e-6,
            per_gather_ray: 1e-6,
            pixels: 640 * 480,
            probe_seconds: 0.1,
            ..Costs::default()
        }
    }

    fn requested() -> PassSize {
        PassSize {
            photons: 2_000_000,
            caustic_photons: 1_000_000,
            spp: 4,
            gather: 8,
        }
    }

    #[test]
    fn a_budget_asks_for_more_caustic_photons_only_where_caustics_carry_much_light() {
        let heavy = requested().for_budget(&costs(), f64::INFINITY);
        assert_eq!(heavy.caustic_photons, CAUSTIC_BOOST * 1_000_000);
        // (No plane counts a photon in these costs: the samples are boosted too.)
        assert_eq!(
            (heavy.photons, heavy.spp, heavy.gather),
            (2_000_000, 4 * SAMPLE_BOOST_MAX, 8)
        );
        let light = Costs {
            caustic_share: 0.004,
            ..costs()
        };
        let light = requested().for_budget(&light, f64::INFINITY);
        assert_eq!((light.photons, light.caustic_photons), (2_000_000, 1_000_000));
    }

    #[test]
    fn caustic_photons_take_their_share_of_the_pass_time() {
        let heavy = costs();
        let target = 2.0; // 1 s of caustic paths at 0.4 µs: 2.5 M
        assert_eq!(heavy.caustic_boost(1_000_000, target), 2_500_000);
        // Never fewer than requested, never more than CAUSTIC_BOOST times.
        assert_eq!(heavy.caustic_boost(1_000_000, 0.1), 1_000_000);
        assert_eq!(heavy.caustic_boost(1_000_000, 1e6), CAUSTIC_BOOST * 1_000_000);
        let light = Costs {
            caustic_share: 0.004,
            ..costs()
        };
        assert_eq!(light.caustic_boost(1_000_000, 1e6), 1_000_000);
        // Whatever the budget, the pass keeps fitting: the caustic share is of the target.
        let b = requested().for_budget(&heavy, PLANNED_PASSES * 4.0);
        assert!(
            b.caustic_photons as f64 * heavy.per_caustic_path <= CAUSTIC_TIME_SHARE * 4.0 + 1e-9,
            "{b:?}"
        );
    }

    #[test]
    fn a_budget_buys_global_photons_where_the_planes_count_them_and_they_are_cheap() {
        // The camera's side: 307200 × 4 × (2e-6 + 8 × 1e-6) = 12.3 s; the global photons':
        // 2 M × 1e-6 = 2 s, so up to 6.1 s (half the camera's) is worth 3.07 times the photons.
        // (Caustics carry little light here: the caustic photons stay as requested.)
        let planar = Costs {
            plane_share: 0.9,
            caustic_share: 0.004,
            ..costs()
        };
        let b = requested().for_budget(&planar, f64::INFINITY);
        let camera = planar.pixels as f64 * 4.0 * (2e-6 + 8.0 * 1e-6);
        assert!((b.photons as f64 * 1e-6 - camera / 2.0).abs() < 1e-3, "{b:?}");
        assert_eq!((b.spp, b.gather), (4, 8));
        // Off the planes (k nearest neighbours) more photons narrow kernels, not noise.
        let curved = Costs {
            plane_share: 0.3,
            ..planar
        };
        assert_eq!(requested().for_budget(&curved, f64::INFINITY).photons, 2_000_000);
        // Photons already dearer than half the camera's side: none added.
        let dear = Costs {
            per_path: 4e-6,
            ..planar
        };
        assert_eq!(requested().for_budget(&dear, f64::INFINITY).photons, 2_000_000);
        // Very cheap photons: at most GLOBAL_BOOST_MAX times.
        let cheap = Costs {
            per_path: 1e-8,
            ..planar
        };
        assert_eq!(
            requested().for_budget(&cheap, f64::INFINITY).photons as f64,
            2e6 * GLOBAL_BOOST_MAX
        );
        // A budget with room for about two passes of the request: photons are added only
        // while the pass still fits PLANNED_PASSES times.
        let full = planar.pass_seconds(&requested());
        let left = 2.0 * full;
        let b = requested().for_budget(&planar, left);
        assert!(b.photons > 2_000_000, "{b:?}");
        assert!(planar.pass_seconds(&b) <= left / PLANNED_PASSES, "{b:?}");
        let p = plan(&planar, left, b, Stage::First);
        assert_eq!(p.size, b, "{p:?}");
        assert!(p.reason.contains("fits"), "{}", p.reason);
        // Room for the request once only: samples go (at most half of them) before photons,
        // and the photons then get their boost.
        let tight = requested().for_budget(&planar, full);
        assert!(tight.spp < 4 && tight.spp >= 2, "{tight:?}");
        assert!(tight.photons > 2_000_000, "{tight:?}");
        assert!(
            planar.pass_seconds(&tight) <= full / PLANNED_PASSES * 1.0001,
            "{tight:?}"
        );
        // Too little room even for half the samples: nothing given up here (shrink decides).
        assert_eq!(requested().for_budget(&planar, full / 4.0).spp, 4);
        // Not where the planes count few photons, nor where caustics carry much light.
        assert_eq!(requested().for_budget(&curved, full).spp, 4);
        let caustic = Costs {
            caustic_share: 0.2,
            ..planar
        };
        assert_eq!(requested().for_budget(&caustic, full).spp, 4);
    }

    #[test]
    fn a_budget_buys_camera_samples_where_the_planes_count_few_photons() {
        let off_planes = Costs {
            plane_share: 0.3,
            caustic_share: 0.004,
            ..costs()
        };
        let per_spp = off_planes.camera_seconds(&requested()) / 4.0;
        let b = requested().for_budget(&off_planes, f64::INFINITY);
        assert_eq!(
            (b.spp, b.gather, b.photons),
            (4 * SAMPLE_BOOST_MAX, 8, 2_000_000),
            "{b:?}"
        );
        // Room for the request and about 2.5 more samples per pixel, PLANNED_PASSES times: 2.
        let full = off_planes.pass_seconds(&requested());
        let b = requested().for_budget(&off_planes, PLANNED_PASSES * (full + 2.5 * per_spp));
        assert_eq!(b.spp, 6, "{b:?}");
        assert!(off_planes.pass_seconds(&b) <= full + 2.5 * per_spp);
        // No room: the request as it was (plan shrinks it).
        assert_eq!(requested().for_budget(&off_planes, full).spp, 4);
        // Without final gathering the camera shows the photons: no more samples.
        let shown = PassSize {
            gather: 0,
            ..requested()
        };
        assert_eq!(shown.for_budget(&off_planes, f64::INFINITY).spp, 4);
        // Where the planes count the photons, the samples stay as requested.
        let planar = Costs {
            plane_share: 0.9,
            ..costs()
        };
        assert_eq!(requested().for_budget(&planar, f64::INFINITY).spp, 4);
    }

    #[test]
    fn a_long_budget_keeps_the_requested_pass() {
        let c = costs();
        let full = c.pass_seconds(&requested());
        let p = plan(&c, full * 10.0, requested(), Stage::First);
        assert_eq!(p.size, requested());
        assert!(!p.over_budget);
    }

    #[test]
    fn a_short_budget_gives_up_global_photons_then_samples_then_caustic_photons() {
        short_budget_order(&costs());
    }

    /// Where the planes count the global photons and caustics carry little light, a pass keeps
    /// half of them before it gives up a sample per pixel.
    #[test]
    fn where_the_planes_count_photons_half_of_them_outlast_samples() {
        let c = Costs {
            plane_share: 0.9,
            caustic_share: 0.01,
            ..costs()
        };
        assert_eq!(c.photon_floor_share(), PHOTON_FLOOR_SHARE_PLANES);
        let caustic_heavy = Costs {
            caustic_share: 0.2,
            ..c
        };
        assert_eq!(caustic_heavy.photon_floor_share(), PHOTON_FLOOR_SHARE);
        let half = requested().photons / 2;
        let full = c.pass_seconds(&requested());
        let mut cut_samples = false;
        for left in [full, full / 2.0, full / 3.0, full / 4.0] {
            let p = plan(&c, left, requested(), Stage::First);
            let target = left / PLANNED_PASSES;
            assert!(p.size.photons >= half, "{p:?}");
            if p.size.spp < requested().spp {
                cut_samples = true;
                let one_more = PassSize {
                    photons: half,
                    spp: p.size.spp + 1,
                    ..p.size
                };
                assert!(c.pass_seconds(&one_more) > target, "{p:?}");
            }
        }
        assert!(cut_samples);
    }

    fn short_budget_order(c: &Costs) {
        let full = c.pass_seconds(&requested());
        let mut last = requested();
        let floor = |n: usize| (n as f64 * c.photon_floor_share()).round() as usize;
        let mut cut_caustics = false;
        for left in [full * 1.5, full, full / 2.0, full / 4.0, full / 6.0, full / 8.0] {
            let p = plan(c, left, requested(), Stage::First);
            let target = left / PLANNED_PASSES;
            assert!(p.predicted_pass_seconds <= target * 1.0001, "{p:?}");
            assert!(!p.over_budget);
            // Fewer samples as the budget shrinks (photons may come back in the time a sample
            // leaves: samples are whole).
            assert!(p.size.spp <= last.spp, "{p:?} after {last:?}");
            assert!(p.size.photons >= floor(requested().photons), "{p:?}");
            // Samples go only when the global photons are at their floor and the caustic ones
            // still whole do not leave room for one more (with every gather ray).
            if p.size.spp < requested().spp {
                let one_more = PassSize {
                    photons: floor(requested().photons),
                    caustic_photons: requested().caustic_photons,
                    spp: p.size.spp + 1,
                    gather: requested().gather,
                };
                assert!(c.pass_seconds(&one_more) > target, "{p:?}");
            }
            // Caustic photons go only at 1 spp, and before any gather ray.
            if p.size.caustic_photons < requested().caustic_photons {
                cut_caustics = true;
                assert_eq!(p.size.spp, 1, "{p:?}");
                assert_eq!(p.size.photons, floor(requested().photons), "{p:?}");
                if p.size.gather < requested().gather {
                    // One more gather ray does not fit even with the caustic photons at floor.
                    let one_more = PassSize {
                        caustic_photons: floor(requested().caustic_photons),
                        gather: p.size.gather + 1,
                        ..p.size
                    };
                    assert!(c.pass_seconds(&one_more) > target, "{p:?}");
                }
            } else if p.size != requested() {
                assert_eq!(p.size.gather, requested().gather, "{p:?}");
            }
            last = p.size;
        }
        assert!(last.spp < requested().spp, "the shortest budget cut samples: {last:?}");
        assert!(cut_caustics, "the shortest budgets cut caustic photons: {last:?}");
    }

    #[test]
    fn where_caustics_carry_little_light_samples_outlast_caustic_photons() {
        let c = Costs {
            caustic_share: 0.01,
            ..costs()
        };
        let floor = |n: usize| (n as f64 * PHOTON_FLOOR_SHARE).round() as usize;
        let full = c.pass_seconds(&requested());
        let mut cut_samples = false;
        for left in [full, full / 2.0, full / 4.0, full / 6.0] {
            let p = plan(&c, left, requested(), Stage::First);
            assert!(p.predicted_pass_seconds <= left / PLANNED_PASSES * 1.0001, "{p:?}");
            if p.size.spp < requested().spp {
                cut_samples = true;
                let one_more = PassSize {
                    photons: floor(requested().photons),
                    caustic_photons: floor(requested().caustic_photons),
                    spp: p.size.spp + 1,
                    gather: requested().gather,
                };
                assert!(c.pass_seconds(&one_more) > left / PLANNED_PASSES, "{p:?}");
            }
        }
        assert!(cut_samples);
        // With caustics carrying much of the light, the same budget keeps more caustic photons.
        // Room for 2 spp with the global photons at their floor and half the caustic ones.
        let two = PassSize {
            photons: floor(requested().photons),
            caustic_photons: requested().caustic_photons / 2,
            spp: 2,
            ..requested()
        };
        let left = c.pass_seconds(&two) * PLANNED_PASSES;
        let rich = plan(&costs(), left, requested(), Stage::First).size;
        let poor = plan(&c, left, requested(), Stage::First).size;
        assert!(rich.caustic_photons > poor.caustic_photons, "{rich:?} vs {poor:?}");
        assert!(rich.spp < poor.spp, "{rich:?} vs {poor:?}");
    }

    #[test]
    fn gather_rays_go_after_samples_and_caustics_and_a_hopeless_budget_says_so() {
        let c = costs();
        let one_spp = c.pixels as f64 * (c.per_sample + 8.0 * c.per_gather_ray);
        let p = plan(&c, one_spp, requested(), Stage::First);
        assert_eq!(p.size.spp, 1);
        assert!(p.size.gather < 8 && p.size.gather >= 1, "{p:?}");
        let floor = |n: usize| (n as f64 * PHOTON_FLOOR_SHARE).round() as usize;
        let one_more = PassSize {
            caustic_photons: floor(requested().caustic_photons),
            gather: p.size.gather + 1,
            ..p.size
        };
        assert!(c.pass_seconds(&one_more) > one_spp / PLANNED_PASSES, "{p:?}");
        let hopeless = plan(&c, 1e-3, requested(), Stage::First);
        assert!(hopeless.over_budget);
        assert_eq!((hopeless.size.spp, hopeless.size.gather), (1, 1));
        assert_eq!(hopeless.size.paths(), MIN_PATHS);
    }

    /// `costs()` with gathering as pool_caustic's probe measured it: a ray's cost jumps six
    /// times between a quarter and an eighth of the requested photons per gather ray.
    fn stepped() -> Costs {
        let r = requested();
        Costs {
            per_gather_ray: 0.2e-6,
            per_gather_ray_sparser: [0.2e-6, 0.2e-6, 1.2e-6, 1.2e-6],
            photons_per_gather_ray: r.photons as f64 / (r.spp * r.gather) as f64,
            ..costs()
        }
    }

    #[test]
    fn a_gather_ray_is_priced_by_the_photons_per_gather_ray() {
        let c = stepped();
        let at = |photons: usize, spp: u32| {
            c.gather_ray_seconds(&PassSize {
                photons,
                spp,
                ..requested()
            })
        };
        let close = |a: f64, b: f64| (a / b - 1.0).abs() < 1e-9;
        assert!(close(at(2_000_000, 4), 0.2e-6));
        assert!(close(at(16_000_000, 4), 0.2e-6), "held above the requested photons");
        assert!(close(at(250_000, 4), 1.2e-6), "an eighth");
        assert!(close(at(1_000, 4), 1.2e-6), "held below a sixteenth");
        // Halfway (in the logarithm) between a quarter and an eighth.
        assert!((at((2e6 / 32f64.sqrt()).round() as usize, 4) / 0.7e-6 - 1.0).abs() < 1e-5);
        // Fewer samples per pixel, fewer gather rays: the same photons go further.
        assert!(close(at(250_000, 2), 0.2e-6));
        // Old reports without the ladder price every pass alike.
        let flat = Costs {
            photons_per_gather_ray: 0.0,
            ..c
        };
        assert!(close(
            flat.gather_ray_seconds(&PassSize {
                photons: 1_000,
                ..requested()
            }),
            0.2e-6
        ));
        // A later pass's photons and rays join the first's (twice as many photons per ray).
        let first = PassSize {
            photons: 1_000_000,
            ..requested()
        };
        let later = corrected(
            &c,
            &first,
            c.per_pass + c.photon_seconds(&first),
            c.camera_seconds(&first),
        );
        let after = PassSize {
            photons: 125_000,
            ..requested()
        };
        assert!(close(c.gather_ray_seconds(&after), 1.2e-6));
        assert!(close(
            later.gather_ray_seconds(&after),
            c.gather_ray_seconds(&PassSize {
                photons: 562_500,
                ..after
            })
        ));
    }

    #[test]
    fn a_shrunk_pass_keeps_its_global_photons_above_a_step_in_the_camera_cost() {
        let c = stepped();
        for left in [3.0, 4.0, 5.0, 6.0, 8.0] {
            let p = plan(&c, left, requested(), Stage::First);
            let target = left / PLANNED_PASSES;
            assert!(p.predicted_pass_seconds <= target * 1.0001, "{p:?}");
            let per_ray = p.size.photons as f64 / (p.size.spp * p.size.gather) as f64;
            assert!(per_ray >= c.photons_per_gather_ray / 4.0, "below the step: {p:?}");
            assert!(p.predicted_pass_seconds >= 0.95 * target, "the time is used: {p:?}");
        }
        // Priced alike at any photons, some of the same budgets go below the step.
        let flat = Costs {
            photons_per_gather_ray: 0.0,
            ..c
        };
        let below = [3.0, 4.0, 5.0, 6.0, 8.0].into_iter().find(|&left| {
            let p = plan(&flat, left, requested(), Stage::First).size;
            p.photons as f64 / ((p.spp * p.gather) as f64) < c.photons_per_gather_ray / 4.0
        });
        assert!(below.is_some());
    }

    #[test]
    fn a_later_pass_keeps_the_first_passs_gather_rays_while_fewer_photons_make_room() {
        let c = Costs {
            caustic_share: 0.01,
            ..costs()
        };
        // Room for 1 spp with every gather ray and a fortieth of the requested photons (below
        // their floor, a sixteenth), once: the first pass would give up gather rays, a later
        // one gives up photons.
        let room = PassSize {
            photons: requested().photons / 40,
            caustic_photons: requested().caustic_photons / 40,
            spp: 1,
            ..requested()
        };
        let left = c.pass_seconds(&room) * REPLANNED_PASSES;
        let first = plan(&c, left * PLANNED_PASSES / REPLANNED_PASSES, requested(), Stage::First).size;
        assert!(first.gather < 8, "{first:?}");
        let later = plan(&c, left, requested(), Stage::After { gather: 8, spp: 1 });
        assert_eq!((later.size.spp, later.size.gather), (1, 8), "{later:?}");
        assert!(later.size.photons < first.photons, "{later:?} vs {first:?}");
        assert!(
            later.predicted_pass_seconds <= left / REPLANNED_PASSES * 1.0001,
            "{later:?}"
        );
        // With no room for that either, gather rays go only when MIN_PATHS photons do not fit
        // beside one more of them (the photons then take what the dropped rays leave).
        let target = c.pass_seconds(&room) * 0.5 / REPLANNED_PASSES;
        let tight = plan(
            &c,
            target * REPLANNED_PASSES,
            requested(),
            Stage::After { gather: 8, spp: 1 },
        );
        assert!(tight.size.gather < 8, "{tight:?}");
        let one_more = PassSize {
            photons: MIN_PATHS * 2 / 3,
            caustic_photons: MIN_PATHS / 3,
            gather: tight.size.gather + 1,
            ..tight.size
        };
        assert!(c.pass_seconds(&one_more) > target, "{tight:?}");
        // A first pass with fewer gather rays than requested: later passes need not keep more.
        let few = plan(&c, left, requested(), Stage::After { gather: 2, spp: 1 }).size;
        assert!(few.gather >= 2 && few.photons >= later.size.photons, "{few:?}");
    }

    #[test]
    fn a_later_pass_keeps_two_samples_per_pixel_and_gives_up_caustic_photons_instead() {
        // Caustics carry much light: a pass planned as a first one keeps its caustic photons and
        // gives up samples, down to one per pixel.
        let c = costs();
        let requested = PassSize {
            caustic_photons: 12_000_000,
            ..requested()
        };
        let room = PassSize {
            photons: requested.photons / 16,
            spp: 1,
            ..requested
        };
        let left = c.pass_seconds(&room);
        let as_first = plan(&c, left * PLANNED_PASSES, requested, Stage::First).size;
        assert!(
            as_first.spp == 1 && as_first.caustic_photons >= 11_999_000,
            "{as_first:?}"
        );
        // The same time after a first pass of 4 spp: 2 kept, caustic photons given up instead.
        let later = plan(
            &c,
            left * REPLANNED_PASSES,
            requested,
            Stage::After { gather: 8, spp: 4 },
        );
        assert_eq!((later.size.spp, later.size.gather), (2, 8), "{later:?}");
        assert!(later.size.caustic_photons < requested.caustic_photons, "{later:?}");
        assert!(later.predicted_pass_seconds <= left * 1.0001, "{later:?}");
        // After a first pass of one sample per pixel, one is enough.
        let after_one = plan(
            &c,
            left * REPLANNED_PASSES,
            requested,
            Stage::After { gather: 8, spp: 1 },
        );
        assert_eq!(after_one.size.spp, 1, "{after_one:?}");
        // Without room for 2 spp beside the photons' floors, a later pass goes down to 1 before
        // its photons go below them (the order of the last steps).
        let floors = PassSize {
            photons: requested.photons / 16,
            caustic_photons: requested.caustic_photons / 16,
            spp: 1,
            ..requested
        };
        let tight = plan(
            &c,
            c.pass_seconds(&floors) * REPLANNED_PASSES,
            requested,
            Stage::After { gather: 8, spp: 4 },
        );
        assert_eq!(tight.size.spp, 1, "{tight:?}");
        assert!(
            tight.size.photons >= floors.photons && tight.size.caustic_photons >= floors.caustic_photons,
            "{tight:?}"
        );
    }

    #[test]
    fn a_fill_pass_uses_the_measured_cost_and_is_skipped_when_too_small() {
        let c = costs();
        let size = plan(&c, c.pass_seconds(&requested()), requested(), Stage::First).size;
        let predicted = c.pass_seconds(&size);
        // The pass took twice the prediction; 1.2 of its durations are left.
        let measured = 2.0 * predicted;
        let f = fill(&c, 1.2 * measured, size, predicted, measured).expect("a fill pass fits");
        assert!(2.0 * c.pass_seconds(&f) <= 1.2 * measured * 1.0001);
        assert!(f.paths() <= size.paths() && f.spp <= size.spp);
        assert_eq!(fill(&c, 0.1 * measured, size, predicted, measured), None);
        // Whatever is left, a fill pass keeps the regular gather rays per sample and at least
        // FILL_MIN_PHOTON_SHARE of each kind of photon.
        for left in [0.3, 0.5, 0.8, 1.2] {
            if let Some(f) = fill(&c, left * measured, size, predicted, measured) {
                assert_eq!(f.gather, size.gather, "{left}: {f:?}");
                assert!(f.photons as f64 >= FILL_MIN_PHOTON_SHARE * size.photons as f64, "{f:?}");
                assert!(f.caustic_photons as f64 >= FILL_MIN_PHOTON_SHARE * size.caustic_photons as f64);
            }
        }
    }

    #[test]
    fn measured_costs_correct_each_side_by_its_own_ratio() {
        let c = costs();
        let size = PassSize {
            photons: 100_000,
            caustic_photons: 50_000,
            spp: 1,
            gather: 4,
        };
        let photons = c.per_pass + c.photon_seconds(&size);
        let camera = c.pass_seconds(&size) - photons;
        let k = corrected(&c, &size, 2.0 * photons, 0.5 * camera);
        assert!((k.per_path / c.per_path - 2.0).abs() < 1e-9);
        assert!((k.per_caustic_path / c.per_caustic_path - 2.0).abs() < 1e-9);
        assert!((k.per_sample / c.per_sample - 0.5).abs() < 1e-9);
        assert!((k.per_gather_ray / c.per_gather_ray - 0.5).abs() < 1e-9);
        assert!((k.pass_seconds(&size) - (2.0 * photons + 0.5 * camera)).abs() < 1e-9);
    }

    #[test]
    fn a_pass_that_fills_the_target_exactly_keeps_its_samples() {
        // Costs a probe measured on cornell_area; a pass of 2 spp fills the target to the
        // photon. Rounding the photon counts once cut such a pass to 1 spp and 1 gather ray.
        let c = Costs {
            per_pass: 0.012916561,
            per_path: 2.6802417813333333e-06,
            per_caustic_path: 0.9802417813333333e-06,
            caustic_share: 0.05,
            plane_share: 0.0,
            per_sample: 3.679861458333333e-06,
            per_gather_ray: 9.686567447916666e-07,
            pixels: 307200,
            probe_seconds: 0.338,
            ..Costs::default()
        };
        // Caustics carry 5 % of the light here: both kinds shrink alike (0.3 of the request).
        let exact = PassSize {
            photons: 600_000,
            caustic_photons: 300_000,
            spp: 2,
            ..requested()
        };
        let p = shrink(&c, c.pass_seconds(&exact), requested(), Stage::First);
        assert_eq!((p.spp, p.gather), (2, 8), "{p:?}");
        assert!(p.photons.abs_diff(exact.photons) <= 2, "{p:?}");
        assert!(p.caustic_photons.abs_diff(exact.caustic_photons) <= 1, "{p:?}");
    }
}
