//! The multiscale estimate: at a point on a plane, each photon layer's irradiance at the
//! widest scale of its flux pyramid that agrees with every finer scale — the intersection of
//! confidence intervals rule (Goldenshluger & Nemirovski 1997; Katkovnik 1999). Where the
//! light is flat the intervals keep intersecting up to wide kernels holding thousands of
//! photons (smooth global light from few photons per pixel); at a shadow edge or a caustic
//! filament a wide kernel's estimate leaves the finer ones' intervals and the scale stops
//! there (sharp edges).

use super::photon_map::Gather;
use crate::grid::multiscale::{MultiscaleGrids, ScaleEstimate, LAYERS};
use crate::Rgb;
use std::f32::consts::PI;

use super::Query;

/// Luminance, the scalar the intervals are tested on.
fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The irradiance of one layer at the scale the rule chooses, with that scale's kernel area
/// and photon count. `floor` is one photon's variance (an empty kernel is not certain to be
/// dark), `passes` divides the accumulated sums.
pub fn choose_scale(
    scales: impl Iterator<Item = ScaleEstimate>,
    gamma: f32,
    floor: f32,
    passes: f32,
) -> Option<(Rgb, f32, f32)> {
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
        best = Some((Rgb::from(t.flux) * norm, t.area, t.count / passes));
    }
    best
}

/// The photons' irradiance at `q` as a [`Gather`] (flux over a disc of the chosen kernel's
/// area), or None when no plane texture covers the point.
pub fn gather(grids: &MultiscaleGrids, q: &Query, gamma: f32) -> Option<Gather> {
    let tex = grids.texture_of(q.triangle)?;
    let passes = grids.passes.max(1) as f32;
    let mut e = Rgb::ZERO;
    let (mut area, mut count) = (0.0f32, 0.0f32);
    for layer in 0..LAYERS {
        let floor = grids.mean_power[layer] * grids.mean_power[layer];
        if let Some((irradiance, a, n)) = choose_scale(tex[layer].scales(q.position), gamma, floor, passes) {
            e += irradiance;
            // The AOVs show the global layer's kernel (the last layer).
            area = a;
            count += n;
        }
    }
    let r2 = area.max(1e-30) / PI;
    Some(Gather {
        flux: e * (PI * r2),
        r2,
        count: count.round() as usize,
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
        let (e, area, _) = choose_scale(flat.iter().copied(), 2.0, 0.0, 1.0).unwrap();
        assert_eq!(area, 256.0);
        assert!((e.x - 1.0).abs() < 1e-6);
        // An edge at level 3: the wide kernels see half the light.
        let mut edge = flat.clone();
        for s in &mut edge[3..] {
            s.texel.flux = [s.texel.area * 0.5; 3];
        }
        let (e, area, _) = choose_scale(edge.iter().copied(), 2.0, 0.0, 1.0).unwrap();
        assert_eq!(area, 16.0);
        assert!((e.x - 1.0).abs() < 1e-6);
    }
}
