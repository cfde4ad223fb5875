//! Wavelet denoising of photon-count textures.
//!
//! Watanabe, Fujishiro and Ohno ("Adaptive Photon Mapping with Reference to
//! Grid Structures") give every plane a grid whose cells count the photons
//! that land in them. A 2D discrete wavelet transform of that texture, with
//! small detail coefficients set to zero, removes photon noise while large
//! coefficients keep the sharp, bright structure of caustics. The filtered
//! count `N` of a cell then gives the assumed kNN radius `r_a² = n·m²/(N·π)`.
//!
//! The paper thresholds raw counts with one fixed value ([`Threshold::Fixed`]).
//! Photon counts are Poisson, so their noise grows with the count and a fixed
//! threshold is too strict in bright regions and too lax in dim ones. The
//! adaptive rules ([`Threshold::Universal`], [`Threshold::BayesShrink`]) work
//! in the Anscombe domain, where the noise is close to unit variance, and map
//! back with the exact unbiased inverse of Mäkitalo and Foi so that the mean
//! photon level is not shifted (the naive algebraic inverse darkens dim
//! regions). Those formulas live in `grid::noise`, shared with the voxel grid.
//!
//! Transforms use lifting with orthonormal-style scaling (the low band gains
//! `√2` per axis and level, the high band stays near unit noise gain), work on
//! any size (odd lengths put the extra sample in the low band) and use
//! whole-sample symmetric boundary extension for CDF 5/3 and 9/7, so a
//! constant field has exactly zero detail coefficients, edges included.
//!
//! At a sharp step only Haar stays clean on the dim side (its supports end at
//! dyadic block boundaries); CDF 5/3 and 9/7 ring there, and soft
//! thresholding shrinks edges and bright spots (see the tests). For count
//! textures that feed kNN radii, `Wavelet::Haar` with
//! `Threshold::Universal { soft: false }` is therefore the recommended setting.
//!
//! Everything here is plain `std`, without `unsafe`.

use super::noise::{anscombe, inverse_anscombe_unbiased, mad_sigma, universal_threshold};
use std::f64::consts::SQRT_2;

/// Which wavelet.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Wavelet {
    /// Orthonormal Haar: pairwise sums and differences divided by `√2`.
    /// Piecewise constant; its supports never straddle a dyadic block
    /// boundary, so block-aligned edges pass through untouched.
    Haar,
    /// CDF 5/3 (LeGall, the JPEG 2000 reversible filter) as two lifting
    /// steps, scaled by `√2` / `1/√2`. Two vanishing moments.
    Cdf53,
    /// CDF 9/7 (the JPEG 2000 irreversible filter) as four lifting steps and
    /// the Daubechies–Sweldens scaling. Four vanishing moments, nearly
    /// orthogonal.
    Cdf97,
}

/// How detail coefficients are thresholded.
///
/// Thresholds apply to every detail subband; the coarsest low-pass (LL)
/// band is never touched, which keeps the overall photon level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Threshold {
    /// No thresholding: [`denoise_counts`] reconstructs its input (up to `f32`
    /// rounding and the final clamp at 0).
    None,
    /// The paper's fixed threshold, applied to the wavelet coefficients of
    /// the raw counts (no variance stabilisation). `value` is in the
    /// coefficient scale of this module (orthonormal for Haar). `soft`
    /// selects soft shrinkage instead of hard keep-or-kill.
    Fixed {
        /// Magnitude at or below which a detail coefficient is set to 0.
        value: f32,
        /// Soft thresholding (shrink survivors by `value`) instead of hard.
        soft: bool,
    },
    /// VisuShrink in the Anscombe domain: the noise sigma is the median
    /// absolute deviation of the finest diagonal (HH) band divided by 0.6745,
    /// and the threshold is `sigma·√(2 ln n)` with `n` the number of cells,
    /// scaled per subband by that subband's noise gain. Hard thresholding
    /// keeps large coefficients exactly (sharp caustic edges); soft
    /// thresholding also shrinks them, dimming spots and softening edges.
    Universal {
        /// Soft thresholding instead of hard.
        soft: bool,
    },
    /// BayesShrink (Chang, Yu and Vetterli 2000) in the Anscombe domain: per
    /// subband soft threshold `t = sigma²/sigma_x`, with
    /// `sigma_x = √max(mean(c²) − sigma², 0)`; a subband with no signal
    /// energy above the noise is zeroed entirely.
    BayesShrink,
}

impl Threshold {
    /// Whether the rule works on Anscombe-transformed counts.
    fn uses_vst(self) -> bool {
        matches!(self, Threshold::Universal { .. } | Threshold::BayesShrink)
    }
}

/// A 2D field of f32 in row-major order (width = number of columns).
#[derive(Clone, Debug, PartialEq)]
pub struct Field2 {
    /// Number of columns.
    pub width: usize,
    /// Number of rows.
    pub height: usize,
    /// Row-major samples, `data[y * width + x]`; length `width * height`.
    pub data: Vec<f32>,
}

impl Field2 {
    /// A `width × height` field of zeros.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    /// Wraps row-major `data`. Panics if `data.len() != width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<f32>) -> Self {
        let field = Self { width, height, data };
        field.check();
        field
    }

    /// The sample at column `x`, row `y`. Panics when out of range.
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[self.index(x, y)]
    }

    /// Sets the sample at column `x`, row `y`. Panics when out of range.
    pub fn set(&mut self, x: usize, y: usize, value: f32) {
        let i = self.index(x, y);
        self.data[i] = value;
    }

    /// Sum of all samples, accumulated in `f64`.
    pub fn sum(&self) -> f64 {
        self.data.iter().map(|&v| f64::from(v)).sum()
    }

    /// Row-major index; checks both coordinates so an out-of-range `x`
    /// cannot silently alias a cell of the next row.
    fn index(&self, x: usize, y: usize) -> usize {
        assert!(
            x < self.width && y < self.height,
            "Field2 index ({x}, {y}) out of range for {}×{}",
            self.width,
            self.height
        );
        y * self.width + x
    }

    /// Panics if the buffer does not match the dimensions.
    fn check(&self) {
        assert_eq!(
            self.data.len(),
            self.width * self.height,
            "Field2 data length does not match {}×{}",
            self.width,
            self.height
        );
    }
}

/// What [`denoise_counts`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DenoiseReport {
    /// Estimated noise standard deviation of the transformed signal (in the
    /// Anscombe domain, so ≈ 1 for Poisson counts); 0 for rules that do not
    /// estimate noise ([`Threshold::None`], [`Threshold::Fixed`]).
    pub sigma: f32,
    /// One threshold per detail subband, finest level first and within a
    /// level in the order HL (high along x), LH (high along y), HH; bands
    /// that do not exist for thin fields are skipped. Empty for
    /// [`Threshold::None`].
    pub thresholds: Vec<f32>,
    /// Fraction of detail coefficients whose magnitude exceeded their
    /// threshold (1 when nothing is thresholded or there are no details).
    pub kept_fraction: f32,
    /// Mean count per cell of the input.
    pub mean_before: f64,
    /// Mean count per cell of the output.
    pub mean_after: f64,
}

/// Forward multi-level 2D DWT in place (Mallat layout: LL in the top-left corner after each level).
///
/// Each level transforms the rows and then the columns of the current LL
/// rectangle; the new LL has `ceil(w/2) × ceil(h/2)` cells. An axis whose
/// current length is 1 is left untransformed at that level (so a `33×1`
/// field gets a 1D transform along x), and once both lengths are 1 further
/// levels do nothing. Use [`max_levels`] for the usual square-ish choice.
pub fn forward_2d(f: &mut Field2, wavelet: Wavelet, levels: usize) {
    f.check();
    let plan = plan_levels(f.width, f.height, levels);
    let mut data = widen(&f.data);
    transform_2d(&mut data, f.width, &plan, wavelet, Direction::Forward);
    narrow_into(&data, &mut f.data);
}

/// Exact inverse of forward_2d.
///
/// `wavelet` and `levels` must be the values given to [`forward_2d`].
pub fn inverse_2d(f: &mut Field2, wavelet: Wavelet, levels: usize) {
    f.check();
    let plan = plan_levels(f.width, f.height, levels);
    let mut data = widen(&f.data);
    transform_2d(&mut data, f.width, &plan, wavelet, Direction::Inverse);
    narrow_into(&data, &mut f.data);
}

/// The number of levels that fits a width×height field (while both dims >= 2, halve, cap at `max`).
///
/// Halving rounds up, e.g. `128×37` fits 6 levels; a field with a dimension
/// of 1 (such as `33×1`) fits 0.
pub fn max_levels(width: usize, height: usize, max: usize) -> usize {
    let (mut w, mut h) = (width, height);
    let mut levels = 0;
    while levels < max && w >= 2 && h >= 2 {
        w = w.div_ceil(2);
        h = h.div_ceil(2);
        levels += 1;
    }
    levels
}

/// Denoise a count texture: (optional VST) → forward → threshold details → inverse → (inverse VST), clamp ≥ 0.
/// Returns the filtered field plus a small report.
///
/// Counts are expected to be finite and non-negative. [`Threshold::Universal`]
/// and [`Threshold::BayesShrink`] apply the Anscombe transform first and the
/// exact unbiased inverse afterwards; [`Threshold::None`] and
/// [`Threshold::Fixed`] work on raw counts. Levels follow [`forward_2d`].
/// An all-zero texture (a plane no photon reached) is returned unchanged, and
/// so is any texture when no level can be performed (a 1×1 grid, `levels`
/// = 0), apart from the clamp at 0.
/// All arithmetic is done in `f64`.
pub fn denoise_counts(
    counts: &Field2,
    wavelet: Wavelet,
    levels: usize,
    threshold: Threshold,
) -> (Field2, DenoiseReport) {
    counts.check();
    let (width, height) = (counts.width, counts.height);
    let mean_before = mean(&counts.data);
    // Empty planes are common; skipping them also keeps them exactly zero.
    if counts.data.iter().all(|&c| c == 0.0) {
        let report = DenoiseReport {
            kept_fraction: 1.0,
            mean_before,
            mean_after: mean_before,
            ..DenoiseReport::default()
        };
        return (counts.clone(), report);
    }

    let plan = plan_levels(width, height, levels);
    // The unbiased inverse assumes a smoothed estimate of E[anscombe(z)];
    // with no level to filter (e.g. a 1×1 grid) the counts pass unchanged.
    let vst = threshold.uses_vst() && !plan.is_empty();
    let mut data: Vec<f64> = counts
        .data
        .iter()
        .map(|&c| {
            let c = f64::from(c);
            if vst {
                anscombe(c.max(0.0))
            } else {
                c
            }
        })
        .collect();

    transform_2d(&mut data, width, &plan, wavelet, Direction::Forward);
    let bands = detail_bands(&plan);
    let rule = choose_thresholds(&data, width, height, &plan, &bands, wavelet, threshold);
    let kept_fraction = match rule.soft {
        Some(soft) => apply_thresholds(&mut data, width, &bands, &rule.thresholds, soft),
        None => 1.0,
    };
    transform_2d(&mut data, width, &plan, wavelet, Direction::Inverse);

    let out: Vec<f32> = data
        .iter()
        .map(|&v| {
            let v = if vst { inverse_anscombe_unbiased(v) } else { v };
            v.max(0.0) as f32
        })
        .collect();
    let mean_after = mean(&out);
    let report = DenoiseReport {
        sigma: rule.sigma as f32,
        thresholds: rule.thresholds.iter().map(|&t| t as f32).collect(),
        kept_fraction: kept_fraction as f32,
        mean_before,
        mean_after,
    };
    (Field2::from_vec(width, height, out), report)
}

// ---------------------------------------------------------------------------
// Formulas
// ---------------------------------------------------------------------------

/// BayesShrink threshold `sigma²/sigma_x` for one subband, with
/// `sigma_x² = max(mean(c²) − sigma², 0)`. A band with no energy above the
/// noise gets a threshold of its largest magnitude (zeroing it); a band with
/// no noise gets 0.
fn bayes_shrink_threshold(noise_var: f64, coeffs: &[f64]) -> f64 {
    if noise_var <= 0.0 || coeffs.is_empty() {
        return 0.0;
    }
    let energy = coeffs.iter().map(|c| c * c).sum::<f64>() / coeffs.len() as f64;
    let signal_var = energy - noise_var;
    if signal_var <= 0.0 {
        return coeffs.iter().fold(0.0, |m, c| m.max(c.abs()));
    }
    noise_var / signal_var.sqrt()
}

/// Soft thresholding: zero small coefficients and shrink the rest by `t`.
fn soft(c: f64, t: f64) -> f64 {
    c.signum() * (c.abs() - t).max(0.0)
}

/// Hard thresholding: zero small coefficients and keep the rest as they are.
fn hard(c: f64, t: f64) -> f64 {
    if c.abs() > t {
        c
    } else {
        0.0
    }
}

// ---------------------------------------------------------------------------
// 1D lifting
// ---------------------------------------------------------------------------

const CDF97_ALPHA: f64 = -1.586_134_342_059_924;
const CDF97_BETA: f64 = -0.052_980_118_572_961;
const CDF97_GAMMA: f64 = 0.882_911_075_530_934;
const CDF97_DELTA: f64 = 0.443_506_852_043_971;
const CDF97_ZETA: f64 = 1.149_604_398_860_241;

/// One lifting step on the even (`s`) and odd (`d`) polyphase halves.
#[derive(Clone, Copy, Debug)]
enum Step {
    /// `d[i] += c·(s[i] + s[i+1])`, symmetric extension at the right end.
    Predict(f64),
    /// `s[i] += c·(d[i-1] + d[i])`, symmetric extension at both ends.
    Update(f64),
    /// Haar predict `d[i] -= s[i]` (difference).
    HaarPredict,
    /// Haar update `s[i] += d[i]/2` (mean); an unpaired last `s` is kept.
    HaarUpdate,
}

impl Wavelet {
    /// Lifting steps in forward order.
    fn steps(self) -> &'static [Step] {
        match self {
            Wavelet::Haar => &[Step::HaarPredict, Step::HaarUpdate],
            Wavelet::Cdf53 => &[Step::Predict(-0.5), Step::Update(0.25)],
            Wavelet::Cdf97 => &[
                Step::Predict(CDF97_ALPHA),
                Step::Update(CDF97_BETA),
                Step::Predict(CDF97_GAMMA),
                Step::Update(CDF97_DELTA),
            ],
        }
    }

    /// Final scaling: the low band is multiplied and the high band divided
    /// by this, giving DC gain `√2` and near-unit noise gain in the details.
    fn scale(self) -> f64 {
        match self {
            Wavelet::Haar | Wavelet::Cdf53 => SQRT_2,
            Wavelet::Cdf97 => CDF97_ZETA,
        }
    }
}

/// Applies one lifting step, forward (`sign = 1`) or undone (`sign = -1`).
///
/// Whole-sample symmetric extension of the signal (`x[-1] = x[1]`,
/// `x[n] = x[n-2]`) means `d[-1] = d[0]`, a missing `s[i+1]` is `s[i]`
/// (even length) and a missing `d[i]` is `d[i-1]` (odd length). Each step
/// reads only the half it does not write, so undoing it is exact.
fn apply_step(step: Step, s: &mut [f64], d: &mut [f64], sign: f64) {
    let (ns, nd) = (s.len(), d.len());
    match step {
        Step::Predict(c) => {
            for i in 0..nd {
                let right = if i + 1 < ns { s[i + 1] } else { s[i] };
                d[i] += sign * c * (s[i] + right);
            }
        }
        Step::Update(c) => {
            for i in 0..ns {
                let left = d[i.saturating_sub(1)];
                let right = d[i.min(nd - 1)];
                s[i] += sign * c * (left + right);
            }
        }
        Step::HaarPredict => {
            for i in 0..nd {
                d[i] -= sign * s[i];
            }
        }
        Step::HaarUpdate => {
            for i in 0..nd {
                s[i] += sign * 0.5 * d[i];
            }
        }
    }
}

/// Transform direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Direction {
    Forward,
    Inverse,
}

/// One level of the 1D transform in place: `x` becomes `[low | high]`, the
/// low half holding `ceil(n/2)` samples. Lengths below 2 are left alone.
fn lift_1d(x: &mut [f64], wavelet: Wavelet, direction: Direction, scratch: &mut Vec<f64>) {
    let n = x.len();
    if n < 2 {
        return;
    }
    let ns = n.div_ceil(2);
    let k = wavelet.scale();
    scratch.clear();
    match direction {
        Direction::Forward => {
            scratch.extend(x.iter().step_by(2));
            scratch.extend(x.iter().skip(1).step_by(2));
            let (s, d) = scratch.split_at_mut(ns);
            for &step in wavelet.steps() {
                apply_step(step, s, d, 1.0);
            }
            s.iter_mut().for_each(|v| *v *= k);
            d.iter_mut().for_each(|v| *v /= k);
            x.copy_from_slice(scratch);
        }
        Direction::Inverse => {
            scratch.extend_from_slice(x);
            let (s, d) = scratch.split_at_mut(ns);
            s.iter_mut().for_each(|v| *v /= k);
            d.iter_mut().for_each(|v| *v *= k);
            for &step in wavelet.steps().iter().rev() {
                apply_step(step, s, d, -1.0);
            }
            for (i, &v) in s.iter().enumerate() {
                x[2 * i] = v;
            }
            for (i, &v) in d.iter().enumerate() {
                x[2 * i + 1] = v;
            }
        }
    }
}

// ---------------------------------------------------------------------------
// 2D transform
// ---------------------------------------------------------------------------

/// One level of the 2D transform: the LL rectangle it starts from and the
/// axes it transforms (an axis of length 1 is skipped).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct LevelPlan {
    w: usize,
    h: usize,
    along_x: bool,
    along_y: bool,
}

impl LevelPlan {
    /// Width of the LL rectangle after this level.
    fn w_low(&self) -> usize {
        if self.along_x {
            self.w.div_ceil(2)
        } else {
            self.w
        }
    }

    /// Height of the LL rectangle after this level.
    fn h_low(&self) -> usize {
        if self.along_y {
            self.h.div_ceil(2)
        } else {
            self.h
        }
    }
}

/// The levels actually performed for `levels` requested; stops early once
/// the LL rectangle is a single cell (or empty).
fn plan_levels(width: usize, height: usize, levels: usize) -> Vec<LevelPlan> {
    let mut plan = Vec::new();
    let (mut w, mut h) = (width, height);
    for _ in 0..levels {
        let level = LevelPlan {
            w,
            h,
            along_x: w >= 2,
            along_y: h >= 2,
        };
        if !level.along_x && !level.along_y {
            break;
        }
        w = level.w_low();
        h = level.h_low();
        plan.push(level);
    }
    plan
}

/// Runs the planned levels on a row-major buffer with row length `stride`:
/// forward does rows then columns per level, inverse mirrors it exactly.
fn transform_2d(data: &mut [f64], stride: usize, plan: &[LevelPlan], wavelet: Wavelet, direction: Direction) {
    let mut scratch = Vec::new();
    let mut column = Vec::new();
    let rows = |data: &mut [f64], level: &LevelPlan, scratch: &mut Vec<f64>| {
        for y in 0..level.h {
            let row = &mut data[y * stride..y * stride + level.w];
            lift_1d(row, wavelet, direction, scratch);
        }
    };
    let mut columns = |data: &mut [f64], level: &LevelPlan, scratch: &mut Vec<f64>| {
        for x in 0..level.w {
            column.clear();
            column.extend((0..level.h).map(|y| data[y * stride + x]));
            lift_1d(&mut column, wavelet, direction, scratch);
            for (y, &v) in column.iter().enumerate() {
                data[y * stride + x] = v;
            }
        }
    };
    match direction {
        Direction::Forward => {
            for level in plan {
                if level.along_x {
                    rows(data, level, &mut scratch);
                }
                if level.along_y {
                    columns(data, level, &mut scratch);
                }
            }
        }
        Direction::Inverse => {
            for level in plan.iter().rev() {
                if level.along_y {
                    columns(data, level, &mut scratch);
                }
                if level.along_x {
                    rows(data, level, &mut scratch);
                }
            }
        }
    }
}

/// `f32` samples to `f64` working precision.
fn widen(data: &[f32]) -> Vec<f64> {
    data.iter().map(|&v| f64::from(v)).collect()
}

/// `f64` working values back into `f32` storage.
fn narrow_into(src: &[f64], dst: &mut [f32]) {
    for (d, &s) in dst.iter_mut().zip(src) {
        *d = s as f32;
    }
}

/// Mean of `f32` samples in `f64` (0 for an empty field).
fn mean(data: &[f32]) -> f64 {
    if data.is_empty() {
        return 0.0;
    }
    data.iter().map(|&v| f64::from(v)).sum::<f64>() / data.len() as f64
}

// ---------------------------------------------------------------------------
// Subbands and their noise gains
// ---------------------------------------------------------------------------

/// A detail subband: a rectangle of the Mallat layout plus how many 1D
/// transforms each axis had gone through (indexes into [`NoiseGains`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Band {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
    x_depth: usize,
    y_depth: usize,
    /// High-pass along every axis transformed at its level (HH, or the only
    /// detail band of a thin field): the purest noise estimate.
    diagonal: bool,
}

impl Band {
    /// Cells of the band as `(x, y)`.
    fn cells(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (self.y0..self.y1).flat_map(move |y| (self.x0..self.x1).map(move |x| (x, y)))
    }

    /// Coefficients of the band, row by row.
    fn values(&self, data: &[f64], stride: usize) -> Vec<f64> {
        self.cells().map(|(x, y)| data[y * stride + x]).collect()
    }
}

/// Detail subbands in report order: finest level first, then HL, LH, HH.
fn detail_bands(plan: &[LevelPlan]) -> Vec<Band> {
    let mut bands = Vec::new();
    let (mut kx, mut ky) = (0, 0);
    for level in plan {
        let x_depth = kx + usize::from(level.along_x);
        let y_depth = ky + usize::from(level.along_y);
        let (wl, hl) = (level.w_low(), level.h_low());
        let band = |x0, x1, y0, y1, diagonal| Band {
            x0,
            x1,
            y0,
            y1,
            x_depth,
            y_depth,
            diagonal,
        };
        let both = level.along_x && level.along_y;
        if level.along_x {
            bands.push(band(wl, level.w, 0, hl, !level.along_y));
        }
        if level.along_y {
            bands.push(band(0, wl, hl, level.h, !level.along_x));
        }
        if both {
            bands.push(band(wl, level.w, hl, level.h, true));
        }
        kx = x_depth;
        ky = y_depth;
    }
    bands
}

/// Per-axis noise variance gains: `x[t][i]` is the squared norm of the
/// analysis row of coefficient `i` after `t` 1D levels along x, i.e. the
/// variance that unit white noise has there. Lifting filters are not exactly
/// orthonormal (CDF 5/3 details carry ~0.75 of the input variance at the
/// finest level and more further down), so thresholds from one noise
/// estimate must be rescaled per band. 2D gains are products of the axes'.
#[derive(Clone, Debug)]
struct NoiseGains {
    x: Vec<Vec<f64>>,
    y: Vec<Vec<f64>>,
}

impl NoiseGains {
    /// Gains for the axes of a planned transform.
    fn new(width: usize, height: usize, plan: &[LevelPlan], wavelet: Wavelet) -> Self {
        let kx = plan.iter().filter(|l| l.along_x).count();
        let ky = plan.iter().filter(|l| l.along_y).count();
        Self {
            x: axis_gains(width, kx, wavelet),
            y: axis_gains(height, ky, wavelet),
        }
    }

    /// Variance gain of the coefficient at `(x, y)` of `band`.
    fn at(&self, band: &Band, x: usize, y: usize) -> f64 {
        self.x[band.x_depth][x] * self.y[band.y_depth][y]
    }

    /// Mean variance gain over `band` (separable, so a product of means).
    fn band_mean(&self, band: &Band) -> f64 {
        let mean = |g: &[f64]| g.iter().sum::<f64>() / g.len().max(1) as f64;
        mean(&self.x[band.x_depth][band.x0..band.x1]) * mean(&self.y[band.y_depth][band.y0..band.y1])
    }
}

/// Squared analysis-row norms of a `depth`-level 1D transform of length
/// `len`, found by transforming every unit impulse (`O(len²)`, negligible for
/// grid sizes). Entry `t` covers the `len_{t-1}` coefficients touched by
/// level `t`; entry 0 is the identity.
fn axis_gains(len: usize, depth: usize, wavelet: Wavelet) -> Vec<Vec<f64>> {
    let mut lens = vec![len];
    for t in 0..depth {
        lens.push(lens[t].div_ceil(2));
    }
    let mut gains: Vec<Vec<f64>> = vec![vec![1.0; len]];
    gains.extend((1..=depth).map(|t| vec![0.0; lens[t - 1]]));
    let mut impulse = vec![0.0; len];
    let mut scratch = Vec::new();
    for i in 0..len {
        impulse.fill(0.0);
        impulse[i] = 1.0;
        for t in 1..=depth {
            let active = &mut impulse[..lens[t - 1]];
            lift_1d(active, wavelet, Direction::Forward, &mut scratch);
            for (g, v) in gains[t].iter_mut().zip(active.iter()) {
                *g += v * v;
            }
        }
    }
    gains
}

// ---------------------------------------------------------------------------
// Thresholding
// ---------------------------------------------------------------------------

/// Thresholds chosen for one denoising run.
#[derive(Clone, Debug)]
struct BandRule {
    /// Input-domain noise sigma (0 when not estimated).
    sigma: f64,
    /// One threshold per band of [`detail_bands`].
    thresholds: Vec<f64>,
    /// `Some(soft)` when thresholds are to be applied.
    soft: Option<bool>,
}

/// Noise sigma of the transform input: MAD of the finest diagonal band,
/// each coefficient divided by its own noise gain first.
fn estimate_sigma(data: &[f64], stride: usize, bands: &[Band], gains: &NoiseGains) -> f64 {
    let Some(band) = bands.iter().find(|b| b.diagonal) else {
        return 0.0;
    };
    let mut normalised: Vec<f64> = band
        .cells()
        .map(|(x, y)| data[y * stride + x] / gains.at(band, x, y).sqrt())
        .collect();
    mad_sigma(&mut normalised)
}

/// Picks per-band thresholds for `threshold` from the forward coefficients.
fn choose_thresholds(
    data: &[f64],
    width: usize,
    height: usize,
    plan: &[LevelPlan],
    bands: &[Band],
    wavelet: Wavelet,
    threshold: Threshold,
) -> BandRule {
    let noise = || {
        let gains = NoiseGains::new(width, height, plan, wavelet);
        let sigma = estimate_sigma(data, width, bands, &gains);
        (gains, sigma)
    };
    match threshold {
        Threshold::None => BandRule {
            sigma: 0.0,
            thresholds: Vec::new(),
            soft: None,
        },
        Threshold::Fixed { value, soft } => BandRule {
            sigma: 0.0,
            thresholds: vec![f64::from(value); bands.len()],
            soft: Some(soft),
        },
        Threshold::Universal { soft } => {
            let (gains, sigma) = noise();
            let t = universal_threshold(sigma, width * height);
            BandRule {
                sigma,
                thresholds: bands.iter().map(|b| t * gains.band_mean(b).sqrt()).collect(),
                soft: Some(soft),
            }
        }
        Threshold::BayesShrink => {
            let (gains, sigma) = noise();
            let thresholds = bands
                .iter()
                .map(|b| {
                    let noise_var = sigma * sigma * gains.band_mean(b);
                    bayes_shrink_threshold(noise_var, &b.values(data, width))
                })
                .collect();
            BandRule {
                sigma,
                thresholds,
                soft: Some(true),
            }
        }
    }
}

/// Thresholds every detail band in place; returns the fraction of detail
/// coefficients that survived (1 when there are none).
fn apply_thresholds(data: &mut [f64], stride: usize, bands: &[Band], thresholds: &[f64], soft_rule: bool) -> f64 {
    let shrink = if soft_rule { soft } else { hard };
    let (mut kept, mut total) = (0usize, 0usize);
    for (band, &t) in bands.iter().zip(thresholds) {
        for (x, y) in band.cells() {
            let c = &mut data[y * stride + x];
            total += 1;
            kept += usize::from(c.abs() > t);
            *c = shrink(*c, t);
        }
    }
    if total == 0 {
        1.0
    } else {
        kept as f64 / total as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;
    use crate::test_util::{test_rng, uniform_f64};

    const WAVELETS: [Wavelet; 3] = [Wavelet::Haar, Wavelet::Cdf53, Wavelet::Cdf97];

    /// Exact Poisson sample: a sum of Knuth draws with means ≤ 16
    /// (Poisson variables add), so large means do not underflow.
    fn poisson(rng: &mut Rng, lambda: f64) -> u32 {
        let mut remaining = lambda;
        let mut k = 0;
        while remaining > 0.0 {
            let chunk = remaining.min(16.0);
            remaining -= chunk;
            let limit = (-chunk).exp();
            let mut p = uniform_f64(rng);
            while p > limit {
                k += 1;
                p *= uniform_f64(rng);
            }
        }
        k
    }

    /// Poisson counts with mean `truth(x, y)`, plus the truth itself.
    fn poisson_field(
        width: usize,
        height: usize,
        seed: u64,
        truth: impl Fn(usize, usize) -> f64,
    ) -> (Field2, Vec<f64>) {
        let mut rng = test_rng(seed);
        let mut field = Field2::new(width, height);
        let mut mean = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let m = truth(x, y);
                field.set(x, y, poisson(&mut rng, m) as f32);
                mean.push(m);
            }
        }
        (field, mean)
    }

    fn rmse(field: &[f32], truth: &[f64]) -> f64 {
        let sq: f64 = field.iter().zip(truth).map(|(&v, &t)| (f64::from(v) - t).powi(2)).sum();
        (sq / truth.len() as f64).sqrt()
    }

    fn random_field(width: usize, height: usize, seed: u64) -> Field2 {
        let mut rng = test_rng(seed);
        let data = (0..width * height).map(|_| rng.uniform() * 200.0).collect();
        Field2::from_vec(width, height, data)
    }

    /// The algebraic inverse of the Anscombe transform (biased at low counts).
    fn naive_inverse_anscombe(y: f64) -> f64 {
        (0.25 * y * y - 0.375).max(0.0)
    }

    #[test]
    fn max_levels_halves_with_ceiling() {
        assert_eq!(max_levels(128, 128, 10), 7);
        assert_eq!(max_levels(128, 128, 4), 4);
        assert_eq!(max_levels(128, 37, 10), 6);
        assert_eq!(max_levels(33, 1, 5), 0);
        assert_eq!(max_levels(1, 1, 5), 0);
        assert_eq!(max_levels(5, 7, 10), 3);
        assert_eq!(max_levels(2, 2, 0), 0);
    }

    #[test]
    fn plan_skips_axes_of_length_one() {
        let plan = plan_levels(33, 1, 10);
        // 33 → 17 → 9 → 5 → 3 → 2 → 1 along x only.
        assert_eq!(plan.len(), 6);
        assert!(plan.iter().all(|l| l.along_x && !l.along_y));
        assert!(plan_levels(1, 1, 4).is_empty());
        // 5×7 with 10 levels: 5×7, 3×4, 2×2, then 1×1 stops.
        let plan = plan_levels(5, 7, 10);
        assert_eq!(plan.len(), 3);
        let plan = plan_levels(4, 9, 10);
        // 4×9 → 2×5 → 1×3 → 1×2 → 1×1: the last two levels are y-only.
        assert_eq!(plan.len(), 4);
        assert!(!plan[2].along_x && plan[2].along_y);
    }

    /// Test 1: perfect reconstruction without thresholding.
    #[test]
    fn perfect_reconstruction_all_wavelets_and_sizes() {
        let sizes = [(128, 128), (128, 37), (33, 1), (1, 1), (5, 7), (1, 9)];
        for wavelet in WAVELETS {
            for (i, &(w, h)) in sizes.iter().enumerate() {
                for levels in [1, 2, max_levels(w, h, 10), 10] {
                    let original = random_field(w, h, 17 + i as u64);
                    let mut f = original.clone();
                    forward_2d(&mut f, wavelet, levels);
                    if w * h > 1 {
                        // Guard against a do-nothing transform passing.
                        let changed = f.data.iter().zip(&original.data).any(|(a, b)| (a - b).abs() > 1e-3);
                        assert!(changed || plan_levels(w, h, levels).is_empty());
                    }
                    inverse_2d(&mut f, wavelet, levels);
                    let err = f
                        .data
                        .iter()
                        .zip(&original.data)
                        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
                    assert!(err < 1e-4, "{wavelet:?} {w}×{h} levels {levels}: max error {err}");
                }
            }
        }
    }

    /// Test 1b: `denoise_counts` with no threshold reproduces the counts.
    #[test]
    fn denoise_without_threshold_is_identity() {
        let (counts, _) = poisson_field(37, 21, 5, |_, _| 12.0);
        for wavelet in WAVELETS {
            let (out, report) = denoise_counts(&counts, wavelet, 4, Threshold::None);
            for (a, b) in out.data.iter().zip(&counts.data) {
                assert!((a - b).abs() < 1e-4, "{wavelet:?}: {a} vs {b}");
            }
            assert!(report.thresholds.is_empty());
            assert_eq!(report.kept_fraction, 1.0);
        }
    }

    /// Test 2: Haar on a constant field has all-zero details; with the
    /// symmetric extension the CDF wavelets do too, boundaries included.
    #[test]
    fn constant_field_has_zero_details() {
        for wavelet in WAVELETS {
            for &(w, h) in &[(128, 128), (128, 37), (5, 7), (33, 1)] {
                let levels = 10;
                let mut f = Field2::from_vec(w, h, vec![42.0; w * h]);
                forward_2d(&mut f, wavelet, levels);
                let plan = plan_levels(w, h, levels);
                let last = plan.last().unwrap();
                let (lw, lh) = (last.w_low(), last.h_low());
                let tol = if wavelet == Wavelet::Haar { 1e-6 } else { 1e-3 };
                for y in 0..h {
                    for x in 0..w {
                        if x >= lw || y >= lh {
                            let c = f.get(x, y);
                            assert!(c.abs() < tol, "{wavelet:?} {w}×{h} ({x},{y}) = {c}");
                        }
                    }
                }
            }
        }
    }

    /// The lifting constants are right: interior details vanish on
    /// polynomials up to the wavelet's vanishing moments (1 for Haar, 2 for
    /// 5/3, 4 for 9/7), and Haar preserves energy (orthonormal).
    #[test]
    fn vanishing_moments_and_haar_energy() {
        type Polynomial = fn(f64) -> f64;
        let cases: [(Wavelet, Polynomial); 3] = [
            (Wavelet::Haar, |_| 3.0),
            (Wavelet::Cdf53, |x| 2.0 + 0.5 * x),
            (Wavelet::Cdf97, |x| 1.0 + 0.3 * x - 0.02 * x * x + 0.001 * x * x * x),
        ];
        for (wavelet, poly) in cases {
            let mut x: Vec<f64> = (0..64).map(|i| poly(i as f64)).collect();
            lift_1d(&mut x, wavelet, Direction::Forward, &mut Vec::new());
            // Details 32..64; skip the 3 nearest each boundary.
            for (i, &d) in x[35..61].iter().enumerate() {
                assert!(d.abs() < 1e-8, "{wavelet:?} detail {} = {d}", i + 35);
            }
        }
        // A quadratic is not annihilated by 5/3: the test can fail.
        let mut q: Vec<f64> = (0..64).map(|i| (i * i) as f64).collect();
        lift_1d(&mut q, Wavelet::Cdf53, Direction::Forward, &mut Vec::new());
        assert!(q[40].abs() > 0.1);

        let f = random_field(64, 32, 3);
        let mut g = f.clone();
        forward_2d(&mut g, Wavelet::Haar, 5);
        let (e0, e1): (f64, f64) = (
            f.data.iter().map(|&v| f64::from(v).powi(2)).sum(),
            g.data.iter().map(|&v| f64::from(v).powi(2)).sum(),
        );
        assert!((e0 - e1).abs() < 1e-5 * e0, "{e0} vs {e1}");
    }

    /// Noise gains: 1 for orthonormal Haar, near 1 for 9/7, 0.75 for the
    /// finest 5/3 details.
    #[test]
    fn axis_gains_match_filter_norms() {
        let haar = axis_gains(64, 3, Wavelet::Haar);
        assert!(haar.iter().flatten().all(|&g| (g - 1.0).abs() < 1e-12));
        let cdf53 = axis_gains(64, 1, Wavelet::Cdf53);
        // Interior highpass (−1/2, 1, −1/2)/√2: 1.5/2.
        assert!((cdf53[1][40] - 0.75).abs() < 1e-12);
        // Interior lowpass (−1, 2, 6, 2, −1)/8·√2: 46/64·2.
        assert!((cdf53[1][10] - 1.4375).abs() < 1e-12);
        // 9/7 is nearly orthonormal away from the boundaries.
        let cdf97 = axis_gains(64, 2, Wavelet::Cdf97);
        for &g in cdf97[1][4..28].iter().chain(&cdf97[1][36..60]) {
            assert!((g - 1.0).abs() < 0.05, "9/7 level-1 gain {g}");
        }
        for &g in cdf97[2][4..12].iter().chain(&cdf97[2][20..28]) {
            assert!((g - 1.0).abs() < 0.15, "9/7 level-2 gain {g}");
        }
    }

    /// Test 3: Poisson noise on a flat field. RMSE drops ≥ 3× and the mean
    /// stays put (1 % at 20 photons/cell, 3 % at 2).
    #[test]
    fn flat_poisson_field_denoised_without_bias() {
        let rules = [
            Threshold::Universal { soft: true },
            Threshold::Universal { soft: false },
            Threshold::BayesShrink,
        ];
        for (lambda, tolerance) in [(20.0, 0.01), (2.0, 0.03)] {
            let (counts, truth) = poisson_field(128, 128, 42, |_, _| lambda);
            let rmse_before = rmse(&counts.data, &truth);
            for wavelet in WAVELETS {
                for rule in rules {
                    let (out, report) = denoise_counts(&counts, wavelet, 5, rule);
                    let rmse_after = rmse(&out.data, &truth);
                    let drift = (report.mean_after - report.mean_before) / report.mean_before;
                    println!(
                        "flat λ={lambda} {wavelet:?} {rule:?}: RMSE {rmse_before:.3} → \
                         {rmse_after:.3} ({:.1}×), mean {:.4} → {:.4} ({:+.2} %), sigma {:.3}, \
                         kept {:.5}",
                        rmse_before / rmse_after,
                        report.mean_before,
                        report.mean_after,
                        100.0 * drift,
                        report.sigma,
                        report.kept_fraction
                    );
                    assert!(rmse_after * 3.0 < rmse_before, "RMSE {rmse_after}");
                    assert!(drift.abs() < tolerance, "mean drift {drift}");
                    assert!((report.mean_after - out.sum() / 16384.0).abs() < 1e-9);
                    // The Anscombe domain has unit noise; the gain-corrected
                    // MAD estimate must find it whatever the wavelet.
                    if lambda > 10.0 {
                        assert!((report.sigma - 1.0).abs() < 0.1, "sigma {}", report.sigma);
                    }
                }
            }
        }
    }

    /// Why the unbiased inverse: the algebraic inverse of the same denoised
    /// Anscombe field loses > 5 % of the photons at 2 per cell.
    #[test]
    fn naive_inverse_anscombe_would_be_biased() {
        let (counts, _) = poisson_field(128, 128, 7, |_, _| 2.0);
        let mut data: Vec<f64> = counts.data.iter().map(|&c| anscombe(c.into())).collect();
        let plan = plan_levels(128, 128, 5);
        transform_2d(&mut data, 128, &plan, Wavelet::Haar, Direction::Forward);
        let bands = detail_bands(&plan);
        for band in &bands {
            for (x, y) in band.cells() {
                data[y * 128 + x] = 0.0;
            }
        }
        transform_2d(&mut data, 128, &plan, Wavelet::Haar, Direction::Inverse);
        let before = counts.sum() / 16384.0;
        let naive = data.iter().map(|&y| naive_inverse_anscombe(y)).sum::<f64>() / 16384.0;
        let unbiased = data.iter().map(|&y| inverse_anscombe_unbiased(y)).sum::<f64>() / 16384.0;
        println!("λ=2 mean {before:.4}: naive inverse {naive:.4}, unbiased {unbiased:.4}");
        assert!((naive - before) / before < -0.05);
        assert!(((unbiased - before) / before).abs() < 0.02);
    }

    /// Profile statistics of a denoised vertical step at column `edge`:
    /// the worst relative error of single cells and of column means (over
    /// all rows) with ≥ 2 cells between them and the edge, and the smallest
    /// per-row jump across the edge as a fraction of the true step.
    fn edge_errors(out: &Field2, edge: usize, lo: f64, hi: f64) -> (f64, f64, f64) {
        let truth = |x: usize| if x < edge { lo } else { hi };
        let far = || (0..edge - 2).chain(edge + 2..out.width);
        let (mut cell, mut column, mut step) = (0.0f64, 0.0f64, f64::INFINITY);
        for x in far() {
            let mut sum = 0.0;
            for y in 0..out.height {
                let v = f64::from(out.get(x, y));
                cell = cell.max((v - truth(x)).abs() / truth(x));
                sum += v;
            }
            let column_mean = sum / out.height as f64;
            column = column.max((column_mean - truth(x)).abs() / truth(x));
        }
        for y in 0..out.height {
            let jump = f64::from(out.get(edge, y)) - f64::from(out.get(edge - 1, y));
            step = step.min(jump / (hi - lo));
        }
        (cell, column, step)
    }

    /// Test 4: a sharp edge (left half 5, right half 200 photons/cell)
    /// survives Universal denoising with Haar: every cell with ≥ 2 cells
    /// between it and the edge is within 10 % of the truth, and every row
    /// keeps > 70 % of the step across the two edge cells. At an edge off
    /// the dyadic grid (column 61) the surviving straddling coefficients
    /// carry their noise, so single cells reach ~15 %; there the column
    /// means (bias and ringing) must be within 10 %. CDF 5/3 and 9/7 ring on
    /// the dim side of a 40:1 step and are only reported.
    #[test]
    fn edge_stays_sharp() {
        let (lo, hi) = (5.0, 200.0);
        for edge in [64, 61] {
            // Statistical bounds: for some seeds (about one in five) a noise coefficient on the
            // dim side survives the universal threshold and one cell breaks the 10 % bound.
            let (counts, truth) = poisson_field(128, 128, 100, |x, _| if x < edge { lo } else { hi });
            let rules = [
                Threshold::Universal { soft: false },
                Threshold::Universal { soft: true },
                Threshold::BayesShrink,
            ];
            for wavelet in WAVELETS {
                for rule in rules {
                    let (out, report) = denoise_counts(&counts, wavelet, 5, rule);
                    let (cell, column, step) = edge_errors(&out, edge, lo, hi);
                    println!(
                        "edge@{edge} {wavelet:?} {rule:?}: RMSE {:.3} → {:.3}, worst cell {:.1} \
                         %, worst column mean {:.1} %, weakest row step {:.1} %, mean {:.3} → \
                         {:.3}",
                        rmse(&counts.data, &truth),
                        rmse(&out.data, &truth),
                        100.0 * cell,
                        100.0 * column,
                        100.0 * step,
                        report.mean_before,
                        report.mean_after
                    );
                    if wavelet != Wavelet::Haar {
                        continue;
                    }
                    let hard = rule == Threshold::Universal { soft: false };
                    if edge == 64 && rule != Threshold::BayesShrink {
                        assert!(cell < 0.10, "{rule:?}: cell error {cell}");
                        assert!(step > 0.70, "{rule:?}: step kept {step}");
                    }
                    if edge == 61 && hard {
                        assert!(column < 0.10, "{rule:?}: column-mean error {column}");
                        assert!(step > 0.70, "{rule:?}: step kept {step}");
                    }
                }
            }
        }
    }

    fn spot_field(seed: u64) -> (Field2, Vec<f64>) {
        poisson_field(128, 128, seed, |x, y| {
            if (61..64).contains(&x) && (70..73).contains(&y) {
                2000.0
            } else {
                10.0
            }
        })
    }

    fn spot_sum(f: &Field2) -> f64 {
        (70..73)
            .flat_map(|y| (61..64).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(f.get(x, y)))
            .sum()
    }

    /// Test 5: a small, very bright spot (a caustic focus) keeps ≥ 80 % of
    /// its photons.
    #[test]
    fn bright_spot_is_kept() {
        let (counts, _) = spot_field(11);
        let before = spot_sum(&counts);
        for wavelet in WAVELETS {
            for rule in [
                Threshold::Universal { soft: true },
                Threshold::Universal { soft: false },
                Threshold::BayesShrink,
            ] {
                let (out, _) = denoise_counts(&counts, wavelet, 5, rule);
                let kept = spot_sum(&out) / before;
                println!("spot {wavelet:?} {rule:?}: kept {:.1} %", 100.0 * kept);
                // Soft VisuShrink shrinks every survivor by t; with the wide
                // CDF supports that costs ~21 % of the spot (reported only).
                let soft_cdf = rule == Threshold::Universal { soft: true } && wavelet != Wavelet::Haar;
                if !soft_cdf {
                    assert!(kept >= 0.8, "{wavelet:?} {rule:?} kept {kept}");
                }
            }
        }
    }

    /// Test 6: the paper's fixed threshold. A huge value zeroes every detail,
    /// so Haar leaves each 2^L × 2^L block at its mean: piecewise constant,
    /// which smears caustics. A zero threshold changes nothing.
    #[test]
    fn fixed_threshold_behaves_as_defined() {
        let (counts, _) = spot_field(13);
        let levels = 3;
        let huge = Threshold::Fixed {
            value: 1e9,
            soft: false,
        };
        let (out, report) = denoise_counts(&counts, Wavelet::Haar, levels, huge);
        assert_eq!(report.kept_fraction, 0.0);
        assert_eq!(report.thresholds.len(), 3 * levels);
        for by in 0..16 {
            for bx in 0..16 {
                let cells = || (0..8).flat_map(move |y| (0..8).map(move |x| (bx * 8 + x, by * 8 + y)));
                let block_mean = cells().map(|(x, y)| f64::from(counts.get(x, y))).sum::<f64>() / 64.0;
                for (x, y) in cells() {
                    let v = f64::from(out.get(x, y));
                    assert!((v - block_mean).abs() < 1e-3 * block_mean.max(1.0), "({x},{y})");
                }
            }
        }
        let (same, _) = denoise_counts(
            &counts,
            Wavelet::Cdf97,
            levels,
            Threshold::Fixed { value: 0.0, soft: true },
        );
        for (a, b) in same.data.iter().zip(&counts.data) {
            assert!((a - b).abs() < 1e-2, "{a} vs {b}");
        }
        // Report how the fixed rule treats the spot and the background.
        let before = spot_sum(&counts);
        for value in [30.0, 100.0, 1e9] {
            let rule = Threshold::Fixed { value, soft: false };
            let (out, report) = denoise_counts(&counts, Wavelet::Haar, 5, rule);
            let bg_peak = (0..128)
                .flat_map(|y| (0..128).map(move |x| (x, y)))
                .filter(|&(x, y)| !((56..69).contains(&x) && (65..78).contains(&y)))
                .map(|(x, y)| out.get(x, y))
                .fold(0.0f32, f32::max);
            println!(
                "fixed {value}: spot kept {:.1} %, kept coefficients {:.4}, brightest \
                 background cell {bg_peak:.1} (truth 10)",
                100.0 * spot_sum(&out) / before,
                report.kept_fraction
            );
        }
    }

    /// The paper's weakness: one fixed threshold for raw counts cannot fit
    /// Poisson noise whose sigma grows with the count. Tuned to the dim side
    /// of the step it leaves the bright side noisy (reported, not asserted).
    #[test]
    fn fixed_threshold_versus_adaptive_on_two_levels() {
        let (counts, truth) = poisson_field(128, 128, 31, |x, _| if x < 64 { 5.0 } else { 200.0 });
        let side_rmse = |out: &Field2, right: bool| {
            let mut sq = 0.0;
            for y in 0..128 {
                for x in (0..128).filter(|&x| (x >= 64) == right) {
                    sq += (f64::from(out.get(x, y)) - truth[y * 128 + x]).powi(2);
                }
            }
            (sq / (64.0 * 128.0)).sqrt()
        };
        let rules = [
            Threshold::Fixed {
                value: 9.0,
                soft: false,
            },
            Threshold::Fixed {
                value: 60.0,
                soft: false,
            },
            Threshold::Universal { soft: false },
        ];
        for rule in rules {
            let (out, report) = denoise_counts(&counts, Wavelet::Haar, 5, rule);
            println!(
                "{rule:?}: RMSE dim side {:.3} (noisy {:.3}), bright side {:.3} (noisy {:.3}), \
                 kept {:.4}",
                side_rmse(&out, false),
                side_rmse(&counts, false),
                side_rmse(&out, true),
                side_rmse(&counts, true),
                report.kept_fraction
            );
        }
    }

    /// Test 7: an all-zero texture stays exactly zero for every rule.
    #[test]
    fn zero_field_stays_zero() {
        let rules = [
            Threshold::None,
            Threshold::Fixed { value: 3.0, soft: true },
            Threshold::Universal { soft: true },
            Threshold::Universal { soft: false },
            Threshold::BayesShrink,
        ];
        for &(w, h) in &[(128, 128), (128, 37), (1, 1), (5, 7)] {
            for wavelet in WAVELETS {
                for rule in rules {
                    let (out, report) = denoise_counts(&Field2::new(w, h), wavelet, 5, rule);
                    assert!(out.data.iter().all(|&v| v == 0.0), "{wavelet:?} {rule:?}");
                    assert_eq!(report.mean_after, 0.0);
                    assert!(report.sigma.is_finite() && report.kept_fraction.is_finite());
                }
            }
        }
    }

    /// Degenerate inputs (noise-free constants, a single photon, thin and
    /// one-cell grids) never produce NaN or negative counts; the raw-count
    /// rules keep constants exactly and the VST rules keep them uniform.
    #[test]
    fn degenerate_fields_stay_finite() {
        let rules = [
            Threshold::None,
            Threshold::Fixed { value: 3.0, soft: true },
            Threshold::Universal { soft: true },
            Threshold::BayesShrink,
        ];
        for &(w, h) in &[(64, 64), (128, 37), (33, 1), (1, 1), (5, 7)] {
            for wavelet in WAVELETS {
                for rule in rules {
                    let constant = Field2::from_vec(w, h, vec![7.0; w * h]);
                    let (out, report) = denoise_counts(&constant, wavelet, 5, rule);
                    assert!(out.data.iter().all(|v| v.is_finite() && *v >= 0.0));
                    assert!(report.thresholds.iter().all(|t| t.is_finite()));
                    let first = out.data[0];
                    assert!(out.data.iter().all(|&v| (v - first).abs() < 1e-3));
                    if !rule.uses_vst() || plan_levels(w, h, 5).is_empty() {
                        assert!((first - 7.0).abs() < 1e-3, "{rule:?} {first}");
                    }

                    let mut single = Field2::new(w, h);
                    single.set(w / 2, h / 2, 1.0);
                    let (out, _) = denoise_counts(&single, wavelet, 5, rule);
                    assert!(out.data.iter().all(|v| v.is_finite() && *v >= 0.0));
                }
            }
        }
    }

    /// Non-square, non-power-of-two grids denoise as well as square ones.
    #[test]
    fn thin_grid_denoises() {
        let (counts, truth) = poisson_field(128, 37, 23, |_, _| 20.0);
        for wavelet in WAVELETS {
            let rule = Threshold::Universal { soft: true };
            let levels = max_levels(128, 37, 5);
            let (out, report) = denoise_counts(&counts, wavelet, levels, rule);
            let (r0, r1) = (rmse(&counts.data, &truth), rmse(&out.data, &truth));
            assert!(r1 * 3.0 < r0, "{wavelet:?}: {r0} → {r1}");
            let drift = (report.mean_after - report.mean_before) / report.mean_before;
            assert!(drift.abs() < 0.01, "{wavelet:?}: drift {drift}");
        }
    }
}
