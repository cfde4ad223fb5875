//! Image-comparison metrics: score a rendered image against a reference.
//!
//! This module is a faithful port of the project's Python scorer (numpy),
//! including its edge cases. All arithmetic is done in `f64`; sums use
//! compensated (Neumaier) summation, so results agree with numpy's pairwise
//! summation to far better than `1e-9` relative.
//!
//! Definitions (`keep` = pixels not excluded by the mask, `L` = Rec.709
//! luminance, see [`luminance`]):
//!
//! * Non-finite channels (NaN, ±inf) of either image are replaced by `0.0`
//!   before anything else. [`Scores::nonfinite_pixels`] counts the pixels of
//!   the *image* (not the reference) with at least one non-finite channel,
//!   over **all** pixels, excluded ones included.
//! * `mi`, `mr`: mean luminance of the image / reference over kept pixels.
//! * `mean_lum_ratio = mi / mr`; `rel_rmse = sqrt(mean((Li - Lr)^2)) / mr`
//!   over kept pixels.
//! * `rgb_mean_ratio[c] = mean(img_c) / max(mean(ref_c), 1e-30)` over kept
//!   pixels (Python's `max`, so a negative reference mean gives `1e-30`).
//! * Blocks: the image is tiled into `block × block` tiles starting at the top
//!   left; partial tiles at the right and bottom edges are dropped. A tile's
//!   value is the sum of the luminance of its kept pixels divided by
//!   `block²` (excluded pixels count as `0`). A tile is *full* when its kept
//!   fraction is `> 0.999` — note that for `block >= 32` a tile with a single
//!   excluded pixel still counts as full, exactly as in the Python scorer.
//! * `block_rel_rmse = sqrt(mean((Bi - Br)^2)) / mr` over full tiles.
//! * `block_frac_off_10pct` = fraction of full tiles with
//!   `|Bi - Br| / maximum(Br, 1e-3 * mr) > 0.10` (numpy `maximum`: NaN
//!   propagates; `0/0 = NaN` is not off, `x/0 = inf` is off).
//!
//! Edge cases:
//!
//! * `mr == 0` → `mean_lum_ratio`, `rel_rmse`, `block_rel_rmse` are `None`.
//! * No kept pixel at all (everything masked, or an empty image): numpy would
//!   produce NaN ratios; this port returns `None` for `mean_lum_ratio` and
//!   `rel_rmse` instead. The plain `f64` fields keep numpy's NaN:
//!   `mean_lum_image`, `mean_lum_reference` and every `rgb_mean_ratio` entry
//!   are NaN. The block metrics are `None` (no tile can be full).
//! * No full tile (block larger than the image, or every tile partially
//!   masked) → `block_rel_rmse` and `block_frac_off_10pct` are `None`.
//! * `block == 0` is an error ([`MetricsError::BadBlock`]).

use std::fmt;

use exr::prelude::{read_all_flat_layers_from_file, FlatSamples};
use serde::{Deserialize, Deserializer, Serialize};
use std::path::Path;

/// Rec.709 luminance weights for linear R, G, B.
const LUM: [f64; 3] = [0.2126, 0.7152, 0.0722];
/// A full tile must have a kept fraction strictly above this.
const FULL_BLOCK_FRACTION: f64 = 0.999;
/// A tile is "off" when its relative error is strictly above this.
const OFF_THRESHOLD: f64 = 0.10;
/// Floor of the reference channel mean in `rgb_mean_ratio`.
const RGB_MEAN_FLOOR: f64 = 1e-30;
/// Floor of a tile's reference value, relative to `mr`, in the off test.
const BLOCK_FLOOR_REL: f64 = 1e-3;
/// Luminance above which a mask pixel excludes its pixel.
const MASK_THRESHOLD: f64 = 0.5;

/// The block size the Python scorer uses by default.
pub const DEFAULT_BLOCK: usize = 8;

/// A linear RGB image, row-major, `data.len() == width*height`.
///
/// Pixel `(x, y)` lives at `data[y * width + x]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels, row-major, top row first; length `width * height`.
    pub data: Vec<[f32; 3]>,
}

impl Image {
    /// A black image of `width × height` pixels.
    ///
    /// # Panics
    /// If `width * height` overflows `usize`.
    pub fn new(width: usize, height: usize) -> Self {
        let n = width
            .checked_mul(height)
            .expect("Image::new: width * height overflows usize");
        Image {
            width,
            height,
            data: vec![[0.0; 3]; n],
        }
    }

    /// The pixel at column `x`, row `y`.
    ///
    /// # Panics
    /// If `x >= width` or `y >= height`.
    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        self.data[self.index(x, y)]
    }

    /// Sets the pixel at column `x`, row `y` to `rgb`.
    ///
    /// # Panics
    /// If `x >= width` or `y >= height`.
    pub fn set(&mut self, x: usize, y: usize, rgb: [f32; 3]) {
        let i = self.index(x, y);
        self.data[i] = rgb;
    }

    fn index(&self, x: usize, y: usize) -> usize {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) out of bounds for a {}x{} image",
            self.width,
            self.height
        );
        y * self.width + x
    }

    /// Panics unless `data.len() == width * height`.
    fn check_len(&self, what: &str) {
        let ok = self
            .width
            .checked_mul(self.height)
            .is_some_and(|n| n == self.data.len());
        assert!(
            ok,
            "{what}: data.len() = {} does not match {}x{}",
            self.data.len(),
            self.width,
            self.height
        );
    }
}

/// Rec.709 luminance — the one place for these weights.
///
/// `0.2126 R + 0.7152 G + 0.0722 B`, computed in `f64`. Non-finite inputs
/// propagate (callers that need it sanitise first).
pub fn luminance(rgb: [f32; 3]) -> f64 {
    LUM[0] * f64::from(rgb[0]) + LUM[1] * f64::from(rgb[1]) + LUM[2] * f64::from(rgb[2])
}

/// The result of [`score`]; field names and order match the Python scorer's
/// JSON output.
///
/// Serialising with `serde_json` writes NaN as `null`; deserialising accepts
/// `null` for the plain `f64` fields and reads it back as NaN. Note that
/// `PartialEq` follows `f64`, so two `Scores` holding NaN never compare equal.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// `mi / mr`; `None` when `mr == 0` or no pixel is kept.
    pub mean_lum_ratio: Option<f64>,
    /// Per channel `mean(img_c) / max(mean(ref_c), 1e-30)` over kept pixels;
    /// NaN when no pixel is kept.
    #[serde(deserialize_with = "de_f64x3_or_nan")]
    pub rgb_mean_ratio: [f64; 3],
    /// `sqrt(mean((Li - Lr)^2)) / mr` over kept pixels; `None` when `mr == 0`
    /// or no pixel is kept.
    pub rel_rmse: Option<f64>,
    /// The block (tile) size used.
    pub block: usize,
    /// `sqrt(mean((Bi - Br)^2)) / mr` over full tiles; `None` when there is
    /// no full tile or `mr == 0`.
    pub block_rel_rmse: Option<f64>,
    /// Fraction of full tiles whose relative error exceeds 10 %; `None` when
    /// there is no full tile.
    pub block_frac_off_10pct: Option<f64>,
    /// Image pixels with at least one non-finite channel (all pixels, masked
    /// or not).
    pub nonfinite_pixels: usize,
    /// Number of kept (not excluded) pixels.
    pub pixels_scored: usize,
    /// `mi`: mean luminance of the image over kept pixels (NaN if none).
    #[serde(deserialize_with = "de_f64_or_nan")]
    pub mean_lum_image: f64,
    /// `mr`: mean luminance of the reference over kept pixels (NaN if none).
    #[serde(deserialize_with = "de_f64_or_nan")]
    pub mean_lum_reference: f64,
}

fn de_f64_or_nan<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

fn de_f64x3_or_nan<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    Ok(<[Option<f64>; 3]>::deserialize(d)?.map(|v| v.unwrap_or(f64::NAN)))
}

/// Why [`score`] refused its inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MetricsError {
    /// Image and reference differ in size; both given as `(width, height)`.
    SizeMismatch {
        /// `(width, height)` of the image.
        image: (usize, usize),
        /// `(width, height)` of the reference.
        reference: (usize, usize),
    },
    /// The exclusion mask does not have one entry per pixel.
    MaskSizeMismatch {
        /// `width * height` of the images.
        expected: usize,
        /// Length of the mask given.
        got: usize,
    },
    /// The block size is unusable (only `0` is).
    BadBlock(usize),
}

impl fmt::Display for MetricsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MetricsError::SizeMismatch { image, reference } => write!(
                f,
                "size mismatch: image is {}x{}, reference is {}x{}",
                image.0, image.1, reference.0, reference.1
            ),
            MetricsError::MaskSizeMismatch { expected, got } => {
                write!(f, "mask size mismatch: expected {expected} entries, got {got}")
            }
            MetricsError::BadBlock(b) => write!(f, "bad block size {b} (must be at least 1)"),
        }
    }
}

impl std::error::Error for MetricsError {}

/// Neumaier compensated sum.
#[derive(Clone, Copy, Default)]
struct Sum {
    s: f64,
    c: f64,
}

impl Sum {
    fn add(&mut self, v: f64) {
        let t = self.s + v;
        if self.s.abs() >= v.abs() {
            self.c += (self.s - t) + v;
        } else {
            self.c += (v - t) + self.s;
        }
        self.s = t;
    }

    fn value(self) -> f64 {
        self.s + self.c
    }
}

/// Per-tile accumulators.
#[derive(Clone, Copy, Default)]
struct BlockAcc {
    li: Sum,
    lr: Sum,
    kept: usize,
}

/// Replaces each non-finite channel by `0.0`.
fn sanitize(p: [f32; 3]) -> [f32; 3] {
    p.map(|v| if v.is_finite() { v } else { 0.0 })
}

/// Python's builtin `max(a, b)`: `b if b > a else a`.
fn py_max(a: f64, b: f64) -> f64 {
    if b > a {
        b
    } else {
        a
    }
}

/// numpy's `maximum(a, b)`: NaN if either is NaN, else the larger.
fn np_maximum(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b > a {
        b
    } else {
        a
    }
}

/// Score `image` against `reference`; `exclude[i] == true` leaves pixel i out.
///
/// `exclude`, when given, has one entry per pixel in the images' row-major
/// order (see [`mask_from_rgb`] for turning a mask image into one). `block`
/// is the tile size of the block metrics ([`DEFAULT_BLOCK`] in the Python
/// scorer). See the module docs for the exact definitions and edge cases.
///
/// # Errors
/// [`MetricsError::SizeMismatch`] if the sizes differ,
/// [`MetricsError::MaskSizeMismatch`] if `exclude` has the wrong length,
/// [`MetricsError::BadBlock`] if `block == 0` (checked in that order).
///
/// # Panics
/// If an image violates `data.len() == width * height`.
pub fn score(image: &Image, reference: &Image, exclude: Option<&[bool]>, block: usize) -> Result<Scores, MetricsError> {
    check_inputs(image, reference, exclude, block)?;
    let (sums, blocks) = accumulate(image, reference, exclude, block);
    let kept = sums.kept;

    // With no kept pixel these are 0/0 = NaN, as in numpy.
    let kept_f = kept as f64;
    let mi = sums.li.value() / kept_f;
    let mr = sums.lr.value() / kept_f;
    let rgb_mean_ratio: [f64; 3] = std::array::from_fn(|c| {
        (sums.img[c].value() / kept_f) / py_max(sums.reference[c].value() / kept_f, RGB_MEAN_FLOOR)
    });
    // numpy: `if mr` (NaN is truthy there; we choose None when nothing is kept).
    let mr_usable = kept > 0 && mr != 0.0;
    let mean_lum_ratio = mr_usable.then(|| mi / mr);
    let rel_rmse = mr_usable.then(|| (sums.d2.value() / kept_f).sqrt() / mr);
    let (block_rel_rmse, block_frac_off_10pct) = block_metrics(&blocks, block, mr, mr_usable);

    Ok(Scores {
        mean_lum_ratio,
        rgb_mean_ratio,
        rel_rmse,
        block,
        block_rel_rmse,
        block_frac_off_10pct,
        nonfinite_pixels: sums.nonfinite,
        pixels_scored: kept,
        mean_lum_image: mi,
        mean_lum_reference: mr,
    })
}

/// The errors of [`score`], in the order it documents.
fn check_inputs(image: &Image, reference: &Image, exclude: Option<&[bool]>, block: usize) -> Result<(), MetricsError> {
    image.check_len("image");
    reference.check_len("reference");
    if (image.width, image.height) != (reference.width, reference.height) {
        return Err(MetricsError::SizeMismatch {
            image: (image.width, image.height),
            reference: (reference.width, reference.height),
        });
    }
    let n = image.data.len();
    if let Some(m) = exclude {
        if m.len() != n {
            return Err(MetricsError::MaskSizeMismatch {
                expected: n,
                got: m.len(),
            });
        }
    }
    if block == 0 {
        return Err(MetricsError::BadBlock(block));
    }
    Ok(())
}

/// Whole-image accumulators over the kept pixels.
#[derive(Default)]
struct PixelSums {
    nonfinite: usize,
    kept: usize,
    li: Sum,
    lr: Sum,
    d2: Sum,
    img: [Sum; 3],
    reference: [Sum; 3],
}

/// One pass over the pixels: the whole-image sums and the per-tile sums (row-major tiles;
/// partial tiles at the right and bottom edges are dropped).
fn accumulate(image: &Image, reference: &Image, exclude: Option<&[bool]>, block: usize) -> (PixelSums, Vec<BlockAcc>) {
    let w = image.width;
    let (nbx, nby) = (w / block, image.height / block);
    let mut blocks = vec![BlockAcc::default(); nbx * nby];
    let mut sums = PixelSums::default();
    for (i, (&pi, &pr)) in image.data.iter().zip(&reference.data).enumerate() {
        if !pi.iter().all(|v| v.is_finite()) {
            sums.nonfinite += 1;
        }
        if exclude.is_some_and(|m| m[i]) {
            continue;
        }
        let (pi, pr) = (sanitize(pi), sanitize(pr));
        let (li, lr) = (luminance(pi), luminance(pr));
        sums.kept += 1;
        sums.li.add(li);
        sums.lr.add(lr);
        let d = li - lr;
        sums.d2.add(d * d);
        for c in 0..3 {
            sums.img[c].add(f64::from(pi[c]));
            sums.reference[c].add(f64::from(pr[c]));
        }
        let (bx, by) = ((i % w) / block, (i / w) / block);
        if bx < nbx && by < nby {
            let acc = &mut blocks[by * nbx + bx];
            acc.li.add(li);
            acc.lr.add(lr);
            acc.kept += 1;
        }
    }
    (sums, blocks)
}

/// `block_rel_rmse` and `block_frac_off_10pct` over the full tiles. `area` is exact: block
/// <= w, h here.
fn block_metrics(blocks: &[BlockAcc], block: usize, mr: f64, mr_usable: bool) -> (Option<f64>, Option<f64>) {
    let area = (block as f64) * (block as f64);
    let mut n_full = 0usize;
    let mut n_off = 0usize;
    let mut sum_db2 = Sum::default();
    for acc in blocks {
        if acc.kept as f64 / area > FULL_BLOCK_FRACTION {
            let bi = acc.li.value() / area;
            let br = acc.lr.value() / area;
            let db = bi - br;
            sum_db2.add(db * db);
            let off = db.abs() / np_maximum(br, BLOCK_FLOOR_REL * mr);
            if off > OFF_THRESHOLD {
                n_off += 1;
            }
            n_full += 1;
        }
    }
    let block_rel_rmse = (n_full > 0 && mr_usable).then(|| (sum_db2.value() / n_full as f64).sqrt() / mr);
    let block_frac_off_10pct = (n_full > 0).then(|| n_off as f64 / n_full as f64);
    (block_rel_rmse, block_frac_off_10pct)
}

/// Turns a mask image into an exclusion mask for [`score`]:
/// pixel `i` is excluded when `luminance(mask.data[i]) > 0.5`.
///
/// Like the Python `(mask_rgb @ LUM) > 0.5`, a NaN luminance is not `> 0.5`
/// and so keeps its pixel; `+inf` excludes it.
pub fn mask_from_rgb(mask: &Image) -> Vec<bool> {
    mask.data.iter().map(|&p| luminance(p) > MASK_THRESHOLD).collect()
}

/// Read the colour of an EXR's first part: `R,G,B` (or `<layer>.R`...), or `Y` as grey.
pub fn read_exr_rgb(path: &Path) -> Result<Image, photongrid::output::OutputError> {
    let err = |message: String| photongrid::output::OutputError::Exr {
        path: path.to_path_buf(),
        message,
    };
    let image = read_all_flat_layers_from_file(path).map_err(|e| err(e.to_string()))?;
    let layer = image.layer_data.first().ok_or_else(|| err("no layer".into()))?;
    let (w, h) = (layer.size.width(), layer.size.height());
    let names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
    let find = |c: &str| {
        names
            .iter()
            .position(|n| n == c)
            .or_else(|| names.iter().position(|n| n.ends_with(&format!(".{c}"))))
    };
    let values = |i: usize| -> Vec<f32> {
        match &layer.channel_data.list[i].sample_data {
            FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
            FlatSamples::F32(v) => v.clone(),
            FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
        }
    };
    let (r, g, b) = match (find("R"), find("G"), find("B"), find("Y")) {
        (Some(r), Some(g), Some(b), _) => (values(r), values(g), values(b)),
        (_, _, _, Some(y)) => {
            let y = values(y);
            (y.clone(), y.clone(), y)
        }
        _ => return Err(err(format!("no R,G,B or Y channels (has {})", names.join(", ")))),
    };
    let mut img = Image::new(w, h);
    for i in 0..w * h {
        img.data[i] = [r[i], g[i], b[i]];
    }
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filled(w: usize, h: usize, rgb: [f32; 3]) -> Image {
        Image {
            width: w,
            height: h,
            data: vec![rgb; w * h],
        }
    }

    fn from_fn(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Image {
        let mut img = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                img.set(x, y, f(x, y));
            }
        }
        img
    }

    fn mask_fn(w: usize, h: usize, f: impl Fn(usize, usize) -> bool) -> Vec<bool> {
        (0..w * h).map(|i| f(i % w, i / w)).collect()
    }

    #[track_caller]
    fn close(got: f64, want: f64, tol: f64) {
        assert!(
            (got - want).abs() <= tol * want.abs().max(1.0),
            "got {got:?}, want {want:?} (tol {tol})"
        );
    }

    #[track_caller]
    fn close_opt(got: Option<f64>, want: f64, tol: f64) {
        match got {
            Some(g) => close(g, want, tol),
            None => panic!("got None, want {want:?}"),
        }
    }

    /// Deterministic 64-bit LCG (Knuth's MMIX constants); mirrored in the
    /// Python cross-check script quoted in `matches_numpy_scorer`.
    struct Lcg(u64);

    impl Lcg {
        fn next(&mut self) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            self.0
        }

        fn unit(&mut self) -> f32 {
            (self.next() >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    fn random(w: usize, h: usize, seed: u64) -> Image {
        let mut rng = Lcg(seed);
        let data = (0..w * h)
            .map(|_| [rng.unit() + 0.01, rng.unit() + 0.01, rng.unit() + 0.01])
            .collect();
        Image {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn luminance_weights() {
        assert_eq!(luminance([1.0, 0.0, 0.0]), 0.2126);
        assert_eq!(luminance([0.0, 1.0, 0.0]), 0.7152);
        assert_eq!(luminance([0.0, 0.0, 1.0]), 0.0722);
        close(luminance([1.0, 1.0, 1.0]), 1.0, 1e-15);
        close(luminance([2.0, 0.5, 4.0]), 0.4252 + 0.3576 + 0.2888, 1e-15);
    }

    #[test]
    fn image_get_set_new() {
        let mut img = Image::new(3, 2);
        assert_eq!(img.data.len(), 6);
        assert_eq!(img.get(2, 1), [0.0; 3]);
        img.set(2, 1, [1.0, 2.0, 3.0]);
        img.set(0, 1, [4.0, 5.0, 6.0]);
        assert_eq!(img.get(2, 1), [1.0, 2.0, 3.0]);
        assert_eq!(img.data[5], [1.0, 2.0, 3.0]);
        assert_eq!(img.data[3], [4.0, 5.0, 6.0]);
    }

    #[test]
    #[should_panic(expected = "out of bounds")]
    fn image_get_x_out_of_bounds_panics() {
        // (3, 0) would alias (0, 1) with a naive index.
        Image::new(3, 2).get(3, 0);
    }

    #[test]
    #[should_panic(expected = "does not match")]
    fn inconsistent_image_panics() {
        let mut img = Image::new(4, 4);
        img.data.pop();
        let _ = score(&img, &img, None, 2);
    }

    #[test]
    fn identical_images() {
        let img = random(16, 16, 7);
        let s = score(&img, &img, None, 8).unwrap();
        assert_eq!(s.mean_lum_ratio, Some(1.0));
        assert_eq!(s.rgb_mean_ratio, [1.0; 3]);
        assert_eq!(s.rel_rmse, Some(0.0));
        assert_eq!(s.block, 8);
        assert_eq!(s.block_rel_rmse, Some(0.0));
        assert_eq!(s.block_frac_off_10pct, Some(0.0));
        assert_eq!(s.nonfinite_pixels, 0);
        assert_eq!(s.pixels_scored, 256);
        assert_eq!(s.mean_lum_image, s.mean_lum_reference);
        assert!(s.mean_lum_image > 0.0);
    }

    fn scaled(reference: &Image, k: f32) -> Image {
        Image {
            data: reference.data.iter().map(|p| p.map(|v| v * k)).collect(),
            ..reference.clone()
        }
    }

    #[test]
    fn uniformly_scaled_image() {
        // A constant-luminance reference: then rel_rmse == block_rel_rmse == k - 1.
        let reference = filled(24, 16, [0.25, 0.5, 0.75]);
        let s = score(&scaled(&reference, 1.1), &reference, None, 8).unwrap();
        close_opt(s.mean_lum_ratio, 1.1, 1e-6);
        for r in s.rgb_mean_ratio {
            close(r, 1.1, 1e-6);
        }
        close_opt(s.rel_rmse, 0.1, 1e-5);
        close_opt(s.block_rel_rmse, 0.1, 1e-5);
        close(s.mean_lum_reference, luminance([0.25, 0.5, 0.75]), 1e-12);
        assert_eq!(s.pixels_scored, 384);

        // 1.1 sits on the 10 % threshold; 1.2 and 1.05 are clear of it.
        let s = score(&scaled(&reference, 1.2), &reference, None, 8).unwrap();
        assert_eq!(s.block_frac_off_10pct, Some(1.0));
        close_opt(s.rel_rmse, 0.2, 1e-5);
        let s = score(&scaled(&reference, 1.05), &reference, None, 8).unwrap();
        assert_eq!(s.block_frac_off_10pct, Some(0.0));
        close_opt(s.block_rel_rmse, 0.05, 1e-5);
        // Too dark is off as well.
        let s = score(&scaled(&reference, 0.8), &reference, None, 8).unwrap();
        assert_eq!(s.block_frac_off_10pct, Some(1.0));
    }

    /// 16×8 gray images, block 8 → two tiles.
    /// Reference: every pixel 1.0. Image: left tile 1.0; right tile has its
    /// top 4 rows at 2.0 and its bottom 4 rows at 1.0.
    fn two_tile_case() -> (Image, Image) {
        let reference = filled(16, 8, [1.0; 3]);
        let image = from_fn(16, 8, |x, y| if x >= 8 && y < 4 { [2.0; 3] } else { [1.0; 3] });
        (image, reference)
    }

    #[test]
    fn hand_computed_two_tiles() {
        let (image, reference) = two_tile_case();
        let s = score(&image, &reference, None, 8).unwrap();
        // Gray v has luminance v (weights sum to 1).
        // mi = (96 * 1 + 32 * 2) / 128 = 160 / 128 = 1.25, mr = 1.
        close(s.mean_lum_image, 1.25, 1e-12);
        close(s.mean_lum_reference, 1.0, 1e-12);
        close_opt(s.mean_lum_ratio, 1.25, 1e-12);
        // Gray, so every channel ratio is the luminance ratio.
        for r in s.rgb_mean_ratio {
            close(r, 1.25, 1e-12);
        }
        // d = 1 on 32 pixels, 0 on 96: mean d² = 32/128 = 0.25 → rmse 0.5.
        close_opt(s.rel_rmse, 0.5, 1e-12);
        // Tiles: Bi = [1, (32*2 + 32*1)/64 = 1.5], Br = [1, 1], db = [0, 0.5]:
        // sqrt((0 + 0.25) / 2) = sqrt(0.125) = 0.353553…
        close_opt(s.block_rel_rmse, 0.125f64.sqrt(), 1e-12);
        // off = [0, 0.5 / 1] → one of two tiles off.
        assert_eq!(s.block_frac_off_10pct, Some(0.5));
        assert_eq!(s.nonfinite_pixels, 0);
        assert_eq!(s.pixels_scored, 128);
    }

    #[test]
    fn hand_computed_colour_weights() {
        // 16×8, block 8. Reference gray 0.5 (luminance 0.5).
        // Image: left tile [1, 0.5, 0.5] → luminance 0.5 + 0.2126 * 0.5 = 0.6063;
        // right tile equals the reference.
        let reference = filled(16, 8, [0.5; 3]);
        let image = from_fn(16, 8, |x, _| if x < 8 { [1.0, 0.5, 0.5] } else { [0.5; 3] });
        let s = score(&image, &reference, None, 8).unwrap();
        // mi = (0.6063 + 0.5) / 2 = 0.55315; ratio 1.1063.
        close(s.mean_lum_image, 0.55315, 1e-12);
        close_opt(s.mean_lum_ratio, 1.1063, 1e-12);
        // Red mean 0.75 vs 0.5; green and blue equal.
        close(s.rgb_mean_ratio[0], 1.5, 1e-12);
        close(s.rgb_mean_ratio[1], 1.0, 1e-12);
        close(s.rgb_mean_ratio[2], 1.0, 1e-12);
        // d = 0.1063 on half the pixels: rmse = 0.1063 / sqrt(2); / mr = 0.5.
        let want = 0.1063 / 2f64.sqrt() / 0.5;
        close_opt(s.rel_rmse, want, 1e-12);
        // Tiles are uniform, so the tile rmse is the same number.
        close_opt(s.block_rel_rmse, want, 1e-12);
        // off = [0.1063 / 0.5 = 0.2126, 0] → 0.5.
        assert_eq!(s.block_frac_off_10pct, Some(0.5));
    }

    #[test]
    fn mask_excluding_half() {
        // Left tile: image 1.5 vs reference 1.0. Right tile: image 100 (garbage)
        // vs 1.0, excluded by the mask.
        let reference = filled(16, 8, [1.0; 3]);
        let image = from_fn(16, 8, |x, _| if x < 8 { [1.5; 3] } else { [100.0; 3] });
        let mask = mask_fn(16, 8, |x, _| x >= 8);
        let s = score(&image, &reference, Some(&mask), 8).unwrap();
        assert_eq!(s.pixels_scored, 64);
        close(s.mean_lum_image, 1.5, 1e-12);
        close_opt(s.mean_lum_ratio, 1.5, 1e-12);
        for r in s.rgb_mean_ratio {
            close(r, 1.5, 1e-12);
        }
        close_opt(s.rel_rmse, 0.5, 1e-12);
        // Only the left tile is full: db = 0.5, off = 0.5.
        close_opt(s.block_rel_rmse, 0.5, 1e-12);
        assert_eq!(s.block_frac_off_10pct, Some(1.0));

        // Without the mask the garbage dominates.
        let s = score(&image, &reference, None, 8).unwrap();
        assert_eq!(s.pixels_scored, 128);
        close_opt(s.mean_lum_ratio, 50.75, 1e-12);
    }

    #[test]
    fn partially_kept_tile_is_not_full() {
        // Two-tile case; exclude one pixel (12, 3) of the right tile.
        let (image, reference) = two_tile_case();
        let mask = mask_fn(16, 8, |x, y| (x, y) == (12, 3));
        let s = score(&image, &reference, Some(&mask), 8).unwrap();
        assert_eq!(s.pixels_scored, 127);
        // Pixels: 31 at 2.0 and 96 at 1.0 → mi = (62 + 96) / 127, mr = 1.
        close_opt(s.mean_lum_ratio, 158.0 / 127.0, 1e-12);
        // d = 1 on 31 pixels → sqrt(31 / 127).
        close_opt(s.rel_rmse, (31.0f64 / 127.0).sqrt(), 1e-12);
        // The right tile is 63/64 kept → not full; only the identical left
        // tile is scored.
        assert_eq!(s.block_rel_rmse, Some(0.0));
        assert_eq!(s.block_frac_off_10pct, Some(0.0));

        // Masking a pixel in both tiles leaves no full tile.
        let mask = mask_fn(16, 8, |x, y| y == 0 && (x == 0 || x == 15));
        let s = score(&image, &reference, Some(&mask), 8).unwrap();
        assert_eq!(s.block_rel_rmse, None);
        assert_eq!(s.block_frac_off_10pct, None);
        assert!(s.rel_rmse.is_some());
    }

    #[test]
    fn full_means_kept_fraction_above_0_999() {
        // Block 32: one excluded pixel leaves 1023/1024 = 0.99902 > 0.999, so
        // the tile is still "full" and the excluded pixel counts as 0 in both
        // tile means (exactly the numpy behaviour).
        let reference = filled(32, 32, [1.0; 3]);
        let image = filled(32, 32, [2.0; 3]);
        let one = mask_fn(32, 32, |x, y| (x, y) == (5, 9));
        let s = score(&image, &reference, Some(&one), 32).unwrap();
        assert_eq!(s.pixels_scored, 1023);
        // Bi = 2 * 1023/1024, Br = 1023/1024, mr = 1 → db = 1023/1024.
        close_opt(s.block_rel_rmse, 1023.0 / 1024.0, 1e-12);
        // off = (1023/1024) / (1023/1024) = 1.
        assert_eq!(s.block_frac_off_10pct, Some(1.0));
        // Two excluded: 1022/1024 = 0.998 → not full.
        let two = mask_fn(32, 32, |x, y| (x, y) == (5, 9) || (x, y) == (6, 9));
        let s = score(&image, &reference, Some(&two), 32).unwrap();
        assert_eq!(s.block_rel_rmse, None);
        assert_eq!(s.block_frac_off_10pct, None);
    }

    #[test]
    fn nonfinite_pixels_counted_and_zeroed() {
        let reference = filled(16, 8, [1.0; 3]);
        let mut image = reference.clone();
        image.set(0, 0, [f32::NAN, 1.0, 1.0]); // → [0, 1, 1], lum 0.7874
        image.set(9, 2, [f32::INFINITY, f32::NEG_INFINITY, 1.0]); // → [0, 0, 1], lum 0.0722
        let mut reference_bad = reference.clone();
        reference_bad.set(5, 5, [f32::NAN; 3]); // → 0; not counted (image only)
        let s = score(&image, &reference_bad, None, 8).unwrap();
        assert_eq!(s.nonfinite_pixels, 2);
        assert_eq!(s.pixels_scored, 128);
        // mi = (126 untouched pixels * 1 + 0.7874 + 0.0722) / 128; the reference
        // loses pixel (5, 5): mr = 127 / 128.
        let mi = (126.0 + 0.7874 + 0.0722) / 128.0;
        let mr = 127.0 / 128.0;
        close(s.mean_lum_image, mi, 1e-12);
        close(s.mean_lum_reference, mr, 1e-12);
        close_opt(s.mean_lum_ratio, mi / mr, 1e-12);
        // Image R/G/B sums 126, 127, 128; the reference has 127 in each.
        close(s.rgb_mean_ratio[0], 126.0 / 127.0, 1e-12);
        close(s.rgb_mean_ratio[1], 1.0, 1e-12);
        close(s.rgb_mean_ratio[2], 128.0 / 127.0, 1e-12);
        // d: (0,0): 0.7874 - 1; (9,2): 0.0722 - 1; (5,5): 1 - 0.
        let d2 = (0.7874f64 - 1.0).powi(2) + (0.0722f64 - 1.0).powi(2) + 1.0;
        close_opt(s.rel_rmse, (d2 / 128.0).sqrt() / mr, 1e-12);
        // Value printed by the numpy scorer for this case.
        close_opt(s.block_rel_rmse, 0.013550682847812889, 1e-9);
        for v in [s.mean_lum_image, s.rel_rmse.unwrap(), s.block_rel_rmse.unwrap()] {
            assert!(v.is_finite());
        }

        // Non-finite pixels are counted even where excluded.
        let mask = mask_fn(16, 8, |x, y| (x, y) == (0, 0));
        let s = score(&image, &reference, Some(&mask), 8).unwrap();
        assert_eq!(s.nonfinite_pixels, 2);
        assert_eq!(s.pixels_scored, 127);
    }

    #[test]
    fn errors() {
        let a = Image::new(16, 8);
        let b = Image::new(8, 16);
        let e = score(&a, &b, None, 8).unwrap_err();
        assert_eq!(
            e,
            MetricsError::SizeMismatch {
                image: (16, 8),
                reference: (8, 16)
            }
        );
        assert!(e.to_string().contains("16x8"));
        let e = score(&a, &a, Some(&[false; 127]), 8).unwrap_err();
        assert_eq!(
            e,
            MetricsError::MaskSizeMismatch {
                expected: 128,
                got: 127
            }
        );
        let e = score(&a, &a, None, 0).unwrap_err();
        assert_eq!(e, MetricsError::BadBlock(0));
        let _: &dyn std::error::Error = &e;
        assert!(!e.to_string().is_empty());
    }

    #[test]
    fn edge_tiles_dropped() {
        // 20×8: tiles cover x < 16 only; the 4 right columns differ.
        let reference = filled(20, 8, [1.0; 3]);
        let image = from_fn(20, 8, |x, _| if x >= 16 { [3.0; 3] } else { [1.0; 3] });
        let s = score(&image, &reference, None, 8).unwrap();
        assert_eq!(s.block_rel_rmse, Some(0.0));
        assert_eq!(s.block_frac_off_10pct, Some(0.0));
        // Pixel metrics still see them: d = 2 on 32 of 160 pixels.
        close_opt(s.rel_rmse, (4.0f64 * 32.0 / 160.0).sqrt(), 1e-12);

        // 16×12: rows 8..12 are dropped.
        let reference = filled(16, 12, [1.0; 3]);
        let image = from_fn(16, 12, |_, y| if y >= 8 { [3.0; 3] } else { [1.0; 3] });
        let s = score(&image, &reference, None, 8).unwrap();
        assert_eq!(s.block_rel_rmse, Some(0.0));
        // …but block 4 reaches them: 4×3 tiles, the bottom row of 4 off by 2;
        // mr = 1 → sqrt(4 * 4 / 12).
        let s = score(&image, &reference, None, 4).unwrap();
        close_opt(s.block_rel_rmse, (4.0f64 * 4.0 / 12.0).sqrt(), 1e-12);
        close_opt(s.block_frac_off_10pct, 4.0 / 12.0, 1e-12);

        // Block larger than the image: no tiles at all.
        let s = score(&image, &reference, None, 32).unwrap();
        assert_eq!(s.block_rel_rmse, None);
        assert_eq!(s.block_frac_off_10pct, None);
        assert!(s.rel_rmse.is_some());
        assert_eq!(s.block, 32);
    }

    #[test]
    fn zero_reference() {
        let reference = Image::new(16, 8);
        let image = filled(16, 8, [1.0; 3]);
        let s = score(&image, &reference, None, 8).unwrap();
        assert_eq!(s.mean_lum_reference, 0.0);
        assert_eq!(s.mean_lum_ratio, None);
        assert_eq!(s.rel_rmse, None);
        assert_eq!(s.block_rel_rmse, None);
        // off = 1 / max(0, 0) = inf > 0.1.
        assert_eq!(s.block_frac_off_10pct, Some(1.0));
        // 1 / max(0, 1e-30).
        close(s.rgb_mean_ratio[0], 1e30, 1e-12);

        // Both zero: off = 0/0 = NaN, which is not > 0.1.
        let s = score(&reference, &reference, None, 8).unwrap();
        assert_eq!(s.block_frac_off_10pct, Some(0.0));
        assert_eq!(s.rgb_mean_ratio, [0.0; 3]);
        assert_eq!(s.mean_lum_ratio, None);

        // A negative reference channel mean is floored to 1e-30 (Python max).
        let reference = filled(16, 8, [-1.0, 1.0, 1.0]);
        let s = score(&image, &reference, None, 8).unwrap();
        close(s.rgb_mean_ratio[0], 1e30, 1e-12);
        close(s.rgb_mean_ratio[1], 1.0, 1e-12);
    }

    #[test]
    fn nothing_kept() {
        let mut image = filled(16, 8, [1.0; 3]);
        image.set(3, 3, [f32::NAN; 3]);
        let reference = filled(16, 8, [2.0; 3]);
        let mask = vec![true; 128];
        let s = score(&image, &reference, Some(&mask), 8).unwrap();
        assert_eq!(s.pixels_scored, 0);
        assert_eq!(s.nonfinite_pixels, 1);
        assert_eq!(s.mean_lum_ratio, None);
        assert_eq!(s.rel_rmse, None);
        assert_eq!(s.block_rel_rmse, None);
        assert_eq!(s.block_frac_off_10pct, None);
        assert!(s.mean_lum_image.is_nan() && s.mean_lum_reference.is_nan());
        assert!(s.rgb_mean_ratio.iter().all(|v| v.is_nan()));

        // An empty image behaves the same.
        let e = Image::new(0, 0);
        let s = score(&e, &e, None, 8).unwrap();
        assert_eq!(s.pixels_scored, 0);
        assert_eq!(s.mean_lum_ratio, None);
        assert_eq!(s.block_frac_off_10pct, None);
    }

    #[test]
    fn mask_from_rgb_thresholds_luminance() {
        let mut m = Image::new(6, 1);
        m.set(0, 0, [1.0; 3]); // 1.0 → excluded
        m.set(1, 0, [0.5; 3]); // exactly 0.5 → kept
        m.set(2, 0, [1.0, 0.0, 0.0]); // 0.2126 → kept
        m.set(3, 0, [0.0, 1.0, 0.0]); // 0.7152 → excluded
        m.set(4, 0, [f32::NAN, 0.0, 0.0]); // NaN → kept
        m.set(5, 0, [0.0, 0.0, f32::INFINITY]); // inf → excluded
        assert_eq!(mask_from_rgb(&m), vec![true, false, false, true, false, true]);

        // And it plugs into score.
        let reference = filled(6, 1, [1.0; 3]);
        let s = score(&reference, &reference, Some(&mask_from_rgb(&m)), 1).unwrap();
        assert_eq!(s.pixels_scored, 3);
    }

    #[test]
    fn serde_roundtrip() {
        let (image, reference) = two_tile_case();
        let s = score(&image, &reference, None, 8).unwrap();
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.starts_with("{\"mean_lum_ratio\":"), "{json}");
        assert!(json.contains("\"block_frac_off_10pct\":0.5"), "{json}");
        let back: Scores = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);

        // NaN (nothing kept) is written as null and read back as NaN / None.
        let mask = vec![true; 128];
        let s = score(&image, &reference, Some(&mask), 8).unwrap();
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains("\"mean_lum_image\":null"), "{json}");
        let back: Scores = serde_json::from_str(&json).unwrap();
        assert!(back.mean_lum_image.is_nan() && back.mean_lum_reference.is_nan());
        assert!(back.rgb_mean_ratio.iter().all(|v| v.is_nan()));
        assert_eq!(back.mean_lum_ratio, None);
        assert_eq!(back.pixels_scored, 0);
    }

    /// Expected values below were printed by the Python scorer from the task
    /// spec (numpy 2.4.6) on this data, generated there by:
    ///
    /// ```python
    /// state = 0x5EED   # same LCG: state = state * 6364136223846793005 + 1442695040888963407 mod 2**64
    /// for y in range(16):
    ///     for x in range(24):
    ///         for c in range(3):
    ///             r = nxt() >> 41
    ///             f = 700 + 100 * ((x // 8 + y // 8) % 4) + (nxt() >> 57)
    ///             i = r * f // 1000
    ///             ref[y, x, c] = r / 2.0**21
    ///             img[y, x, c] = i / 2.0**21
    /// img[2, 3, 1] = nan; img[10, 20, 0] = inf; img[14, 9, 2] = -inf; ref[5, 5, 2] = nan
    /// mask[y, x] = (x >= 18 and y < 5) or (x == 3 and y == 12) or (8 <= x < 16 and y >= 8)
    /// ```
    /// (all values are exact in f32).
    #[test]
    fn matches_numpy_scorer() {
        let (w, h) = (24usize, 16usize);
        let mut rng = Lcg(0x5EED);
        let mut image = Image::new(w, h);
        let mut reference = Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    let r = rng.next() >> 41;
                    let f = 700 + 100 * ((x / 8 + y / 8) % 4) as u64 + (rng.next() >> 57);
                    let i = r * f / 1000;
                    let scale = (1u64 << 21) as f64;
                    reference.data[y * w + x][c] = (r as f64 / scale) as f32;
                    image.data[y * w + x][c] = (i as f64 / scale) as f32;
                }
            }
        }
        // Python printed img[0,0] and ref[0,0]: the generators agree.
        assert_eq!(
            image.get(0, 0).map(f64::from),
            [3.016850471496582, 1.2780776023864746, 0.19401264190673828]
        );
        assert_eq!(
            reference.get(0, 0).map(f64::from),
            [3.7429909706115723, 1.6995716094970703, 0.2755866050720215]
        );
        image.data[2 * w + 3][1] = f32::NAN;
        image.data[10 * w + 20][0] = f32::INFINITY;
        image.data[14 * w + 9][2] = f32::NEG_INFINITY;
        reference.data[5 * w + 5][2] = f32::NAN;
        let mask = mask_fn(w, h, |x, y| {
            (x >= 18 && y < 5) || (x == 3 && y == 12) || ((8..16).contains(&x) && y >= 8)
        });

        struct Want {
            ratio: f64,
            rgb: [f64; 3],
            rel_rmse: f64,
            block: usize,
            block_rel_rmse: f64,
            frac_off: f64,
            scored: usize,
            mi: f64,
            mr: f64,
        }
        let unmasked = |block, block_rel_rmse, frac_off| Want {
            ratio: 0.9057859168512107,
            rgb: [0.9083074242931705, 0.9040116806410157, 0.9159116196416713],
            rel_rmse: 0.15202653898891003,
            block,
            block_rel_rmse,
            frac_off,
            scored: 384,
            mi: 1.785988709738602,
            mr: 1.9717558823913335,
        };
        let masked = |block, block_rel_rmse, frac_off| Want {
            ratio: 0.8868869178140406,
            rgb: [0.8897162515551373, 0.8844740406965174, 0.9021150327156854],
            rel_rmse: 0.1737906023932543,
            block,
            block_rel_rmse,
            frac_off,
            scored: 289,
            mi: 1.7340078165209416,
            mr: 1.955162244127861,
        };
        let cases = [
            (None, unmasked(8, 0.13740125423644114, 0.5)),
            (Some(&mask[..]), masked(8, 0.17311536610275538, 0.6666666666666666)),
            (Some(&mask[..]), masked(5, 0.20953182508805754, 1.0)),
            (None, unmasked(5, 0.14430404389914053, 0.5833333333333334)),
        ];
        for (m, want) in cases {
            let s = score(&image, &reference, m, want.block).unwrap();
            let tol = 1e-9;
            close_opt(s.mean_lum_ratio, want.ratio, tol);
            for c in 0..3 {
                close(s.rgb_mean_ratio[c], want.rgb[c], tol);
            }
            close_opt(s.rel_rmse, want.rel_rmse, tol);
            assert_eq!(s.block, want.block);
            close_opt(s.block_rel_rmse, want.block_rel_rmse, tol);
            close_opt(s.block_frac_off_10pct, want.frac_off, 1e-12);
            assert_eq!(s.nonfinite_pixels, 3);
            assert_eq!(s.pixels_scored, want.scored);
            close(s.mean_lum_image, want.mi, tol);
            close(s.mean_lum_reference, want.mr, tol);
        }
    }
}
