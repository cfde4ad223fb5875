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
    /// Per-pixel scrambling of the final-gather directions.
    pub const GATHER: u64 = 6;
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
    let y = owen_scramble(sobol_second_dimension(index), (seed >> 32) as u32);
    let unit = |v: u32| (v >> 8) as f32 * (1.0 / 16_777_216.0);
    Vec2::new(unit(x), unit(y))
}

/// The scramble of one pixel's sequence of positions for `purpose` (a [`stream`] key): fixed
/// by the render's seed, so every pass continues the same sequence.
pub fn pixel_scramble(seed: u64, purpose: u64, pixel: u64) -> u64 {
    mix64(seed ^ mix64(purpose ^ pixel << 8))
}

/// The Sobol sequence's second dimension (primitive polynomial x + 1: direction numbers
/// v₀ = 2³¹, vᵢ = vᵢ₋₁ ⊕ vᵢ₋₁ >> 1).
fn sobol_second_dimension(mut index: u32) -> u32 {
    let (mut v, mut x) = (1u32 << 31, 0u32);
    while index != 0 {
        if index & 1 == 1 {
            x ^= v;
        }
        index >>= 1;
        v ^= v >> 1;
    }
    x
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
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, PI / 4.0 * (o.y / o.x))
    } else {
        (o.y, PI / 2.0 - PI / 4.0 * (o.x / o.y))
    };
    r * Vec2::new(theta.cos(), theta.sin())
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
