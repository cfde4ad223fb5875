//! Radiance from photons: the density estimate of METHOD.md eq. (1) over a photon map.

use crate::photon::neighbours::{KnnBuffer, PointGrid};
use crate::photon::{Photon, PhotonKind};
use crate::Rgb;
use glam::Vec3;
use std::f32::consts::PI;

/// Photons whose surface normal is further than this from the query's (cosine) belong to
/// another surface (a corner, the other side of a thin wall) and are not gathered.
pub const NORMAL_AGREEMENT: f32 = 0.6;

/// Eq. (1) for a Lambert receiver: `L = (albedo/π) Σ Φ_p / (π r²)`, with the flux sum given.
pub fn density_radiance(albedo: Rgb, flux_sum: Rgb, r2: f32) -> Rgb {
    if r2 <= 0.0 {
        return Rgb::ZERO;
    }
    albedo * std::f32::consts::FRAC_1_PI * flux_sum / (PI * r2)
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
}

/// The photons of one render, indexed for neighbour queries.
pub struct PhotonMap {
    grid: PointGrid<Photon>,
    /// Largest radius a query may grow to (m).
    pub max_radius: f32,
    /// Whether direct-light photons take part in estimates.
    pub include_direct: bool,
}

impl PhotonMap {
    /// Index `photons` with cells sized for `k` neighbours on `surface_area` m².
    pub fn build(photons: Vec<Photon>, k: usize, surface_area: f32, max_radius: f32, include_direct: bool) -> Self {
        let n = photons.len().max(1);
        let cell =
            crate::photon::neighbours::suggest_cell_size(n, surface_area.max(1e-6), k.max(1)).min(max_radius.max(1e-6));
        PhotonMap {
            grid: PointGrid::build(photons, cell),
            max_radius,
            include_direct,
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

    /// The underlying index.
    pub fn grid(&self) -> &PointGrid<Photon> {
        &self.grid
    }

    fn accepts(&self, p: &Photon, normal: Vec3) -> bool {
        (self.include_direct || p.kind() != PhotonKind::Direct) && p.normal().dot(normal) > NORMAL_AGREEMENT
    }

    /// k-nearest-neighbour gather at `x` on a surface with unit `normal`.
    ///
    /// With the k-th photon on the disc's edge, `Σ_k Φ / (π r_k²)` overestimates a uniform
    /// density by k/(k−1) (E[1/r_k²] for a Poisson process); the flux is scaled by (k−1)/k.
    pub fn knn(&self, x: Vec3, normal: Vec3, k: usize, buf: &mut KnnBuffer) -> Gather {
        let r2 = self.grid.knn(x, k, self.max_radius, |p| self.accepts(p, normal), buf);
        let items = self.grid.items();
        let found = buf.as_slice();
        let mut flux: Rgb = found.iter().map(|&(i, _)| items[i as usize].power()).sum();
        if found.len() >= k && k > 1 {
            flux *= (k - 1) as f32 / k as f32;
        }
        Gather {
            flux,
            r2,
            count: found.len(),
        }
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
