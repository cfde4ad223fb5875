//! The density-estimation formulas, each once: radiance from photons in a disc (METHOD.md
//! eq. (1)), the kNN bias correction, the paper's assumed radius (eq. (3)) and its blend, and
//! the progressive radius schedules of (S)PPM.

use crate::Rgb;
use std::f32::consts::PI;

/// Irradiance from photons of total flux `flux_sum` in a disc of squared radius `r2`:
/// `E = Σ Φ / (π r²)` (zero for an empty disc).
pub fn irradiance(flux_sum: Rgb, r2: f32) -> Rgb {
    if r2 <= 0.0 {
        return Rgb::ZERO;
    }
    flux_sum / (PI * r2)
}

/// Eq. (1) for a Lambert receiver: `L = (albedo/π) Σ Φ_p / (π r²)`.
pub fn density_radiance(albedo: Rgb, flux_sum: Rgb, r2: f32) -> Rgb {
    if r2 <= 0.0 {
        return Rgb::ZERO;
    }
    albedo * std::f32::consts::FRAC_1_PI * flux_sum / (PI * r2)
}

/// Photons per unit area of `count` photons in a disc of squared radius `r2`.
pub fn photon_density(count: f32, r2: f32) -> f32 {
    count / (PI * r2.max(1e-30))
}

/// The k-th nearest photon lies on the disc's edge, so `Σ_k Φ / (π r_k²)` overestimates a
/// uniform density by k/(k−1) (E[1/r_k²] for a Poisson process): the flux is scaled by this.
pub fn knn_flux_correction(k: usize) -> f32 {
    if k > 1 {
        (k - 1) as f32 / k as f32
    } else {
        1.0
    }
}

/// The radius of a disc holding `k` photons where there are `density` photons per m²:
/// `r² = k / (π ρ)`. With `ρ = N / m²` for `N` photons in a cell of area `m²` this is the
/// paper's assumed radius, METHOD.md eq. (3): `r_a² = n m² / (N π)`.
pub fn assumed_radius(k: usize, density: f32) -> f32 {
    (k as f32 / (PI * density)).sqrt()
}

/// The paper's correction: `r = r_a + α (r_k − r_a)`.
pub fn blended_radius(r_a: f32, r_k: f32, alpha: f32) -> f32 {
    r_a + alpha * (r_k - r_a)
}

/// Exponent of the progressive radius reduction, the α of progressive photon mapping
/// (Hachisuka et al. 2008, eq. 6; 2/3 as in pbrt-v4's SPPM): the share of a pass's photons
/// kept in the accumulated count.
pub const PROGRESSIVE_ALPHA: f64 = 2.0 / 3.0;

/// Neighbours for pass `pass` (0-based) of a progressive render with `n` neighbours:
/// `(n_all, k_pass)` = (neighbours counted among all photons of passes 0..=pass, neighbours
/// within the current pass's map).
///
/// The grid method's count textures accumulate every pass's photons, so after P passes a cell
/// holds `N ≈ P c` photons. Keeping `n` fixed would give `r_a² = n m²/(π N) ∝ 1/P`: the bias
/// vanishes, but each pass then gathers only `≈ n/P` of its own photons, and the average of P
/// such pass estimates keeps a variance ∝ `(1/P²) Σ p/n ≈ 1/(2n)` that never falls. Growing
/// `n_all = n P^α` instead gives `r_a² ∝ P^(α−1)`, the rate of (S)PPM's radius reduction
/// (Knaus & Zwicker 2011): each pass gathers `≈ n P^(α−1)` photons of its own map, so the
/// average of the pass estimates has variance ∝ `P^(−α)` and bias ∝ `P^(α−1)`; both vanish. The
/// kNN radius it is blended with is taken in the pass's own map with `k_pass = n_all / P`
/// neighbours (the same expected radius as `n_all` neighbours among all photons so far). Pass 0
/// gives `(n, n)`: a one-pass render is the paper's method unchanged.
pub fn progressive_neighbours(n: usize, pass: u32) -> (usize, usize) {
    let p = pass as f64 + 1.0;
    let n_all = ((n as f64) * p.powf(PROGRESSIVE_ALPHA)).round().max(1.0);
    let k_pass = (n_all / p).round().max(1.0);
    (n_all as usize, k_pass as usize)
}

/// SPPM's update when `m` new photons fall within a sample's radius, holding `n` so far
/// (Hachisuka & Jensen 2009, eqs. 5–8): returns `N' = N + αM` and the factor
/// `(N + αM)/(N + M)` by which the squared radius and the accumulated flux shrink.
pub fn progressive_shrink(n: f32, m: f32) -> (f32, f32) {
    let n_new = n + PROGRESSIVE_ALPHA as f32 * m;
    (n_new, n_new / (n + m))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assumed_radius_matches_uniform_field() {
        // A uniform field of density ρ photons/m²: the disc holding n photons has r² = n/(πρ),
        // and a cell of area m² holds N = ρ m², so eq. (3) must give the same radius.
        let rho = 250_000.0f32;
        let cell_area = (2.0f32 / 128.0).powi(2);
        let n = 100;
        let count = rho * cell_area;
        let r = assumed_radius(n, count / cell_area);
        assert!((r * r - n as f32 * cell_area / (count * PI)).abs() / (r * r) < 1e-5);
        assert!((photon_density(n as f32, r * r) / rho - 1.0).abs() < 1e-5);
        assert_eq!(blended_radius(1.0, 2.0, 0.1), 1.1);
        assert_eq!(blended_radius(1.0, 2.0, 1.0), 2.0);
    }

    #[test]
    fn radiance_of_a_uniform_disc() {
        // 1 W over a disc of 1 m²: irradiance 1 W/m², white Lambert radiance 1/π.
        let r2 = 1.0 / PI;
        assert!((irradiance(Rgb::ONE, r2) - Rgb::ONE).abs().max_element() < 1e-6);
        let l = density_radiance(Rgb::ONE, Rgb::ONE, r2);
        assert!((l.x - std::f32::consts::FRAC_1_PI).abs() < 1e-6);
        assert_eq!(irradiance(Rgb::ONE, 0.0), Rgb::ZERO);
        assert_eq!(knn_flux_correction(100), 0.99);
        assert_eq!(knn_flux_correction(1), 1.0);
    }

    #[test]
    fn progressive_schedule_starts_at_n_and_shrinks_the_radius_like_sppm() {
        assert_eq!(progressive_neighbours(100, 0), (100, 100));
        let (n8, k8) = progressive_neighbours(100, 7); // P = 8: n 8^(2/3) = 400, k = 50
        assert_eq!((n8, k8), (400, 50));
        // r_a² ∝ n_all / (P c): 8 passes → 400/(8 c) = half of pass 0's 100/c.
        let r0 = assumed_radius(100, 1000.0);
        let r8 = assumed_radius(n8, 8000.0);
        assert!(((r8 / r0).powi(2) - 0.5).abs() < 1e-4);
        assert_eq!(progressive_neighbours(1, 1_000_000).1, 1);
        let (n, f) = progressive_shrink(0.0, 30.0);
        assert!((n - 20.0).abs() < 1e-5 && (f - 2.0 / 3.0).abs() < 1e-6);
    }
}
