//! Stochastic progressive photon mapping's per-sample statistics (Hachisuka & Jensen 2009,
//! "Stochastic Progressive Photon Mapping"; radius update of Knaus & Zwicker 2011, α as
//! pbrt-v4's `SPPMIntegrator`): every camera sample keeps a radius, a photon count and a flux
//! across passes.

use super::density::{irradiance, progressive_shrink};
use crate::Rgb;

/// The statistics of one camera sample across passes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SppmPixel {
    /// Squared gather radius (0: no visible point yet, radius not chosen).
    pub r2: f32,
    /// Accumulated photon count `N`.
    pub n: f32,
    /// Accumulated flux `τ` (BSDF and path weight applied), in units of one pass's photons.
    pub tau: Rgb,
}

impl SppmPixel {
    /// Add a pass in which `m` photons with weighted flux sum `phi` fell within the radius
    /// ([`progressive_shrink`]): `r'² = r² s`, `τ' = (τ + Φ_M) s`. Without photons nothing
    /// changes (the pass still counts in [`SppmPixel::radiance`]).
    pub fn update(&mut self, m: usize, phi: Rgb) {
        if m == 0 {
            return;
        }
        let (n_new, shrink) = progressive_shrink(self.n, m as f32);
        self.r2 *= shrink;
        self.tau = (self.tau + phi) * shrink;
        self.n = n_new;
    }

    /// Reflected radiance from photons after `passes` passes: `τ / (P π r²)`.
    ///
    /// Normalisation: the SPPM estimate is `L = τ / (N_e π r²)` when each photon carries the
    /// power of one emitted path, `Φ_light / p_light`, and `N_e` paths were emitted over all
    /// passes. Our photons already carry `Φ_light / (p_light N_pass)` (the pass's paths,
    /// `photon::trace`), so our `τ` is pbrt's divided by `N_pass`, and with `N_e = P N_pass`
    /// the estimate is `τ / (P π r²)`. This holds for any mixture of global and caustic-pass
    /// paths, since every pass's photons are by themselves an unbiased flux estimate.
    pub fn radiance(&self, passes: u32) -> Rgb {
        if self.r2 <= 0.0 || passes == 0 {
            return Rgb::ZERO;
        }
        irradiance(self.tau / passes as f32, self.r2)
    }
}

#[cfg(test)]
mod tests {
    use super::SppmPixel;
    use crate::sampling::Rng;
    use crate::Rgb;

    /// Photons spread uniformly over a unit square, a visible point at its centre: after many
    /// passes the estimate converges to the true density and the radius shrinks.
    #[test]
    fn update_converges_on_a_uniform_field() {
        let per_pass = 2000; // photons per pass over 1 m²
        let e = Rgb::new(3.0, 2.0, 1.0); // irradiance [W/m²]: each photon carries e / per_pass
        let phi = e / per_pass as f32;
        let mut px = SppmPixel {
            r2: 0.2f32 * 0.2,
            ..Default::default()
        };
        let r2_start = px.r2;
        let mut rng = Rng::keyed(1, 2, 3);
        let passes = 2000;
        let mut r2_at = Vec::new();
        for p in 1..=passes {
            let (mut m, mut flux) = (0, Rgb::ZERO);
            for _ in 0..per_pass {
                let q = rng.uniform2() - glam::Vec2::splat(0.5);
                if q.length_squared() <= px.r2 {
                    m += 1;
                    flux += phi;
                }
            }
            px.update(m, flux);
            if p == 10 || p == 100 || p == 1000 {
                r2_at.push(px.r2);
            }
        }
        // Weight 1 (no BSDF): the estimate is the irradiance itself.
        let got = px.radiance(passes);
        let rel = (got / e - Rgb::ONE).abs().max_element();
        assert!(rel < 0.02, "estimate {got} vs {e} ({rel})");
        // The radius shrinks monotonically, roughly as P^(α−1) = P^(−1/3) in r².
        assert!(r2_at.windows(2).all(|w| w[1] < w[0]) && px.r2 < r2_at[2]);
        let ratio = r2_at[2] / r2_at[1]; // 1000 vs 100 passes: 10^(−1/3) ≈ 0.46
        assert!((0.35..0.6).contains(&ratio), "r² ratio {ratio}");
        assert!(px.r2 < 0.1 * r2_start);
        // No photons: nothing changes.
        let before = px;
        px.update(0, Rgb::ZERO);
        assert_eq!(px, before);
    }
}
