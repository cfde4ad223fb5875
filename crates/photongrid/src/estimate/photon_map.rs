//! The photons of one pass indexed for neighbour queries: k nearest, fixed radius, and the
//! subset of a kNN result within a smaller radius.

use super::density::knn_flux_correction;
use crate::photon::Photon;
use crate::spatial::{KnnBuffer, PointGrid};
use crate::Rgb;
use glam::Vec3;
use rayon::prelude::*;
use std::f32::consts::PI;

/// Photons whose surface normal is further than this from the query's (cosine) belong to
/// another surface (a corner, the other side of a thin wall) and are not gathered.
pub const NORMAL_AGREEMENT: f32 = 0.6;

/// Cell size for a k-neighbour search over photons that may cover only part of the scene
/// (caustics): the covered area is estimated from the cells a sample of photons occupies.
fn cell_size_for(photons: &[Photon], k: usize, surface_area: f32) -> f32 {
    use crate::spatial::suggest_cell_size;
    let n = photons.len().max(1);
    let mut cell = suggest_cell_size(n, surface_area.max(f32::MIN_POSITIVE), k.max(1));
    let stride = (n / 1_000_000).max(1);
    for _ in 0..2 {
        // Distinct cells by sorting (in parallel): a SipHash set of up to a million cells took
        // about a sixth of an index build.
        let mut cells: Vec<[i32; 3]> = photons
            .par_iter()
            .step_by(stride)
            .map(|p| (p.pos() / cell).floor().as_ivec3().to_array())
            .collect();
        cells.par_sort_unstable();
        let occupied = cells.len() - cells.windows(2).filter(|w| w[0] == w[1]).count();
        // Occupied cells bound the covered area; a surface crosses a cell over about cell² · 1.5.
        let covered = occupied as f32 * cell * cell * 1.5;
        let c = suggest_cell_size(n, covered.min(surface_area.max(f32::MIN_POSITIVE)), k.max(1));
        if (c - cell).abs() < 0.1 * cell {
            break;
        }
        cell = c;
    }
    cell
}

/// Flux gathered around a point.
#[derive(Clone, Copy, Debug, Default)]
pub struct Gather {
    /// Σ Φ of the photons used (already scaled for the k-th-photon bias, see [`PhotonMap::knn`]).
    pub flux: Rgb,
    /// Squared radius of the gather disc; where the estimate knows the surface the disc covers
    /// ([`PhotonMap::adaptive_knn`]), the squared radius of a disc of that area.
    pub r2: f32,
    /// Photons used.
    pub count: usize,
    /// True when the estimate leaves out indirect light, which final gathering must then add
    /// (the methods that show only caustics at visible points when gathering); false when the
    /// estimate already includes it.
    pub needs_gathering: bool,
}

/// How far, in mean kNN radii (the radius holding k photons at the map's mean density over the
/// surfaces it covers), a query may grow. Where photons are sparser than that (small objects,
/// shadows, dim corners) the estimate uses the photons within this reach: a wider search
/// scanned photons of other surfaces for most of a camera pass on scenes of small objects
/// without changing the image (docs/time_budget.md).
pub const SPARSE_REACH: f32 = 3.0;

/// Lepski's rule for nested kNN discs: whether a narrow disc's estimate `e_narrow` (of
/// `n_narrow` photons) is consistent with the wider disc's `e_wide` (`n_wide` photons) if the
/// light were flat. A kNN estimate's disc area is Gamma-distributed, so the test is on the
/// logarithm, whose spread is then the same for a narrow disc that by chance holds few photons
/// and one that holds many (ln Γ(n) has variance ψ₁(n) ≈ 1/(n − ½)); nested discs share
/// photons, so the log-ratio's variance is the difference of the two.
pub fn lepski_agrees(e_narrow: f32, n_narrow: usize, e_wide: f32, n_wide: usize, gamma: f32) -> bool {
    if !(e_narrow > 0.0 && e_wide > 0.0) {
        return e_narrow == e_wide;
    }
    let trigamma = |n: usize| 1.0 / (n as f32 - 0.5).max(0.5);
    let spread = (trigamma(n_narrow) - trigamma(n_wide)).max(0.0).sqrt();
    (e_narrow / e_wide).ln().abs() <= gamma * spread
}

/// The photons of one render, indexed for neighbour queries.
pub struct PhotonMap {
    grid: PointGrid<Photon>,
    /// Largest radius a query may grow to (m).
    pub max_radius: f32,
}

/// The photons of the adaptive search's narrowest disc: discs of 8 stopped the widening by
/// chance often enough to speckle flat light (docs/multiscale.md).
pub const ADAPTIVE_MIN_NEIGHBOURS: usize = 16;

/// Lepski's threshold for the adaptive search (standard deviations of the log-ratio): each
/// point tests up to about 20 pairs of discs, so a narrower one stops flat light too often.
pub const LEPSKI_GAMMA: f32 = 3.0;

/// Whether a point recorded on a surface with unit normal `n` may count for a query on a
/// surface with unit `normal`: the one test of photon and irradiance lookups.
pub(crate) fn faces(n: Vec3, normal: Vec3) -> bool {
    n.dot(normal) > NORMAL_AGREEMENT
}

impl PhotonMap {
    /// Index `photons` with cells sized for `k` neighbours on `surface_area` m². Queries grow
    /// to `max_radius` at most, and to [`SPARSE_REACH`] times the mean kNN radius.
    pub fn build(photons: Vec<Photon>, k: usize, surface_area: f32, max_radius: f32) -> Self {
        let mean = cell_size_for(&photons, k, surface_area);
        let max_radius = max_radius.min(SPARSE_REACH * mean).max(f32::MIN_POSITIVE);
        PhotonMap {
            grid: PointGrid::build(photons, mean.min(max_radius)),
            max_radius,
        }
    }

    /// Number of photons indexed.
    pub fn len(&self) -> usize {
        self.grid.len()
    }

    /// True if the map holds no photons.
    pub fn is_empty(&self) -> bool {
        self.grid.is_empty()
    }

    /// Approximate memory of the index and photons.
    pub fn memory_bytes(&self) -> usize {
        self.grid.memory_bytes()
    }

    /// The kNN filter: [`faces`] without normalising each photon's decoded normal (a square
    /// root and a division per photon met took a seventh of a camera pass over small objects).
    fn accepts(&self, p: &Photon, normal: Vec3) -> bool {
        p.faces(normal)
    }

    /// All photons, in index order.
    pub fn photons(&self) -> &[Photon] {
        self.grid.items()
    }

    /// k-nearest-neighbour gather at `x` on a surface with unit `normal`; the flux is scaled by
    /// [`knn_flux_correction`] when k photons were found. `buf` keeps the photons found.
    pub fn knn(&self, x: Vec3, normal: Vec3, k: usize, buf: &mut KnnBuffer) -> Gather {
        let r2 = self.grid.knn(x, k, self.max_radius, |p| self.accepts(p, normal), buf);
        let items = self.grid.items();
        let found = buf.as_slice();
        let mut flux: Rgb = found.iter().map(|&(i, _)| items[i as usize].power()).sum();
        if found.len() >= k {
            flux *= knn_flux_correction(k);
        }
        Gather {
            flux,
            r2,
            count: found.len(),
            needs_gathering: false,
        }
    }

    /// The widest of nested discs of the `k_max` nearest photons (holding
    /// [`ADAPTIVE_MIN_NEIGHBOURS`], twice as many, … photons and all `k_max`) whose estimate
    /// agrees with every narrower one's ([`lepski_agrees`]). Where the light is flat the disc
    /// grows to `k_max` photons (less noise than a fixed k); across a caustic's edge or a
    /// filament it stops at a few (sharp). For surfaces no plane grid covers. A disc narrower
    /// than `min_radius` (a camera pixel's footprint) is replaced by the disc of that radius:
    /// fixed-radius discs spread each photon's power over exactly its disc, where kNN discs
    /// next to a line of light finer than a pixel count it again and again (up to twice the
    /// line's power in the pixel holding it).
    ///
    /// `area` gives the surface each disc covers (for squared radii, their areas:
    /// [`super::support::Surfaces::kernel_areas`], or [`super::support::flat_disc_areas`]);
    /// estimates divide by it, and the result's `r2` is that area over π.
    pub fn adaptive_knn(
        &self,
        x: Vec3,
        normal: Vec3,
        (k_max, min_radius): (usize, f32),
        area: &dyn Fn(&[f32], &mut [f32]),
        buf: &mut KnnBuffer,
    ) -> Gather {
        let (mut g, mut a) = self.adaptive_knn_discs(x, normal, k_max, area, buf);
        if g.r2 < min_radius * min_radius {
            g = self.within(x, normal, min_radius);
            let mut one = [0.0];
            area(&[g.r2], &mut one);
            a = one[0];
        }
        Gather { r2: a / PI, ..g }
    }

    /// The chosen disc (its real radius) and its area on the surface.
    fn adaptive_knn_discs(
        &self,
        x: Vec3,
        normal: Vec3,
        k_max: usize,
        area: &dyn Fn(&[f32], &mut [f32]),
        buf: &mut KnnBuffer,
    ) -> (Gather, f32) {
        let r2_search = self
            .grid
            .knn(x, k_max, self.max_radius, |p| self.accepts(p, normal), buf);
        let items = self.grid.items();
        let found = buf.sorted();
        let full = found.len() >= k_max;
        if found.len() <= ADAPTIVE_MIN_NEIGHBOURS {
            // No photon, no light: the area would not change the estimate.
            let mut one = [PI * r2_search];
            if !found.is_empty() {
                area(&[r2_search], &mut one);
            }
            let g = Gather {
                flux: found.iter().map(|&(i, _)| items[i as usize].power()).sum(),
                r2: r2_search,
                count: found.len(),
                needs_gathering: false,
            };
            return (g, one[0]);
        }
        let mut flux = Rgb::ZERO;
        // (flux, squared radius, photons) of each disc, narrowest first.
        let mut discs: [(Rgb, f32, usize); 24] = [(Rgb::ZERO, 0.0, 0); 24];
        let mut m = 0;
        let mut next = ADAPTIVE_MIN_NEIGHBOURS;
        for (n, &(i, d2)) in found.iter().enumerate() {
            flux += items[i as usize].power();
            let n = n + 1;
            let last = n == found.len();
            if (n == next || last) && m < discs.len() {
                // The n-th photon bounds the disc (knn_flux_correction); the last disc of a
                // search that stopped short is the search's own radius.
                discs[m] = if last && !full {
                    (flux, r2_search, n)
                } else {
                    (flux * knn_flux_correction(n), d2, n)
                };
                m += 1;
                next *= 2;
            }
        }
        let (mut r2, mut areas) = ([0.0f32; 24], [0.0f32; 24]);
        for (r2, d) in r2.iter_mut().zip(&discs[..m]) {
            *r2 = d.1;
        }
        area(&r2[..m], &mut areas[..m]);
        let e = |j: usize| crate::luminance(discs[j].0) / areas[j].max(1e-30);
        let mut best = 0;
        for j in 1..m {
            let (ej, nj) = (e(j), discs[j].2);
            if !(0..j).all(|f| lepski_agrees(e(f), discs[f].2, ej, nj, LEPSKI_GAMMA)) {
                break;
            }
            best = j;
        }
        let (flux, r2, count) = discs[best];
        let g = Gather {
            flux,
            r2,
            count,
            needs_gathering: false,
        };
        (g, areas[best])
    }

    /// The photons of the last [`PhotonMap::knn`] result in `buf` that lie within `r` (≤ the
    /// kNN radius): a smaller disc without a second search.
    pub fn knn_within(&self, buf: &KnnBuffer, r: f32) -> Gather {
        let items = self.grid.items();
        let r2 = r * r;
        let mut g = Gather {
            r2,
            ..Default::default()
        };
        for &(i, d2) in buf.as_slice() {
            if d2 <= r2 {
                g.flux += items[i as usize].power();
                g.count += 1;
            }
        }
        g
    }

    /// Fixed-radius gather (all accepted photons within `r`).
    pub fn within(&self, x: Vec3, normal: Vec3, r: f32) -> Gather {
        let mut g = Gather {
            r2: r * r,
            ..Default::default()
        };
        self.grid.for_each_within(x, r, |p, _| {
            if self.accepts(p, normal) {
                g.flux += p.power();
                g.count += 1;
            }
        });
        g
    }
}

#[cfg(test)]
mod tests {
    use super::super::support::flat_disc_areas;
    use super::*;
    use crate::photon::PhotonKind;
    use crate::sampling::Rng;

    /// A photon of `power` W on the plane y = 0, arriving from above.
    fn photon(x: f32, z: f32, power: f32) -> Photon {
        Photon::new(
            Vec3::new(x, 0.0, z),
            Rgb::splat(power),
            Vec3::Y,
            Vec3::Y,
            PhotonKind::Caustic,
        )
    }

    /// Photons uniform over the square x, z ∈ [-1, 1] of the plane y = 0, `per_m2` per m² where
    /// `lit(x)`, carrying 1 W/m² there; and that irradiance.
    fn map(per_m2: f32, lit: impl Fn(f32) -> bool) -> (PhotonMap, f32) {
        let n = (4.0 * per_m2) as usize;
        let mut rng = Rng::keyed(7, 0, 0);
        let power = 1.0 / per_m2;
        let photons: Vec<Photon> = (0..n)
            .filter_map(|_| {
                let (x, z) = (rng.uniform() * 2.0 - 1.0, rng.uniform() * 2.0 - 1.0);
                lit(x).then(|| photon(x, z, power))
            })
            .collect();
        (PhotonMap::build(photons, 100, 4.0, 0.5), 1.0)
    }

    fn irradiance(g: &Gather) -> f32 {
        crate::luminance(g.flux) / (PI * g.r2)
    }

    /// Flat light: the discs grow to the widest, whose estimate is as right and less noisy
    /// than k = 100's.
    #[test]
    fn flat_light_gathers_the_widest_disc() {
        let (m, truth) = map(40_000.0, |_| true);
        let mut buf = KnnBuffer::new();
        let (mut se_fixed, mut se_adaptive, mut n, mut widest) = (0.0f32, 0.0f32, 0, 0);
        for i in 0..40 {
            let x = Vec3::new(-0.5 + 0.025 * i as f32, 0.0, 0.1 * (i % 7) as f32 - 0.3);
            let a = m.adaptive_knn(x, Vec3::Y, (400, 0.0), &flat_disc_areas, &mut buf);
            widest += (a.count == 400) as usize;
            let k = m.knn(x, Vec3::Y, 100, &mut buf);
            se_fixed += (irradiance(&k) - truth).powi(2);
            se_adaptive += (irradiance(&a) - truth).powi(2);
            n += 1;
        }
        let (rmse_fixed, rmse_adaptive) = ((se_fixed / n as f32).sqrt(), (se_adaptive / n as f32).sqrt());
        // A narrow disc's estimate now and then falls outside a wide one's interval.
        assert!(widest >= 30, "{widest} of {n} at the widest disc");
        // k = 100 has about 10 % noise, k = 400 about 5 %.
        assert!(rmse_adaptive < 0.7 * rmse_fixed, "{rmse_adaptive} vs {rmse_fixed}");
        assert!(rmse_adaptive < 0.08, "{rmse_adaptive}");
    }

    /// A caustic filament 4 cm wide, ten times as bright as the light around it: a k = 100
    /// disc is wider than the filament and reads it at about half its brightness; the adaptive
    /// discs stop inside it.
    #[test]
    fn a_filament_stops_the_widening() {
        let (bg, width) = (4_000.0, 0.04);
        let mut rng = Rng::keyed(11, 0, 0);
        let power = 1.0 / bg;
        let mut photons = Vec::new();
        for _ in 0..(4.0 * bg) as usize {
            let (x, z) = (rng.uniform() * 2.0 - 1.0, rng.uniform() * 2.0 - 1.0);
            photons.push(photon(x, z, power));
        }
        for _ in 0..(9.0 * bg * 2.0 * width) as usize {
            let (x, z) = ((rng.uniform() - 0.5) * width, rng.uniform() * 2.0 - 1.0);
            photons.push(photon(x, z, power));
        }
        let m = PhotonMap::build(photons, 100, 4.0, 0.5);
        let truth = 10.0;
        let mut buf = KnnBuffer::new();
        let (mut fixed, mut adaptive, mut n) = (0.0f32, 0.0f32, 0);
        for i in 0..60 {
            let x = Vec3::new(0.0, 0.0, -0.6 + 0.02 * i as f32);
            adaptive += irradiance(&m.adaptive_knn(x, Vec3::Y, (400, 0.0), &flat_disc_areas, &mut buf));
            fixed += irradiance(&m.knn(x, Vec3::Y, 100, &mut buf));
            n += 1;
        }
        let (fixed, adaptive) = (fixed / n as f32 / truth, adaptive / n as f32 / truth);
        assert!(fixed < 0.8, "k = 100 is expected to blur the filament: {fixed}");
        assert!(
            adaptive > 0.85 && adaptive < 1.1,
            "adaptive {adaptive} (k = 100: {fixed})"
        );
    }

    /// Where a search finds fewer photons than the finest disc holds, the estimate is the
    /// search's own (the photons within the largest radius).
    #[test]
    fn sparse_photons_keep_the_search_radius() {
        // Five photons in all.
        let (m, _) = map(1.25, |_| true);
        let mut buf = KnnBuffer::new();
        let a = m.adaptive_knn(Vec3::ZERO, Vec3::Y, (400, 0.0), &flat_disc_areas, &mut buf);
        let k = m.knn(Vec3::ZERO, Vec3::Y, 400, &mut buf);
        assert!(
            a.count <= ADAPTIVE_MIN_NEIGHBOURS && a.count == k.count && (a.r2 / k.r2 - 1.0).abs() < 1e-6,
            "{a:?} {k:?}"
        );
    }

    /// A line of light finer than a pixel: the irradiance integrated across it is the line's
    /// power per unit length when no disc is narrower than the pixel's footprint, and far more
    /// with kNN discs (each point beside the line counts the line's photons again).
    #[test]
    fn a_line_finer_than_the_footprint_keeps_its_power() {
        let mut rng = Rng::keyed(3, 0, 0);
        let n = 200_000;
        // 1 W over 2 m of a line 1 mm wide: 0.5 W/m.
        let photons: Vec<Photon> = (0..n)
            .map(|_| photon((rng.uniform() - 0.5) * 1e-3, rng.uniform() * 2.0 - 1.0, 1.0 / n as f32))
            .collect();
        let m = PhotonMap::build(photons, 100, 0.002, 0.5);
        let mut buf = KnnBuffer::new();
        let across = |footprint: f32, buf: &mut KnnBuffer| -> f32 {
            let dx = 2.5e-4;
            (-200..=200)
                .map(|i| {
                    irradiance(&m.adaptive_knn(
                        Vec3::new(i as f32 * dx, 0.0, 0.0),
                        Vec3::Y,
                        (100, footprint),
                        &flat_disc_areas,
                        buf,
                    )) * dx
                })
                .sum()
        };
        let floored = across(5e-3, &mut buf);
        let knn = across(0.0, &mut buf);
        assert!((floored / 0.5 - 1.0).abs() < 0.03, "with the footprint: {floored} W/m");
        assert!(knn / 0.5 > 1.3, "kNN discs: {knn} W/m");
    }
}
