//! The voxel grid itself: a hash of the occupied voxels with, per normal bin, their area,
//! photon count and flux; counting photons into it and reading density and radius back.
//!
//! * **Normal bins** ([`NORMAL_BINS`] = 6): dominant axis of the normal and its sign
//!   (`+x, −x, +y, −y, +z, −z` = bins `0..6`, see [`normal_bin`]). Two sides of a thin wall,
//!   or a sphere's underside and the floor it rests on, land in opposite bins and never mix.
//!   Six bins (rather than a finer octahedral quantisation) keep every bin's area large,
//!   so counts per voxel-bin stay high. Triangles are binned by their winding normal
//!   `(b−a)×(c−a)`; photons must be counted with the same geometric (not shading, not
//!   face-forwarded) normal.
//! * **Sparse storage**: a hash map (fast multiplicative hash) from the integer voxel
//!   coordinate to a dense slot index; per slot the voxel key, `area[6]` (f32, m²),
//!   `count[6]` (u32), `flux[6]` (f32) and, after [`VoxelGrid::denoise`], filtered
//!   counts `[6]` (f32). Memory is proportional to the number of voxels the surfaces
//!   cross, never to the bounding box.
//! * **Grid space**: a point `p` maps to `g = (p − origin)·(1/s)`; its voxel is `floor(g)`.
//!   The same f32 expression is used for triangle vertices and photons, so a surface lying
//!   exactly on a voxel face is attributed consistently. [`VoxelGrid::from_triangles`] puts
//!   the origin at the scene minimum minus an irrational fraction of a voxel per axis, so
//!   axis-aligned walls at the scene's extremes sit inside voxels rather than on faces.
//! * **Photon location**: the voxel containing `p`, bin of `n`. If that voxel has no area
//!   in the bin (photon a hair off a surface that lies on/near a voxel face), the face
//!   neighbours within [`SNAP_FRACTION`] of a voxel are tried, then — for normals within 2 %
//!   of a bin tie — the second-dominant bin. Photons still unmatched are dropped and counted
//!   ([`VoxelGrid::dropped_photons`]).
//! * **Density interpolation**: trilinear between voxel centres of the same bin, weighting
//!   each of the 8 neighbours by its trilinear weight times its area:
//!   `ρ(p) = Σ wᵢ Nᵢ / Σ wᵢ Aᵢ = Σ (wᵢAᵢ) ρᵢ / Σ (wᵢAᵢ)`. Neighbours without area in the bin
//!   contribute nothing (weights renormalised); partially covered voxels count in proportion
//!   to their area, so slivers do not inject noise. Continuous in `p`; `None` when none of
//!   the 8 neighbours has area in the bin.

use super::clip::clip_triangle;
use glam::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hash, Hasher};

/// Number of normal-direction bins: dominant axis × sign (`+x, −x, +y, −y, +z, −z`).
///
/// Surfaces in one voxel whose normals fall in different bins (two sides of a thin wall, a
/// sphere's underside above a floor, a wall meeting a floor) keep separate areas and counts.
pub const NORMAL_BINS: usize = 6;

/// Default voxel-size constant `c` of [`VoxelGrid::suggest_voxel_size`]: `s² = c·k·A/N`.
///
/// A plane of random orientation crosses on average `|n|₁/s² = 1.5/s²` voxels per unit
/// area, so a voxel-bin holds on average `≈ s²/1.5` of area and `N·s²/(1.5·A)` photons;
/// `c = 3` makes that `2k` — the geometric middle of the `k..4k` target.
pub const SUGGEST_C: f64 = 3.0;

/// Photons whose voxel lacks area in their bin are re-tried in face neighbours when they lie
/// within this fraction of a voxel edge from the shared face.
pub const SNAP_FRACTION: f32 = 0.05;

/// Origin offset (fractions of a voxel per axis) below the scene minimum used by
/// [`VoxelGrid::from_triangles`]: irrational-looking, so planes at the scene extremes and at
/// "round" coordinates rarely coincide with voxel faces.
const ORIGIN_OFFSET: [f32; 3] = [0.381_966, 0.414_213_6, 0.267_949_2];

/// Bin of a surface normal: `2·axis + (component < 0)` for the axis of largest magnitude.
///
/// Exact ties prefer x over y over z; a zero normal gives bin 0 (`+x`); non-finite input
/// still yields some bin in `0..NORMAL_BINS`. The normal need not be normalised.
#[inline]
pub fn normal_bin(n: Vec3) -> usize {
    let a = n.abs();
    if a.x >= a.y && a.x >= a.z {
        usize::from(n.x < 0.0)
    } else if a.y >= a.z {
        2 + usize::from(n.y < 0.0)
    } else {
        4 + usize::from(n.z < 0.0)
    }
}

/// The axis direction a bin stands for (`bin_direction(normal_bin(n))` is the closest axis
/// direction to `n`). Panics if `bin >= NORMAL_BINS`.
pub fn bin_direction(bin: usize) -> Vec3 {
    assert!(bin < NORMAL_BINS, "normal bin out of range");
    let mut v = Vec3::ZERO;
    v[bin / 2] = if bin.is_multiple_of(2) { 1.0 } else { -1.0 };
    v
}

/// Second-dominant bin if the normal is within 2 % of a tie with it (fallback only).
pub(super) fn secondary_bin(n: Vec3) -> Option<usize> {
    let a = n.abs();
    let p = normal_bin(n) / 2;
    let (q1, q2) = match p {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let q = if a[q1] >= a[q2] { q1 } else { q2 };
    (a[q] > 0.0 && a[q] >= 0.98 * a[p]).then(|| 2 * q + usize::from(n[q] < 0.0))
}

// ---------------------------------------------------------------------------------------------
// Hashing of voxel keys.

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
struct Key([i32; 3]);

impl Hash for Key {
    #[inline]
    fn hash<H: Hasher>(&self, state: &mut H) {
        let [x, y, z] = self.0;
        let h = (x as u32 as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (y as u32 as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ (z as u32 as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
        state.write_u64(h);
    }
}

/// Finalising hasher for [`Key`] (the key already did the mixing multiply).
#[derive(Default, Clone, Copy, Debug)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    #[inline]
    fn finish(&self) -> u64 {
        let mut h = self.0;
        h ^= h >> 32;
        h = h.wrapping_mul(0xD6E8_FEB8_6659_FD93);
        h ^ (h >> 29)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3);
        }
    }
    #[inline]
    fn write_u64(&mut self, v: u64) {
        self.0 ^= v;
    }
}

/// Voxel key → `slot | bin_mask << SLOT_BITS` (bit `SLOT_BITS + b` set iff bin `b` has area).
type KeyMap = HashMap<Key, u32, BuildHasherDefault<KeyHasher>>;
const SLOT_BITS: u32 = 26;
const SLOT_MASK: u32 = (1 << SLOT_BITS) - 1;

#[inline]
fn floor_key(g: Vec3) -> [i32; 3] {
    [g.x.floor() as i32, g.y.floor() as i32, g.z.floor() as i32]
}

#[inline]
fn key_vec(k: [i32; 3]) -> Vec3 {
    Vec3::new(k[0] as f32, k[1] as f32, k[2] as f32)
}

// ---------------------------------------------------------------------------------------------
// The grid.

/// Sparse voxel grid of receiving-surface area, photon counts and flux per normal bin.
///
/// A hash map from occupied voxel coordinates to dense slots; memory follows the surfaces,
/// not the bounding box. See the module docs for the exact definitions.
#[derive(Clone, Debug)]
pub struct VoxelGrid {
    size: f32,
    inv_size: f32,
    origin: Vec3,
    map: KeyMap,
    /// Voxel key of every slot.
    pub(super) keys: Vec<[i32; 3]>,
    /// Receiving area (m²) per slot and bin.
    pub(super) area: Vec<[f32; NORMAL_BINS]>,
    /// Raw photon count per slot and bin.
    pub(super) count: Vec<[u32; NORMAL_BINS]>,
    flux: Vec<[f32; NORMAL_BINS]>,
    /// Denoised counts, which replace `count` in every estimate while present.
    pub(super) filtered: Option<Vec<[f32; NORMAL_BINS]>>,
    photons: u64,
    dropped: u64,
}

/// Sums over the 8 trilinear neighbours of one bin.
#[derive(Clone, Copy, Default)]
struct Stencil {
    w: f32,
    wa: f32,
    wc: f32,
    wf: f32,
}

impl VoxelGrid {
    /// Build from world triangles with voxel edge `voxel_size` (> 0, finite; panics otherwise).
    ///
    /// Each triangle's area inside every voxel it crosses is computed exactly by polygon
    /// clipping (see module docs) and added to the bin of its winding normal. Degenerate and
    /// non-finite triangles are skipped. The origin is the triangles' minimum corner minus
    /// an irrational fraction of a voxel per axis.
    pub fn from_triangles(triangles: &[[Vec3; 3]], voxel_size: f32) -> Self {
        let mut lo = Vec3::splat(f32::INFINITY);
        for t in triangles {
            if t.iter().all(|v| v.is_finite()) {
                lo = lo.min(t[0]).min(t[1]).min(t[2]);
            }
        }
        if !lo.is_finite() {
            lo = Vec3::ZERO;
        }
        let origin = lo - Vec3::from(ORIGIN_OFFSET) * voxel_size;
        Self::from_triangles_with_origin(triangles, voxel_size, origin)
    }

    /// As [`VoxelGrid::from_triangles`] with an explicit grid origin: voxel `(i, j, k)` spans
    /// `origin + s·[i, i+1] × [j, j+1] × [k, k+1]`.
    pub fn from_triangles_with_origin(triangles: &[[Vec3; 3]], voxel_size: f32, origin: Vec3) -> Self {
        assert!(
            voxel_size.is_finite() && voxel_size > 0.0,
            "voxel size must be positive and finite"
        );
        assert!(origin.is_finite(), "grid origin must be finite");
        let inv_size = 1.0 / voxel_size;
        let to_grid = |v: Vec3| ((v - origin) * inv_size).as_dvec3();
        let pieces: Vec<Vec<([i32; 3], u8, f64)>> = triangles
            .par_chunks(1024)
            .map(|chunk| {
                let mut out = Vec::with_capacity(chunk.len() * 2);
                for t in chunk {
                    if !t.iter().all(|v| v.is_finite()) {
                        continue;
                    }
                    let [a, b, c] = t.map(|v| v.as_dvec3());
                    let nrm = (b - a).cross(c - a);
                    let len = nrm.length();
                    if len.is_nan() || len <= 0.0 {
                        continue;
                    }
                    let bin = normal_bin((nrm / len).as_vec3()) as u8;
                    clip_triangle(t.map(to_grid), &mut |k, area| out.push((k, bin, area)));
                }
                out
            })
            .collect();

        let s2 = f64::from(voxel_size) * f64::from(voxel_size);
        let total: usize = pieces.iter().map(Vec::len).sum();
        let mut map = KeyMap::with_capacity_and_hasher(total / 2 + 16, Default::default());
        let mut keys: Vec<[i32; 3]> = Vec::new();
        let mut acc: Vec<[f64; NORMAL_BINS]> = Vec::new();
        for (k, bin, a) in pieces.into_iter().flatten() {
            let slot = *map.entry(Key(k)).or_insert_with(|| {
                keys.push(k);
                acc.push([0.0; NORMAL_BINS]);
                (keys.len() - 1) as u32
            });
            acc[slot as usize][bin as usize] += a * s2;
        }
        assert!(keys.len() <= SLOT_MASK as usize, "too many occupied voxels");
        map.shrink_to_fit();
        let area: Vec<[f32; NORMAL_BINS]> = acc.iter().map(|a| a.map(|x| x as f32)).collect();
        // Cache each voxel's bin-presence mask next to its slot, so locating a photon touches
        // only the hash table.
        for v in map.values_mut() {
            let a = &area[*v as usize];
            let mask = (0..NORMAL_BINS).filter(|&b| a[b] > 0.0).fold(0u32, |m, b| m | (1 << b));
            *v |= mask << SLOT_BITS;
        }
        let n = keys.len();
        VoxelGrid {
            size: voxel_size,
            inv_size,
            origin,
            map,
            keys,
            area,
            count: vec![[0; NORMAL_BINS]; n],
            flux: vec![[0.0; NORMAL_BINS]; n],
            filtered: None,
            photons: 0,
            dropped: 0,
        }
    }

    /// Default voxel edge: `s = sqrt(c·k·A_total/N_photons)` with `c` = [`SUGGEST_C`] = 3,
    /// which puts on average `≈ 2k` photons in a voxel-bin (target `k..4k`) if photons were
    /// spread uniformly over the area; clamped to `[diag/2048, diag/8]`. Degenerate input
    /// (no photons, no area) gives `diag/8`; a non-positive diagonal is treated as 1.
    pub fn suggest_voxel_size(n_photons: usize, k: usize, total_area: f32, scene_diagonal: f32) -> f32 {
        let diag = if scene_diagonal.is_finite() && scene_diagonal > 0.0 {
            scene_diagonal
        } else {
            1.0
        };
        let (lo, hi) = (diag / 2048.0, diag / 8.0);
        if n_photons == 0 || !(total_area.is_finite() && total_area > 0.0) {
            return hi;
        }
        let s = (SUGGEST_C * k.max(1) as f64 * f64::from(total_area) / n_photons as f64).sqrt() as f32;
        s.clamp(lo, hi)
    }

    /// Voxel edge length `s` (world units).
    pub fn voxel_size(&self) -> f32 {
        self.size
    }

    /// Grid origin: the minimum corner of voxel `(0, 0, 0)`.
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// Number of voxels holding surface area (in any bin).
    pub fn occupied(&self) -> usize {
        self.keys.len()
    }

    /// Approximate heap + inline memory of the grid in bytes (hash table buckets and control
    /// bytes, per-slot arrays, filtered counts if present).
    pub fn memory_bytes(&self) -> usize {
        let cap = self.map.capacity();
        let buckets = if cap == 0 { 0 } else { (cap * 8 / 7).next_power_of_two() };
        let entry = std::mem::size_of::<(Key, u32)>();
        std::mem::size_of::<Self>()
            + buckets * (entry + 1)
            + self.keys.capacity() * std::mem::size_of::<[i32; 3]>()
            + self.area.capacity() * std::mem::size_of::<[f32; NORMAL_BINS]>()
            + self.count.capacity() * std::mem::size_of::<[u32; NORMAL_BINS]>()
            + self.flux.capacity() * std::mem::size_of::<[f32; NORMAL_BINS]>()
            + self
                .filtered
                .as_ref()
                .map_or(0, |f| f.capacity() * std::mem::size_of::<[f32; NORMAL_BINS]>())
    }

    /// Grid-space coordinates of a world point: `(p − origin) / s`.
    #[inline]
    pub fn to_grid(&self, p: Vec3) -> Vec3 {
        (p - self.origin) * self.inv_size
    }

    /// Integer coordinates of the voxel containing `p` (saturating for far-away points).
    #[inline]
    pub fn voxel_key(&self, p: Vec3) -> [i32; 3] {
        floor_key(self.to_grid(p))
    }

    /// World-space centre of voxel `key`.
    pub fn voxel_center(&self, key: [i32; 3]) -> Vec3 {
        self.origin + (key_vec(key) + Vec3::splat(0.5)) * self.size
    }

    #[inline]
    fn slot(&self, key: [i32; 3]) -> Option<usize> {
        self.map.get(&Key(key)).map(|&s| (s & SLOT_MASK) as usize)
    }

    #[inline]
    fn slot_with_area(&self, key: [i32; 3], bin: usize) -> Option<usize> {
        match self.map.get(&Key(key)) {
            Some(&v) if v & (1 << (SLOT_BITS as usize + bin)) != 0 => Some((v & SLOT_MASK) as usize),
            _ => None,
        }
    }

    /// Area (m²) of bin `bin` in voxel `key` (0 if unoccupied). Panics if `bin >= NORMAL_BINS`.
    pub fn area_in_voxel(&self, key: [i32; 3], bin: usize) -> f32 {
        self.slot(key).map_or(0.0, |s| self.area[s][bin])
    }

    /// Area (m²) in the voxel containing `p`, for the bin of normal `n`.
    pub fn area_at(&self, p: Vec3, n: Vec3) -> f32 {
        self.area_in_voxel(self.voxel_key(p), normal_bin(n))
    }

    /// Total area over all voxels and bins (f64 sum); equals the mesh area up to float error.
    pub fn total_area(&self) -> f64 {
        self.area.iter().flat_map(|a| a.iter()).map(|&x| f64::from(x)).sum()
    }

    /// Total area per bin.
    pub fn bin_areas(&self) -> [f64; NORMAL_BINS] {
        let mut out = [0.0; NORMAL_BINS];
        for a in &self.area {
            for b in 0..NORMAL_BINS {
                out[b] += f64::from(a[b]);
            }
        }
        out
    }

    /// Voxel keys with area, in slot order.
    pub fn voxel_keys(&self) -> &[[i32; 3]] {
        &self.keys
    }

    /// Slot and bin a photon at `p` with normal `n` is counted in (see module docs).
    fn locate(&self, p: Vec3, n: Vec3) -> Option<(usize, usize)> {
        if !p.is_finite() {
            return None;
        }
        let g = self.to_grid(p);
        let base = floor_key(g);
        let bin = normal_bin(n);
        if let Some(s) = self.slot_with_area(base, bin) {
            return Some((s, bin));
        }
        let f = g - key_vec(base);
        let mut off = [0i32; 3];
        for ax in 0..3 {
            off[ax] = if f[ax] < SNAP_FRACTION {
                -1
            } else if f[ax] > 1.0 - SNAP_FRACTION {
                1
            } else {
                0
            };
        }
        let neighbours = |bin: usize| -> Option<usize> {
            'mask: for mask in 1..8usize {
                let mut k = base;
                for ax in 0..3 {
                    if mask & (1 << ax) != 0 {
                        if off[ax] == 0 {
                            continue 'mask;
                        }
                        k[ax] = k[ax].saturating_add(off[ax]);
                    }
                }
                if let Some(s) = self.slot_with_area(k, bin) {
                    return Some(s);
                }
            }
            None
        };
        if let Some(s) = neighbours(bin) {
            return Some((s, bin));
        }
        let b2 = secondary_bin(n)?;
        self.slot_with_area(base, b2)
            .or_else(|| neighbours(b2))
            .map(|s| (s, b2))
    }

    /// Count one photon landing at `p` on a surface with geometric normal `n`, carrying
    /// flux weight `weight`. Photons that match no voxel-bin with area are dropped (counted
    /// in [`VoxelGrid::dropped_photons`]). Invalidates a previous [`VoxelGrid::denoise`].
    pub fn add_photon(&mut self, p: Vec3, n: Vec3, weight: f32) {
        self.filtered = None;
        match self.locate(p, n) {
            Some((s, b)) => {
                self.count[s][b] += 1;
                self.flux[s][b] += weight;
                self.photons += 1;
            }
            None => self.dropped += 1,
        }
    }

    /// Serial accumulation of `(position, normal, flux weight)` photons.
    pub fn add_photons(&mut self, photons: impl Iterator<Item = (Vec3, Vec3, f32)>) {
        for (p, n, w) in photons {
            self.add_photon(p, n, w);
        }
    }

    /// Parallel, atomics-free accumulation: photons are located (hash look-ups) in parallel
    /// into a flat `slot·6 + bin` index array; then each thread owns a contiguous range of
    /// slots and scans the index array, adding only the photons falling in its range.
    /// Same result as [`VoxelGrid::add_photons`] (flux sums may differ in rounding order).
    pub fn count_parallel(&mut self, items: &[(Vec3, Vec3, f32)]) {
        self.filtered = None;
        if items.is_empty() {
            return;
        }
        let idx: Vec<u32> = {
            let this = &*self;
            items
                .par_iter()
                .with_min_len(4096)
                .map(|&(p, n, _)| {
                    this.locate(p, n)
                        .map_or(u32::MAX, |(s, b)| (s * NORMAL_BINS + b) as u32)
                })
                .collect()
        };
        let dropped = idx.iter().filter(|&&i| i == u32::MAX).count();
        let slots = self.count.len();
        if slots > 0 {
            let threads = rayon::current_num_threads().max(1);
            let per = slots.div_ceil(threads).max(1);
            self.count
                .par_chunks_mut(per)
                .zip(self.flux.par_chunks_mut(per))
                .enumerate()
                .for_each(|(ci, (cc, fc))| {
                    let base = ci * per * NORMAL_BINS;
                    let end = base + cc.len() * NORMAL_BINS;
                    for (&ix, item) in idx.iter().zip(items) {
                        let ix = ix as usize;
                        if ix >= base && ix < end {
                            let l = ix - base;
                            cc[l / NORMAL_BINS][l % NORMAL_BINS] += 1;
                            fc[l / NORMAL_BINS][l % NORMAL_BINS] += item.2;
                        }
                    }
                });
        }
        self.dropped += dropped as u64;
        self.photons += (items.len() - dropped) as u64;
    }

    /// Photons counted into some voxel-bin.
    pub fn photon_count(&self) -> u64 {
        self.photons
    }

    /// Photons that matched no voxel-bin with area (off-surface or wrong-normal input).
    pub fn dropped_photons(&self) -> u64 {
        self.dropped
    }

    /// Reset counts, flux and filtered counts (areas are kept).
    pub fn clear_photons(&mut self) {
        self.count.iter_mut().for_each(|c| *c = [0; NORMAL_BINS]);
        self.flux.iter_mut().for_each(|f| *f = [0.0; NORMAL_BINS]);
        self.filtered = None;
        self.photons = 0;
        self.dropped = 0;
    }

    /// Whether filtered counts from [`VoxelGrid::denoise`] are in use.
    pub fn is_denoised(&self) -> bool {
        self.filtered.is_some()
    }

    /// Drop the filtered counts; estimates use the raw counts again.
    pub fn clear_denoise(&mut self) {
        self.filtered = None;
    }

    #[inline]
    fn count_value(&self, slot: usize, bin: usize) -> f32 {
        match &self.filtered {
            Some(f) => f[slot][bin],
            None => self.count[slot][bin] as f32,
        }
    }

    /// Photon count (filtered if denoised) of bin `bin` in voxel `key`.
    pub fn count_in_voxel(&self, key: [i32; 3], bin: usize) -> f32 {
        self.slot(key).map_or(0.0, |s| self.count_value(s, bin))
    }

    /// Raw photon count of bin `bin` in voxel `key`.
    pub fn raw_count_in_voxel(&self, key: [i32; 3], bin: usize) -> u32 {
        self.slot(key).map_or(0, |s| self.count[s][bin])
    }

    /// Photon count (filtered if denoised) in the voxel containing `p`, bin of `n`.
    pub fn voxel_count(&self, p: Vec3, n: Vec3) -> f32 {
        self.count_in_voxel(self.voxel_key(p), normal_bin(n))
    }

    /// Sum of the (filtered if denoised) counts over all voxels and bins.
    pub fn total_count(&self) -> f64 {
        match &self.filtered {
            Some(f) => f.iter().flat_map(|c| c.iter()).map(|&x| f64::from(x)).sum(),
            None => self.count.iter().flat_map(|c| c.iter()).map(|&x| f64::from(x)).sum(),
        }
    }

    fn stencil(&self, p: Vec3, bin: usize) -> Option<Stencil> {
        if !p.is_finite() {
            return None;
        }
        let g = self.to_grid(p) - Vec3::splat(0.5);
        let base = floor_key(g);
        let f = g - key_vec(base);
        let mut st = Stencil::default();
        for dz in 0..2 {
            let wz = if dz == 0 { 1.0 - f.z } else { f.z };
            for dy in 0..2 {
                let wy = if dy == 0 { 1.0 - f.y } else { f.y };
                for dx in 0..2 {
                    let wx = if dx == 0 { 1.0 - f.x } else { f.x };
                    let k = [
                        base[0].saturating_add(dx),
                        base[1].saturating_add(dy),
                        base[2].saturating_add(dz),
                    ];
                    if let Some(s) = self.slot_with_area(k, bin) {
                        let w = wx * wy * wz;
                        st.w += w;
                        st.wa += w * self.area[s][bin];
                        st.wc += w * self.count_value(s, bin);
                        st.wf += w * self.flux[s][bin];
                    }
                }
            }
        }
        (st.wa > 0.0 && st.w > 0.0).then_some(st)
    }

    /// Photon density (photons per m², filtered counts if denoised) at `p` for the bin of
    /// normal `n`: `Σ wᵢNᵢ / Σ wᵢAᵢ` over the 8 trilinear neighbours (voxel centres) that have
    /// area in the bin — trilinear interpolation of the voxel densities with weights `wᵢAᵢ`,
    /// renormalised. Continuous in `p`; never uses other bins or empty voxels. `None` when no
    /// neighbour has area in the bin (far from any surface of that orientation).
    pub fn density_at(&self, p: Vec3, n: Vec3) -> Option<f32> {
        self.stencil(p, normal_bin(n)).map(|st| st.wc / st.wa)
    }

    /// Interpolated photon count per voxel-bin at `p` (`Σ wᵢNᵢ / Σ wᵢ` over neighbours with
    /// area): the "filtered count N" a shadow threshold can be applied to.
    pub fn count_at(&self, p: Vec3, n: Vec3) -> Option<f32> {
        self.stencil(p, normal_bin(n)).map(|st| st.wc / st.w)
    }

    /// Flux density (Σ weights per m², raw — not denoised) at `p`, interpolated as
    /// [`VoxelGrid::density_at`].
    pub fn flux_density_at(&self, p: Vec3, n: Vec3) -> Option<f32> {
        self.stencil(p, normal_bin(n)).map(|st| st.wf / st.wa)
    }

    /// Assumed kNN radius for `neighbours` photons: `sqrt(neighbours / (π·ρ))` with
    /// `ρ = density_at(p, n)` (equivalently `r_a² = n·A/(N·π)`). `None` where the density is
    /// unavailable, zero, or the radius is not finite; the shadow fallback (use the real kNN
    /// radius) is the caller's decision, e.g. via [`VoxelGrid::count_at`].
    pub fn assumed_radius(&self, p: Vec3, n: Vec3, neighbours: usize) -> Option<f32> {
        let rho = self.density_at(p, n)?;
        if rho.is_nan() || rho <= 0.0 {
            return None;
        }
        let r = (neighbours as f32 / (std::f32::consts::PI * rho)).sqrt();
        r.is_finite().then_some(r)
    }
}
