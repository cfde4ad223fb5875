//! Irradiance precomputed at a subset of photon positions (Christensen 1999), so that a final
//! gather ray costs one nearest-point lookup instead of a k-nearest-neighbour estimate.

use super::density::irradiance;
use super::photon_map::{faces, PhotonMap};
use crate::photon::store::{oct_decode, oct_encode};
use crate::photon::Photon;
use crate::spatial::{KnnBuffer, PointGrid};
use crate::Rgb;
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// An irradiance sample on a surface.
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
        let sites: Vec<Photon> = map.photons().iter().step_by(stride.max(1)).copied().collect();
        Self::build_at(map, &sites, k, surface_area)
    }

    /// Estimate irradiance with `k` neighbours from `map` at the positions of `sites`.
    pub fn build_at(map: &PhotonMap, sites: &[Photon], k: usize, surface_area: f32) -> Self {
        let points: Vec<IrradiancePoint> = sites
            .par_iter()
            .map_init(KnnBuffer::default, |buf, p| {
                let n = p.normal();
                let g = map.knn(p.pos(), n, k, buf);
                let e = irradiance(g.flux, g.r2);
                let o = oct_encode(n) * i16::MAX as f32;
                IrradiancePoint {
                    position: p.position,
                    normal: [o.x as i16, o.y as i16],
                    irradiance: e.to_array(),
                }
            })
            .collect();
        let n = points.len().max(1);
        let cell = crate::spatial::suggest_cell_size(n, surface_area.max(f32::MIN_POSITIVE), 8).min(map.max_radius);
        IrradianceCache {
            grid: PointGrid::build(points, cell),
            max_radius: map.max_radius,
        }
    }

    /// Irradiance at the nearest point on a surface facing the same way (zero if none near).
    pub fn lookup(&self, x: Vec3, normal: Vec3, buf: &mut KnnBuffer) -> Rgb {
        self.grid.knn(x, 1, self.max_radius, |p| faces(p.normal(), normal), buf);
        match buf.as_slice().first() {
            Some(&(i, _)) => Rgb::from(self.grid.items()[i as usize].irradiance),
            None => Rgb::ZERO,
        }
    }
}
