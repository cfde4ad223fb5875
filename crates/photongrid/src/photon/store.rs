//! A photon record in 24 bytes: position, RGBE power, octahedral normal and direction, kind.

use crate::spatial::Positioned;
use crate::Rgb;
use glam::{Vec2, Vec3};

/// How the light reached the surface the photon is stored on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[repr(u8)]
pub enum PhotonKind {
    /// Straight from the light (L D): shadow rays compute this more precisely.
    Direct = 0,
    /// Through glass or mirrors only (L S+ D): a caustic.
    Caustic = 1,
    /// After at least one diffuse bounce (L D (S|D)* D).
    Indirect = 2,
}

/// One stored photon (24 bytes; 5 M photons take 120 MB).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Photon {
    /// World position.
    pub position: [f32; 3],
    power: [u8; 4],
    normal: [u16; 2],
    direction: [u8; 2],
    kind: u8,
    /// Surface interactions of the photon's path up to and including this one (glass and
    /// mirrors count), 1 for light arriving straight from the light.
    depth: u8,
}

const _: () = assert!(std::mem::size_of::<Photon>() == 24);

impl Photon {
    /// Pack a photon, power rounded to the nearest RGBE step. `normal` is the surface normal on
    /// the side the photon arrived from; `incoming` points from the surface towards where the
    /// photon came from.
    pub fn new(position: Vec3, power: Rgb, normal: Vec3, incoming: Vec3, kind: PhotonKind) -> Self {
        Self::dithered(position, power, normal, incoming, kind, Vec3::splat(0.5))
    }

    /// Pack a photon with its power rounded stochastically: `dither` holds one uniform number
    /// in [0, 1) per channel, so that every channel is unbiased on average ([`rgbe_encode_dithered`]).
    /// The photon tracer uses this: its photons share a few exact powers (Russian roulette keeps
    /// the largest channel constant), so rounding to the nearest step would bias them all alike.
    pub fn dithered(position: Vec3, power: Rgb, normal: Vec3, incoming: Vec3, kind: PhotonKind, dither: Vec3) -> Self {
        let n = oct_encode(normal);
        let d = oct_encode(incoming);
        Photon {
            position: position.to_array(),
            power: rgbe_encode_dithered(power, dither),
            normal: [quantise(n.x, 16) as u16, quantise(n.y, 16) as u16],
            direction: [quantise(d.x, 8) as u8, quantise(d.y, 8) as u8],
            kind: kind as u8,
            depth: 1,
        }
    }

    /// The same photon recorded as the `depth`-th surface interaction of its path (1: the first
    /// surface the light reached; saturates at 255).
    pub fn with_depth(mut self, depth: u32) -> Self {
        self.depth = depth.clamp(1, 255) as u8;
        self
    }

    /// Power [W] per channel.
    pub fn power(&self) -> Rgb {
        rgbe_decode(self.power)
    }

    /// Unit surface normal on the receiving side.
    pub fn normal(&self) -> Vec3 {
        self.normal_direction().normalize_or_zero()
    }

    /// The surface normal's direction, not normalised.
    fn normal_direction(&self) -> Vec3 {
        oct_unnormalised(Vec2::new(
            dequantise(self.normal[0] as u32, 16),
            dequantise(self.normal[1] as u32, 16),
        ))
    }

    /// Whether the photon's surface faces the way `normal` does ([`crate::estimate::photon_map::faces`]),
    /// without normalising the decoded normal: the counting of every photon into the grids
    /// and the photon map's kNN filter ask this for every photon they meet.
    pub fn faces(&self, normal: Vec3) -> bool {
        let v = self.normal_direction();
        let d = v.dot(normal);
        let t = crate::estimate::NORMAL_AGREEMENT;
        d > 0.0 && d * d > t * t * v.length_squared()
    }

    /// Unit direction towards where the photon came from (≈1° precision).
    pub fn incoming(&self) -> Vec3 {
        oct_decode(Vec2::new(
            dequantise(self.direction[0] as u32, 8),
            dequantise(self.direction[1] as u32, 8),
        ))
    }

    /// How the photon got here.
    pub fn kind(&self) -> PhotonKind {
        match self.kind {
            0 => PhotonKind::Direct,
            1 => PhotonKind::Caustic,
            _ => PhotonKind::Indirect,
        }
    }

    /// Surface interactions of the path up to this photon, glass and mirrors included (1: straight
    /// from the light). Seen by the camera at the photon, the light has travelled `depth + 1`
    /// segments; through one final-gather bounce, `depth + 2`.
    pub fn depth(&self) -> u32 {
        self.depth as u32
    }

    /// Position as a vector.
    #[inline]
    pub fn pos(&self) -> Vec3 {
        Vec3::from(self.position)
    }
}

impl Positioned for Photon {
    #[inline]
    fn position(&self) -> Vec3 {
        Vec3::from(self.position)
    }
}

fn quantise(x: f32, bits: u32) -> u32 {
    let max = ((1u32 << bits) - 1) as f32;
    round_non_negative((x.clamp(-1.0, 1.0) * 0.5 + 0.5) * max)
}

/// `v.round() as u32` for `v ≥ 0`, without the library call that `round` is on baseline
/// x86-64 (`v - trunc(v)` is exact).
#[inline]
fn round_non_negative(v: f32) -> u32 {
    let t = v as u32;
    t + (v - t as f32 >= 0.5) as u32
}

fn dequantise(q: u32, bits: u32) -> f32 {
    let max = ((1u32 << bits) - 1) as f32;
    q as f32 / max * 2.0 - 1.0
}

/// Octahedral map of a unit vector to [-1, 1]².
pub fn oct_encode(n: Vec3) -> Vec2 {
    let n = n / (n.x.abs() + n.y.abs() + n.z.abs()).max(1e-20);
    if n.z >= 0.0 {
        Vec2::new(n.x, n.y)
    } else {
        Vec2::new((1.0 - n.y.abs()) * n.x.signum(), (1.0 - n.x.abs()) * n.y.signum())
    }
}

/// Inverse of [`oct_encode`].
pub fn oct_decode(e: Vec2) -> Vec3 {
    oct_unnormalised(e).normalize_or_zero()
}

/// [`oct_decode`] before normalisation (same direction).
fn oct_unnormalised(e: Vec2) -> Vec3 {
    let z = 1.0 - e.x.abs() - e.y.abs();
    let (x, y) = if z >= 0.0 {
        (e.x, e.y)
    } else {
        ((1.0 - e.y.abs()) * e.x.signum(), (1.0 - e.x.abs()) * e.y.signum())
    };
    Vec3::new(x, y, z)
}

/// Ward's shared-exponent RGBE, each channel rounded to the nearest step (error ≤ half a step
/// of 2^e/256: relative error ≤ 0.4 % on the largest channel, whose mantissa is in [127.5, 255]).
pub fn rgbe_encode(c: Rgb) -> [u8; 4] {
    rgbe_encode_dithered(c, Vec3::splat(0.5))
}

/// RGBE with stochastic rounding: channel `i` becomes `floor(v_i / step + dither_i)`. With
/// `dither_i` uniform in [0, 1) the decoded value is unbiased (its expectation is exactly `v_i`);
/// 0.5 rounds to the nearest step. The exponent depends on the largest channel only (it is the
/// smallest whose 255 steps hold that channel), never on the dither, so no channel can round
/// past 255 and the choice of step cannot correlate with the rounding.
///
/// Why it matters: Russian roulette keeps the largest channel of every photon at the same value
/// and a surface's albedo fixes the colour ratios, so a whole photon map holds a few exact
/// powers; nearest rounding then shifts all of them the same way (pool_caustic, 2 M photons:
/// +0.18 % on every photon's largest channel, up to ±2.5 % on the small channels of photons
/// that bounced several times off a coloured wall) instead of averaging out.
pub fn rgbe_encode_dithered(c: Rgb, dither: Vec3) -> [u8; 4] {
    let c = c.max(Rgb::ZERO);
    let m = c.max_element();
    if !(m > 1e-38) || !m.is_finite() {
        return [0; 4];
    }
    let mut e = floor_log2(m) + 1; // m / 2^e in [0.5, 1)
    if m * 256.0 * exp2i(-e) > 255.0 {
        // Just below a power of two the largest channel needs more than 255 steps: take the next
        // exponent (clamping at 255 would lose up to a whole step).
        e += 1;
    }
    let scale = 256.0 * exp2i(-e);
    // Truncation is the floor here (the sum is ≥ 0), without a library call.
    let enc = |v: f32, u: f32| ((v * scale + u.clamp(0.0, 0.999_999)) as u32).min(255) as u8;
    let r = [enc(c.x, dither.x), enc(c.y, dither.y), enc(c.z, dither.z)];
    [r[0], r[1], r[2], (e + 128).clamp(0, 255) as u8]
}

/// `floor(log2 m)` for a positive, finite `m`: the exponent bits of a normal float (no
/// `log2f` and `floorf` calls per photon).
#[inline]
fn floor_log2(m: f32) -> i32 {
    let biased = (m.to_bits() >> 23) as i32 & 0xff;
    if biased == 0 {
        m.log2().floor() as i32 // subnormal
    } else {
        biased - 127
    }
}

/// `2^k` rounded to an `f32` (subnormal, zero or infinite out of range), built from its bits
/// (the photon pass encodes and counts every photon's power). No `powi`, not even for a rare
/// out-of-range `k`: LLVM treats it as free of side effects and computed it on every call,
/// hoisted out of the branch (and `2f32.powi(k)` is 0 from k = −128 on: 2¹²⁸ overflows).
#[inline]
fn exp2i(k: i32) -> f32 {
    match k {
        128.. => f32::INFINITY,
        -126..=127 => f32::from_bits(((k + 127) as u32) << 23),
        -149..=-127 => f32::from_bits(1 << (k + 149)), // subnormal
        _ => 0.0,
    }
}

/// Decode [`rgbe_encode`].
pub fn rgbe_decode(v: [u8; 4]) -> Rgb {
    if v[3] == 0 {
        return Rgb::ZERO;
    }
    let f = exp2i(v[3] as i32 - 128 - 8);
    Rgb::new(v[0] as f32, v[1] as f32, v[2] as f32) * f
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{uniform_sphere, Rng};

    #[test]
    fn round_trips() {
        let mut rng = Rng::keyed(5, 5, 5);
        for _ in 0..10_000 {
            let n = uniform_sphere(rng.uniform2());
            let d = uniform_sphere(rng.uniform2());
            let p = Rgb::new(rng.uniform(), rng.uniform(), rng.uniform()) * 1e-6;
            let ph = Photon::new(Vec3::ONE, p, n, d, PhotonKind::Caustic);
            assert!(ph.normal().dot(n) > 0.99999, "normal");
            assert!(ph.incoming().dot(d) > 0.999, "direction");
            let q = ph.power();
            let m = p.max_element();
            // Each channel is rounded to the nearest step of 2^e/256, e being the smallest
            // exponent whose 256 steps hold the largest channel (so a step is ≤ m/128 + ε).
            let e = rgbe_encode(p)[3] as i32 - 128;
            let step = 2f32.powi(e) / 256.0;
            assert!(
                m <= 255.0 * step * (1.0 + 1e-6) && m >= 127.5 * step,
                "{p}: exponent {e}"
            );
            assert!((q - p).abs().max_element() <= 0.5 * step * (1.0 + 1e-5), "{p} {q}");
            assert_eq!(ph.kind(), PhotonKind::Caustic);
            assert_eq!(ph.depth(), 1);
            assert_eq!(ph.with_depth(11).depth(), 11);
        }
        // Just below a power of two: rounds up to the power of two, not down by a step.
        let below = 1.0 - 1e-4;
        let q = rgbe_decode(rgbe_encode(Rgb::new(below, 0.5, 0.0)));
        assert!((q.x - below).abs() < 1e-3, "{q}");
    }

    #[test]
    fn bit_tricks_match_the_library() {
        let mut rng = Rng::keyed(8, 8, 8);
        for i in 0..100_000 {
            let m = f32::from_bits(rng.next_u32() & 0x7f7f_ffff).max(f32::from_bits(1));
            assert_eq!(floor_log2(m), m.log2().floor() as i32, "{m:e}");
            let v = (i as f32 * 0.5 + rng.uniform()).min(65535.0);
            assert_eq!(round_non_negative(v), v.round() as u32, "{v}");
        }
        for v in [0.0, 0.5, 0.49999997, 1.5, 2.5, 65534.5, 65535.0] {
            assert_eq!(round_non_negative(v), v.round() as u32, "{v}");
        }
    }

    #[test]
    fn exp2i_is_two_to_the_k() {
        for k in (-400..=400).chain([i32::MIN, i32::MAX]) {
            assert_eq!(exp2i(k).to_bits(), (2f64.powi(k) as f32).to_bits(), "2^{k}");
        }
    }

    #[test]
    fn rgbe_is_unbiased_on_average() {
        let mut rng = Rng::keyed(6, 6, 6);
        let (mut a, mut b) = (0.0f64, 0.0f64);
        for _ in 0..100_000 {
            let v = rng.uniform() * 3e-5 + 1e-7;
            a += v as f64;
            b += rgbe_decode(rgbe_encode(Rgb::splat(v))).x as f64;
        }
        assert!((b / a - 1.0).abs() < 1e-3, "{}", b / a);
        assert_eq!(rgbe_decode(rgbe_encode(Rgb::ZERO)), Rgb::ZERO);
    }

    #[test]
    fn dithered_rgbe_is_unbiased_for_one_repeated_power() {
        // The photon tracer's case: every photon carries the same power (Russian roulette keeps
        // the largest channel, a sand wall fixes the ratios), so nearest rounding is one fixed
        // error, not noise. pool_caustic with 2 M photons: 18.0866 W / 2e6 per photon.
        let p = Rgb::new(1.0, 0.64 / 0.72, (0.5f32 / 0.72).powi(5)) * (18.086_573 / 2e6);
        let nearest = rgbe_decode(rgbe_encode(p));
        let bias = nearest / p - Rgb::ONE;
        assert!(bias.x > 1.5e-3, "nearest rounding is biased here: {bias}");
        let mut rng = Rng::keyed(7, 7, 7);
        let n = 200_000;
        let mut sum = [0f64; 3];
        for _ in 0..n {
            let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let q = rgbe_decode(rgbe_encode_dithered(p, u));
            for c in 0..3 {
                sum[c] += q[c] as f64;
            }
        }
        // The tracer shares one uniform between the channels: a grey power stays exactly grey.
        let grey = rgbe_decode(rgbe_encode_dithered(Rgb::splat(p.y), Vec3::splat(rng.uniform())));
        assert!(grey.x == grey.y && grey.y == grey.z, "{grey}");
        for c in 0..3 {
            let r = sum[c] / n as f64 / p[c] as f64;
            // A step is ≤ 1/127.5 of the largest channel; the mean of n dithered roundings has a
            // standard deviation below step/√(12 n).
            assert!((r - 1.0).abs() < 2e-4 / (p[c] / p.x) as f64, "channel {c}: {r}");
        }
    }
}
