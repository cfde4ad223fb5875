//! Radiance from photons: the density estimate of METHOD.md eq. (1) over a photon map.

use crate::photon::store::{oct_decode, oct_encode};
use crate::photon::Photon;
use crate::spatial::{KnnBuffer, PointGrid};
use crate::Rgb;
use glam::Vec2;
use glam::Vec3;
use rayon::prelude::*;
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

/// Cell size for a k-neighbour search over photons that may cover only part of the scene
/// (caustics): the covered area is estimated from the cells a sample of photons occupies.
fn cell_size_for(photons: &[Photon], k: usize, surface_area: f32) -> f32 {
    use crate::spatial::suggest_cell_size;
    let n = photons.len().max(1);
    let mut cell = suggest_cell_size(n, surface_area.max(1e-6), k.max(1));
    let stride = (n / 1_000_000).max(1);
    for _ in 0..2 {
        let occupied: std::collections::HashSet<[i32; 3]> = photons
            .iter()
            .step_by(stride)
            .map(|p| (p.pos() / cell).floor().as_ivec3().to_array())
            .collect();
        // Occupied cells bound the covered area; a surface crosses a cell over about cell² · 1.5.
        let covered = occupied.len() as f32 * cell * cell * 1.5;
        let c = suggest_cell_size(n, covered.min(surface_area.max(1e-6)), k.max(1));
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
}

/// The photons of one render, indexed for neighbour queries.
pub struct PhotonMap {
    grid: PointGrid<Photon>,
    /// Largest radius a query may grow to (m).
    pub max_radius: f32,
}

impl PhotonMap {
    /// Index `photons` with cells sized for `k` neighbours on `surface_area` m².
    pub fn build(photons: Vec<Photon>, k: usize, surface_area: f32, max_radius: f32) -> Self {
        let cell = cell_size_for(&photons, k, surface_area).min(max_radius.max(1e-6));
        PhotonMap {
            grid: PointGrid::build(photons, cell),
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

    /// The underlying index.
    pub fn grid(&self) -> &PointGrid<Photon> {
        &self.grid
    }

    fn accepts(&self, p: &Photon, normal: Vec3) -> bool {
        p.normal().dot(normal) > NORMAL_AGREEMENT
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

/// Irradiance precomputed at a subset of photon positions (Christensen 1999), so that a final
/// gather ray costs one nearest-point lookup instead of a k-nearest-neighbour estimate.
#[derive(Clone, Copy, Debug)]
pub struct IrradiancePoint {
    position: [f32; 3],
    normal: [i16; 2],
    /// Irradiance [W/m²] per channel.
    pub irradiance: [f32; 3],
}

impl crate::spatial::Positioned for IrradiancePoint {
    #[inline]
    fn position(&self) -> Vec3 {
        Vec3::from(self.position)
    }
}

impl IrradiancePoint {
    fn normal(&self) -> Vec3 {
        oct_decode(Vec2::new(self.normal[0] as f32, self.normal[1] as f32) / i16::MAX as f32)
    }
}

/// The precomputed irradiance points, indexed for nearest lookups.
pub struct IrradianceCache {
    grid: PointGrid<IrradiancePoint>,
    max_radius: f32,
}

impl IrradianceCache {
    /// Estimate irradiance with `k` neighbours at every `stride`-th photon of `map`.
    pub fn build(map: &PhotonMap, k: usize, stride: usize, surface_area: f32) -> Self {
        let photons = map.grid.items();
        let points: Vec<IrradiancePoint> = photons
            .par_iter()
            .step_by(stride.max(1))
            .map_init(KnnBuffer::default, |buf, p| {
                let n = p.normal();
                let g = map.knn(p.pos(), n, k, buf);
                let e = if g.r2 > 0.0 { g.flux / (PI * g.r2) } else { Rgb::ZERO };
                let o = oct_encode(n) * i16::MAX as f32;
                IrradiancePoint {
                    position: p.position,
                    normal: [o.x as i16, o.y as i16],
                    irradiance: e.to_array(),
                }
            })
            .collect();
        let n = points.len().max(1);
        let cell = crate::spatial::suggest_cell_size(n, surface_area.max(1e-6), 8).min(map.max_radius);
        IrradianceCache {
            grid: PointGrid::build(points, cell),
            max_radius: map.max_radius,
        }
    }

    /// Irradiance at the nearest point on a surface facing the same way (zero if none near).
    pub fn lookup(&self, x: Vec3, normal: Vec3, buf: &mut KnnBuffer) -> Rgb {
        self.grid.knn(
            x,
            1,
            self.max_radius,
            |p| p.normal().dot(normal) > NORMAL_AGREEMENT,
            buf,
        );
        match buf.as_slice().first() {
            Some(&(i, _)) => Rgb::from(self.grid.items()[i as usize].irradiance),
            None => Rgb::ZERO,
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.grid.len()
    }

    /// True if there are no points.
    pub fn is_empty(&self) -> bool {
        self.grid.is_empty()
    }

    /// Approximate memory.
    pub fn memory_bytes(&self) -> usize {
        self.grid.memory_bytes()
    }
}
