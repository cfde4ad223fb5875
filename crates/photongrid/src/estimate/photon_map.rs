//! The photons of one pass indexed for neighbour queries: k nearest, fixed radius, and the
//! subset of a kNN result within a smaller radius.

use super::density::knn_flux_correction;
use crate::photon::Photon;
use crate::spatial::{KnnBuffer, PointGrid};
use crate::Rgb;
use glam::Vec3;

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
        let occupied: std::collections::HashSet<[i32; 3]> = photons
            .iter()
            .step_by(stride)
            .map(|p| (p.pos() / cell).floor().as_ivec3().to_array())
            .collect();
        // Occupied cells bound the covered area; a surface crosses a cell over about cell² · 1.5.
        let covered = occupied.len() as f32 * cell * cell * 1.5;
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
    /// Squared radius of the gather disc.
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

/// The photons of one render, indexed for neighbour queries.
pub struct PhotonMap {
    grid: PointGrid<Photon>,
    /// Largest radius a query may grow to (m).
    pub max_radius: f32,
}

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

    fn accepts(&self, p: &Photon, normal: Vec3) -> bool {
        faces(p.normal(), normal)
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
