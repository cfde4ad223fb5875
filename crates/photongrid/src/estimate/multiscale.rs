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
use crate::grid::multiscale::{
    LayerTexture, MultiscaleGrids, Resolved, ScaleEstimate, Texel, CAUSTIC, DIRECT, INDIRECT, NO_LEVEL, TAIL,
};
use crate::Rgb;
use glam::Vec3;
use rayon::prelude::*;
use std::f32::consts::PI;

/// Luminance, the scalar the intervals are tested on.
fn luminance(c: [f32; 3]) -> f32 {
    crate::luminance(Rgb::from_array(c))
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
    /// The kernel's sums (moments about the point).
    pub kernel: Texel,
}

/// The local-linear fit of a kernel's sums (moments about the query point, fine cells):
/// irradiance = a + b·x fitted to the light under the kernel, and a read at the point.
/// Returns the factor taking the kernel's plain mean to `a`, and the factor on its variance
/// (the leverage 1 + x̄ᵀ C⁻¹ x̄ of a point `x̄` away from the covered area's centroid, C the
/// area's covariance). A kernel centred on its covered area gets (1, 1); one that reaches past
/// a plane's edge or into a buried footprint no longer mistakes the light's gradient for its
/// level. `side` is the kernel's texel side (fine cells): the covariance is regularised at a
/// hundredth of its square so that a kernel over a thin strip does not tilt across it.
pub fn local_linear(t: &Texel, side: f32) -> (f32, f32) {
    let m0 = t.area;
    let f0 = luminance(t.flux);
    if !(m0 > 0.0) || !(f0 > 0.0) {
        return (1.0, 1.0);
    }
    let c = [t.area_moment[0] / m0, t.area_moment[1] / m0];
    let reg = 0.01 * side * side;
    let cxx = t.area_moment2[0] / m0 - c[0] * c[0] + reg;
    let cxy = t.area_moment2[1] / m0 - c[0] * c[1];
    let cyy = t.area_moment2[2] / m0 - c[1] * c[1] + reg;
    let det = cxx * cyy - cxy * cxy;
    if !(det > 0.0) {
        return (1.0, 1.0);
    }
    let inv = [cyy / det, -cxy / det, cxx / det];
    // The flux's first moment about the area's centroid, then the slope b = C⁻¹ g / m0.
    let g = [t.flux_moment[0] - c[0] * f0, t.flux_moment[1] - c[1] * f0];
    let b = [
        (inv[0] * g[0] + inv[1] * g[1]) / m0,
        (inv[1] * g[0] + inv[2] * g[1]) / m0,
    ];
    let mean = f0 / m0;
    let a = mean - (b[0] * c[0] + b[1] * c[1]);
    let leverage = 1.0 + c[0] * (inv[0] * c[0] + inv[1] * c[1]) + c[1] * (inv[1] * c[0] + inv[2] * c[1]);
    ((a / mean).clamp(0.0, MAX_TILT), leverage)
}

/// The most a local-linear fit may raise a kernel's mean: beyond it the fit extrapolates
/// noise.
const MAX_TILT: f32 = 4.0;

/// The curvature bias of a local-linear kernel estimate ([`local_linear`]): where the
/// irradiance has Hessian `h` (xx, xy, yy; per fine cell²) about the point, the fit's value
/// at the point exceeds the truth by ½ tr(H M) − μᵀHμ, `M` the kernel's second area moments
/// about the point and `μ` its area centroid, both per unit area (fine cells). Under a point
/// light the light peaks with negative curvature, and a wide kernel reads it low.
pub fn curvature_bias(kernel: &Texel, h: [f32; 3]) -> f32 {
    let a = kernel.area;
    if !(a > 0.0) {
        return 0.0;
    }
    let m = kernel.area_moment2.map(|v| v / a);
    let (mx, my) = (kernel.area_moment[0] / a, kernel.area_moment[1] / a);
    let quad = |x: f32, xy: f32, y: f32| h[0] * x + 2.0 * h[1] * xy + h[2] * y;
    0.5 * quad(m[0], m[1], m[2]) - quad(mx * mx, mx * my, my * my)
}

/// The Hessian (xx, xy, yy; per fine cell²) of the mean irradiance (luminance) over a 3×3
/// block of texels `side` fine cells wide, from second differences. A texel's mean is a box
/// average, which adds the same constant to every texel of a quadratic: the differences see
/// the light's own curvature.
pub fn block_hessian(block: &[[&Texel; 3]; 3], side: f32) -> [f32; 3] {
    means_hessian(block.map(|row| row.map(Texel::mean)), side)
}

/// [`block_hessian`] of a 3×3 block's means (rows along y).
fn means_hessian(m: [[f32; 3]; 3], side: f32) -> [f32; 3] {
    let s2 = side * side;
    [
        (m[1][2] - 2.0 * m[1][1] + m[1][0]) / s2,
        (m[2][2] - m[2][0] - m[0][2] + m[0][0]) / (4.0 * s2),
        (m[2][1] - 2.0 * m[1][1] + m[0][1]) / s2,
    ]
}

/// The Hessian ([`block_hessian`]) of `t`'s texel means on `level` at fine grid coordinates
/// `(gx, gy)`: those of the full 3×3 blocks centred on the four texels nearest the point,
/// blended bilinearly, so that the correction varies smoothly. Read from the one block around
/// the point, it stepped at every texel edge, and a flat wall showed rectangles a few per cent
/// apart (the README sample's box). The blocks lie in a 4×4 patch of texels
/// ([`LayerTexture::full_patch`]); where no patch near the point lies on the surface, the one
/// block around it ([`LayerTexture::full_block`]). None where no block is full.
fn blended_hessian(t: &LayerTexture, level: usize, gx: f32, gy: f32) -> Option<[f32; 3]> {
    let side = (1u32 << level) as f32;
    let Some((m, [fu, fv])) = t.full_patch(level, gx, gy) else {
        // Ragged coverage: the one block around the point.
        return Some(block_hessian(&t.full_block(level, gx, gy, INTERIOR_COVERAGE)?, side));
    };
    // The Hessian is linear in the means: blend the means, then difference once.
    let lerp = |a: f32, b: f32, f: f32| a + f * (b - a);
    let blended = std::array::from_fn(|b| {
        std::array::from_fn(|a| {
            lerp(
                lerp(m[b][a], m[b][a + 1], fu),
                lerp(m[b + 1][a], m[b + 1][a + 1], fu),
                fv,
            )
        })
    });
    Some(means_hessian(blended, side))
}

/// The largest relative curvature correction applied; a larger one means the block the
/// curvature was read from is not smooth (an edge or a caustic within it), not a curved light.
const MAX_CURVATURE_CORRECTION: f32 = 0.15;

/// The estimate at the widest scale whose confidence interval meets every finer one's.
/// `floor` is one photon's variance (an empty kernel is not certain to be dark), `passes`
/// divides the accumulated sums.
///
/// A finer scale's own variance says little where it holds few photons: an empty kernel
/// beside a lit one has only the floor's, so a wide kernel half over the light still met its
/// interval and light leaked a kernel's reach into shadows (a quarter of the light beside a
/// blocker). Each finer scale is therefore also tested against the variance it would have
/// if the light were as the wider kernel says ([`poisson_variance`]): no photons where the
/// wider kernel expects dozens ends the widening. Intervals narrower than 2σ are kept for
/// kernels that should hold enough photons for them ([`interval_width`]).
pub fn choose_scale(
    scales: impl Iterator<Item = ScaleEstimate>,
    gamma: f32,
    floor: f32,
    passes: f32,
) -> Option<LayerEstimate> {
    let mut best = None;
    // Finer scales so far: (estimate, its variance and standard deviation, its area × passes,
    // leverage).
    let mut finer: [(f32, f32, f32, f32, f32); 24] = [(0.0, 0.0, 0.0, 0.0, 0.0); 24];
    let mut n = 0;
    let photon_power = floor.sqrt();
    for s in scales {
        let t = s.texel;
        if !(t.area > 0.0) {
            continue;
        }
        let (tilt, leverage) = local_linear(&t, (1u32 << s.level) as f32);
        let norm = tilt / (t.area * passes);
        let e = luminance(t.flux) * norm;
        let var = (t.var + floor) * leverage / (t.area * passes).powi(2);
        let sigma = var.sqrt();
        // Each finer interval's width follows the photons its kernel should hold if the light
        // were as this kernel says, not the photons it caught: a kernel that caught few by
        // chance gets no wider interval than one that caught many.
        let g = interval_width(gamma, t.count);
        let (mut lo, mut hi) = (e - g * sigma, e + g * sigma);
        let mut contradicted = false;
        for &(ef, vf, sf, af, lf) in &finer[..n] {
            let gf = interval_width(gamma, e * af / photon_power);
            lo = lo.max(ef - gf * sf);
            hi = hi.min(ef + gf * sf);
            let v = vf.max(poisson_variance(e, photon_power, af) * lf);
            contradicted |= (ef - e).abs() > gf * v.sqrt();
        }
        if lo > hi || contradicted {
            break;
        }
        if n < finer.len() {
            finer[n] = (e, var, sigma, t.area * passes, leverage);
            n += 1;
        }
        best = Some(LayerEstimate {
            irradiance: Rgb::from(t.flux) * norm,
            level: s.level,
            area: t.area,
            count: t.count / passes,
            kernel: t,
        });
    }
    best
}

/// Photons a kernel must hold for its confidence interval to be narrower than
/// [`FEW_PHOTONS_GAMMA`] standard deviations. Below that the normal approximation of a Poisson
/// count misplaces the interval (Garwood's 84 % upper bound for 2 counted photons is 4.6, the
/// normal one 3.4): at the caustic layer's 1σ a fine kernel that by chance caught few photons
/// ended the widening and read dark, a speck a kernel wide (the pool floor's dark flecks;
/// docs/multiscale.md, "Few photons, wider intervals").
const NARROW_INTERVAL_MIN_PHOTONS: f32 = 8.0;

/// The interval width (standard deviations) used where a kernel holds too few photons for a
/// narrower one ([`NARROW_INTERVAL_MIN_PHOTONS`]): the global layers' default.
const FEW_PHOTONS_GAMMA: f32 = 2.0;

/// The interval width for a kernel of `photons` photons when `gamma` is asked for.
fn interval_width(gamma: f32, photons: f32) -> f32 {
    if photons < NARROW_INTERVAL_MIN_PHOTONS {
        gamma.max(FEW_PHOTONS_GAMMA)
    } else {
        gamma
    }
}

/// The caustic estimate's widest chosen level still checked against its neighbours'
/// ([`MultiscaleGrids::caustic_consensus`]); wider kernels hold enough photons that a chance
/// stop changes little.
const CONSENSUS_MAX_LEVEL: usize = 2;

/// Share of a point's caustic and direct light the caustic must carry for its scale to be
/// checked against its neighbours' ([`MultiscaleGrids::caustic_consensus`]): where caustics
/// are a faint part of the light (the walls of a room with a glass ball) their blotches do
/// not show, and the check would cost camera time for nothing (docs/multiscale.md).
const CONSENSUS_SHARE: f32 = 0.1;

/// Levels by which the consensus may widen a kernel: the neighbours' scales are chosen no
/// wider than that (they are only compared).
const CONSENSUS_WIDENING: usize = 2;

/// The most photons a kernel widened by the consensus holds, as a multiple of its own: four
/// times the area per level.
const CONSENSUS_MAX_GAIN: f32 = (1 << (2 * CONSENSUS_WIDENING)) as f32;

/// The estimate of the one scale `at` yields (no choice), as [`choose_scale`] would give it.
fn choose_scale_fixed(at: impl Iterator<Item = ScaleEstimate>, floor: f32, passes: f32) -> Option<LayerEstimate> {
    choose_scale(at, f32::INFINITY, floor, passes)
}

/// The variance of an irradiance estimate over `area_passes` (kernel area × passes) where
/// the irradiance is `e` and photons carry `photon_power` each: the flux sum of a Poisson
/// count of `e · area_passes / photon_power` photons, over `area_passes` squared.
pub fn poisson_variance(e: f32, photon_power: f32, area_passes: f32) -> f32 {
    (e.max(0.0) * photon_power / area_passes.max(1e-30)).max(0.0)
}

/// The confidence-interval widths (standard deviations of a Poisson count) of the scale
/// choice: caustics are filaments and sharp outlines, where a narrower interval keeps them
/// sharp and costs less than it does in smooth global light; photons that land from
/// stratified points scatter less than a Poisson count, so theirs is narrower still.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gammas {
    /// Indirect layers.
    pub global: f32,
    /// The direct layer.
    pub direct: f32,
    /// The caustic layer.
    pub caustic: f32,
}

impl Gammas {
    /// The widths `settings` ask for, for grids whose direct and caustic photons land from
    /// stratified points or not ([`MultiscaleGrids::stratified`]).
    pub fn of_settings(settings: &crate::Settings, stratified: bool) -> Self {
        let (direct, caustic) = if stratified {
            (
                settings.stratified_ici_threshold,
                settings.stratified_caustic_ici_threshold,
            )
        } else {
            (settings.ici_threshold, settings.caustic_ici_threshold)
        };
        Gammas {
            global: settings.ici_threshold,
            direct,
            caustic,
        }
    }

    /// The width for photon layer `layer`.
    pub fn of(self, layer: usize) -> f32 {
        match layer {
            CAUSTIC => self.caustic,
            DIRECT => self.direct,
            _ => self.global,
        }
    }
}

/// Share of a kernel's span that must lie on the surface for its indirect estimate to be
/// used; below it the point is near the plane's edge and final gathering supplies indirect
/// light.
pub const INTERIOR_COVERAGE: f32 = crate::grid::multiscale::FULL_COVERAGE;

/// Photons (over all passes) an interior kernel must hold for the photons' indirect estimate
/// to be used when final gathering could supply it instead: fewer give blotches that cost
/// more block error than gathering's grain (measured on cornell_glass, docs/multiscale.md).
const MIN_INDIRECT_PHOTONS: f32 = 64.0;

/// The most relative noise, as a share of all the light at the point, that the photons'
/// indirect estimate may bring where final gathering could supply it instead, whatever the
/// gather rays: its blotches are a kernel wide and do not average out over pixels, while
/// gathering's grain does (docs/time_budget.md, "Gathering where the photons' blotches would
/// show").
const INDIRECT_NOISE: f32 = 0.005;

/// Photons per final-gather ray (a kernel's photons over all passes, the pixel's gather rays
/// over all passes) from which a kernel's indirect estimate is used however large a share of
/// the light it is. The kernel's relative noise 1/√N and the gathered estimate's σ/√R scale
/// alike with that share; over an 8×8 block gathering's grain falls 8× more, so the photons win
/// the block where N ≥ 64 R / σ² (σ: a gather ray's relative spread, which depends on the
/// scene). The value is measured: docs/multiscale.md, "Photons or gathering, by the gather
/// rays".
const PHOTONS_PER_GATHER_RAY: f32 = 16.0;

/// Whether a kernel's `photons` (over all passes) make its `indirect` irradiance (luminance)
/// quiet enough beside the point's `other` light (direct and caustic) and the `gather_rays` per
/// pixel (over all passes) that final gathering would spend instead (infinite where gathering
/// is preferred on other grounds): at least [`MIN_INDIRECT_PHOTONS`], and either its relative
/// noise 1/√photons times indirect light's share of the point's light at most
/// [`INDIRECT_NOISE`] or at least [`PHOTONS_PER_GATHER_RAY`] photons per gather ray.
pub fn photons_suffice(indirect: f32, other: f32, photons: f32, gather_rays: f32) -> bool {
    let total = indirect + other;
    let share = if total > 0.0 { indirect / total } else { 1.0 };
    photons >= MIN_INDIRECT_PHOTONS
        && (share * share <= INDIRECT_NOISE * INDIRECT_NOISE * photons
            || photons >= PHOTONS_PER_GATHER_RAY * gather_rays)
}

impl MultiscaleGrids {
    /// One layer's estimate at `p` of the plane texture `tex`. No kernel of global light reaches
    /// farther than the open space in front of the surface it covers: light next to a shelf
    /// board standing out of a wall is not that of the wall across it.
    pub fn layer_estimate(&self, tex: &[LayerTexture], layer: usize, p: Vec3, gamma: Gammas) -> Option<LayerEstimate> {
        let floor = self.mean_power[layer] * self.mean_power[layer];
        let t = &tex[layer];
        let e = choose_scale(self.scales_within(t, p), gamma.of(layer), floor, self.passes_of(layer))?;
        Some(self.curvature_corrected(t, layer, p, e))
    }

    /// The scales of `t` at `p` that [`layer_estimate`](Self::layer_estimate) chooses among:
    /// none reaching farther than `--max-radius` or the open space in front of the surface.
    fn scales_within<'t>(&self, t: &'t LayerTexture, p: Vec3) -> impl Iterator<Item = ScaleEstimate> + 't {
        let max_radius = self.max_radius;
        t.scales(p)
            .take_while(move |s| s.level == 0 || t.kernel_reach(s.level) <= max_radius.min(s.texel.clearance))
    }

    /// The scale chosen at `p` for a caustic (`e`), widened when it stopped alone
    /// ([`consensus`](Self::consensus)), if it stopped at [`CONSENSUS_MAX_LEVEL`] or finer.
    pub(crate) fn caustic_consensus(
        &self,
        t: &LayerTexture,
        p: Vec3,
        gamma: Gammas,
        e: LayerEstimate,
    ) -> LayerEstimate {
        if e.level > CONSENSUS_MAX_LEVEL {
            return e;
        }
        self.consensus(t, CAUSTIC, p, gamma.caustic, e, |q| self.scales_within(t, q))
    }

    /// The interior indirect scale `e` chosen at `p` ([`interior_estimate`](Self::interior_estimate)),
    /// widened when it stopped alone ([`consensus`](Self::consensus)). Asked where `e` holds
    /// too few photons and final gathering would supply the point's indirect light: a chance
    /// stop on a wall lit evenly would otherwise show as a cluster of gathering's grain, a
    /// kernel wide, amid the photons' smooth estimate.
    pub(crate) fn indirect_consensus(
        &self,
        tex: &[LayerTexture],
        p: Vec3,
        gamma: Gammas,
        e: LayerEstimate,
    ) -> LayerEstimate {
        let t = &tex[INDIRECT];
        if self.interior_scales(t, p).nth(e.level + 1).is_none() {
            // The widening ran out of scales (the plane's edge, the clearance or the largest
            // radius stopped it), which the neighbours share: nothing to compare.
            return e;
        }
        let w = self.consensus(t, INDIRECT, p, gamma.global, e, |q| self.interior_scales(t, q));
        if w.level == e.level {
            e
        } else {
            self.curvature_corrected(t, INDIRECT, p, w)
        }
    }

    /// The scale `e` chosen at `p` in `layer` among the scales `within` yields, widened when it
    /// stopped alone: the scales chosen at eight points two of its texels away (along the
    /// plane's axes and diagonals) are compared, and when at most one of them is as fine, `p`
    /// is read at the second finest of them. A filament, an outline or an edge through `p`
    /// stops the widening at the two neighbours along it, so it keeps its scale; a fine kernel
    /// that stopped because its few photons were by chance many or few stops alone, and its
    /// blotch (a kernel wide, bright or dark) is read at its neighbours' scale instead.
    fn consensus<I: Iterator<Item = ScaleEstimate>>(
        &self,
        t: &LayerTexture,
        layer: usize,
        p: Vec3,
        gamma: f32,
        e: LayerEstimate,
        within: impl Fn(Vec3) -> I,
    ) -> LayerEstimate {
        let floor = self.mean_power[layer] * self.mean_power[layer];
        let passes = self.passes_of(layer);
        let step = 2.0 * t.cell_size() * (1u32 << e.level) as f32;
        let (u, v) = (t.plane.u * step, t.plane.v * step);
        let diagonal = std::f32::consts::FRAC_1_SQRT_2;
        let mut levels = [e.level; 8];
        let around = [
            u,
            -u,
            v,
            -v,
            (u + v) * diagonal,
            (u - v) * diagonal,
            (v - u) * diagonal,
            -(u + v) * diagonal,
        ];
        for (i, d) in around.into_iter().enumerate() {
            let n = choose_scale(
                within(p + d).take(e.level + 1 + CONSENSUS_WIDENING),
                gamma,
                floor,
                passes,
            );
            levels[i] = n.map_or(0, |n| n.level);
            if i >= 1 && levels[..=i].iter().filter(|&&l| l <= e.level).count() >= 2 {
                return e;
            }
        }
        levels.sort_unstable();
        let widened = levels[1];
        if widened <= e.level {
            return e;
        }
        let at = within(p).filter(|s| s.level == widened);
        choose_scale_fixed(at, floor, passes).unwrap_or(e)
    }

    /// One layer's estimate at `p` from kernels lying (almost) wholly on the plane and no
    /// wider than the open space in front of it: near an edge, or something standing on or
    /// near the plane, the scale stops before the kernel reaches past it.
    pub fn interior_estimate(
        &self,
        tex: &[LayerTexture],
        layer: usize,
        p: Vec3,
        gamma: Gammas,
    ) -> Option<LayerEstimate> {
        let floor = self.mean_power[layer] * self.mean_power[layer];
        let t = &tex[layer];
        let e = choose_scale(
            self.interior_scales(t, p),
            gamma.of(layer),
            floor,
            self.passes_of(layer),
        )?;
        Some(self.curvature_corrected(t, layer, p, e))
    }

    /// The scales of `t` at `p` that [`interior_estimate`](Self::interior_estimate) chooses
    /// among: [`scales_within`](Self::scales_within) that lie (almost) wholly on the plane,
    /// the finest too within the clearance.
    fn interior_scales<'t>(&self, t: &'t LayerTexture, p: Vec3) -> impl Iterator<Item = ScaleEstimate> + 't {
        self.scales_within(t, p).take_while(|s| {
            s.texel.area >= INTERIOR_COVERAGE * t.kernel_area(s.level) && t.kernel_reach(s.level) <= s.texel.clearance
        })
    }

    /// A global layer's estimate less its kernel's curvature bias ([`curvature_bias`]), the
    /// curvature read from the 3×3 blocks of full texels one level coarser around the point,
    /// blended ([`blended_hessian`]; their means hold four times the photons of the kernel's
    /// texels, so the correction adds little noise), else at the kernel's level (near an edge,
    /// where a coarser block does not fit). Caustics are left as they are: their curvature is
    /// that of filaments and outlines, which no block resolves.
    fn curvature_corrected(&self, t: &LayerTexture, layer: usize, p: Vec3, e: LayerEstimate) -> LayerEstimate {
        if layer == CAUSTIC {
            return e;
        }
        let (gx, gy) = t.plane.grid_coords(p);
        let coarser = (e.level + 1).min(t.level_count() - 1);
        let Some(h) = [coarser, e.level]
            .into_iter()
            .find_map(|l| blended_hessian(t, l, gx, gy))
        else {
            return e;
        };
        let passes = self.passes_of(layer);
        let value = crate::luminance(e.irradiance);
        let bias = curvature_bias(&e.kernel, h) / passes;
        let rel = bias / value;
        if !(rel.abs() <= MAX_CURVATURE_CORRECTION) {
            return e;
        }
        LayerEstimate {
            irradiance: e.irradiance * (1.0 - rel),
            ..e
        }
    }

    /// Total irradiance (every layer) at a point on a plane, for final-gather rays: the
    /// resolved textures where [`MultiscaleGrids::resolve_for_gathering`] built them, else
    /// (and in their outline texels, [`Resolved::outline`]) the estimate at the point. None
    /// off the planes.
    pub fn irradiance(&self, triangle: u32, p: Vec3, normal: Vec3, gamma: Gammas) -> Option<Rgb> {
        let tex = self.texture_facing(triangle, normal)?;
        Some(
            [CAUSTIC, INDIRECT, DIRECT]
                .iter()
                .map(|&l| self.resolved_layer(tex, l, p, gamma))
                .sum(),
        )
    }

    /// One layer's irradiance at `p` as gather rays read it: its resolved texture, else (and
    /// in the texture's outline texels) the estimate at the point.
    pub fn resolved_layer(&self, tex: &[LayerTexture], l: usize, p: Vec3, gamma: Gammas) -> Rgb {
        let (gx, gy) = tex[l].plane.grid_coords(p);
        match &tex[l].resolved {
            Some(r) if !r.on_outline(gx, gy) => r.lookup(gx, gy),
            _ => self
                .layer_estimate(tex, l, p, gamma)
                .map_or(Rgb::ZERO, |e| e.irradiance),
        }
    }

    /// Resolve every layer's estimate at the texel centres of the finest pyramid level with
    /// at most [`RESOLVED_TEXELS`] texels, for final-gather rays to read
    /// ([`MultiscaleGrids::irradiance`]). Call after each pass's photons are added.
    pub fn resolve_for_gathering(&mut self, gamma: Gammas) {
        let started = std::time::Instant::now();
        let resolved: Vec<Vec<Option<Resolved>>> = self
            .textures
            .par_iter()
            .map(|tex| {
                (0..tex.len())
                    .map(|l| {
                        if l == TAIL {
                            return None; // never gathered
                        }
                        let t = &tex[l];
                        let (level, w, h) = t.level_within(RESOLVED_TEXELS);
                        let side = (1u32 << level) as f32;
                        // Each texel's estimate is taken on its surface (at the centroid of
                        // the area it covers): a centre off a plane's edge would read a
                        // sliver of surface as a kernel and give every ray nearby its noise.
                        let estimates: Vec<Option<LayerEstimate>> = (0..w * h)
                            .map(|i| {
                                let (x, y) = t.texel_centroid(level, i)?;
                                let p = t.plane.grid_to_world(x, y);
                                self.layer_estimate(tex, l, p, gamma)
                            })
                            .collect();
                        Some(Resolved {
                            side,
                            w,
                            h,
                            values: estimates.iter().map(|e| e.map(|e| e.irradiance)).collect(),
                            levels: estimates
                                .iter()
                                .map(|e| e.map_or(NO_LEVEL, |e| e.level.min(NO_LEVEL as usize - 1) as u8))
                                .collect(),
                            outline: t.outline(level),
                        })
                    })
                    .collect()
            })
            .collect();
        for (tex, r) in self.textures.iter_mut().zip(resolved) {
            for (t, r) in tex.iter_mut().zip(r) {
                t.resolved = r;
            }
        }
        self.bright = super::bright::BrightTexels::build(self);
        tracing::debug!(
            seconds = started.elapsed().as_secs_f64(),
            "multiscale estimate resolved for gathering"
        );
    }
}

/// Texels of a layer's resolved irradiance per plane, at most: the paper's 128 × 128.
pub const RESOLVED_TEXELS: usize = 128 * 128;

/// Photons (per pass) the disc finer than the finest texel must be expected to hold before it
/// is read: fewer would put grain where the kernel was right. Caustic photons are shared with
/// the cells around them, so a caustic line narrower than a cell reaches the kernels up to two
/// cells away, where they hold a few dozen photons: with more required, the disc would not
/// be read there and the line's light would be counted twice (beside it by the kernels, on it
/// by the disc).
const FINER_PHOTONS: f32 = 32.0;

/// Radius of that disc, in fine cells, at least: a fixed disc (a convolution, like the
/// texels) keeps a caustic's flux, where a k-nearest-neighbour disc, wider on a fold's dark
/// side, adds to it. The disc is no narrower than the camera pixel's footprint.
const FINER_RADIUS: f32 = 0.5;

/// Widest disc, in fine cells, worth reading: a pixel whose footprint is wider averages over
/// the finest kernel's reach anyway, and the disc's test would only add its false alarms.
const FINER_MAX_RADIUS: f32 = 0.75;

/// Standard deviations by which the finer disc's estimate must differ from the finest
/// kernel's to be used: a false alarm puts grain where the kernel was right, so the test is
/// strict; the cusp or fold of a caustic is far brighter than a kernel's mean over it.
const FINER_GAMMA: f32 = 3.0;

/// Photons the disc finer than the texels must hold to be read in a dark cell (no kernel
/// there), where a pixel's footprint reaches a caustic's bright side across a fold.
const FINER_DARK_PHOTONS: usize = 16;

/// Finer than the finest texel: where a caustic's estimate `c` stopped at level 0 and that
/// kernel holds many photons (the cusp or fold of a caustic, narrower than a cell), the
/// estimate of the photons within a disc of [`FINER_RADIUS`] cells or the pixel's footprint
/// (`finer`: this pass's caustic photons within a radius) replaces it when Lepski's rule says
/// the two differ ([`lepski_agrees`](super::photon_map::lepski_agrees)); in a dark cell
/// (`c` None) it is read where it holds [`FINER_DARK_PHOTONS`].
fn finer_than_texels(
    c: Option<LayerEstimate>,
    (cell, footprint): (f32, f32),
    passes: f32,
    finer: &mut dyn FnMut(f32) -> Gather,
) -> Option<LayerEstimate> {
    let r = (FINER_RADIUS * cell).max(footprint);
    let area = PI * r * r;
    if r > FINER_MAX_RADIUS * cell {
        return c;
    }
    if let Some(c) = c {
        if c.level != 0 || !(c.area > 0.0) || c.count * area / c.area < FINER_PHOTONS {
            return Some(c);
        }
    }
    let g = finer(r);
    let irradiance = g.flux / area;
    let agrees = match c {
        Some(c) => {
            let (e_disc, e_kernel) = (crate::luminance(irradiance), crate::luminance(c.irradiance));
            let n_kernel = (c.count * passes).round() as usize;
            super::photon_map::lepski_agrees(e_disc, g.count, e_kernel, n_kernel, FINER_GAMMA)
        }
        None => g.count < FINER_DARK_PHOTONS,
    };
    if agrees {
        return c;
    }
    Some(LayerEstimate {
        irradiance,
        level: 0,
        area,
        count: g.count as f32,
        kernel: c.map_or(Texel::default(), |c| c.kernel),
    })
}

/// The caustic layer's estimate at a visible point `q` of the plane texture `tex`: checked
/// against its neighbours' scales where it is a good part of the point's light besides
/// `direct_light` ([`MultiscaleGrids::caustic_consensus`]), and read finer than the finest
/// texel where `finer` is given ([`finer_than_texels`]).
fn caustic_estimate(
    grids: &MultiscaleGrids,
    tex: &[LayerTexture],
    q: &Query,
    gamma: Gammas,
    direct_light: &dyn Fn() -> Rgb,
    finer: Option<&mut dyn FnMut(f32) -> Gather>,
) -> Option<LayerEstimate> {
    let caustic = grids.layer_estimate(tex, CAUSTIC, q.position, gamma).map(|c| {
        let (lc, ld) = (crate::luminance(c.irradiance), crate::luminance(direct_light()));
        if lc >= CONSENSUS_SHARE * (lc + ld) {
            grids.caustic_consensus(&tex[CAUSTIC], q.position, gamma, c)
        } else {
            c
        }
    });
    match finer {
        Some(f) => finer_than_texels(
            caustic,
            (tex[CAUSTIC].cell_size(), q.footprint),
            grids.passes_of(CAUSTIC),
            f,
        ),
        None => caustic,
    }
}

/// The photons' indirect estimate at a visible point `q` of the plane texture `tex` where
/// final gathering is at hand: used only where a kernel on the plane holds enough photons
/// ([`photons_suffice`], beside the point's `other` light, direct and caustic, and the
/// `gather_rays` per pixel gathering would spend). None where gathering does better (edges,
/// corners, dim places).
fn indirect_where_photons_suffice(
    grids: &MultiscaleGrids,
    tex: &[LayerTexture],
    q: &Query,
    gamma: Gammas,
    other: &dyn Fn() -> Rgb,
    gather_rays: f32,
) -> Option<LayerEstimate> {
    let passes = grids.passes_of(INDIRECT);
    let suffice = |i: &LayerEstimate, photons: f32| {
        photons_suffice(
            crate::luminance(i.irradiance),
            crate::luminance(other()),
            photons * passes,
            if q.glossy { f32::INFINITY } else { gather_rays },
        )
    };
    let i = grids.interior_estimate(tex, INDIRECT, q.position, gamma)?;
    if suffice(&i, i.count) {
        return Some(i);
    }
    // A kernel too poor for the photons may have stopped by chance: its neighbours' scale
    // decides, where a kernel as wide as the consensus may widen to would hold enough
    // (elsewhere, as under a budget's probe, it could not change the choice).
    if !suffice(&i, i.count * CONSENSUS_MAX_GAIN) {
        return None;
    }
    let w = grids.indirect_consensus(tex, q.position, gamma, i);
    suffice(&w, w.count).then_some(w)
}

/// The photons' irradiance at a visible point `q` as a [`Gather`] (flux over a disc of the
/// kernel's area): caustics always, direct light when `direct` (the single-map setting), and
/// indirect light unless final gathering (`gathering`) does better here. None off the planes.
/// `gather_rays` (per pixel, over all passes so far) is what gathering would spend instead
/// ([`photons_suffice`]). `finer`, when given, gathers this pass's caustic photons within a
/// radius of `q`, read where a caustic is finer than the finest texel ([`finer_than_texels`]).
pub fn gather(
    grids: &MultiscaleGrids,
    q: &Query,
    gamma: Gammas,
    direct: bool,
    gathering: bool,
    gather_rays: f32,
    finer: Option<&mut dyn FnMut(f32) -> Gather>,
) -> Option<Gather> {
    let tex = grids.texture_facing(q.triangle, q.facing_normal)?;
    let mut e = Rgb::ZERO;
    let (mut area, mut count) = (0.0f32, 0.0f32);
    let mut add = |l: &LayerEstimate| {
        e += l.irradiance;
        area = area.max(l.area);
        count += l.count;
    };
    let direct_estimate = direct
        .then(|| grids.layer_estimate(tex, DIRECT, q.position, gamma))
        .flatten();
    // Direct light as the image has it: the direct photons' estimate in the single-map
    // setting, else (shadow rays) the direct layer as gather rays read it. Read once, when
    // first needed.
    let direct_read = std::cell::OnceCell::new();
    let direct_light = || {
        *direct_read.get_or_init(|| match (direct, &direct_estimate) {
            (true, d) => d.map_or(Rgb::ZERO, |d| d.irradiance),
            (false, _) => grids.resolved_layer(tex, DIRECT, q.position, gamma),
        })
    };
    let caustic = caustic_estimate(grids, tex, q, gamma, &direct_light, finer);
    if let Some(c) = &caustic {
        add(c);
    }
    if let Some(d) = &direct_estimate {
        add(d);
    }
    let (indirect, needs_gathering) = if gathering {
        let caustic_light = caustic.map_or(Rgb::ZERO, |c| c.irradiance);
        let i = indirect_where_photons_suffice(grids, tex, q, gamma, &|| direct_light() + caustic_light, gather_rays);
        let needs = i.is_none();
        (i, needs)
    } else {
        (grids.layer_estimate(tex, INDIRECT, q.position, gamma), false)
    };
    if !needs_gathering {
        // Indirect light too deep for gathering is read here only: where gathering supplies
        // indirect light, its deepest ray reaches the same paths one bounce earlier.
        let tail = grids.layer_estimate(tex, TAIL, q.position, gamma);
        for l in indirect.iter().chain(tail.iter()) {
            add(l);
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

    fn scale(level: usize, flux: f32, var: f32, area: f32) -> ScaleEstimate {
        ScaleEstimate {
            level,
            texel: Texel {
                flux: [flux; 3],
                var,
                count: 0.0,
                area,
                ..Texel::default()
            },
        }
    }

    #[test]
    fn photons_from_stratified_points_take_their_own_width_in_the_direct_and_caustic_layers() {
        let s = crate::Settings {
            ici_threshold: 2.0,
            caustic_ici_threshold: 1.0,
            stratified_ici_threshold: 0.25,
            stratified_caustic_ici_threshold: 0.125,
            ..Default::default()
        };
        let widths = |g: Gammas| [CAUSTIC, INDIRECT, DIRECT, TAIL].map(|l| g.of(l));
        assert_eq!(widths(Gammas::of_settings(&s, true)), [0.125, 2.0, 0.25, 2.0]);
        assert_eq!(widths(Gammas::of_settings(&s, false)), [1.0, 2.0, 2.0, 2.0]);
    }

    #[test]
    fn the_photons_indirect_estimate_needs_more_photons_where_it_is_more_of_the_light() {
        let n = 1.0 / (INDIRECT_NOISE * INDIRECT_NOISE);
        let no_rays = f32::INFINITY;
        // Only indirect light: 1/√N at most INDIRECT_NOISE.
        assert!(photons_suffice(1.0, 0.0, n, no_rays));
        assert!(!photons_suffice(1.0, 0.0, 0.9 * n, no_rays));
        // Half the light: a quarter of the photons (above the floor).
        assert!(0.25 * n > MIN_INDIRECT_PHOTONS);
        assert!(photons_suffice(0.5, 0.5, 0.25 * n * 1.001, no_rays));
        assert!(!photons_suffice(0.5, 0.5, 0.24 * n, no_rays));
        // Never below the floor, however little of the light it is.
        assert!(!photons_suffice(1e-4, 1.0, MIN_INDIRECT_PHOTONS - 1.0, no_rays));
        assert!(photons_suffice(1e-4, 1.0, MIN_INDIRECT_PHOTONS, no_rays));
        // No light at all: as if all of it were indirect.
        assert!(!photons_suffice(0.0, 0.0, 0.5 * n, no_rays));
    }

    #[test]
    fn few_gather_rays_leave_indirect_light_to_the_photons_sooner() {
        // All of the light indirect, 1/√N far above INDIRECT_NOISE: the photons are used where
        // they hold PHOTONS_PER_GATHER_RAY per gather ray, and never below the floor.
        let rays = 32.0;
        let n = PHOTONS_PER_GATHER_RAY * rays;
        assert!(n < 0.1 / (INDIRECT_NOISE * INDIRECT_NOISE));
        assert!(photons_suffice(1.0, 0.0, n, rays));
        assert!(!photons_suffice(1.0, 0.0, 0.99 * n, rays));
        assert!(!photons_suffice(1.0, 0.0, n, 16.0 * rays));
        assert!(!photons_suffice(1.0, 0.0, MIN_INDIRECT_PHOTONS - 1.0, 0.0));
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

    use crate::estimate::photon_map::PhotonMap;
    use crate::grid::multiscale::{MultiscaleParams, Probes};
    use crate::photon::{Photon, PhotonKind};
    use crate::sampling::Rng;

    fn p(x: f32, z: f32) -> Vec3 {
        Vec3::new(x, 0.0, z)
    }

    /// Multiscale grids of the 2 m square [0, 2]² at y = 0 (two triangles, no probes' limits,
    /// kernels up to 0.5 m) holding the photons `photon(rng)` gives until it has `n` (None:
    /// the draw is rejected).
    fn square_grids(n: usize, seed: u64, photon: impl FnMut(&mut Rng) -> Option<Photon>) -> MultiscaleGrids {
        square_grids_deep(n, seed, 0, photon)
    }

    /// [`square_grids`] under a `--max-depth` of `max_depth`.
    fn square_grids_deep(
        n: usize,
        seed: u64,
        max_depth: u32,
        mut photon: impl FnMut(&mut Rng) -> Option<Photon>,
    ) -> MultiscaleGrids {
        use crate::grid::planes::{detect_planes, PlaneParams};
        let tris = vec![
            [p(0.0, 0.0), p(0.0, 2.0), p(2.0, 2.0)],
            [p(0.0, 0.0), p(2.0, 2.0), p(2.0, 0.0)],
        ];
        let set = detect_planes(&tris, &PlaneParams::default());
        let mut rng = Rng::keyed(seed, 2, 7);
        let (mut photons, mut tri) = (Vec::new(), Vec::new());
        while photons.len() < n {
            if let Some(ph) = photon(&mut rng) {
                let q = ph.pos();
                tri.push(if q.z > q.x { 0 } else { 1 });
                photons.push(ph);
            }
        }
        let probes = Probes {
            buried: &|_, _| false,
            clearance: &|_, _, _| f32::INFINITY,
        };
        let params = MultiscaleParams {
            max_radius: 0.5,
            max_depth,
            ..MultiscaleParams::default()
        };
        MultiscaleGrids::build(set, &tris, &photons, &tri, &params, &probes, None)
    }

    /// Under `--max-depth 12` indirect photons stored at their 11th interaction are the last
    /// order of light the camera may show, and one final-gather bounce would make their paths
    /// 13 segments long: the camera reads them where it reads the photons' indirect light,
    /// gather rays never do. Without a limit every photon is gathered.
    #[test]
    fn light_too_deep_for_gathering_is_read_by_the_camera_only() {
        let n = 200_000;
        // 1 W/m² over the 4 m² square, half of it at depth 10 and half at depth 11.
        let power = Rgb::splat(4.0 / n as f32);
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 2.0,
        };
        let q = Query {
            position: p(1.2, 0.8),
            facing_normal: Vec3::Y,
            geometric_normal: Vec3::Y,
            triangle: 1,
            footprint: 0.0,
            glossy: false,
        };
        for (max_depth, gathered_share) in [(12, 0.5), (0, 1.0)] {
            let mut k = 0u32;
            let mut g = square_grids_deep(n, 9, max_depth, |rng| {
                k += 1;
                let at = p(rng.uniform() * 2.0, rng.uniform() * 2.0);
                let ph = Photon::new(at, power, Vec3::Y, Vec3::Y, PhotonKind::Indirect);
                Some(ph.with_depth(10 + k % 2))
            });
            g.resolve_for_gathering(gammas);
            let gathered = g.irradiance(q.triangle, q.position, Vec3::Y, gammas).unwrap();
            assert!((gathered.x - gathered_share).abs() < 0.03, "{max_depth}: {gathered:?}");
            let seen = gather(&g, &q, gammas, false, false, 32.0, None).unwrap();
            let seen = seen.flux.x / (PI * seen.r2);
            assert!((seen - 1.0).abs() < 0.03, "{max_depth}: {seen}");
        }
    }

    /// Flat indirect light on a 2 m square, 20 000 photons: far too few for its noise to be
    /// negligible, enough per gather ray when the pixel has one; a glossy point gathers anyway.
    #[test]
    fn the_gather_rays_and_a_glossy_lobe_decide_who_supplies_indirect_light() {
        let n = 20_000;
        let power = Rgb::splat(4.0 / n as f32);
        let mut g = square_grids(n, 3, |rng| {
            let at = p(rng.uniform() * 2.0, rng.uniform() * 2.0);
            Some(Photon::new(at, power, Vec3::Y, Vec3::Y, PhotonKind::Indirect))
        });
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 2.0,
        };
        g.resolve_for_gathering(gammas);
        let q = Query {
            position: p(1.0, 1.0),
            facing_normal: Vec3::Y,
            geometric_normal: Vec3::Y,
            triangle: 1,
            footprint: 0.0,
            glossy: false,
        };
        let needs = |q: &Query, rays: f32| gather(&g, q, gammas, false, true, rays, None).unwrap().needs_gathering;
        assert!(!needs(&q, 1.0), "one gather ray: the photons' estimate");
        assert!(needs(&q, 1e4), "ten thousand gather rays: gathering");
        let glossy = Query { glossy: true, ..q };
        assert!(needs(&glossy, 1.0), "a glossy lobe: gathering");
    }

    /// A field rising linearly with x, sampled by photons on a 2 m square: at the square's
    /// corners and edges (one-sided kernels) the local-linear fit reads the level at the
    /// point, not the kernel's mean, which lies towards the square's inside.
    #[test]
    fn a_gradient_at_the_plane_edge_is_read_at_the_point() {
        // Irradiance 1 + x W/m²: 8 W over the square.
        let n = 400_000;
        let power = Rgb::splat(8.0 / n as f32);
        let g = square_grids(n, 5, |rng| {
            let (x, z) = (rng.uniform() * 2.0, rng.uniform() * 2.0);
            (rng.uniform() * 3.0 <= 1.0 + x).then(|| Photon::new(p(x, z), power, Vec3::Y, Vec3::Y, PhotonKind::Direct))
        });
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 2.0,
        };
        for q in [
            p(0.002, 0.002),
            p(1.998, 1.0),
            p(0.002, 1.0),
            p(1.0, 1.998),
            p(1.0, 1.0),
        ] {
            let e = g.layer_estimate(&g.textures[0], DIRECT, q, gammas).unwrap();
            let truth = 1.0 + q.x;
            let err = e.irradiance.x / truth - 1.0;
            assert!(
                err.abs() < 0.04,
                "{q}: {} W/m² against {truth} (level {})",
                e.irradiance.x,
                e.level
            );
        }
    }

    /// The curvature formulas against closed forms: box means of f = x² + 3xy − y² give
    /// its Hessian exactly (a box mean adds the same constant to every texel), and a box
    /// kernel of side s centred on the point reads ½ (f_xx + f_yy) s²/12 too high.
    #[test]
    fn curvature_bias_and_hessian_match_closed_forms() {
        let side = 4.0f32;
        // Over a texel of side S centred at (x, y): mean x² = x² + S²/12, mean y² = y² + S²/12,
        // mean xy = xy; the S²/12 terms cancel in this f.
        let texels: Vec<Vec<Texel>> = (0..3)
            .map(|j| {
                (0..3)
                    .map(|i| {
                        let (x, y) = ((i as f32 - 1.0) * side + 0.5, (j as f32 - 1.0) * side - 0.25);
                        let area = side * side;
                        let mean = x * x + 3.0 * x * y - y * y;
                        Texel {
                            flux: [mean * area; 3],
                            area,
                            ..Texel::default()
                        }
                    })
                    .collect()
            })
            .collect();
        let block = [0, 1, 2].map(|j| [0, 1, 2].map(|i| &texels[j][i]));
        let h = block_hessian(&block, side);
        for (got, want) in h.iter().zip([2.0, 3.0, -2.0]) {
            assert!((got - want).abs() < 1e-4, "{h:?}");
        }
        let s = 3.0f32;
        let a = s * s;
        let kernel = Texel {
            area: a,
            area_moment2: [a * s * s / 12.0, 0.0, a * s * s / 12.0],
            ..Texel::default()
        };
        assert!(curvature_bias(&kernel, h).abs() < 1e-5, "f_xx + f_yy = 0");
        // f = (x² + y²)/2: the centred box's local-linear value is s²/12 above f(0) = 0.
        let h2 = [1.0, 0.0, 1.0];
        assert!((curvature_bias(&kernel, h2) - s * s / 12.0).abs() < 1e-5);
        // A box centred at (1, 0): the fit over it, read at 0, is s²/12 − ½ (x: the box mean
        // ½ (1 + s²/12) less the slope 1 times the centroid's offset 1; y: s²/24).
        let shifted = Texel {
            area_moment: [a, 0.0],
            area_moment2: [a * (s * s / 12.0 + 1.0), 0.0, a * s * s / 12.0],
            ..kernel
        };
        assert!((curvature_bias(&shifted, h2) - (s * s / 12.0 - 0.5)).abs() < 1e-5);
    }

    /// Noisy flat light: the curvature read at a point moves smoothly with it (one block per
    /// texel stepped at each texel edge) and equals the centred block's at a texel's centre,
    /// in the interior and where the blocks are shifted off the plane's edge.
    #[test]
    fn the_curvature_moves_smoothly_across_texel_edges() {
        let n = 200_000;
        let power = Rgb::splat(4.0 / n as f32);
        let g = square_grids(n, 5, |rng| {
            let at = p(2.0 * rng.uniform(), 2.0 * rng.uniform());
            Some(Photon::new(at, power, Vec3::Y, Vec3::Y, PhotonKind::Direct))
        });
        let t = &g.textures[0][DIRECT];
        let level = 3;
        let side = 8.0f32;
        let cells = t.plane.res_u as f32;
        assert!(cells >= 8.0 * side, "a grid of {cells} cells");
        let at = |gx: f32, gy: f32| blended_hessian(t, level, gx, gy).expect("full blocks");
        let block = |gx: f32, gy: f32| block_hessian(&t.full_block(level, gx, gy, INTERIOR_COVERAGE).unwrap(), side);
        let close = |a: [f32; 3], b: [f32; 3], tol: f32| a.iter().zip(b).all(|(a, b)| (a - b).abs() <= tol);
        let gy = 3.3 * side;
        let mut largest_step = 0.0f32;
        let mut spread = 0.0f32;
        for k in 0..(cells / side) as usize {
            // A texel's centre, then both sides of its upper edge.
            let centre = (k as f32 + 0.5) * side;
            let scale = block(centre, 3.5 * side).iter().fold(0.0f32, |m, h| m.max(h.abs()));
            assert!(
                close(
                    at(centre, 3.5 * side),
                    block(centre, 3.5 * side),
                    1e-4 * scale.max(1e-6)
                ),
                "texel {k}"
            );
            spread = spread.max(scale);
            let edge = (k + 1) as f32 * side;
            let (a, b) = (at(edge - 1e-3, gy), at(edge + 1e-3, gy));
            largest_step = largest_step.max(a.iter().zip(b).fold(0.0, |m, (a, b)| m.max((a - b).abs())));
        }
        assert!(spread > 0.0, "noise has curvature");
        assert!(
            largest_step < 1e-2 * spread,
            "a step of {largest_step} where blocks differ by {spread}"
        );
    }

    /// A point light 0.8 m above the middle of the square: the light peaks beneath it with
    /// negative curvature (E = h³ / (h² + r²)^{3/2}), and a kernel wide enough to hold
    /// thousands of photons reads a local-linear fit about 2 % low there unless its
    /// curvature bias is taken off (−1.8 % over these points without it, +0.2 % with).
    #[test]
    fn a_point_lights_peak_is_not_flattened() {
        let h = 0.8f64;
        let irradiance = |x: f64, z: f64| {
            let r2 = (x - 1.0).powi(2) + (z - 1.0).powi(2);
            (h * h / (h * h + r2)).powf(1.5)
        };
        // Total power on the square: a midpoint sum over 1 mm cells.
        let total: f64 = (0..2000)
            .flat_map(|i| (0..2000).map(move |j| (i, j)))
            .map(|(i, j)| irradiance((i as f64 + 0.5) * 1e-3, (j as f64 + 0.5) * 1e-3) * 1e-6)
            .sum();
        let n = 400_000;
        let power = Rgb::splat((total / n as f64) as f32);
        let g = square_grids(n, 13, |rng| {
            let (x, z) = (rng.uniform() * 2.0, rng.uniform() * 2.0);
            (rng.uniform() <= irradiance(x as f64, z as f64) as f32)
                .then(|| Photon::new(p(x, z), power, Vec3::Y, Vec3::Y, PhotonKind::Direct))
        });
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 2.0,
        };
        let mut sum = 0.0;
        let mut k = 0;
        for i in 0..9 {
            for j in 0..9 {
                let (x, z) = (0.84 + 0.04 * i as f32, 0.84 + 0.04 * j as f32);
                let e = g.layer_estimate(&g.textures[0], DIRECT, p(x, z), gammas).unwrap();
                sum += e.irradiance.x as f64 / irradiance(x as f64, z as f64) - 1.0;
                k += 1;
            }
        }
        let bias = sum / k as f64;
        assert!(bias.abs() < 0.01, "mean relative error beneath the light {bias:.4}");
    }

    /// Flat caustic light of 1 W/m² over the 2 m square (200 000 photons: two per finest cell),
    /// and one photon's variance.
    fn flat_caustic(seed: u64) -> (MultiscaleGrids, f32) {
        let n = 200_000;
        let power = Rgb::splat(4.0 / n as f32);
        let g = square_grids(n, seed, |rng| {
            let at = p(2.0 * rng.uniform(), 2.0 * rng.uniform());
            Some(Photon::new(at, power, Vec3::Y, Vec3::Y, PhotonKind::Caustic))
        });
        let floor = g.mean_power[CAUSTIC] * g.mean_power[CAUSTIC];
        (g, floor)
    }

    /// Flat caustic light: a fine kernel that stopped by chance is read at its neighbours'
    /// (wider) scale, so the estimate's spread over the plane falls; a narrow line keeps its
    /// sharpness (`a_caustic_finer_than_a_cell_follows_the_pixels_and_keeps_its_power`).
    #[test]
    fn a_chance_stop_in_flat_caustic_light_takes_its_neighbours_scale() {
        let (g, floor) = flat_caustic(3);
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 1.0,
        };
        let t = &g.textures[0];
        let mut rng = Rng::keyed(1, 2, 3);
        let (mut with, mut without, mut fine_alone) = (0.0f32, 0.0f32, 0);
        let points = 2000;
        for _ in 0..points {
            let q = p(0.3 + 1.4 * rng.uniform(), 0.3 + 1.4 * rng.uniform());
            let alone = choose_scale(t[CAUSTIC].scales(q), gammas.caustic, floor, 1.0).expect("lit");
            let chosen = g.caustic_consensus(&t[CAUSTIC], q, gammas, alone);
            fine_alone += usize::from(alone.level <= CONSENSUS_MAX_LEVEL);
            without += (alone.irradiance.x - 1.0).powi(2) / points as f32;
            with += (chosen.irradiance.x - 1.0).powi(2) / points as f32;
        }
        let (with, without) = (with.sqrt(), without.sqrt());
        assert!(
            fine_alone > points / 50,
            "chance stops at the finest levels: {fine_alone} of {points}"
        );
        assert!(
            with < 0.7 * without,
            "RMS error {with} with the consensus, {without} without"
        );
    }

    /// Indirect light on the square, `photon_at(rng)` placing each photon (None: rejected).
    fn indirect_square(seed: u64, mut photon_at: impl FnMut(&mut Rng) -> Option<Vec3>) -> MultiscaleGrids {
        let n = 200_000;
        let power = Rgb::splat(4.0 / n as f32);
        square_grids(n, seed, |rng| {
            let at = photon_at(rng)?;
            Some(Photon::new(at, power, Vec3::Y, Vec3::Y, PhotonKind::Indirect).with_depth(2))
        })
    }

    /// Flat indirect light: an interior kernel that stopped by chance (few photons: final
    /// gathering would take over there, a cluster of grain amid the photons' smooth estimate)
    /// is read at its neighbours' wider scale. Beside a sharp step in the light (no geometry
    /// to stop the kernels) the reads get little worse.
    #[test]
    fn a_chance_stop_in_flat_indirect_light_takes_its_neighbours_scale() {
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 1.0,
        };
        let flat = indirect_square(8, |rng| Some(p(2.0 * rng.uniform(), 2.0 * rng.uniform())));
        let t = &flat.textures[0];
        let mut rng = Rng::keyed(2, 3, 4);
        let points = 4000;
        let (mut alone, mut chosen) = (Vec::new(), Vec::new());
        for _ in 0..points {
            let q = p(0.6 + 0.8 * rng.uniform(), 0.6 + 0.8 * rng.uniform());
            let a = flat.interior_estimate(t, INDIRECT, q, gammas).expect("lit");
            alone.push(a);
            chosen.push(flat.indirect_consensus(t, q, gammas, a));
        }
        let widest = alone.iter().map(|e| e.level).max().unwrap_or(0);
        let stops = |es: &[LayerEstimate]| es.iter().filter(|e| e.level + 2 <= widest).count();
        let rms = |es: &[LayerEstimate]| {
            (es.iter().map(|e| (e.irradiance.x - 1.0).powi(2)).sum::<f32>() / es.len() as f32).sqrt()
        };
        eprintln!(
            "flat: widest {widest}, stops two levels finer {} alone, {} with the consensus; RMS {} → {}",
            stops(&alone),
            stops(&chosen),
            rms(&alone),
            rms(&chosen)
        );
        assert!(
            stops(&alone) > points / 100,
            "chance stops: {} of {points}",
            stops(&alone)
        );
        assert!(
            stops(&chosen) * 4 < stops(&alone),
            "{} → {}",
            stops(&alone),
            stops(&chosen)
        );
        assert!(
            rms(&chosen) < 0.9 * rms(&alone),
            "RMS error {} → {}",
            rms(&alone),
            rms(&chosen)
        );

        // Light on x < 1 only, read within 4 cm of the step.
        let step = indirect_square(9, |rng| {
            let x = 2.0 * rng.uniform();
            (x < 1.0).then(|| p(x, 2.0 * rng.uniform()))
        });
        let t = &step.textures[0];
        let (mut err_alone, mut err_chosen) = (0.0f32, 0.0f32);
        for i in 0..points {
            let x = 0.96 + 0.08 * (i as f32 + 0.5) / points as f32;
            let q = p(x, 0.6 + 0.8 * rng.uniform());
            let truth = if x < 1.0 { 2.0 } else { 0.0 };
            let Some(a) = step.interior_estimate(t, INDIRECT, q, gammas) else {
                continue;
            };
            let c = step.indirect_consensus(t, q, gammas, a);
            err_alone += (a.irradiance.x - truth).abs();
            err_chosen += (c.irradiance.x - truth).abs();
        }
        eprintln!(
            "step: mean abs error {} alone, {} with the consensus",
            err_alone / points as f32,
            err_chosen / points as f32
        );
        // The price: a few points beside the step widen too (docs/multiscale.md).
        assert!(err_chosen <= 1.1 * err_alone, "at the step: {err_alone} → {err_chosen}");
    }

    /// Flat caustic light with two photons per finest cell, read at the caustic layer's narrow
    /// interval without the consensus: a kernel that by chance caught few photons must not end
    /// the widening at a dark read (the normal approximation's interval for 0–2 photons lies
    /// too low), so the reads are not biased dark.
    #[test]
    fn few_photons_do_not_stop_a_narrow_interval_dark() {
        let (g, floor) = flat_caustic(11);
        let t = &g.textures[0];
        let mut rng = Rng::keyed(4, 5, 6);
        let points = 4000;
        let (mut sum, mut dark) = (0.0f64, 0);
        for _ in 0..points {
            let q = p(0.3 + 1.4 * rng.uniform(), 0.3 + 1.4 * rng.uniform());
            let e = choose_scale(t[CAUSTIC].scales(q), 1.0, floor, 1.0)
                .expect("lit")
                .irradiance
                .x;
            sum += e as f64;
            dark += usize::from(e < 0.5);
        }
        let mean = sum / points as f64;
        assert!((mean - 1.0).abs() < 0.02, "mean read {mean} of 1");
        assert!(dark * 200 < points, "{dark} of {points} reads below half the light");
    }

    /// A caustic line narrower than the finest cell (a fold seen close up, pixels smaller than
    /// a cell): with the disc finer than the texels the estimate follows the line as the
    /// pixels see it, and the light across it sums to the line's power (a fixed disc, unlike
    /// a k-nearest one, adds none).
    #[test]
    fn a_caustic_finer_than_a_cell_follows_the_pixels_and_keeps_its_power() {
        let (n, line_share, width) = (1_000_000, 0.5, 0.00005);
        let power = Rgb::splat(4.0 / n as f32); // 4 W over the 2 m square
        let mut photons = Vec::new();
        let g = square_grids(n, 5, |rng| {
            let x = if rng.uniform() < line_share {
                1.0003 + width * rng.uniform()
            } else {
                2.0 * rng.uniform()
            };
            let ph = Photon::new(
                p(x, 0.2 + 1.6 * rng.uniform()),
                power,
                Vec3::Y,
                Vec3::Y,
                PhotonKind::Caustic,
            );
            photons.push(ph);
            Some(ph)
        });
        let cell = g.textures[0][CAUSTIC].cell_size();
        assert!(
            width < 0.1 * cell,
            "the line ({width} m) must be far narrower than a cell ({cell} m)"
        );
        let footprint = 0.6 * cell;
        let map = PhotonMap::build(photons, 100, 4.0, 0.5);
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 1.25,
        };
        let read = |x: f32, finer: bool| -> f32 {
            let mut e = 0.0;
            for i in 0..20 {
                let q = Query {
                    position: p(x, 0.5 + i as f32 * 0.05),
                    facing_normal: Vec3::Y,
                    geometric_normal: Vec3::Y,
                    triangle: 0,
                    footprint,
                    glossy: false,
                };
                let mut disc = |r: f32| map.within(q.position, Vec3::Y, r);
                let f = finer.then_some(&mut disc as &mut dyn FnMut(f32) -> Gather);
                let got = gather(&g, &q, gammas, false, true, 32.0, f).expect("on the plane");
                e += got.flux.x / (PI * got.r2) / 20.0;
            }
            e
        };
        let background = 4.0 * (1.0 - line_share) / 4.0;
        let per_metre = 4.0 * line_share / 1.6;
        let centre = 1.0003 + 0.5 * width;
        // The line as a pixel of the footprint's radius sees it: its power over the chord.
        let seen = |x: f32| {
            let d = (x - centre).abs().min(footprint);
            background + per_metre * 2.0 * (footprint * footprint - d * d).sqrt() / (PI * footprint * footprint)
        };
        let steps = 480;
        let dx = 12.0 * cell / steps as f32;
        let (mut err, mut err_coarse, mut excess) = (0.0f32, 0.0f32, 0.0f32);
        for i in 0..steps {
            let x = centre - 6.0 * cell + (i as f32 + 0.5) * dx;
            let (fine, coarse) = (read(x, true), read(x, false));
            err += (fine - seen(x)).powi(2) / steps as f32;
            err_coarse += (coarse - seen(x)).powi(2) / steps as f32;
            excess += (fine - background) * dx;
        }
        let peak = seen(centre);
        let (err, err_coarse) = (err.sqrt() / peak, err_coarse.sqrt() / peak);
        assert!(err < 0.1, "finer disc: RMS error across the line {err} of its peak");
        assert!(
            err < 0.6 * err_coarse,
            "finer disc {err}, finest texel {err_coarse} of the peak"
        );
        assert!(
            (excess / per_metre - 1.0).abs() < 0.03,
            "power across the line: {excess} W/m, expected {per_metre}"
        );
    }

    /// A point light's hard shadow edge at x = 1 (light for x > 1 only, 1 W/m²): the lit
    /// side reads its level up to the edge, not the mean of a kernel half in the shadow, and
    /// the shadow reads no light. Without the dark cells the first 2 cm of the lit side read
    /// 0.6–0.8 and light leaked a kernel's reach into the shadow.
    #[test]
    fn a_hard_shadow_edge_stays_sharp_on_both_sides() {
        let n = 400_000;
        let power = Rgb::splat(2.0 / n as f32);
        let g = square_grids(n, 11, |rng| {
            let (x, z) = (1.0 + rng.uniform(), rng.uniform() * 2.0);
            Some(Photon::new(p(x, z), power, Vec3::Y, Vec3::Y, PhotonKind::Direct))
        });
        let gammas = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 2.0,
        };
        let read = |x: f32| {
            let mean: f32 = (0..40)
                .map(|i| {
                    let q = p(x, 0.3 + 1.4 * i as f32 / 40.0);
                    g.layer_estimate(&g.textures[0], DIRECT, q, gammas)
                        .map_or(0.0, |e| e.irradiance.x)
                })
                .sum();
            mean / 40.0
        };
        for x in [1.006, 1.015, 1.03, 1.1] {
            let e = read(x);
            assert!((e - 1.0).abs() < 0.04, "lit side at x = {x}: {e} W/m²");
        }
        for x in [0.99, 0.97, 0.9] {
            let e = read(x);
            assert!(e < 1e-3, "shadow at x = {x}: {e} W/m²");
        }
    }

    /// A thin quad lit by 1 W/m² on top, with a third as many photons landing underneath at
    /// 3 W/m²: the textures keep the top's light only (the underside is the photon map's), and
    /// final-gather rays reading the resolved texture see what the point estimate says.
    #[test]
    fn a_plane_keeps_its_lit_side_and_gather_rays_read_its_estimate() {
        let (n_top, n_under) = (300_000, 100_000);
        let mut i = 0;
        let mut g = square_grids(n_top + n_under, 9, |rng| {
            let (x, z) = (rng.uniform() * 2.0, rng.uniform() * 2.0);
            let (normal, power) = if i < n_top {
                (Vec3::Y, 4.0 / n_top as f32)
            } else {
                (-Vec3::Y, 12.0 / n_under as f32)
            };
            i += 1;
            Some(Photon::new(
                p(x, z),
                Rgb::splat(power),
                normal,
                normal,
                PhotonKind::Direct,
            ))
        });
        let gamma = Gammas {
            global: 2.0,
            direct: 2.0,
            caustic: 1.25,
        };
        for q in [p(1.0, 1.0), p(0.3, 1.7), p(1.99, 0.01)] {
            assert_eq!(g.irradiance(0, q, -Vec3::Y, gamma), None, "underside at {q}");
            let at_point = g.irradiance(0, q, Vec3::Y, gamma).unwrap().x;
            assert!((at_point - 1.0).abs() < 0.05, "{q}: {at_point} W/m² on top");
        }
        // Reports say which side the plane's textures hold, and what gathering reads.
        assert!(
            g.describe()[0].contains("lit side facing (0.00, 1.00, 0.00)"),
            "{:?}",
            g.describe()
        );
        assert!(!g.describe()[0].contains("gathering reads"));
        g.resolve_for_gathering(gamma);
        assert!(g.describe()[0].contains("gathering reads"), "{:?}", g.describe());
        for q in [p(1.0, 1.0), p(0.3, 1.7), p(1.99, 0.01), p(0.0, 0.0)] {
            let read = g.irradiance(1, q, Vec3::Y, gamma).unwrap().x;
            assert!((read - 1.0).abs() < 0.05, "{q}: {read} W/m² read by a gather ray");
        }
    }
}
