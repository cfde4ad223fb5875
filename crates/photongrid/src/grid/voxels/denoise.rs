//! Denoising the voxel counts: multiplicative Haar–Fisz-style hard thresholding over 2×2×2
//! blocks, per normal bin, only over voxels that have area in the bin (see
//! [`VoxelGrid::denoise_with`]). Block totals are conserved exactly at every level, so the mean
//! is preserved.

use super::grid::{VoxelGrid, NORMAL_BINS};
use crate::grid::noise::{anscombe, mad_sigma, universal_threshold};
use rayon::prelude::*;

/// Nodes of one level of the per-bin 2×2×2 hierarchy.
struct Level {
    keys: Vec<[i32; 3]>,
    /// Raw (unfiltered) photon counts, summed over children.
    c: Vec<f64>,
    /// Areas (m²), summed over children.
    a: Vec<f64>,
    /// For levels ≥ 1: children (indices into the level below) of node `p` are
    /// `children[start[p]..start[p + 1]]`.
    children: Vec<u32>,
    start: Vec<u32>,
}

impl Level {
    fn coarsen(&self) -> Level {
        let parent = |k: [i32; 3]| [k[0] >> 1, k[1] >> 1, k[2] >> 1];
        let mut order: Vec<u32> = (0..self.keys.len() as u32).collect();
        order.sort_unstable_by_key(|&i| parent(self.keys[i as usize]));
        let mut out = Level {
            keys: Vec::new(),
            c: Vec::new(),
            a: Vec::new(),
            children: Vec::new(),
            start: Vec::new(),
        };
        for (pos, &i) in order.iter().enumerate() {
            let k = parent(self.keys[i as usize]);
            if out.keys.last() != Some(&k) {
                out.keys.push(k);
                out.c.push(0.0);
                out.a.push(0.0);
                out.start.push(pos as u32);
            }
            *out.c.last_mut().unwrap() += self.c[i as usize];
            *out.a.last_mut().unwrap() += self.a[i as usize];
        }
        out.start.push(order.len() as u32);
        out.children = order;
        out
    }

    fn block(&self, p: usize) -> &[u32] {
        &self.children[self.start[p] as usize..self.start[p + 1] as usize]
    }
}

struct Hierarchy {
    /// Level-0 node → grid slot.
    slots: Vec<u32>,
    levels: Vec<Level>,
}

/// Anscombe-domain residual of count `c` against expectation `lambda`, normalised by the
/// standard deviation of a residual against a mean estimated from a pool containing the
/// child (`1 − aᵢ/A_pool`).
#[inline]
fn residual(c: f64, lambda: f64, a_child: f64, a_pool: f64) -> f64 {
    let frac = (1.0 - a_child / a_pool).max(1e-9);
    (anscombe(c) - anscombe(lambda)) / frac.sqrt()
}

/// Hard-threshold one block's details with sequential exclusion of significant children.
/// Writes the thresholded child counts to `u` (whose sum equals `Σ c`), returns how many
/// children were kept as significant.
fn threshold_block(c: &[f64], a: &[f64], tau: f64, u: &mut [f64]) -> usize {
    let k = c.len();
    let mut kept = [false; 8];
    let mut n_kept = 0;
    loop {
        let (mut cr, mut ar, mut nr) = (0.0, 0.0, 0);
        for j in 0..k {
            if !kept[j] {
                cr += c[j];
                ar += a[j];
                nr += 1;
            }
        }
        if nr < 2 || ar <= 0.0 || cr <= 0.0 {
            break;
        }
        let rho = cr / ar;
        let mut best = (0.0, usize::MAX);
        for j in 0..k {
            if !kept[j] {
                let z = residual(c[j], rho * a[j], a[j], ar).abs();
                if z > best.0 {
                    best = (z, j);
                }
            }
        }
        if best.1 != usize::MAX && best.0 > tau {
            kept[best.1] = true;
            n_kept += 1;
        } else {
            break;
        }
    }
    let (mut cr, mut ar) = (0.0, 0.0);
    for j in 0..k {
        if !kept[j] {
            cr += c[j];
            ar += a[j];
        }
    }
    let rho = if ar > 0.0 { cr / ar } else { 0.0 };
    for j in 0..k {
        u[j] = if kept[j] { c[j] } else { rho * a[j] };
    }
    n_kept
}

/// Noise level σ of the normalised finest details and their number `M` (steps 3 and 4 of
/// [`VoxelGrid::denoise_with`]).
fn finest_noise(hiers: &[Hierarchy]) -> (f64, usize) {
    let mut z: Vec<f64> = Vec::new();
    let mut m = 0usize;
    for h in hiers {
        let (l1, l0) = (&h.levels[1], &h.levels[0]);
        for p in 0..l1.keys.len() {
            let ch = l1.block(p);
            if ch.len() < 2 || l1.c[p] <= 0.0 {
                continue;
            }
            m += ch.len() - 1;
            let rho = l1.c[p] / l1.a[p];
            for &i in ch {
                let i = i as usize;
                z.push(residual(l0.c[i], rho * l0.a[i], l0.a[i], l1.a[p]));
            }
        }
    }
    let sigma = if z.is_empty() {
        1.0
    } else {
        mad_sigma(&mut z).clamp(0.5, 4.0)
    };
    (sigma, m)
}

/// Statistics of one [`VoxelGrid::denoise_with`] pass.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DenoiseStats {
    /// Noise level of the normalised finest details (MAD / 0.6745, clamped to `[0.5, 4]`).
    pub sigma: f32,
    /// Threshold applied to normalised details: `scale · σ · sqrt(2 ln M)`.
    pub threshold: f32,
    /// `M`: number of finest-level detail coefficients (Σ over blocks of `children − 1`).
    pub finest_details: usize,
    /// Children kept as significant, summed over all levels and bins.
    pub kept: usize,
    /// Number of Haar levels used.
    pub levels: usize,
}

impl VoxelGrid {
    /// Two-level 3D Haar denoising of the counts; see [`VoxelGrid::denoise_with`].
    pub fn denoise(&mut self, threshold_scale: f32) {
        self.denoise_with(threshold_scale, 2);
    }

    /// Denoise the per-bin photon counts with a `levels`-level (clamped to 1..=8) Haar
    /// transform over 2×2×2 blocks of the sparse grid. Recomputed from the raw counts on each
    /// call; the result replaces the counts used by all estimates until the next photon is
    /// added or [`VoxelGrid::clear_denoise`].
    ///
    /// Exactly, for every bin independently and only over voxels with area in that bin
    /// (missing voxels are "no surface": never filled, never averaged across):
    ///
    /// 1. **Hierarchy**: level-0 nodes are voxels with area; a level-`l` node is the set of
    ///    level-`l−1` nodes with the same key `>> 1` (a 2×2×2 block, 1..8 present children);
    ///    its count `N` and area `A` are the children's sums (the unnormalised Haar scaling
    ///    coefficients, area-weighted / unbalanced where children differ in area).
    /// 2. **Details** (Haar–Fisz / Anscombe): child `i` of a block deviates from the block's
    ///    density `ρ = N/A` by `zᵢ = 2(√(Nᵢ+3/8) − √(ρAᵢ+3/8)) / √(1 − Aᵢ/A)`: the Anscombe
    ///    variance-stabilised residual against the block mean, scaled to unit variance
    ///    under Poisson noise (the factor accounts for the child's share in the mean).
    /// 3. **σ** = median |zᵢ| / 0.6745 over all finest-level (level 1) blocks with ≥ 2
    ///    children and non-zero count (all bins), clamped to `[0.5, 4]` (≈ 1 for Poisson).
    /// 4. **Universal threshold** `τ = threshold_scale · σ · sqrt(2 ln M)`, `M` = Σ over
    ///    finest blocks of (children − 1).
    /// 5. **Hard thresholding with exclusion**, per block at every level: repeatedly take
    ///    the not-yet-kept child with the largest |z| (z recomputed against the mean of the
    ///    not-yet-kept children); if above τ keep it (its detail is significant) and repeat.
    ///    Kept children keep their count; the others get `ρ_rest·Aᵢ` with `ρ_rest` the
    ///    density of the non-kept children. The block total is unchanged, and a bright (or
    ///    dark) child is neither smeared into its siblings nor diluted by them.
    /// 6. **Reconstruction** top-down: a coarsest node keeps its raw count; a node's new
    ///    count `V` is passed to its children by scaling their thresholded counts by
    ///    `V / N_raw` (multiplicative Haar: keeps zeros/shadows at zero, never negative).
    ///
    /// Totals are conserved per coarsest block, so the mean density is preserved. Flux is
    /// not filtered.
    pub fn denoise_with(&mut self, threshold_scale: f32, levels: usize) -> DenoiseStats {
        let levels = levels.clamp(1, 8);
        let hiers: Vec<Hierarchy> = (0..NORMAL_BINS)
            .into_par_iter()
            .map(|b| self.hierarchy(b, levels))
            .collect();

        let (sigma, m) = finest_noise(&hiers);
        // Scaling σ rather than τ keeps the rounding of the product (scale·σ)·√(2 ln M).
        let tau = universal_threshold(f64::from(threshold_scale.max(0.0)) * sigma, m.max(2));

        let results: Vec<(Vec<f64>, usize)> = hiers.par_iter().map(|h| Self::reconstruct(h, tau)).collect();
        let mut filtered = vec![[0.0f32; NORMAL_BINS]; self.count.len()];
        let mut kept = 0;
        for (b, (h, (v0, k))) in hiers.iter().zip(results).enumerate() {
            kept += k;
            for (node, &slot) in h.slots.iter().enumerate() {
                filtered[slot as usize][b] = v0[node] as f32;
            }
        }
        self.filtered = Some(filtered);
        DenoiseStats {
            sigma: sigma as f32,
            threshold: tau as f32,
            finest_details: m,
            kept,
            levels,
        }
    }

    fn hierarchy(&self, bin: usize, levels: usize) -> Hierarchy {
        let mut slots = Vec::new();
        let mut l0 = Level {
            keys: Vec::new(),
            c: Vec::new(),
            a: Vec::new(),
            children: Vec::new(),
            start: Vec::new(),
        };
        for (s, a) in self.area.iter().enumerate() {
            if a[bin] > 0.0 {
                slots.push(s as u32);
                l0.keys.push(self.keys[s]);
                l0.c.push(f64::from(self.count[s][bin]));
                l0.a.push(f64::from(a[bin]));
            }
        }
        let mut lv = vec![l0];
        for _ in 0..levels {
            let next = lv.last().unwrap().coarsen();
            lv.push(next);
        }
        Hierarchy { slots, levels: lv }
    }

    fn reconstruct(h: &Hierarchy, tau: f64) -> (Vec<f64>, usize) {
        let top = h.levels.len() - 1;
        let mut v = h.levels[top].c.clone();
        let mut kept = 0;
        for l in (1..=top).rev() {
            let (lev, below) = (&h.levels[l], &h.levels[l - 1]);
            let mut nv = vec![0.0; below.c.len()];
            let (mut c, mut a, mut u) = ([0.0; 8], [0.0; 8], [0.0; 8]);
            for (p, &vp) in v.iter().enumerate() {
                let ch = lev.block(p);
                let k = ch.len();
                for (j, &i) in ch.iter().enumerate() {
                    c[j] = below.c[i as usize];
                    a[j] = below.a[i as usize];
                }
                kept += threshold_block(&c[..k], &a[..k], tau, &mut u[..k]);
                let (cp, ap) = (lev.c[p], lev.a[p]);
                for (j, &i) in ch.iter().enumerate() {
                    nv[i as usize] = if cp > 0.0 {
                        u[j] * vp / cp
                    } else if ap > 0.0 {
                        vp * a[j] / ap
                    } else {
                        0.0
                    };
                }
            }
            v = nv;
        }
        (v, kept)
    }
}
