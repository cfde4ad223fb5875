//! Noise statistics of Poisson photon counts, shared by the denoisers of the plane textures
//! (`wavelet`) and of the voxel grid (`voxels`): variance stabilisation and its unbiased
//! inverse, a robust noise estimate, and the threshold that separates noise from signal.

/// Anscombe variance-stabilising transform `2·√(x + 3/8)`: Poisson data become roughly
/// unit-variance Gaussian, so one threshold fits dim and bright cells alike.
// Source: F. J. Anscombe, Biometrika 35 (1948), pp. 246–254.
pub(super) fn anscombe(x: f64) -> f64 {
    2.0 * (x + 0.375).sqrt()
}

/// Closed-form approximation of the exact unbiased inverse Anscombe
/// transform:
/// `y²/4 + √(3/2)/(4y) − 11/(8y²) + 5√(3/2)/(8y³) − 1/8`, clamped at 0.
///
/// It maps `E[anscombe(z)]` back to the Poisson mean, which the algebraic
/// inverse `(y/2)² − 3/8` underestimates at low counts.
// Source: M. Mäkitalo and A. Foi, IEEE Trans. Image Processing 20(9) (2011), pp. 2697–2698.
pub(super) fn inverse_anscombe_unbiased(y: f64) -> f64 {
    // No Poisson mean has E[anscombe(z)] below anscombe(0) (where this series
    // is exactly 0), and below it the series turns back up: that is a zero count.
    if y <= anscombe(0.0) {
        return 0.0;
    }
    let s = 1.5f64.sqrt();
    let y2 = y * y;
    (0.25 * y2 + 0.25 * s / y - 1.375 / y2 + 0.625 * s / (y2 * y) - 0.125).max(0.0)
}

/// Robust noise sigma of zero-mean values (such as detail coefficients) from their median
/// absolute value (MAD): 0.6745 is the median of |N(0, 1)|. Replaces the values by their
/// magnitudes and reorders them; 0 when there are none.
// Source: D. L. Donoho and I. M. Johnstone, Biometrika 81(3) (1994), pp. 425–455.
pub(super) fn mad_sigma(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    for v in values.iter_mut() {
        *v = v.abs();
    }
    let mid = values.len() / 2;
    let (_, median, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    *median / 0.6745
}

/// Universal threshold `sigma·√(2 ln n)`: with high probability above the largest of `n`
/// pure-noise values of standard deviation `sigma`.
// Source: D. L. Donoho and I. M. Johnstone, Biometrika 81(3) (1994), pp. 425–455.
pub(super) fn universal_threshold(sigma: f64, n: usize) -> f64 {
    sigma * (2.0 * (n.max(1) as f64).ln()).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `(k, P(Poisson(λ) = k))` for `k < 2000`.
    fn poisson_pmf(lambda: f64) -> impl Iterator<Item = (f64, f64)> {
        (0..2000).scan((-lambda).exp(), move |p, k| {
            let out = (k as f64, *p);
            *p *= lambda / (k as f64 + 1.0);
            Some(out)
        })
    }

    #[test]
    fn anscombe_stabilises_poisson_variance() {
        assert_eq!(anscombe(0.0), 2.0 * 0.375f64.sqrt());
        assert_eq!(anscombe(3.625), 4.0);
        // Var[anscombe(Poisson(λ))] → 1 as λ grows, whereas Var[Poisson(λ)] = λ.
        for (lambda, tolerance) in [(5.0, 0.01), (20.0, 1e-3), (200.0, 1e-5)] {
            let mean: f64 = poisson_pmf(lambda).map(|(k, p)| p * anscombe(k)).sum();
            let var: f64 = poisson_pmf(lambda).map(|(k, p)| p * (anscombe(k) - mean).powi(2)).sum();
            assert!((var - 1.0).abs() < tolerance, "λ={lambda}: variance {var}");
        }
    }

    #[test]
    fn inverse_anscombe_formula() {
        // Exactly zero at anscombe(0), zero below, and never negative.
        assert!(inverse_anscombe_unbiased(anscombe(0.0)).abs() < 1e-12);
        assert_eq!(inverse_anscombe_unbiased(0.5), 0.0);
        assert_eq!(inverse_anscombe_unbiased(0.0), 0.0);
        for i in 0..1000 {
            let y = i as f64 * 0.05;
            assert!(inverse_anscombe_unbiased(y) >= 0.0);
        }
        // Unbiased: maps E[anscombe(Poisson(λ))] back to λ.
        for lambda in [1.0f64, 2.0, 5.0, 20.0, 200.0] {
            let mut expect = 0.0;
            let mut p = (-lambda).exp();
            for k in 0..2000 {
                expect += p * anscombe(k as f64);
                p *= lambda / (k as f64 + 1.0);
            }
            let back = inverse_anscombe_unbiased(expect);
            assert!((back - lambda).abs() < 0.01 * lambda, "λ={lambda}: {back}");
        }
    }

    #[test]
    fn mad_sigma_is_the_median_magnitude_over_0_6745() {
        assert_eq!(mad_sigma(&mut []), 0.0);
        let mut v = [-3.0, 1.0, 2.0, -0.5, 4.0];
        assert_eq!(mad_sigma(&mut v), 2.0 / 0.6745);
        assert!(v.iter().all(|&x| x >= 0.0), "values become magnitudes");
        // The upper median for an even count; the sign and order do not matter.
        assert_eq!(mad_sigma(&mut [0.1, -0.4, 0.3, -0.2]), 0.3 / 0.6745);
        // A few huge outliers (signal) barely move it.
        let mut noisy: Vec<f64> = (0..1000).map(|i| if i % 100 == 0 { 1e6 } else { 1.0 }).collect();
        assert_eq!(mad_sigma(&mut noisy), 1.0 / 0.6745);
    }

    #[test]
    fn universal_threshold_grows_as_sqrt_2_ln_n() {
        assert_eq!(universal_threshold(2.0, 100), 2.0 * (2.0 * 100f64.ln()).sqrt());
        assert_eq!(universal_threshold(1.0, 1), 0.0);
        assert_eq!(universal_threshold(1.0, 0), 0.0);
        assert!(universal_threshold(1.0, 1 << 20) > universal_threshold(1.0, 1 << 10));
        // For a million unit Gaussians it sits about 5.3 σ out.
        assert!((universal_threshold(1.0, 1_000_000) - 5.257).abs() < 1e-3);
    }
}
