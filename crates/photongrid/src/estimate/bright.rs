//! Bright surfaces for final gathering: the planes' resolved irradiance read as a
//! distribution over texels in proportion to the light they reflect, so that some gather rays
//! are aimed at where the light is. A cosine-distributed gather ray that happens upon a small,
//! very bright patch (the ceiling right above a point light) makes a white speck; aimed rays
//! find it at a rate that matches its share of the light. The camera pass weights both kinds
//! by multiple importance sampling (Veach's balance heuristic).
//!
//! A plane is chosen first, per gathering point, by its light over its squared distance and
//! only where its lit side can reach the point at all (as a light tree's node would be); then
//! a texel of it in proportion to its light, then a point uniform in the texel.

use crate::grid::multiscale::{MultiscaleGrids, DIRECT, LAYERS};
use crate::sampling::Distribution;
use crate::Rgb;
use glam::{Vec2, Vec3};

/// Texels darker than this share of their plane's brightest are never aimed at: the balance
/// heuristic leaves them to cosine-distributed rays, which find them as often as aimed ones.
const DIM_SHARE: f32 = 1e-3;

/// Most planes aimed at (the brightest): choosing among them costs a few operations per plane
/// and gathering point.
pub const MAX_AIMED_PLANES: usize = 64;

/// Planes with less than this share of the brightest plane's light are not aimed at.
const DIM_PLANE_SHARE: f32 = 1e-3;

/// One plane's texels: the resolved grid of its direct-light layer.
#[derive(Clone, Debug)]
struct PlaneTexels {
    /// Index of the plane in the grids.
    plane: usize,
    /// World position of grid coordinates (0, 0).
    origin: Vec3,
    /// Unit axes of the grid.
    u: Vec3,
    v: Vec3,
    /// The side the plane's light leaves from.
    normal: Vec3,
    /// A texel's sides (m).
    size_u: f32,
    size_v: f32,
    /// Texels along u and v.
    w: usize,
    h: usize,
    /// The grid's corners.
    corners: [Vec3; 4],
    /// Where its light is, on average (weighted by the texels' light).
    centre: Vec3,
    /// Area of the grid (m²).
    area: f32,
    /// Its texels by their light.
    texels: Distribution,
}

impl PlaneTexels {
    /// The texel under `p`, if `p` projects into the grid.
    fn texel_at(&self, p: Vec3) -> Option<usize> {
        let d = p - self.origin;
        let (x, y) = (d.dot(self.u) / self.size_u, d.dot(self.v) / self.size_v);
        // Negative and NaN coordinates are outside.
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (i, j) = (x as usize, y as usize);
        (i < self.w && j < self.h).then_some(j * self.w + i)
    }

    /// How much of its light may reach a point `x` with normal `n`, for choosing among planes:
    /// zero where no point of its lit side is in front of `x` or `x` is not in front of it
    /// (exact: the plane is flat and its grid convex), else its light over the squared
    /// distance to where its light is (at least its area).
    fn reach(&self, x: Vec3, n: Vec3) -> f32 {
        if (x - self.origin).dot(self.normal) <= 0.0 || !self.corners.iter().any(|&c| (c - x).dot(n) > 0.0) {
            return 0.0;
        }
        self.texels.total() / (self.centre - x).length_squared().max(self.area)
    }

    /// Probability of texel `i` within the plane (a difference of running sums: exactly what
    /// sampling does) over its area.
    fn texel_pdf(&self, i: usize) -> f32 {
        self.texels.weight(i) / self.texels.total() / (self.size_u * self.size_v)
    }
}

/// A point aimed at on a bright plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrightSample {
    /// The plane (index into the grids' planes).
    pub plane: usize,
    /// The point, uniform within its texel.
    pub point: Vec3,
    /// The side of the plane its light leaves from.
    pub normal: Vec3,
    /// Probability density of the point per unit area.
    pub pdf_area: f32,
}

/// The brightest planes' texels, chosen in proportion to their resolved irradiance (all
/// layers) times the surface they cover.
#[derive(Clone, Debug)]
pub struct BrightTexels {
    /// The planes aimed at, brightest first.
    planes: Vec<PlaneTexels>,
    /// Per plane of the grids, its place in `planes`.
    slot: Vec<Option<usize>>,
    /// Share of the global photons' light that lands on the planes.
    plane_share: f32,
}

/// How a gathering point chooses among the planes ([`BrightTexels::aim`]).
#[derive(Clone, Debug, Default)]
pub struct Aim {
    /// Per aimed plane, its weight.
    weights: Vec<f32>,
    total: f32,
}

impl Aim {
    /// Whether any plane can be aimed at.
    pub fn any(&self) -> bool {
        self.total > 0.0
    }
}

impl BrightTexels {
    /// The distribution over the planes' resolved texels (call after the grids are resolved
    /// for gathering); None when no plane holds light.
    pub fn build(grids: &MultiscaleGrids) -> Option<Self> {
        let mut planes: Vec<PlaneTexels> = (0..grids.textures.len())
            .filter_map(|k| plane_texels(grids, k))
            .collect();
        planes.sort_by(|a, b| b.texels.total().total_cmp(&a.texels.total()));
        let brightest = planes.first()?.texels.total();
        planes.retain(|p| p.texels.total() >= DIM_PLANE_SHARE * brightest);
        planes.truncate(MAX_AIMED_PLANES);
        let mut slot = vec![None; grids.textures.len()];
        for (i, p) in planes.iter().enumerate() {
            slot[p.plane] = Some(i);
        }
        Some(BrightTexels {
            planes,
            slot,
            plane_share: grids.plane_power_share,
        })
    }

    /// How many of `n` gather rays to aim when `share` of them would be aimed if the planes
    /// held all the light: in proportion to the share of the light they hold (off the planes
    /// aimed rays find little: curved_3d's trough), and at least one ray spread.
    pub fn aimed_rays(&self, n: u32, share: f32) -> u32 {
        ((n as f32 * share * self.plane_share).round() as u32).min(n.saturating_sub(1))
    }

    /// For reports: how many planes are aimed at and how much of the light they hold.
    pub fn describe(&self) -> String {
        format!(
            "final gathering aims at {} bright plane(s); the planes hold {:.1} % of the global photons' light, \
             so that share of --gather-bright's rays is aimed (at least one ray of each sample is spread)",
            self.planes.len(),
            100.0 * self.plane_share
        )
    }

    /// The planes' weights seen from a gathering point `x` with normal `n` (into `aim`).
    pub fn aim(&self, x: Vec3, n: Vec3, aim: &mut Aim) {
        aim.weights.clear();
        aim.weights.extend(self.planes.iter().map(|p| p.reach(x, n)));
        aim.total = aim.weights.iter().sum();
    }

    /// A point aimed at from where `aim` was made: a plane and a texel chosen by `u`, a
    /// uniform point within the texel by `uv`. None if `aim` has no plane.
    pub fn sample(&self, aim: &Aim, u: f32, uv: Vec2) -> Option<BrightSample> {
        if !(aim.total > 0.0) {
            return None;
        }
        // One number picks the plane, then (rescaled) the texel.
        let mut x = u * aim.total;
        let mut k = aim.weights.len() - 1;
        for (i, &w) in aim.weights.iter().enumerate() {
            if x < w {
                k = i;
                break;
            }
            x -= w;
        }
        while aim.weights[k] <= 0.0 {
            k -= 1;
        }
        let p = &self.planes[k];
        let t = p.texels.sample((x / aim.weights[k]).clamp(0.0, 1.0 - f32::EPSILON));
        let (gx, gy) = ((t % p.w) as f32 + uv.x, (t / p.w) as f32 + uv.y);
        Some(BrightSample {
            plane: p.plane,
            point: p.origin + p.u * (gx * p.size_u) + p.v * (gy * p.size_v),
            normal: p.normal,
            pdf_area: aim.weights[k] / aim.total * p.texel_pdf(t),
        })
    }

    /// The density per unit area with which [`BrightTexels::sample`] picks `point` on grid
    /// plane `plane`, from where `aim` was made.
    pub fn pdf_area(&self, aim: &Aim, plane: usize, point: Vec3) -> f32 {
        let Some(&Some(k)) = self.slot.get(plane) else {
            return 0.0;
        };
        if !(aim.total > 0.0) || !(aim.weights[k] > 0.0) {
            return 0.0;
        }
        let p = &self.planes[k];
        p.texel_at(point)
            .map_or(0.0, |t| aim.weights[k] / aim.total * p.texel_pdf(t))
    }
}

/// Plane `k`'s texels (its direct layer's resolved grid) weighted by their irradiance (all
/// layers) times their surface; None if it has no light or no resolved grid.
fn plane_texels(grids: &MultiscaleGrids, k: usize) -> Option<PlaneTexels> {
    let tex = &grids.textures[k];
    let t = &tex[DIRECT];
    let r = t.resolved.as_ref()?;
    let level = r.side.log2().round() as usize;
    let mut centre = (Vec3::ZERO, 0.0f32);
    let mut weights: Vec<f32> = (0..r.w * r.h)
        .map(|i| {
            let Some((x, y)) = t.texel_centroid(level, i) else {
                return 0.0;
            };
            let p = t.plane.grid_to_world(x, y);
            let e: Rgb = (0..LAYERS)
                .filter_map(|l| {
                    let (gx, gy) = tex[l].plane.grid_coords(p);
                    tex[l].resolved.as_ref().map(|r| r.lookup(gx, gy))
                })
                .sum();
            let w = crate::luminance(e) * t.texel_area(level, i);
            let w = if w.is_finite() { w.max(0.0) } else { 0.0 };
            centre = (centre.0 + p * w, centre.1 + w);
            w
        })
        .collect();
    let max = weights.iter().copied().fold(0.0f32, f32::max);
    if !(max > 0.0) {
        return None;
    }
    for w in &mut weights {
        if *w < DIM_SHARE * max {
            *w = 0.0;
        }
    }
    let plane = &t.plane;
    let (size_u, size_v) = (
        r.side * plane.size_u / plane.res_u.max(1) as f32,
        r.side * plane.size_v / plane.res_v.max(1) as f32,
    );
    let (eu, ev) = (plane.u * (size_u * r.w as f32), plane.v * (size_v * r.h as f32));
    Some(PlaneTexels {
        plane: k,
        origin: plane.origin,
        u: plane.u,
        v: plane.v,
        normal: plane.normal,
        size_u,
        size_v,
        w: r.w,
        h: r.h,
        corners: [
            plane.origin,
            plane.origin + eu,
            plane.origin + ev,
            plane.origin + eu + ev,
        ],
        centre: centre.0 / centre.1,
        area: eu.length() * ev.length(),
        texels: Distribution::new(weights),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 1 × 0.5 m grids of 2 × 2 texels facing +y: one at the origin, one at x = 5 m,
    /// y = 1 m, with these texel weights.
    fn texels(weights: [[f32; 4]; 2]) -> BrightTexels {
        let plane = |k: usize, origin: Vec3, w: [f32; 4]| PlaneTexels {
            plane: k,
            origin,
            u: Vec3::X,
            v: Vec3::Z,
            normal: Vec3::Y,
            size_u: 0.5,
            size_v: 0.25,
            w: 2,
            h: 2,
            corners: [
                origin,
                origin + Vec3::X,
                origin + Vec3::Z * 0.5,
                origin + Vec3::new(1.0, 0.0, 0.5),
            ],
            centre: origin + Vec3::new(0.5, 0.0, 0.25),
            area: 0.5,
            texels: Distribution::new(w),
        };
        BrightTexels {
            planes: vec![
                plane(0, Vec3::ZERO, weights[0]),
                plane(1, Vec3::new(5.0, 1.0, 0.0), weights[1]),
            ],
            slot: vec![Some(0), Some(1)],
            plane_share: 1.0,
        }
    }

    #[test]
    fn samples_land_in_proportion_and_report_their_density() {
        let b = texels([[1.0, 0.0, 0.0, 1.0], [0.0, 6.0, 0.0, 0.0]]);
        // A point above both planes, facing down: both reach it.
        let (x, n) = (Vec3::new(2.5, 3.0, 0.25), -Vec3::Y);
        let mut aim = Aim::default();
        b.aim(x, n, &mut aim);
        assert!(aim.weights.iter().all(|&w| w > 0.0), "{:?}", aim.weights);
        let plane_share = [aim.weights[0] / aim.total, aim.weights[1] / aim.total];
        let want = |i: usize| plane_share[i / 4] * [[0.5, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0]][i / 4][i % 4];
        let n_samples = 80_000;
        let mut hits = [0usize; 8];
        let mut rng = crate::sampling::Rng::keyed(3, 1, 2);
        for _ in 0..n_samples {
            let s = b.sample(&aim, rng.uniform(), rng.uniform2()).expect("planes to aim at");
            let t = b.planes[s.plane].texel_at(s.point).expect("a sample lies in its texel");
            hits[s.plane * 4 + t] += 1;
            assert_eq!(s.pdf_area, b.pdf_area(&aim, s.plane, s.point));
            assert!((s.pdf_area - want(s.plane * 4 + t) / 0.125).abs() < 1e-4 * s.pdf_area);
        }
        for (i, &h) in hits.iter().enumerate() {
            let share = h as f64 / n_samples as f64;
            assert!(
                (share - want(i) as f64).abs() < 0.01,
                "texel {i}: {share} vs {}",
                want(i)
            );
        }
        // The densities integrate to one over the planes.
        let total: f32 = (0..8)
            .map(|i| {
                let p = &b.planes[i / 4];
                let t = i % 4;
                let c =
                    p.origin + p.u * (((t % 2) as f32 + 0.5) * p.size_u) + p.v * (((t / 2) as f32 + 0.5) * p.size_v);
                b.pdf_area(&aim, i / 4, c) * p.size_u * p.size_v
            })
            .sum();
        assert!((total - 1.0).abs() < 1e-5, "{total}");
    }

    #[test]
    fn planes_that_cannot_light_the_point_are_not_aimed_at() {
        let b = texels([[1.0; 4], [1.0; 4]]);
        let mut aim = Aim::default();
        // Below both planes' lit side.
        b.aim(Vec3::new(0.5, -1.0, 0.25), Vec3::Y, &mut aim);
        assert!(!aim.any());
        assert_eq!(b.sample(&aim, 0.5, Vec2::splat(0.5)), None);
        assert_eq!(b.pdf_area(&aim, 0, Vec3::new(0.5, 0.0, 0.25)), 0.0);
        // Above the first, facing up: neither is in front of it.
        b.aim(Vec3::new(0.5, 2.0, 0.25), Vec3::Y, &mut aim);
        assert!(!aim.any());
        // Between them (above the first, below the second), facing down: the first only.
        b.aim(Vec3::new(2.5, 0.5, 0.25), -Vec3::Y, &mut aim);
        assert!(aim.weights[0] > 0.0 && aim.weights[1] == 0.0, "{:?}", aim.weights);
        let s = b.sample(&aim, 0.999, Vec2::splat(0.5)).unwrap();
        assert_eq!(s.plane, 0);
    }

    #[test]
    fn rays_are_aimed_in_proportion_to_the_light_on_the_planes() {
        let mut b = texels([[1.0; 4], [1.0; 4]]);
        assert_eq!(b.aimed_rays(8, 0.25), 2);
        assert_eq!(b.aimed_rays(1, 0.9), 0, "one ray is spread");
        assert_eq!(b.aimed_rays(0, 0.5), 0);
        b.plane_share = 0.1;
        assert_eq!(b.aimed_rays(8, 0.25), 0);
        assert_eq!(b.aimed_rays(32, 0.25), 1);
    }

    #[test]
    fn points_off_the_grid_have_no_density() {
        let b = texels([[1.0; 4], [1.0; 4]]);
        let mut aim = Aim::default();
        b.aim(Vec3::new(2.5, 3.0, 0.25), -Vec3::Y, &mut aim);
        assert_eq!(b.pdf_area(&aim, 0, Vec3::new(-0.01, 0.0, 0.1)), 0.0);
        assert_eq!(b.pdf_area(&aim, 0, Vec3::new(1.01, 0.0, 0.1)), 0.0);
        assert_eq!(b.pdf_area(&aim, 0, Vec3::new(0.1, 0.0, 0.51)), 0.0);
        assert_eq!(b.pdf_area(&aim, 0, Vec3::splat(f32::NAN)), 0.0);
        assert_eq!(b.pdf_area(&aim, 7, Vec3::ZERO), 0.0, "no such plane");
        assert!(b.pdf_area(&aim, 0, Vec3::new(0.9, 0.0, 0.4)) > 0.0);
    }
}
