//! Assumed radius from the filtered photon-count textures (METHOD.md eq. (3)), bilinear
//! interpolation between cells, the blend with the real kNN radius and the shadow fallback.

use super::planes::{detect_planes, PlaneParams, PlaneSet, NO_PLANE};
use super::wavelet::{denoise_counts, max_levels, DenoiseReport, Field2, Threshold, Wavelet};
use crate::photon::Photon;
use glam::Vec3;
use rayon::prelude::*;

/// What a cell of the texture accumulates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum GridQuantity {
    /// Number of photons. The kNN radius is set by how many photons lie around a point, so
    /// counts predict it directly, whatever each photon's power.
    Count,
    /// Flux, expressed in "mean photons" (cell flux / mean photon flux of the plane): equals
    /// the count when photons carry equal power, differs after coloured bounces.
    Flux,
}

/// Assumed radius, METHOD.md eq. (3): `r_a² = n m² / (N π)` for `n` neighbours, cell area
/// `m²` and `N` photons in the cell.
pub fn assumed_radius(neighbours: usize, cell_area: f32, count: f32) -> f32 {
    (neighbours as f32 * cell_area / (count.max(1e-12) * std::f32::consts::PI)).sqrt()
}

/// The paper's correction: `r = r_a + α (r_k − r_a)`.
pub fn blended_radius(r_a: f32, r_k: f32, alpha: f32) -> f32 {
    r_a + alpha * (r_k - r_a)
}

/// Exponent of the progressive neighbour schedule, the α of progressive photon mapping
/// (Hachisuka et al. 2008; 2/3 as in pbrt-v4's SPPM).
pub const PROGRESSIVE_ALPHA: f64 = 2.0 / 3.0;

/// Neighbours for pass `pass` (0-based) of a progressive render with `n` neighbours:
/// `(n_all, k_pass)` = (neighbours counted among all photons of passes 0..=pass, neighbours
/// within the current pass's map).
///
/// How the grid method's radius evolves over passes. The count textures accumulate every
/// pass's photons (refiltered each pass), so after P passes a cell holds `N ≈ P c` photons.
/// Keeping `n` fixed would give `r_a² = n m²/(π N) ∝ 1/P`: the bias vanishes, but each pass
/// then gathers only `≈ n/P` of its own photons, and the average of P such pass estimates keeps
/// a variance ∝ `(1/P²) Σ p/n ≈ 1/(2n)` that never falls. Growing `n_all = n P^α` instead gives
/// `r_a² ∝ P^(α−1)` (radius ∝ P^(−1/6) for α = 2/3), the rate of (S)PPM's radius reduction
/// (Knaus & Zwicker 2011, "Progressive photon mapping: a probabilistic approach"):
/// each pass gathers `≈ n P^(α−1)` photons of its own map, so the average of the pass estimates
/// has variance ∝ `P^(−α)` and bias ∝ `r² ∝ P^(α−1)`; both go to zero. The kNN radius it is
/// blended with is taken in the pass's own map with `k_pass = n_all / P` neighbours (the
/// same expected radius as `n_all` neighbours among all photons so far). Pass 0 gives `(n, n)`:
/// a one-pass render is the paper's method unchanged.
pub fn progressive_neighbours(n: usize, pass: u32) -> (usize, usize) {
    let p = pass as f64 + 1.0;
    let n_all = ((n as f64) * p.powf(PROGRESSIVE_ALPHA)).round().max(1.0);
    let k_pass = (n_all / p).round().max(1.0);
    (n_all as usize, k_pass as usize)
}

/// A count texture per detected plane, before and after the wavelet step.
#[derive(Clone, Debug)]
pub struct PlaneGrids {
    /// The planes and the triangle → plane map.
    pub set: PlaneSet,
    /// Raw textures (one per plane).
    pub raw: Vec<Field2>,
    /// Filtered textures (what the radius uses).
    pub filtered: Vec<Field2>,
    /// What the filter did per plane.
    pub reports: Vec<DenoiseReport>,
}

impl PlaneGrids {
    /// Find planes among the scene's triangles.
    pub fn detect(triangles: &[crate::scene::Triangle], resolution: usize) -> PlaneSet {
        let tris: Vec<[Vec3; 3]> = triangles.iter().map(|t| t.p).collect();
        detect_planes(&tris, &PlaneParams::default().with_resolution(resolution))
    }

    /// Count `photons` (landing on `triangles[i]`) into the planes' textures. Photons for
    /// which `counts(p)` is false are left out (e.g. direct photons when shadow rays are used).
    pub fn count(
        set: PlaneSet,
        photons: &[Photon],
        triangles: &[u32],
        quantity: GridQuantity,
        counts: impl Fn(&Photon) -> bool + Sync,
    ) -> Self {
        let planes = &set.planes;
        let zero = || planes.iter().map(|p| vec![0f64; p.res_u * p.res_v]).collect::<Vec<_>>();
        let per_photon = |p: &Photon| match quantity {
            GridQuantity::Count => 1.0,
            GridQuantity::Flux => {
                let c = p.power();
                ((c.x + c.y + c.z) / 3.0) as f64
            }
        };
        let sums = photons
            .par_iter()
            .zip(triangles.par_iter())
            .fold(zero, |mut acc, (p, &t)| {
                let plane = set.plane_of_triangle.get(t as usize).copied().unwrap_or(NO_PLANE);
                if plane != NO_PLANE && counts(p) {
                    let pl = &planes[plane as usize];
                    if let Some(cell) = pl.cell_of(p.pos(), f32::INFINITY) {
                        acc[plane as usize][cell] += per_photon(p);
                    }
                }
                acc
            })
            .reduce(zero, |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    for (u, v) in x.iter_mut().zip(y) {
                        *u += v;
                    }
                }
                a
            });
        // Flux is expressed in units of the plane's mean photon flux so that N stays a count.
        let mean_flux = if quantity == GridQuantity::Flux {
            let (s, n) = photons
                .iter()
                .filter(|p| counts(p))
                .fold((0.0f64, 0usize), |(s, n), p| (s + per_photon(p), n + 1));
            if n > 0 {
                s / n as f64
            } else {
                1.0
            }
        } else {
            1.0
        };
        let raw: Vec<Field2> = sums
            .into_iter()
            .zip(planes)
            .map(|(v, p)| {
                Field2::from_vec(
                    p.res_u,
                    p.res_v,
                    v.into_iter().map(|x| (x / mean_flux) as f32).collect(),
                )
            })
            .collect();
        PlaneGrids {
            filtered: raw.clone(),
            reports: vec![DenoiseReport::default(); raw.len()],
            raw,
            set,
        }
    }

    /// Add another set of raw counts over the same planes (the next pass's photons); the
    /// filtered textures are stale until [`PlaneGrids::filter`] runs again.
    pub fn accumulate(&mut self, other: &PlaneGrids) {
        for (a, b) in self.raw.iter_mut().zip(&other.raw) {
            for (x, y) in a.data.iter_mut().zip(&b.data) {
                *x += y;
            }
        }
    }

    /// Filter every texture with `wavelet` and `threshold` over up to `levels` levels
    /// (`wavelet = None` keeps the raw counts).
    pub fn filter(&mut self, wavelet: Option<Wavelet>, threshold: Threshold, levels: usize) {
        let Some(w) = wavelet else {
            self.filtered = self.raw.clone();
            return;
        };
        let out: Vec<(Field2, DenoiseReport)> = self
            .raw
            .par_iter()
            .map(|f| denoise_counts(f, w, max_levels(f.width, f.height, levels), threshold))
            .collect();
        (self.filtered, self.reports) = out.into_iter().unzip();
    }

    /// The filtered count interpolated at `p` on `triangle` and the plane's cell area, or None
    /// if the triangle belongs to no plane.
    pub fn count_at(&self, triangle: u32, p: Vec3) -> Option<(f32, f32)> {
        let plane = *self.set.plane_of_triangle.get(triangle as usize)?;
        if plane == NO_PLANE {
            return None;
        }
        let pl = &self.set.planes[plane as usize];
        let tex = &self.filtered[plane as usize];
        let n: f32 = pl.bilinear(p).iter().map(|&(cell, w)| w * tex.data[cell]).sum();
        Some((n, pl.cell_area()))
    }

    /// Heap memory of the textures.
    pub fn memory_bytes(&self) -> usize {
        self.raw.iter().map(|f| f.data.len() * 8).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::photon::PhotonKind;
    use crate::sampling::Rng;
    use crate::scene::Triangle;
    use glam::Vec2;

    fn quad(size: f32) -> Vec<Triangle> {
        let p = |x: f32, z: f32| Vec3::new(x, 0.0, z);
        let n = [Vec3::Y; 3];
        let uv = [Vec2::ZERO; 3];
        vec![
            Triangle {
                p: [p(0.0, 0.0), p(0.0, size), p(size, size)],
                n,
                uv,
                material: 0,
            },
            Triangle {
                p: [p(0.0, 0.0), p(size, size), p(size, 0.0)],
                n,
                uv,
                material: 0,
            },
        ]
    }

    #[test]
    fn assumed_radius_matches_uniform_field() {
        // A uniform field of density ρ photons/m²: the disc holding n photons has r² = n/(πρ),
        // and a cell of area m² holds N = ρ m², so eq. (3) must give the same radius.
        let rho = 250_000.0f32;
        let cell_area = (2.0f32 / 128.0).powi(2);
        let n = 100;
        let r = assumed_radius(n, cell_area, rho * cell_area);
        assert!((r * r - n as f32 / (std::f32::consts::PI * rho)).abs() / (r * r) < 1e-5);
        assert_eq!(blended_radius(1.0, 2.0, 0.1), 1.1);
        assert_eq!(blended_radius(1.0, 2.0, 1.0), 2.0);
    }

    #[test]
    fn counts_a_uniform_field_and_interpolates() {
        let tris = quad(2.0);
        let set = PlaneGrids::detect(&tris, 16);
        assert_eq!(set.planes.len(), 1);
        let mut rng = Rng::keyed(1, 2, 3);
        let n = 256_000;
        let mut photons = Vec::with_capacity(n);
        let mut tri = Vec::with_capacity(n);
        for _ in 0..n {
            let (x, z) = (rng.uniform() * 2.0, rng.uniform() * 2.0);
            photons.push(Photon::new(
                Vec3::new(x, 0.0, z),
                Vec3::ONE,
                Vec3::Y,
                Vec3::Y,
                PhotonKind::Indirect,
            ));
            tri.push(if x > z { 1 } else { 0 });
        }
        let mut g = PlaneGrids::count(set, &photons, &tri, GridQuantity::Count, |_| true);
        let total: f64 = g.raw[0].sum();
        assert_eq!(total as usize, n);
        g.filter(Some(Wavelet::Haar), Threshold::Universal { soft: false }, 4);
        // 1000 photons per cell expected; filtered counts within 3 %.
        let (c, area) = g.count_at(0, Vec3::new(1.0, 0.0, 1.0)).unwrap();
        assert!((c / 1000.0 - 1.0).abs() < 0.03, "{c}");
        assert!((area - (2.0f32 / 16.0).powi(2)).abs() < 1e-4);
        // Continuous across a cell border.
        let a = g.count_at(0, Vec3::new(0.99999, 0.0, 0.7)).unwrap().0;
        let b = g.count_at(0, Vec3::new(1.00001, 0.0, 0.7)).unwrap().0;
        assert!((a - b).abs() < 0.5, "{a} {b}");
        // A photon that is not counted changes nothing.
        let none = PlaneGrids::count(g.set.clone(), &photons, &tri, GridQuantity::Count, |_| false);
        assert_eq!(none.raw[0].sum(), 0.0);
    }

    #[test]
    fn progressive_schedule_starts_at_n_and_shrinks_the_radius_like_sppm() {
        assert_eq!(progressive_neighbours(100, 0), (100, 100));
        let (n8, k8) = progressive_neighbours(100, 7); // P = 8: n 8^(2/3) = 400, k = 50
        assert_eq!((n8, k8), (400, 50));
        // r_a² ∝ n_all / (P c): 8 passes → 400/(8 c) = half of pass 0's 100/c.
        let r0 = assumed_radius(100, 1.0, 1000.0);
        let r8 = assumed_radius(n8, 1.0, 8000.0);
        assert!(((r8 / r0).powi(2) - 0.5).abs() < 1e-4);
        assert_eq!(progressive_neighbours(1, 1_000_000).1, 1);
    }

    #[test]
    fn plane_without_photons_has_zero_count() {
        let tris = quad(1.0);
        let set = PlaneGrids::detect(&tris, 8);
        let mut g = PlaneGrids::count(set, &[], &[], GridQuantity::Count, |_| true);
        g.filter(Some(Wavelet::Haar), Threshold::Universal { soft: false }, 3);
        assert_eq!(g.count_at(0, Vec3::new(0.5, 0.0, 0.5)).unwrap().0, 0.0);
    }
}
