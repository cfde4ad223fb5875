//! Random numbers and the sampling routines shared by lights, materials and cameras.
//!
//! Every random stream is keyed by (seed, purpose, index) so that an image depends on the seed
//! only, never on the number of threads or the order in which rayon runs the work.

use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// A small, fast generator (PCG-XSH-RR 64/32) with keyed construction.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
    inc: u64,
}

/// SplitMix64 finaliser: a good hash for keying streams.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// A stream for `(seed, stream, index)`: e.g. (user seed, PHOTONS, photon index).
    pub fn keyed(seed: u64, stream: u64, index: u64) -> Self {
        let a = mix64(seed ^ mix64(stream.wrapping_mul(0x2545_F491_4F6C_DD1D)));
        let b = mix64(a ^ index);
        let mut r = Rng {
            state: 0,
            inc: (mix64(b ^ 0xDA3E_39CB_94B9_5BDB) << 1) | 1,
        };
        r.state = b.wrapping_add(r.inc);
        r.next_u32();
        r
    }

    /// Next 32 random bits.
    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// Two uniforms in [0, 1).
    #[inline]
    pub fn uniform2(&mut self) -> Vec2 {
        Vec2::new(self.uniform(), self.uniform())
    }
}

/// Uniform numbers in [0, 1), one or two at a time: what emitting a photon draws from, so that
/// the first numbers of a photon path can come from a low-discrepancy point ([`Stratified`])
/// and the rest from its generator.
pub trait Sampler {
    /// One number.
    fn uniform(&mut self) -> f32;
    /// Two numbers meant as one 2D sample (a direction, a point on a disc).
    fn uniform2(&mut self) -> Vec2;
}

impl Sampler for Rng {
    #[inline]
    fn uniform(&mut self) -> f32 {
        Rng::uniform(self)
    }

    #[inline]
    fn uniform2(&mut self) -> Vec2 {
        Rng::uniform2(self)
    }
}

/// Dimensions of the Sobol points that start photon paths.
const SOBOL_DIMS: usize = 6;

/// Joe and Kuo's direction numbers (new-joe-kuo-6.21201) for the Sobol sequence's dimensions
/// 2 to [`SOBOL_DIMS`]: degree s of the primitive polynomial, its inner coefficients a, initial
/// m₁…mₛ. Dimension 1 is van der Corput's.
const JOE_KUO: [(usize, u32, [u32; 4]); SOBOL_DIMS - 1] = [
    (1, 0, [1, 0, 0, 0]),
    (2, 1, [1, 3, 0, 0]),
    (3, 1, [1, 3, 1, 0]),
    (3, 2, [1, 1, 1, 0]),
    (4, 1, [1, 1, 3, 3]),
];

/// The generator matrices, one 32-bit direction number per bit of the index and dimension.
const SOBOL: [[u32; 32]; SOBOL_DIMS] = sobol_matrices();

const fn sobol_matrices() -> [[u32; 32]; SOBOL_DIMS] {
    let mut v = [[0u32; 32]; SOBOL_DIMS];
    let mut k = 0;
    while k < 32 {
        v[0][k] = 1 << (31 - k);
        k += 1;
    }
    let mut d = 1;
    while d < SOBOL_DIMS {
        let (s, a, m) = JOE_KUO[d - 1];
        let mut k = 0;
        while k < 32 {
            v[d][k] = if k < s {
                m[k] << (31 - k)
            } else {
                let mut x = v[d][k - s] ^ (v[d][k - s] >> s);
                let mut j = 1;
                while j < s {
                    if (a >> (s - 1 - j)) & 1 == 1 {
                        x ^= v[d][k - j];
                    }
                    j += 1;
                }
                x
            };
            k += 1;
        }
        d += 1;
    }
    v
}

/// The Owen scrambles of one pass's [`Stratified`] points, one per dimension, from the pass's
/// seed and stream.
#[derive(Clone, Copy, Debug)]
pub struct Scrambles([u32; SOBOL_DIMS]);

impl Scrambles {
    /// The scrambles of `(seed, stream)`.
    pub fn new(seed: u64, stream: u64) -> Self {
        let key = mix64(seed ^ mix64(stream ^ 0x534F_424F_4C00_0000));
        Scrambles(std::array::from_fn(|d| mix64(key ^ d as u64) as u32))
    }
}

/// The Sobol sequence's points in Gray-code order, from position `i` on: point i is the
/// sequence's point i ⊕ (i >> 1), so each step flips one direction number per dimension
/// instead of recomputing every bit. Every run of 2^m positions from a multiple of 2^m holds
/// the same points as in the natural order, so a pass's photons are as stratified.
#[derive(Clone, Debug)]
pub struct SobolWalk {
    position: u32,
    point: [u32; SOBOL_DIMS],
}

impl SobolWalk {
    /// The walk from position `position`.
    pub fn starting_at(position: u32) -> Self {
        SobolWalk {
            position,
            point: sobol_point(position ^ (position >> 1)),
        }
    }

    /// The point at the current position (unscrambled), then a step to the next position.
    /// Positions wrap at 2³² (the sequence then starts again).
    #[inline]
    pub fn next_point(&mut self) -> SobolPoint {
        let here = SobolPoint(self.point);
        // Position i + 1's Gray code differs from i's in bit (trailing ones of i).
        let k = (!self.position).trailing_zeros() as usize;
        self.position = self.position.wrapping_add(1);
        if k < 32 {
            for (x, v) in self.point.iter_mut().zip(&SOBOL) {
                *x ^= v[k];
            }
        } else {
            self.point = [0; SOBOL_DIMS];
        }
        here
    }
}

/// One unscrambled point of a [`SobolWalk`], as 32-bit fractions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SobolPoint([u32; SOBOL_DIMS]);

/// A photon path's first numbers from one Sobol point, Owen-scrambled (each dimension when it
/// is asked for), then from the path's generator. Two-number requests take the dimension pairs
/// (1, 2) and (4, 5), whose first pair is a (0, 2)-sequence, single ones dimensions 3 and 6:
/// emitting a light's photons at stratified directions and positions spreads them far more
/// evenly than independent draws, and where they reach a surface through smooth glass or
/// mirrors they land as evenly, which is what a density estimate's noise comes from.
pub struct Stratified<'a> {
    point: SobolPoint,
    scrambles: &'a Scrambles,
    next1: usize,
    next2: usize,
    rng: &'a mut Rng,
}

/// The dimensions [`Stratified`] hands out as pairs, best first.
const PAIRS: [(usize, usize); 2] = [(0, 1), (3, 4)];
/// The dimensions [`Stratified`] hands out one at a time: the first is even with either
/// coordinate of the first pair (t ≤ 1), which a light's or a target's choice needs.
const SINGLES: [usize; 2] = [2, 5];

impl<'a> Stratified<'a> {
    /// `point` scrambled by `scrambles`, then `rng`.
    pub fn new(point: SobolPoint, scrambles: &'a Scrambles, rng: &'a mut Rng) -> Self {
        Stratified {
            point,
            scrambles,
            next1: 0,
            next2: 0,
            rng,
        }
    }

    /// Dimension `d`, scrambled.
    #[inline]
    fn dimension(&self, d: usize) -> f32 {
        unit(owen_scramble(self.point.0[d], self.scrambles.0[d]))
    }
}

/// A 32-bit fixed-point fraction as a uniform in [0, 1).
fn unit(v: u32) -> f32 {
    (v >> 8) as f32 * (1.0 / 16_777_216.0)
}

impl Sampler for Stratified<'_> {
    fn uniform(&mut self) -> f32 {
        match SINGLES.get(self.next1) {
            Some(&d) => {
                self.next1 += 1;
                self.dimension(d)
            }
            None => self.rng.uniform(),
        }
    }

    fn uniform2(&mut self) -> Vec2 {
        match PAIRS.get(self.next2) {
            Some(&(a, b)) => {
                self.next2 += 1;
                Vec2::new(self.dimension(a), self.dimension(b))
            }
            None => self.rng.uniform2(),
        }
    }
}

/// The seed of progressive pass `pass` (0-based): pass 0 keeps `seed`, so a one-pass render is
/// the plain render; later passes get unrelated streams for photons and camera paths (the pixels' sample
/// positions continue one sequence across passes: [`pixel_sample`]).
pub fn pass_seed(seed: u64, pass: u32) -> u64 {
    if pass == 0 {
        seed
    } else {
        mix64(seed ^ mix64(0x5050_4153_5300_0000 ^ pass as u64))
    }
}

/// Stream keys, one per purpose.
pub mod stream {
    /// Photon paths.
    pub const PHOTONS: u64 = 1;
    /// Camera samples.
    pub const CAMERA: u64 = 2;
    /// Photon paths of the caustic pass.
    pub const CAUSTIC_PHOTONS: u64 = 4;
    /// Per-pixel scrambling of the camera samples' positions.
    pub const PIXEL: u64 = 3;
    /// Per-pixel scrambling of the emission-only rays at emitter edges.
    pub const EDGE_RAYS: u64 = 5;
    /// Scrambling of the final-gather directions: per tile for a pixel's first samples, per
    /// pixel after (`render::GatherPoints`).
    pub const GATHER: u64 = 6;
    /// Per-tile scrambling of the points final-gather rays aimed at bright planes pick.
    pub const AIMED: u64 = 7;
    /// Camera samples of spare sweeps (beyond a pass's samples per pixel: `render::Spare`).
    pub const SPARE_CAMERA: u64 = 8;
}

/// Point `index` in [0,1)² of a pixel's sequence (film positions, gather directions): the first
/// two dimensions of the Sobol sequence, Owen-scrambled by the pixel's `seed` (Burley 2020,
/// "Practical Hash-based Owen Scrambling"). Every power-of-two run of samples starting at 0 is a
/// (0, m, 2)-net, so a pixel's samples stay stratified across progressive passes (pass `p`
/// continues at the index where pass `p − 1` stopped) and an edge in any direction is
/// anti-aliased far better than by independent jitters. Indices wrap at 2³² (the sequence then
/// starts again).
pub fn owen_sobol(index: u32, seed: u64) -> Vec2 {
    let x = owen_scramble(index.reverse_bits(), seed as u32);
    let y = owen_scramble(sobol_dimension(index, 1), (seed >> 32) as u32);
    Vec2::new(unit(x), unit(y))
}

/// The scramble of one pixel's sequence of positions for `purpose` (a [`stream`] key): fixed
/// by the render's seed, so every pass continues the same sequence.
pub fn pixel_scramble(seed: u64, purpose: u64, pixel: u64) -> u64 {
    mix64(seed ^ mix64(purpose ^ pixel << 8))
}

/// The Morton index of (x, y) (bits interleaved, x's lowest first), each below 2^16.
pub fn morton2(x: u32, y: u32) -> u32 {
    fn spread(v: u32) -> u32 {
        let v = v & 0xffff;
        let v = (v | v << 8) & 0x00ff_00ff;
        let v = (v | v << 4) & 0x0f0f_0f0f;
        let v = (v | v << 2) & 0x3333_3333;
        (v | v << 1) & 0x5555_5555
    }
    spread(x) | spread(y) << 1
}

/// Dimension `d` of point `index` of the (unscrambled) Sobol sequence, as a 32-bit fraction.
fn sobol_dimension(mut index: u32, d: usize) -> u32 {
    let (mut x, mut k) = (0, 0);
    while index != 0 {
        if index & 1 == 1 {
            x ^= SOBOL[d][k];
        }
        index >>= 1;
        k += 1;
    }
    x
}

/// Point `index` of the Sobol sequence, every dimension.
fn sobol_point(index: u32) -> [u32; SOBOL_DIMS] {
    std::array::from_fn(|d| sobol_dimension(index, d))
}

/// Nested uniform (Owen) scrambling of the bits of `x`: each bit is flipped by a hash of `seed`
/// and the bits above it (the Laine–Karras permutation on the reversed bits, with Burley's
/// constants).
fn owen_scramble(x: u32, seed: u32) -> u32 {
    let mut v = x.reverse_bits().wrapping_add(seed);
    for k in [0x6c50_b47c_u32, 0xb82f_1e52, 0xc7af_e638, 0x8d22_f6e6] {
        v ^= v.wrapping_mul(k);
    }
    v.reverse_bits()
}

/// An orthonormal basis (t, b, n) around a unit normal (Duff et al. 2017).
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Express a local direction (z = normal) in world space.
pub fn to_world(local: Vec3, n: Vec3) -> Vec3 {
    let (t, b) = basis(n);
    t * local.x + b * local.y + n * local.z
}

/// Cosine-weighted hemisphere direction around `n` (pdf cosθ/π).
pub fn cosine_hemisphere(u: Vec2, n: Vec3) -> Vec3 {
    let d = concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    to_world(Vec3::new(d.x, d.y, z), n)
}

/// Uniform point on the unit disk (Shirley–Chiu concentric map).
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    // θ = φ in the wedges about ±x, π/2 − φ about ±y, with |φ| ≤ π/4 either way.
    if o.x.abs() > o.y.abs() {
        let (sin, cos) = sin_cos_quarter(PI / 4.0 * (o.y / o.x));
        o.x * Vec2::new(cos, sin)
    } else {
        let (sin, cos) = sin_cos_quarter(PI / 4.0 * (o.x / o.y));
        o.y * Vec2::new(sin, cos)
    }
}

/// `(sin φ, cos φ)` for `|φ| ≤ π/4`, by the minimax polynomials of Cephes' `sinf`/`cosf` on that
/// range (within 10⁻⁷ of the exact values): the general `sincosf` reduces an arbitrary argument
/// first, and every diffuse bounce of the photon pass samples one direction.
#[inline]
fn sin_cos_quarter(phi: f32) -> (f32, f32) {
    let z = phi * phi;
    let sin = ((-1.951_529_6e-4 * z + 8.332_161e-3) * z - 1.666_665_5e-1) * z * phi + phi;
    let cos = ((2.443_315_7e-5 * z - 1.388_731_6e-3) * z + 4.166_664_6e-2) * z * z - 0.5 * z + 1.0;
    (sin, cos)
}

/// Uniform direction on the unit sphere.
pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Direction with cosθ uniform in [cos_max, 1] around `axis` (uniform in solid angle).
pub fn uniform_cone(u: Vec2, cos_max: f32, axis: Vec3) -> Vec3 {
    let cos_t = 1.0 - u.x * (1.0 - cos_max);
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    to_world(Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t), axis)
}

/// Uniform barycentrics (b1, b2) on a triangle (square-root parameterisation).
pub fn uniform_triangle(u: Vec2) -> (f32, f32) {
    let s = u.x.sqrt();
    (1.0 - s, u.y * s)
}

/// A discrete distribution in proportion to non-negative weights: lights by power, emissive
/// triangles by power, specular targets by solid angle.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Distribution {
    /// Inclusive running sums of the weights.
    cdf: Vec<f32>,
}

impl Distribution {
    /// The distribution of `weights`.
    pub fn new(weights: impl IntoIterator<Item = f32>) -> Self {
        let mut acc = 0.0;
        let cdf = weights
            .into_iter()
            .map(|w| {
                acc += w;
                acc
            })
            .collect();
        Distribution { cdf }
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.cdf.len()
    }

    /// True if there are no entries.
    pub fn is_empty(&self) -> bool {
        self.cdf.is_empty()
    }

    /// Sum of the weights.
    pub fn total(&self) -> f32 {
        self.cdf.last().copied().unwrap_or(0.0)
    }

    /// Weight of entry `i`.
    pub fn weight(&self, i: usize) -> f32 {
        self.cdf[i] - if i == 0 { 0.0 } else { self.cdf[i - 1] }
    }

    /// The index of the first running sum greater than `u·total`, for `u` in [0, 1). Empty:
    /// index 0.
    pub fn sample(&self, u: f32) -> usize {
        let x = u * self.total();
        self.cdf
            .partition_point(|&c| c <= x)
            .min(self.cdf.len().saturating_sub(1))
    }

    /// Probability of entry `i`, given its weight (`weight / total`: passing the weight the
    /// caller holds avoids the rounding of a difference of running sums).
    pub fn pmf_of(&self, weight: f32) -> f32 {
        weight / self.total()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distribution_samples_in_proportion() {
        let d = Distribution::new([1.0, 0.0, 3.0]);
        assert_eq!((d.len(), d.total()), (3, 4.0));
        assert_eq!(d.sample(0.0), 0);
        assert_eq!(d.sample(0.2499), 0);
        assert_eq!(d.sample(0.25), 2, "a zero weight is never chosen");
        assert_eq!(d.sample(0.9999), 2);
        assert_eq!(d.weight(2), 3.0);
        assert_eq!(d.pmf_of(d.weight(0)), 0.25);
        assert_eq!(Distribution::default().sample(0.5), 0);
    }

    #[test]
    fn rng_is_keyed_and_uniform() {
        let mut a = Rng::keyed(1, 2, 3);
        let mut b = Rng::keyed(1, 2, 3);
        let mut c = Rng::keyed(1, 2, 4);
        assert_eq!(a.next_u32(), b.next_u32());
        assert_ne!(a.next_u32(), c.next_u32());
        let n = 100_000;
        let mean: f64 = (0..n).map(|_| a.uniform() as f64).sum::<f64>() / n as f64;
        assert!((mean - 0.5).abs() < 0.005, "{mean}");
    }

    #[test]
    fn basis_is_orthonormal() {
        let mut r = Rng::keyed(0, 0, 0);
        for _ in 0..1000 {
            let n = uniform_sphere(r.uniform2());
            let (t, b) = basis(n);
            assert!(t.dot(b).abs() < 1e-5 && t.dot(n).abs() < 1e-5 && b.dot(n).abs() < 1e-5);
            assert!((t.cross(b) - n).length() < 1e-4);
        }
    }

    #[test]
    fn sine_and_cosine_on_a_quarter_match_the_library() {
        let n = 100_000;
        let worst = (0..=n)
            .map(|i| {
                let phi = (i as f32 / n as f32 * 2.0 - 1.0) * PI / 4.0;
                let (s, c) = sin_cos_quarter(phi);
                let (es, ec) = (phi as f64).sin_cos();
                ((s as f64 - es).abs()).max((c as f64 - ec).abs())
            })
            .fold(0.0, f64::max);
        assert!(worst < 1e-7, "{worst:e}");
    }

    #[test]
    fn cosine_hemisphere_mean_cos() {
        // E[cosθ] under the cosθ/π pdf is 2/3.
        let mut r = Rng::keyed(0, 0, 1);
        let n = Vec3::new(0.3, 0.4, 0.866).normalize();
        let k = 200_000;
        let m: f64 = (0..k)
            .map(|_| cosine_hemisphere(r.uniform2(), n).dot(n) as f64)
            .sum::<f64>()
            / k as f64;
        assert!((m - 2.0 / 3.0).abs() < 0.003, "{m}");
    }

    /// Indices of the cells of an `nx`×`ny` grid holding samples `from..to` of one pixel.
    fn cells(from: u32, to: u32, seed: u64, nx: u32, ny: u32) -> Vec<u32> {
        let mut c: Vec<u32> = (from..to)
            .map(|i| {
                let p = owen_sobol(i, seed);
                (p.y * ny as f32) as u32 * nx + (p.x * nx as f32) as u32
            })
            .collect();
        c.sort();
        c
    }

    #[test]
    fn pixel_samples_are_a_net_in_every_power_of_two_prefix() {
        for seed in [0, 1, 0xdead_beef_1234_5678] {
            for m in 0..=8u32 {
                let n = 1u32 << m;
                // Every elementary interval of area 1/n (2^a columns × 2^(m−a) rows) holds one.
                for a in 0..=m {
                    let (nx, ny) = (1 << a, 1 << (m - a));
                    assert_eq!(
                        cells(0, n, seed, nx, ny),
                        (0..n).collect::<Vec<_>>(),
                        "seed {seed} m {m} a {a}"
                    );
                }
            }
        }
    }

    /// The first `n` points of the walk from 0, scrambled by `s`.
    fn scrambled_points(n: u32, s: &Scrambles) -> Vec<[u32; SOBOL_DIMS]> {
        let mut walk = SobolWalk::starting_at(0);
        (0..n)
            .map(|_| {
                let p = walk.next_point();
                std::array::from_fn(|d| owen_scramble(p.0[d], s.0[d]))
            })
            .collect()
    }

    /// The smallest t for which the first 2^m photon emission points, projected on dimensions
    /// `a` and `b`, are a (t, m, 2)-net: every elementary box of area 2^(t−m) holds 2^t.
    fn net_t(a: usize, b: usize, m: u32, scrambles: &Scrambles) -> u32 {
        let points = scrambled_points(1 << m, scrambles);
        let top = |v: u32, bits: u32| if bits == 0 { 0 } else { (v >> (32 - bits)) as usize };
        (0..=m)
            .find(|&t| {
                (0..=m - t).all(|i| {
                    let j = m - t - i;
                    let mut count = vec![0u32; 1 << (m - t)];
                    for p in &points {
                        count[top(p[a], i) << j | top(p[b], j)] += 1;
                    }
                    count.iter().all(|&c| c == 1 << t)
                })
            })
            .unwrap()
    }

    #[test]
    fn photon_emission_points_are_nets_in_the_pairs_they_are_used_as() {
        for seed in [0, 1, 0xdead_beef] {
            let s = Scrambles::new(seed, stream::CAUSTIC_PHOTONS);
            for m in 0..=10 {
                // Each dimension alone: one point per interval of 2^−m.
                let points = scrambled_points(1 << m, &s);
                for d in 0..SOBOL_DIMS {
                    let mut strata: Vec<u64> = points.iter().map(|p| p[d] as u64 >> (32 - m)).collect();
                    strata.sort();
                    assert_eq!(strata, (0..1u64 << m).collect::<Vec<_>>(), "seed {seed} m {m} dim {d}");
                }
                // The first pair (a direction, a point on a disc) is a (0, 2)-sequence; a
                // choice (the first single) with either coordinate of it is nearly as even.
                assert_eq!(net_t(PAIRS[0].0, PAIRS[0].1, m, &s), 0, "seed {seed} m {m}");
                for d in [PAIRS[0].0, PAIRS[0].1] {
                    assert!(net_t(SINGLES[0], d, m, &s) <= 1, "seed {seed} m {m} dim {d}");
                }
                // The second pair (a spot's retry, an emitter's direction) is a weaker net: 2^t
                // points per box of area 2^(t−m), where independent points have t near m.
                assert!(net_t(PAIRS[1].0, PAIRS[1].1, m, &s) <= 3, "seed {seed} m {m}");
            }
        }
    }

    #[test]
    fn the_walk_visits_the_gray_code_points_from_anywhere() {
        for start in [0u32, 1, 2047, 2048, 1_000_003, u32::MAX - 2] {
            let mut walk = SobolWalk::starting_at(start);
            for k in 0..40u32 {
                let i = start.wrapping_add(k);
                assert_eq!(walk.next_point().0, sobol_point(i ^ (i >> 1)), "{start} + {k}");
            }
        }
        // The second dimension, which the pixels' samples use, is the closed form they used
        // before the table (polynomial x + 1: v₀ = 2³¹, vᵢ = vᵢ₋₁ ⊕ vᵢ₋₁ >> 1).
        for i in (0..5000u32).chain([u32::MAX, 0x8000_0001]) {
            let (mut v, mut x, mut j) = (1u32 << 31, 0u32, i);
            while j != 0 {
                x ^= if j & 1 == 1 { v } else { 0 };
                j >>= 1;
                v ^= v >> 1;
            }
            assert_eq!(sobol_dimension(i, 1), x, "{i}");
        }
    }

    #[test]
    fn emission_points_hand_out_pairs_and_singles_then_the_generator() {
        let s = Scrambles::new(3, stream::PHOTONS);
        let mut rng = Rng::keyed(3, 4, 5);
        let mut after = rng.clone();
        let point = SobolWalk::starting_at(77).next_point();
        let p: [f32; SOBOL_DIMS] = std::array::from_fn(|d| unit(owen_scramble(point.0[d], s.0[d])));
        let mut x = Stratified::new(point, &s, &mut rng);
        assert_eq!(x.uniform2(), Vec2::new(p[0], p[1]));
        assert_eq!(x.uniform(), p[2]);
        assert_eq!(x.uniform2(), Vec2::new(p[3], p[4]));
        assert_eq!(x.uniform(), p[5]);
        assert_eq!(x.uniform(), after.uniform());
        assert_eq!(x.uniform2(), after.uniform2());
        // Another pass's scrambles move every dimension.
        let t = Scrambles::new(4, stream::PHOTONS);
        assert!((0..SOBOL_DIMS).all(|d| owen_scramble(point.0[d], s.0[d]) != owen_scramble(point.0[d], t.0[d])));
    }

    #[test]
    fn consecutive_passes_of_four_samples_fill_the_strata_of_their_union() {
        // Pass 1 takes samples 0..4 and pass 2 samples 4..8: together they are one 8-point net,
        // which independent per-pass strata would not be.
        let union = [cells(0, 4, 7, 8, 1), cells(4, 8, 7, 8, 1)].concat();
        let mut union = union;
        union.sort();
        assert_eq!(union, (0..8).collect::<Vec<_>>());
    }

    #[test]
    fn morton_order_visits_each_aligned_square_in_one_run() {
        assert_eq!(
            (morton2(1, 0), morton2(0, 1), morton2(1, 1), morton2(2, 0)),
            (1, 2, 3, 4)
        );
        for side in [2u32, 8, 64] {
            let (x0, y0) = (3 * side, 5 * side);
            let mut m: Vec<u32> = (0..side * side)
                .map(|i| morton2(x0 + i % side, y0 + i / side))
                .collect();
            m.sort();
            let first = morton2(x0, y0);
            assert_eq!(m, (first..first + side * side).collect::<Vec<_>>(), "{side}");
        }
        assert_eq!(morton2(0xffff, 0xffff), u32::MAX);
    }

    #[test]
    fn pixel_samples_differ_between_pixels_and_stay_in_the_unit_square() {
        let a: Vec<Vec2> = (0..64).map(|i| owen_sobol(i, 1)).collect();
        let b: Vec<Vec2> = (0..64).map(|i| owen_sobol(i, 2)).collect();
        assert_ne!(a, b);
        assert!(a
            .iter()
            .chain(&b)
            .all(|p| (0.0..1.0).contains(&p.x) && (0.0..1.0).contains(&p.y)));
        let mean = a.iter().copied().sum::<Vec2>() / 64.0;
        assert!((mean - Vec2::splat(0.5)).abs().max_element() < 0.02, "{mean}");
    }
}
