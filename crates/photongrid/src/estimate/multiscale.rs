//! The multiscale estimate: at a point on a plane, each photon layer's irradiance at the
//! widest scale of its flux pyramid that agrees with every finer scale — the intersection of
//! confidence intervals rule (Goldenshluger & Nemirovski 1997; Katkovnik 1999). Where the
//! light is flat the intervals keep intersecting up to wide kernels holding thousands of
//! photons (smooth global light from few photons per pixel); at a shadow edge or a caustic
//! filament a wide kernel's estimate leaves the finer ones' intervals and the scale stops
//! there (sharp edges).
//!
//! Indirect light near a plane's edge (a corner, the foot of a wall) changes over distances
//! the photons cannot resolve, and a kernel there reaches past the edge; such points take
//! their indirect light from final gathering instead, whose rays read these same estimates
//! where they land.

use super::photon_map::Gather;
use super::Query;
use crate::grid::multiscale::{LayerTexture, MultiscaleGrids, ScaleEstimate, CAUSTIC, DIRECT, INDIRECT};
use crate::Rgb;
use glam::Vec3;
use std::f32::consts::PI;

/// Luminance, the scalar the intervals are tested on.
fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// A layer's irradiance at the chosen scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerEstimate {
    /// Irradiance (W/m²).
    pub irradiance: Rgb,
    /// The chosen level.
    pub level: usize,
    /// Surface area under the kernel (m²).
    pub area: f32,
    /// Photons under the kernel (per pass).
    pub count: f32,
}

/// The estimate at the widest scale whose confidence interval meets every finer one's.
/// `floor` is one photon's variance (an empty kernel is not certain to be dark), `passes`
/// divides the accumulated sums.
pub fn choose_scale(
    scales: impl Iterator<Item = ScaleEstimate>,
    gamma: f32,
    floor: f32,
    passes: f32,
) -> Option<LayerEstimate> {
    let (mut lo, mut hi) = (f32::NEG_INFINITY, f32::INFINITY);
    let mut best = None;
    for s in scales {
        let t = s.texel;
        if !(t.area > 0.0) {
            continue;
        }
        let norm = 1.0 / (t.area * passes);
        let e = luminance(t.flux) * norm;
        let sigma = (t.var + floor).sqrt() * norm;
        lo = lo.max(e - gamma * sigma);
        hi = hi.min(e + gamma * sigma);
        if lo > hi {
            break;
        }
        best = Some(LayerEstimate {
            irradiance: Rgb::from(t.flux) * norm,
            level: s.level,
            area: t.area,
            count: t.count / passes,
        });
    }
    best
}

/// Share of a kernel's span that must lie on the surface for its indirect estimate to be
/// used; below it the point is near the plane's edge and final gathering supplies indirect
/// light.
pub const INTERIOR_COVERAGE: f32 = 0.9;

impl MultiscaleGrids {
    /// One layer's estimate at `p` of the plane texture `tex`.
    pub fn layer_estimate(&self, tex: &[LayerTexture], layer: usize, p: Vec3, gamma: f32) -> Option<LayerEstimate> {
        let floor = self.mean_power[layer] * self.mean_power[layer];
        choose_scale(tex[layer].scales(p), gamma, floor, self.passes.max(1) as f32)
    }

    /// Total irradiance (every layer) at a point on a plane, for final-gather rays; None off
    /// the planes.
    pub fn irradiance(&self, triangle: u32, p: Vec3, gamma: f32) -> Option<Rgb> {
        let tex = self.texture_of(triangle)?;
        Some(
            [CAUSTIC, INDIRECT, DIRECT]
                .iter()
                .filter_map(|&l| self.layer_estimate(tex, l, p, gamma))
                .map(|e| e.irradiance)
                .sum(),
        )
    }
}

/// The photons' irradiance at a visible point `q` as a [`Gather`] (flux over a disc of the
/// kernel's area): caustics always, direct light when `direct` (the single-map setting), and
/// indirect light unless final gathering (`gathering`) does better here. None off the planes.
pub fn gather(grids: &MultiscaleGrids, q: &Query, gamma: f32, direct: bool, gathering: bool) -> Option<Gather> {
    let tex = grids.texture_of(q.triangle)?;
    let mut e = Rgb::ZERO;
    let (mut area, mut count) = (0.0f32, 0.0f32);
    let mut add = |l: &LayerEstimate| {
        e += l.irradiance;
        area = area.max(l.area);
        count += l.count;
    };
    if let Some(c) = grids.layer_estimate(tex, CAUSTIC, q.position, gamma) {
        add(&c);
    }
    if direct {
        if let Some(d) = grids.layer_estimate(tex, DIRECT, q.position, gamma) {
            add(&d);
        }
    }
    let indirect = grids.layer_estimate(tex, INDIRECT, q.position, gamma);
    let interior = indirect.is_some_and(|i| i.area >= INTERIOR_COVERAGE * tex[INDIRECT].kernel_area(i.level));
    let needs_gathering = gathering && !interior;
    if !needs_gathering {
        if let Some(i) = &indirect {
            add(i);
        }
    }
    let r2 = area.max(1e-30) / PI;
    Some(Gather {
        flux: e * (PI * r2),
        r2,
        count: count.round() as usize,
        needs_gathering,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::multiscale::Texel;

    fn scale(level: usize, flux: f32, var: f32, area: f32) -> ScaleEstimate {
        ScaleEstimate {
            level,
            texel: Texel {
                flux: [flux; 3],
                var,
                count: 0.0,
                area,
            },
        }
    }

    #[test]
    fn flat_light_takes_the_widest_scale_and_an_edge_stops_it() {
        // Flat: 1 W/m² at every scale, variance falling with area.
        let flat: Vec<ScaleEstimate> = (0..5)
            .map(|l| {
                let a = 4f32.powi(l);
                scale(l as usize, a, a * 0.01, a)
            })
            .collect();
        let e = choose_scale(flat.iter().copied(), 2.0, 0.0, 1.0).unwrap();
        assert_eq!((e.area, e.level), (256.0, 4));
        assert!((e.irradiance.x - 1.0).abs() < 1e-6);
        // An edge at level 3: the wide kernels see half the light.
        let mut edge = flat.clone();
        for s in &mut edge[3..] {
            s.texel.flux = [s.texel.area * 0.5; 3];
        }
        let e = choose_scale(edge.iter().copied(), 2.0, 0.0, 1.0).unwrap();
        assert_eq!((e.area, e.level), (16.0, 2));
        assert!((e.irradiance.x - 1.0).abs() < 1e-6);
    }
}
