//! The paper's photon-count textures: one per plane, counted from the photons that landed on
//! the plane's triangles, wavelet-filtered, read back with bilinear interpolation.

use super::planes::{detect_planes, PlaneParams, PlaneSet, NO_PLANE};
use super::wavelet::{denoise_counts, max_levels, DenoiseReport, Field2, Threshold, Wavelet};
use crate::photon::Photon;
use crate::settings::GridQuantity;
use glam::Vec3;
use rayon::prelude::*;

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

    /// Find planes among the triangles that receive photons: mirrors and glass store none, so
    /// they get no grid. Triangle indices are the scene's.
    pub fn detect_receivers(scene: &crate::scene::Scene, resolution: usize) -> PlaneSet {
        let receivers: Vec<u32> = (0..scene.triangles.len() as u32)
            .filter(|&t| scene.materials[scene.triangles[t as usize].material as usize].receives_photons())
            .collect();
        let tris: Vec<[Vec3; 3]> = receivers.iter().map(|&t| scene.triangles[t as usize].p).collect();
        let mut set = detect_planes(&tris, &PlaneParams::default().with_resolution(resolution));
        let mut of_triangle = vec![NO_PLANE; scene.triangles.len()];
        for (i, &t) in receivers.iter().enumerate() {
            of_triangle[t as usize] = set.plane_of_triangle[i];
        }
        set.plane_of_triangle = of_triangle;
        for p in &mut set.planes {
            for t in &mut p.triangles {
                *t = receivers[*t as usize];
            }
        }
        set
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
    fn plane_without_photons_has_zero_count() {
        let tris = quad(1.0);
        let set = PlaneGrids::detect(&tris, 8);
        let mut g = PlaneGrids::count(set, &[], &[], GridQuantity::Count, |_| true);
        g.filter(Some(Wavelet::Haar), Threshold::Universal { soft: false }, 3);
        assert_eq!(g.count_at(0, Vec3::new(0.5, 0.0, 0.5)).unwrap().0, 0.0);
    }
}
