//! The directions final gathering draws its rays from, and how it weighs what they bring: a
//! cosine distribution where the surface is Lambert, the surface's own stored lobes where it
//! is a glossy glTF surface (the indirect light then reflects as the BSDF says instead of as
//! if it arrived evenly, which made rough metal lit by bright walls too bright).

use crate::bsdf::{self, GltfPoint};
use crate::sampling::{self, Rng};
use crate::surface::SurfacePoint;
use crate::Rgb;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Where final-gather directions come from.
#[derive(Clone, Copy)]
pub(super) enum GatherLobe<'g> {
    /// Cosine-distributed: the gather gives the cosine-weighted mean radiance (a Lambert
    /// surface's indirect radiance is its albedo times it).
    Cosine,
    /// The stored lobes of a glTF surface, sampled as its BSDF: the gather gives the radiance
    /// they reflect.
    Stored(&'g GltfPoint),
}

/// A gather direction and what its weight needs.
pub(super) struct LobeRay {
    /// World direction away from the surface.
    pub direction: Vec3,
    /// Cosine at the shading normal ([`GatherLobe::Cosine`]).
    cos: f32,
    /// BSDF × cosine ([`GatherLobe::Stored`]).
    f_cos: Rgb,
    /// Solid-angle density of the BSDF sample ([`GatherLobe::Stored`]).
    pdf: f32,
    /// A normal map's shadowing of the light from this direction ([`GatherLobe::Cosine`]; the
    /// glTF BSDF applies its own).
    bump: f32,
}

impl GatherLobe<'_> {
    /// A direction drawn from this lobe at `sp` by the point `u` (a glTF lobe's choice among
    /// its lobes by `rng`); None where it would leave below the geometric surface.
    pub fn sample(&self, sp: &SurfacePoint, u: Vec2, rng: &mut Rng) -> Option<LobeRay> {
        match self {
            GatherLobe::Cosine => {
                let d = sampling::cosine_hemisphere(u, sp.facing_shading_normal);
                (d.dot(sp.facing_normal) > 0.0).then(|| self.eval(sp, d))
            }
            GatherLobe::Stored(g) => {
                let s = g.sample(g.stored, rng.uniform(), u)?;
                Some(LobeRay {
                    direction: s.direction,
                    cos: s.direction.dot(sp.facing_shading_normal),
                    f_cos: s.weight * s.pdf,
                    pdf: s.pdf,
                    bump: 1.0,
                })
            }
        }
    }

    /// The same quantities for a direction `d` chosen otherwise (an aimed ray).
    pub fn eval(&self, sp: &SurfacePoint, d: Vec3) -> LobeRay {
        let cos = d.dot(sp.facing_shading_normal);
        let (f_cos, pdf, bump) = match self {
            GatherLobe::Cosine => (Rgb::ZERO, 0.0, bsdf::bump::at(sp, d)),
            GatherLobe::Stored(g) => {
                let (f, pdf) = g.eval(d, g.stored);
                (f * cos.abs(), pdf, 1.0)
            }
        };
        LobeRay {
            direction: d,
            cos,
            f_cos,
            pdf,
            bump,
        }
    }

    /// The balance-heuristic weight of radiance brought along `r` when `rays.0` directions
    /// come from this lobe and `rays.1` are aimed (`pdf_aimed`: the aim's density along `r`);
    /// the denominators count the rays.
    pub fn weight(&self, r: &LobeRay, pdf_aimed: f32, rays: (u32, u32)) -> Rgb {
        let (spread, aimed) = (rays.0 as f32, rays.1 as f32);
        match self {
            // The cosine density cos/π, written with π moved to the aim's side.
            // A direction on the horizon (a sample point on the disk's rim: u = 0 exactly) has
            // density 0 and brings nothing (0/0 made the pixel NaN).
            GatherLobe::Cosine => {
                let den = spread * r.cos + aimed * PI * pdf_aimed;
                if den > 0.0 && r.cos > 0.0 {
                    Rgb::splat(r.bump * r.cos / den)
                } else {
                    Rgb::ZERO
                }
            }
            GatherLobe::Stored(_) => {
                let den = spread * r.pdf + aimed * pdf_aimed;
                if den > 0.0 {
                    r.f_cos / den
                } else {
                    Rgb::ZERO
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_direction_on_the_horizon_weighs_nothing_instead_of_nan() {
        // u.x = 0 exactly (which an Owen-scrambled point, like a random one, can be) maps to
        // the disk's rim: a direction in the tangent plane (or within 4·10⁻⁴ of it, as the
        // disk's sine and cosine round), of cosine and density 0.
        let rim = sampling::cosine_hemisphere(Vec2::new(0.0, 0.245), Vec3::Z);
        assert!(rim.z.abs() < 4e-4, "{rim}");
        let d = Vec3::new(rim.x, rim.y, 0.0).normalize();
        let r = LobeRay {
            direction: d,
            cos: d.z,
            f_cos: Rgb::ZERO,
            pdf: 0.0,
            bump: 1.0,
        };
        for rays in [(8, 0), (6, 2)] {
            let w = GatherLobe::Cosine.weight(&r, 0.0, rays);
            assert!(w.is_finite() && w == Rgb::ZERO, "{w:?}");
        }
        let inside = LobeRay { cos: 0.5, ..r };
        assert_eq!(GatherLobe::Cosine.weight(&inside, 0.0, (8, 0)), Rgb::splat(0.125));
    }
}
