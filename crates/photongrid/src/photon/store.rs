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
    _pad: u8,
}

const _: () = assert!(std::mem::size_of::<Photon>() == 24);

impl Photon {
    /// Pack a photon. `normal` is the surface normal on the side the photon arrived from;
    /// `incoming` points from the surface towards where the photon came from.
    pub fn new(position: Vec3, power: Rgb, normal: Vec3, incoming: Vec3, kind: PhotonKind) -> Self {
        let n = oct_encode(normal);
        let d = oct_encode(incoming);
        Photon {
            position: position.to_array(),
            power: rgbe_encode(power),
            normal: [quantise(n.x, 16) as u16, quantise(n.y, 16) as u16],
            direction: [quantise(d.x, 8) as u8, quantise(d.y, 8) as u8],
            kind: kind as u8,
            _pad: 0,
        }
    }

    /// Power [W] per channel.
    pub fn power(&self) -> Rgb {
        rgbe_decode(self.power)
    }

    /// Unit surface normal on the receiving side.
    pub fn normal(&self) -> Vec3 {
        oct_decode(Vec2::new(
            dequantise(self.normal[0] as u32, 16),
            dequantise(self.normal[1] as u32, 16),
        ))
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
    ((x.clamp(-1.0, 1.0) * 0.5 + 0.5) * max).round() as u32
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
    let z = 1.0 - e.x.abs() - e.y.abs();
    let (x, y) = if z >= 0.0 {
        (e.x, e.y)
    } else {
        ((1.0 - e.y.abs()) * e.x.signum(), (1.0 - e.x.abs()) * e.y.signum())
    };
    Vec3::new(x, y, z).normalize_or_zero()
}

/// Ward's shared-exponent RGBE with rounding (error ≤ half a step of 2^e/256: relative error
/// ≤ 0.4 % on the largest channel, whose mantissa is in [128, 256)).
pub fn rgbe_encode(c: Rgb) -> [u8; 4] {
    let c = c.max(Rgb::ZERO);
    let m = c.max_element();
    if !(m > 1e-38) || !m.is_finite() {
        return [0; 4];
    }
    let mut e = m.log2().floor() as i32 + 1; // m / 2^e in [0.5, 1)
    if (m * 256.0 * (2.0f32).powi(-e)).round() >= 256.0 {
        // Just below a power of two the largest channel rounds up to 256: it takes the next
        // exponent (clamping it to 255 would lose up to a whole step).
        e += 1;
    }
    let scale = (256.0f32).powi(1) * (2.0f32).powi(-e);
    let enc = |v: f32| ((v * scale).round() as u32).min(255) as u8;
    let r = [enc(c.x), enc(c.y), enc(c.z)];
    [r[0], r[1], r[2], (e + 128).clamp(0, 255) as u8]
}

/// Decode [`rgbe_encode`].
pub fn rgbe_decode(v: [u8; 4]) -> Rgb {
    if v[3] == 0 {
        return Rgb::ZERO;
    }
    let f = (2.0f32).powi(v[3] as i32 - 128 - 8);
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
            assert!(m < 255.5 * step && m >= 127.5 * step, "{p}: exponent {e}");
            assert!((q - p).abs().max_element() <= 0.5 * step * (1.0 + 1e-5), "{p} {q}");
            assert_eq!(ph.kind(), PhotonKind::Caustic);
        }
        // Just below a power of two: rounds up to the power of two, not down by a step.
        let below = 1.0 - 1e-4;
        let q = rgbe_decode(rgbe_encode(Rgb::new(below, 0.5, 0.0)));
        assert!((q.x - below).abs() < 1e-3, "{q}");
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
}
