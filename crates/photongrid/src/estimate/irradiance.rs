//! Irradiance precomputed at a subset of photon positions (Christensen 1999), so that a final
//! gather ray costs one nearest-point lookup instead of a k-nearest-neighbour estimate.

use super::density::irradiance;
use super::photon_map::{faces, PhotonMap};
use super::support::Surfaces;
use crate::photon::store::{oct_decode, oct_encode};
use crate::photon::Photon;
use crate::spatial::{KnnBuffer, PointGrid};
use crate::Rgb;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::f32::consts::PI;

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
    /// Estimate irradiance with `k` neighbours from `map` at `sites` (photons, with the
    /// triangle each landed on). Each estimate divides by the receiving surface inside its
    /// sphere ([`Surfaces::kernel_areas`]), not by πr²: gather rays read these points all over
    /// curved objects and up to the edges of every surface, where πr² darkened the light they
    /// bring (docs/multiscale.md, "Irradiance points divided by the surface under their
    /// discs").
    pub fn build(map: &PhotonMap, sites: &[(Photon, u32)], k: usize, surfaces: &Surfaces, surface_area: f32) -> Self {
        let points: Vec<IrradiancePoint> = sites
            .par_iter()
            .map_init(KnnBuffer::default, |buf, &(p, triangle)| {
                let n = p.normal();
                let g = map.knn(p.pos(), n, k, buf);
                let mut area = [0.0];
                surfaces.kernel_areas(p.pos(), n, triangle, &[g.r2], &mut area);
                let e = irradiance(g.flux, area[0] / PI);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::Accel;
    use crate::photon::PhotonKind;
    use crate::sampling::Rng;
    use crate::scene::Triangle;

    /// A 1 m square lit evenly (1 W/m²): the irradiance points next to its edges and at its
    /// corners read it right, where discs divided by πr² read the edges about a third dark,
    /// and gather rays that land there brought too little light.
    #[test]
    fn points_at_edges_and_corners_read_even_light() {
        let (a, b, c, d) = (Vec3::ZERO, Vec3::Z, Vec3::new(1.0, 0.0, 1.0), Vec3::X);
        let tri = |p: [Vec3; 3]| Triangle {
            p,
            n: [Vec3::Y; 3],
            uv: [Vec2::ZERO; 3],
            material: 0,
        };
        // Both face +y; the first holds the points with x < z.
        let triangles = [tri([a, b, c]), tri([a, c, d])];
        let accel = Accel::build(&triangles);
        let surfaces = Surfaces::of(&triangles, &[true], &accel, 0.5);
        let per_m2 = 400_000.0f32;
        let mut rng = Rng::keyed(21, 0, 0);
        let sites: Vec<(Photon, u32)> = (0..per_m2 as usize)
            .map(|_| {
                let x = Vec3::new(rng.uniform(), 0.0, rng.uniform());
                let power = Rgb::splat(1.0 / per_m2);
                (
                    Photon::new(x, power, Vec3::Y, Vec3::Y, PhotonKind::Indirect),
                    u32::from(x.x >= x.z),
                )
            })
            .collect();
        let map = PhotonMap::build(sites.iter().map(|s| s.0).collect(), 64, 1.0, 0.5);
        let sites: Vec<_> = sites.into_iter().step_by(4).collect();
        let cache = IrradianceCache::build(&map, &sites, 64, &surfaces, 1.0);
        let mut buf = KnnBuffer::default();
        let mut cached = |x: Vec3| crate::luminance(cache.lookup(x, Vec3::Y, &mut buf));
        // Along all four edges, 2 mm in.
        let inward = |u: f32, v: f32, side: usize| {
            let (x, z) = [(u, v), (v, u), (1.0 - u, v), (v, 1.0 - u)][side];
            Vec3::new(x, 0.0, z)
        };
        let edge_points = || (0..800).map(move |i| inward(0.002, 0.05 + 0.9 * (i / 4) as f32 / 200.0, i % 4));
        let edge = mean(edge_points(), &mut cached);
        // About 25 irradiance points lie within 8 mm of a corner (each about 12 % noisy).
        let corner_point = |i: usize| {
            let (u, v) = (0.001 * (i / 4 % 8) as f32, 0.001 * (i / 32 % 8) as f32);
            let (cx, cz) = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)][i % 4];
            Vec3::new((cx - u).abs(), 0.0, (cz - v).abs())
        };
        let corner = mean((0..256).map(corner_point), &mut cached);
        let middle = mean(
            (0..400).map(|i| Vec3::new(0.5, 0.0, 0.05 + 0.9 * i as f32 / 400.0)),
            &mut cached,
        );
        assert!((edge - 1.0).abs() < 0.03, "edge {edge}");
        assert!((corner - 1.0).abs() < 0.08, "corner {corner}");
        assert!((middle - 1.0).abs() < 0.03, "middle {middle}");
        // The same photons divided by πr²: the test can tell.
        let mut buf = KnnBuffer::default();
        let mut flat = |x: Vec3| {
            let g = map.knn(x, Vec3::Y, 64, &mut buf);
            crate::luminance(irradiance(g.flux, g.r2))
        };
        let (flat_edge, flat_corner) = (
            mean(edge_points(), &mut flat),
            mean((0..256).map(corner_point), &mut flat),
        );
        assert!(
            flat_edge < 0.8 && flat_corner < 0.6,
            "πr²: edge {flat_edge}, corner {flat_corner}"
        );
    }

    fn mean(points: impl Iterator<Item = Vec3>, f: &mut dyn FnMut(Vec3) -> f32) -> f32 {
        let e: Vec<f32> = points.map(f).collect();
        e.iter().sum::<f32>() / e.len() as f32
    }
}
