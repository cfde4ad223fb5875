//! Multiscale flux textures on the planes: the grids as an estimator.
//!
//! Every plane gets a fine grid, sized from where its photons are densest (not a fixed 128),
//! holding per cell the photons' flux, the sum of their squared powers (the variance of the
//! flux in the cell, photons being a compound Poisson process) and the exact area of the
//! plane's triangles inside the cell. A pyramid of 2×2 block sums above it answers, at any
//! point and any scale 2^l cells, "how much flux over how much surface, with what variance".
//! Dividing flux by the surface actually covered makes the estimate correct at the plane's
//! edges and corners, where a disc of radius r would count area that is not there.
//!
//! Photons of different kinds (caustic, global) live in separate layers so that the scale
//! chosen for one does not limit the other.

use super::planes::{bilinear_axis, Plane, PlaneSet, NO_PLANE};
use super::wavelet::Field2;
use crate::photon::{Photon, PhotonKind};
use crate::{luminance, Rgb};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Block sums over a cell or a block of cells. The moments are about the texel's centre, in
/// fine cells: with them a kernel fits a plane to the light instead of a constant, so a
/// kernel that reaches past a plane's edge (a corner, the foot of a wall) or sits on a
/// gradient is not biased by the light on its other side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Texel {
    /// Σ photon flux (W), per channel.
    pub flux: [f32; 3],
    /// Σ (luminance of photon flux)²: the variance of the luminance flux sum (a shared
    /// caustic photon adds its share of it, [`Texel::add_photon`]).
    pub var: f32,
    /// Photons (a shared caustic photon adds its share).
    pub count: f32,
    /// Surface area inside (m²).
    pub area: f32,
    /// Σ luminance flux × offset (x, y).
    pub flux_moment: [f32; 2],
    /// ∫ offset dA over the surface inside (x, y).
    pub area_moment: [f32; 2],
    /// ∫ offset ⊗ offset dA over the surface inside (xx, xy, yy).
    pub area_moment2: [f32; 3],
    /// The least open space in front of the surface inside (m; global layers only): light
    /// changes over about this distance next to something standing on or near the plane.
    pub clearance: f32,
}

impl Default for Texel {
    fn default() -> Self {
        Texel {
            flux: [0.0; 3],
            var: 0.0,
            count: 0.0,
            area: 0.0,
            flux_moment: [0.0; 2],
            area_moment: [0.0; 2],
            area_moment2: [0.0; 3],
            clearance: f32::INFINITY,
        }
    }
}

impl Texel {
    /// Add `share` of a photon of flux `f` that landed `d` (in cells) from the centre. Its
    /// variance is shared like its count, not squared with it: cells that share a photon are
    /// summed into coarser texels and read four at a time, and only a whole photon's variance
    /// keeps those sums' variance right (one cell alone is then read as if its count were a
    /// whole photons' count).
    fn add_photon(&mut self, f: Rgb, d: [f32; 2], share: f32) {
        let lum = luminance(f);
        self.flux_moment[0] += lum * share * d[0];
        self.flux_moment[1] += lum * share * d[1];
        self.flux[0] += f.x * share;
        self.flux[1] += f.y * share;
        self.flux[2] += f.z * share;
        self.var += lum * lum * share;
        self.count += share;
    }

    /// Its mean irradiance (luminance): flux over the surface inside.
    pub fn mean(&self) -> f32 {
        luminance(Rgb::from(self.flux)) / self.area
    }

    fn add(&mut self, o: &Texel, w: f32) {
        if w > 0.0 {
            self.clearance = self.clearance.min(o.clearance);
        }
        for c in 0..3 {
            self.flux[c] += w * o.flux[c];
            self.area_moment2[c] += w * o.area_moment2[c];
        }
        for c in 0..2 {
            self.flux_moment[c] += w * o.flux_moment[c];
            self.area_moment[c] += w * o.area_moment[c];
        }
        self.var += w * w * o.var;
        self.count += w * o.count;
        self.area += w * o.area;
    }

    /// The same sums with moments about a point `d` (fine cells) away from the current
    /// reference point, i.e. reference − new point = `d`.
    fn shifted(&self, d: [f32; 2]) -> Texel {
        let mut t = *self;
        let lum = luminance(Rgb::from(self.flux));
        let (m, a) = (self.area_moment, self.area);
        for c in 0..2 {
            t.flux_moment[c] += lum * d[c];
            t.area_moment[c] += a * d[c];
        }
        t.area_moment2[0] += 2.0 * m[0] * d[0] + a * d[0] * d[0];
        t.area_moment2[1] += m[0] * d[1] + m[1] * d[0] + a * d[0] * d[1];
        t.area_moment2[2] += 2.0 * m[1] * d[1] + a * d[1] * d[1];
        t
    }
}

/// One level of a pyramid: `w × h` texels, row-major.
#[derive(Clone, Debug, Default)]
struct Level {
    w: usize,
    h: usize,
    texels: Vec<Texel>,
    /// Per texel, its mean irradiance (luminance) where it lies wholly on the surface
    /// ([`FULL_COVERAGE`]), else NaN; empty in the caustic layer. Kept beside the texels so
    /// that the curvature read at every point ([`LayerTexture::full_patch`]) touches 4 bytes
    /// a texel, not all its sums.
    means: Vec<f32>,
}

impl Level {
    /// Texel `(i, j)` if it lies within the level and covers at least `area` of the surface.
    fn full_texel(&self, i: isize, j: isize, area: f32) -> Option<&Texel> {
        let inside = i >= 0 && j >= 0 && (i as usize) < self.w && (j as usize) < self.h;
        let t = inside.then(|| &self.texels[j as usize * self.w + i as usize])?;
        (t.area >= area).then_some(t)
    }

    /// The next coarser level: sums of 2×2 blocks (a border block may have fewer cells);
    /// `side` is this level's texel side in fine cells (moments move to the block's centre).
    fn coarser(&self, side: f32) -> Level {
        let (w, h) = (self.w.div_ceil(2), self.h.div_ceil(2));
        let mut texels = vec![Texel::default(); w * h];
        let half = |i: usize| if i.is_multiple_of(2) { -0.5 * side } else { 0.5 * side };
        for y in 0..self.h {
            for x in 0..self.w {
                let child = self.texels[y * self.w + x].shifted([half(x), half(y)]);
                texels[(y / 2) * w + x / 2].add(&child, 1.0);
            }
        }
        Level {
            w,
            h,
            texels,
            means: Vec::new(),
        }
    }

    /// Bilinear interpolation of the texels at continuous texel coordinates (centres at
    /// i + 0.5), clamped to the texel centres; moments about the point `(x, y)`, texels being
    /// `side` fine cells wide.
    fn bilinear(&self, x: f32, y: f32, side: f32) -> Texel {
        let (i0, i1, fx) = bilinear_axis(x, self.w);
        let (j0, j1, fy) = bilinear_axis(y, self.h);
        let mut t = Texel::default();
        let mut add = |i: usize, j: usize, w: f32| {
            let d = [(i as f32 + 0.5 - x) * side, (j as f32 + 0.5 - y) * side];
            t.add(&self.texels[j * self.w + i].shifted(d), w);
        };
        add(i0, j0, (1.0 - fx) * (1.0 - fy));
        add(i1, j0, fx * (1.0 - fy));
        add(i0, j1, (1.0 - fx) * fy);
        add(i1, j1, fx * fy);
        t
    }
}

/// The layers photons are sorted into, one per kind, so that the scale chosen for one does not
/// limit another: caustics ([`CAUSTIC`]), indirect light ([`INDIRECT`]), direct light
/// ([`DIRECT`], read by final gathering and the single-map setting), and indirect light too
/// deep for final gathering ([`TAIL`]).
pub const LAYERS: usize = 4;
/// The caustic layer.
pub const CAUSTIC: usize = 0;
/// The indirect layer.
pub const INDIRECT: usize = 1;
/// The direct layer.
pub const DIRECT: usize = 2;
/// Indirect photons at the deepest interaction the camera may read but a final-gather ray
/// may not (`Settings::gathered`: through one more bounce the path would be longer than
/// `--max-depth`). The camera reads them with [`INDIRECT`] where it reads the photons'
/// indirect light; gathering never does (it would add the next order of light, about 1 % of
/// a closed room's, which the references, truncated at the same depth, lack). Caustic photons
/// that deep (ten specular bounces in a row) stay in [`CAUSTIC`].
pub const TAIL: usize = 3;

/// The layer of a photon: by its kind, and [`TAIL`] for indirect photons too deep for final
/// gathering under `max_depth` (0: unlimited).
pub fn layer_of(p: &Photon, max_depth: u32) -> usize {
    match p.kind() {
        PhotonKind::Caustic => CAUSTIC,
        PhotonKind::Indirect if max_depth > 0 && p.depth() + 2 > max_depth => TAIL,
        PhotonKind::Indirect => INDIRECT,
        PhotonKind::Direct => DIRECT,
    }
}

/// Photons are counted into the textures in chunks of this many, read in the order they were
/// traced.
const COUNT_CHUNK: usize = 1 << 20;

/// Photons per block of a chunk, landed and sorted by one thread.
const COUNT_BLOCK: usize = 1 << 16;

/// Photons' power (luminance, times their pass's weight) and count per layer.
#[derive(Clone, Copy, Debug, Default)]
struct Counted {
    power: [f64; LAYERS],
    n: [usize; LAYERS],
}

impl Counted {
    fn add(&mut self, o: &Counted) {
        for l in 0..LAYERS {
            self.power[l] += o.power[l];
            self.n[l] += o.n[l];
        }
    }
}

/// A block's landings sorted by run, and where each run starts (one more entry than runs).
struct LandedBlock {
    landed: Vec<Landing>,
    start: Vec<u32>,
    counted: Counted,
}

/// Fine cells per run that a chunk's photons are sorted into before they are added: a run's
/// texels (about 300 kB) stay in the cache while its photons are added.
const COUNT_RUN_CELLS: usize = 4096;

/// Where a photon lands in a layer's finest level (see `LayerTexture::landing`).
#[derive(Clone, Copy, Debug, Default)]
struct Landing {
    cell: u32,
    d: [f32; 2],
    flux: [f32; 3],
}

/// The cells a caustic photon's count is shared between: the four whose centres surround
/// where it landed, with bilinear weights, each with the photon's offset from its centre;
/// cells off the surface are left out and the others' weights scaled to 1 (the landing cell
/// alone if all are off). A photon's count then changes continuously with where it lands,
/// and caustic photons emitted from Sobol points land so evenly that a box count's jumps at
/// the cell sides were most of their noise (docs/multiscale.md, "Caustic photons shared
/// between the four cells around them").
fn bilinear_shares(l: &Landing, level: &Level) -> ([(usize, f32, [f32; 2]); 4], usize) {
    let (w, h) = (level.w, level.h);
    let g = [
        (l.cell as usize % w) as f32 + 0.5 + l.d[0],
        (l.cell as usize / w) as f32 + 0.5 + l.d[1],
    ];
    let (i0, i1, fx) = bilinear_axis(g[0], w);
    let (j0, j1, fy) = bilinear_axis(g[1], h);
    let mut shares = [(l.cell as usize, 1.0, l.d); 4];
    let (mut n, mut total) = (0, 0.0);
    for (i, j, weight) in [
        (i0, j0, (1.0 - fx) * (1.0 - fy)),
        (i1, j0, fx * (1.0 - fy)),
        (i0, j1, (1.0 - fx) * fy),
        (i1, j1, fx * fy),
    ] {
        let cell = j * w + i;
        if weight > 0.0 && level.texels[cell].area > 0.0 {
            shares[n] = (cell, weight, [g[0] - (i as f32 + 0.5), g[1] - (j as f32 + 0.5)]);
            n += 1;
            total += weight;
        }
    }
    if n == 0 {
        return (shares, 1); // untouched: the landing cell, whole
    }
    for s in &mut shares[..n] {
        s.1 /= total;
    }
    (shares, n)
}

/// Why a layer's fine cells have their size (`MultiscaleGrids::describe`, `--stats`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sizing {
    /// About `--cell-photons` first-pass photons per cell where the layer's photons on the
    /// plane are densest (the 99th percentile of a 32 × 32 count).
    Densest,
    /// No first-pass photon of the layer on the plane: 16 cells along the longer side.
    NoPhotons,
    /// The densest photons asked for finer cells than the resolution cap.
    Finest,
    /// The photons asked for fewer than 8 cells along the longer side.
    Coarsest,
}

impl Sizing {
    fn describe(self) -> &'static str {
        match self {
            Sizing::Densest => "sized for --cell-photons photons per cell where this light is densest",
            Sizing::NoPhotons => "no photons of this kind on the plane",
            Sizing::Finest => "as fine as allowed (2048 cells along a side)",
            Sizing::Coarsest => "as coarse as allowed (8 cells along the longer side)",
        }
    }
}

/// One layer of one plane: its fine grid (sized for that layer's photons) and the pyramid
/// of block sums above it. Level 0 accumulates raw sums over passes.
#[derive(Clone, Debug)]
pub struct LayerTexture {
    /// The plane with this layer's fine resolution.
    pub plane: Plane,
    /// Why the fine cells have their size.
    pub sizing: Sizing,
    /// Level 0 (finest) upwards.
    levels: Vec<Level>,
    /// The layer's estimate resolved on a coarse texture for final-gather rays (set after
    /// the pyramid is rebuilt; see `MultiscaleGrids::resolve_for_gathering`).
    pub resolved: Option<Resolved>,
    /// What the layer does at the hard edges of its light.
    edges: Edges,
    /// Per fine cell: dark ([`dark_cells`]) after the last rebuild; empty when none is.
    dark: Vec<bool>,
    /// The coverage of the dark cells, taken out of level 0 at the last rebuild and put back
    /// before the next (more photons may show them lit).
    stashed: Vec<(u32, Coverage)>,
}

/// What a layer does at the hard edges of its light.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Edges {
    /// Indirect light has none worth finding.
    Smooth,
    /// Caustics: their outlines' dark cells are found ([`dark_cells`]). The cells on the
    /// outline stay whole: a caustic's fold is brightest there, so the cells around one do
    /// not say how much of it is lit.
    Dark,
    /// Direct light: the shadows' dark cells are found, and the cells on a shadow's edge are
    /// cut to their lit share ([`edge_areas`]).
    DarkTrimmed,
}

impl Edges {
    /// Whether the layer shares each photon between the four cells around it
    /// ([`bilinear_shares`]): caustics, whose photons land most evenly; the other layers count
    /// whole photons (sharing was measured on caustics only).
    fn shares_photons(self) -> bool {
        self == Edges::Dark
    }

    fn of_layer(layer: usize) -> Edges {
        match layer {
            DIRECT => Edges::DarkTrimmed,
            CAUSTIC => Edges::Dark,
            _ => Edges::Smooth,
        }
    }
}

/// A fine cell's covered area and its moments ([`Texel`]).
type Coverage = (f32, [f32; 2], [f32; 3]);

/// A layer's irradiance resolved per texel of one pyramid level (at the centroid of the
/// surface each texel covers). Final-gather
/// rays read it bilinearly: choosing a scale for each of millions of rays took most of a
/// camera pass, and gathering averages the light it reads anyway.
#[derive(Clone, Debug, Default)]
pub struct Resolved {
    /// Texel side in fine cells.
    pub side: f32,
    /// Texels along u.
    pub w: usize,
    /// Texels along v.
    pub h: usize,
    /// Irradiance per texel (row-major); None where no kernel covers surface.
    pub values: Vec<Option<Rgb>>,
    /// The pyramid level the scale rule chose at each texel's centroid (row-major;
    /// [`NO_LEVEL`] where none was chosen): where the light is resolved finely.
    pub levels: Vec<u8>,
    /// Texels on or off the surface's outline (partly covered or empty, next to a texel
    /// without surface or to the grid's border, or with something standing within their
    /// reach). Interpolation there holds the value of the texel's centroid up to the edge,
    /// or mixes the light on both sides of a wall's foot, while light often changes fastest
    /// there (the foot of a wall gets the floor's light): rays landing in them take the
    /// estimate at their own point.
    pub outline: Vec<bool>,
}

/// [`Resolved::levels`] where no scale was chosen.
pub const NO_LEVEL: u8 = u8::MAX;

impl Resolved {
    /// Whether fine grid coordinates `(gx, gy)` fall in an outline texel.
    pub fn on_outline(&self, gx: f32, gy: f32) -> bool {
        if self.w == 0 || self.h == 0 {
            return false;
        }
        let i = ((gx / self.side).max(0.0) as usize).min(self.w - 1);
        let j = ((gy / self.side).max(0.0) as usize).min(self.h - 1);
        self.outline[j * self.w + i]
    }

    /// Bilinear read at fine grid coordinates `(gx, gy)`, over the texels that hold an
    /// estimate (their weights renormalised), so that light does not fade towards a
    /// plane's edge; zero where none does.
    pub fn lookup(&self, gx: f32, gy: f32) -> Rgb {
        if self.w == 0 || self.h == 0 {
            return Rgb::ZERO;
        }
        let (i0, i1, fx) = bilinear_axis(gx / self.side, self.w);
        let (j0, j1, fy) = bilinear_axis(gy / self.side, self.h);
        let (mut sum, mut weight) = (Rgb::ZERO, 0.0f32);
        for (i, j, w) in [
            (i0, j0, (1.0 - fx) * (1.0 - fy)),
            (i1, j0, fx * (1.0 - fy)),
            (i0, j1, (1.0 - fx) * fy),
            (i1, j1, fx * fy),
        ] {
            if let Some(v) = self.values[j * self.w + i] {
                sum += v * w;
                weight += w;
            }
        }
        if weight > 0.0 {
            sum / weight
        } else {
            Rgb::ZERO
        }
    }
}

/// Share of a texel's area that must lie on the surface for it to count as whole: for the
/// curvature's blocks and patches, and for a kernel's indirect estimate to be used
/// (`estimate::multiscale::INTERIOR_COVERAGE`).
pub const FULL_COVERAGE: f32 = 0.9;

/// The shifts (in texels, along x and y) a 3×3 block or 4×4 patch of texels is tried at, in
/// order, until all its texels lie on the surface ([`LayerTexture::full_block`],
/// [`LayerTexture::full_patch`]).
const BLOCK_SHIFTS: [(isize, isize); 9] = [
    (0, 0),
    (-1, 0),
    (1, 0),
    (0, -1),
    (0, 1),
    (-1, -1),
    (1, -1),
    (-1, 1),
    (1, 1),
];

impl LayerTexture {
    fn new(plane: Plane, sizing: Sizing, coverage: Vec<Texel>, edges: Edges) -> Self {
        let level = Level {
            w: plane.res_u,
            h: plane.res_v,
            texels: coverage,
            means: Vec::new(),
        };
        LayerTexture {
            plane,
            sizing,
            levels: vec![level],
            resolved: None,
            edges,
            dark: Vec::new(),
            stashed: Vec::new(),
        }
    }

    /// Share of the covered surface found dark at the last rebuild.
    pub fn dark_share(&self) -> f32 {
        let l0 = &self.levels[0];
        let dark: f32 = self.stashed.iter().map(|s| s.1 .0).sum();
        let lit: f32 = l0.texels.iter().map(|t| t.area).sum();
        if dark + lit > 0.0 {
            dark / (dark + lit)
        } else {
            0.0
        }
    }

    /// Whether fine grid coordinates `(gx, gy)` lie on the dark side of the layer's outline
    /// ([`on_dark_side`]).
    fn dark_at(&self, gx: f32, gy: f32) -> bool {
        if self.dark.is_empty() {
            return false;
        }
        let l0 = &self.levels[0];
        // Dark cells' coverage is stashed: they have surface too.
        on_dark_side(&self.plane, &self.dark, |c| l0.texels[c].area > 0.0, gx, gy)
    }

    /// Put the dark cells' coverage back, find them again from the counts so far, and take
    /// theirs out of level 0: kernels then divide the light by the surface it can fall on,
    /// so the lit side of a shadow edge or a caustic's outline is not averaged with the dark
    /// side, and points in dark cells read no light of this layer.
    fn mark_dark(&mut self) {
        let l0 = &mut self.levels[0];
        for (c, (area, m1, m2)) in self.stashed.drain(..) {
            let t = &mut l0.texels[c as usize];
            (t.area, t.area_moment, t.area_moment2) = (area, m1, m2);
        }
        let counts: Vec<f32> = l0.texels.iter().map(|t| t.count).collect();
        let covered: Vec<bool> = l0.texels.iter().map(|t| t.area > 0.0).collect();
        self.dark = dark_cells(l0.w, l0.h, &counts, &covered);
        for (c, _) in self.dark.iter().enumerate().filter(|d| *d.1) {
            let t = &mut l0.texels[c];
            self.stashed.push((c as u32, (t.area, t.area_moment, t.area_moment2)));
            (t.area, t.area_moment, t.area_moment2) = (0.0, [0.0; 2], [0.0; 3]);
        }
        if self.edges == Edges::DarkTrimmed {
            self.trim_edge_cells();
        }
        if self.stashed.is_empty() {
            self.dark = Vec::new();
        }
    }

    /// Cells beside dark ones hold the edge itself: a cell the edge crosses counts the photons
    /// of its lit part only, and divided by its whole area it darkens every kernel that holds
    /// it (the lit side of a shadow edge read 5 % low a cell away, 2 % four cells away). Fine
    /// cells hold a photon or two, too few to say where in a cell the edge runs, so each such
    /// cell's surface is taken as its photons' flux over the flux density of the cells around
    /// it ([`edge_areas`]): in expectation its lit share. Stashed and put back as the dark
    /// cells' coverage is.
    fn trim_edge_cells(&mut self) {
        let l0 = &mut self.levels[0];
        let lums: Vec<f32> = l0.texels.iter().map(|t| luminance(Rgb::from(t.flux))).collect();
        let counts: Vec<f32> = l0.texels.iter().map(|t| t.count).collect();
        let areas: Vec<f32> = l0.texels.iter().map(|t| t.area).collect();
        for (c, area) in edge_areas(l0.w, l0.h, &self.dark, &lums, &counts, &areas) {
            let t = &mut l0.texels[c];
            self.stashed.push((c as u32, (t.area, t.area_moment, t.area_moment2)));
            let k = area / t.area;
            (t.area, t.area_moment, t.area_moment2) =
                (area, t.area_moment.map(|m| k * m), t.area_moment2.map(|m| k * m));
        }
    }

    /// Photons counted per fine cell over all passes, for inspection (`--dump-grids`).
    pub fn count_field(&self) -> Field2 {
        let l = &self.levels[0];
        Field2 {
            width: l.w,
            height: l.h,
            data: l.texels.iter().map(|t| t.count).collect(),
        }
    }

    /// Per texel of the resolved texture: the irradiance final gathering reads (luminance,
    /// W/m²) and the reach of the kernel the scale rule chose there (m; 0 where none), for
    /// inspection (`--dump-grids`). None before the texture is resolved.
    pub fn resolved_fields(&self) -> Option<(Field2, Field2)> {
        let r = self.resolved.as_ref()?;
        let irradiance = r.values.iter().map(|v| v.map_or(0.0, luminance)).collect();
        let reach = r
            .levels
            .iter()
            .map(|&l| {
                if l == NO_LEVEL {
                    0.0
                } else {
                    self.kernel_reach(l as usize)
                }
            })
            .collect();
        let field = |data| Field2 {
            width: r.w,
            height: r.h,
            data,
        };
        Some((field(irradiance), field(reach)))
    }

    /// Fine cell size (m).
    pub fn cell_size(&self) -> f32 {
        self.plane.size_u / self.plane.res_u as f32
    }

    /// Levels, finest first.
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// The area a kernel at `level` spans (bilinear weights sum to 1): the covered area of an
    /// estimate divided by this is below 1 where the kernel reaches past the plane's edge.
    pub fn kernel_area(&self, level: usize) -> f32 {
        self.plane.cell_area() * (1u64 << (2 * level)) as f32
    }

    /// How far from its point a kernel at `level` can reach ([`REACH_TEXELS`]).
    pub fn kernel_reach(&self, level: usize) -> f32 {
        let cell = (self.plane.size_u / self.plane.res_u as f32).max(self.plane.size_v / self.plane.res_v as f32);
        REACH_TEXELS * cell * (1u64 << level) as f32
    }

    /// The reach of the widest kernel within `cap` (m), if any level's is.
    pub fn widest_reach(&self, cap: f32) -> Option<f32> {
        (0..self.level_count())
            .map(|k| self.kernel_reach(k))
            .take_while(|&r| r <= cap)
            .last()
    }

    /// The finest level with at most `max_texels` texels, and its size.
    pub fn level_within(&self, max_texels: usize) -> (usize, usize, usize) {
        let mut best = self.levels.len() - 1;
        for (l, lv) in self.levels.iter().enumerate() {
            if lv.w * lv.h <= max_texels {
                best = l;
                break;
            }
        }
        (best, self.levels[best].w, self.levels[best].h)
    }

    /// The texels of `level` on the surface's outline (see [`Resolved::outline`]): covering
    /// less than all their area, next (4-neighbours) to one with no surface or to the grid's
    /// border, or with something standing within their reach (clearance below a kernel's
    /// reach at this level: the foot of a wall on a floor that runs on behind it, where one
    /// texel holds the lit floor and the dark one behind).
    pub fn outline(&self, level: usize) -> Vec<bool> {
        let lv = &self.levels[level];
        let full = self.kernel_area(level) * (1.0 - 1e-3);
        let reach = self.kernel_reach(level);
        let covered = |x: isize, y: isize| {
            x >= 0
                && y >= 0
                && (x as usize) < lv.w
                && (y as usize) < lv.h
                && lv.texels[y as usize * lv.w + x as usize].area > 0.0
        };
        (0..lv.w * lv.h)
            .map(|i| {
                let (x, y) = ((i % lv.w) as isize, (i / lv.w) as isize);
                lv.texels[i].area < full
                    || lv.texels[i].clearance < reach
                    || [(-1, 0), (1, 0), (0, -1), (0, 1)]
                        .iter()
                        .any(|&(dx, dy)| !covered(x + dx, y + dy))
            })
            .collect()
    }

    /// Where the surface within texel `i` of `level` lies: the centroid of its covered area
    /// in fine grid coordinates; None where the texel covers no surface.
    pub fn texel_centroid(&self, level: usize, i: usize) -> Option<(f32, f32)> {
        let lv = &self.levels[level];
        let t = &lv.texels[i];
        if !(t.area > 0.0) {
            return None;
        }
        let side = (1u32 << level) as f32;
        let (x, y) = ((i % lv.w) as f32 + 0.5, (i / lv.w) as f32 + 0.5);
        Some((
            x * side + t.area_moment[0] / t.area,
            y * side + t.area_moment[1] / t.area,
        ))
    }

    /// The 3×3 block of `level`'s texels nearest the point at fine grid coordinates
    /// `(gx, gy)` that lie wholly on the surface (each covering at least `coverage` of its
    /// area): the centred block, else one shifted a texel towards the surface's interior.
    /// Row-major, rows along y; None where no such block is within a texel.
    pub fn full_block(&self, level: usize, gx: f32, gy: f32, coverage: f32) -> Option<[[&Texel; 3]; 3]> {
        let lv = &self.levels[level];
        if lv.w < 3 || lv.h < 3 {
            return None;
        }
        let side = (1u32 << level) as f32;
        let centre = |g: f32, n: usize| ((g / side).floor() as isize).clamp(1, n as isize - 2);
        let (ci, cj) = (centre(gx, lv.w), centre(gy, lv.h));
        let full = self.kernel_area(level) * coverage;
        let texel = |i: isize, j: isize| lv.full_texel(i, j, full);
        BLOCK_SHIFTS.iter().find_map(|&(di, dj)| {
            let (i, j) = (ci + di, cj + dj);
            let row = |y: isize| Some([texel(i - 1, y)?, texel(i, y)?, texel(i + 1, y)?]);
            Some([row(j - 1)?, row(j)?, row(j + 1)?])
        })
    }

    /// The means ([`Level::means`]) of the 4×4 patch of `level`'s texels (rows along y) that
    /// holds the 3×3 blocks centred on the four texels nearest the point at fine grid
    /// coordinates `(gx, gy)`, and the point's offset (0 to 1 along each axis) from the centre
    /// of the patch's second texel, which weights those blocks bilinearly. Where a texel does
    /// not lie wholly on the surface the patch is shifted a texel towards the interior as
    /// [`full_block`](Self::full_block) shifts its block, and near the grid's edge it is moved
    /// inside; the offset is then held at the patch's end, so the blend stays continuous. A
    /// level three texels wide has one block across, whose last column (or row) the patch
    /// repeats with no weight. None where no such patch is full, the level is narrower than
    /// three texels, or the layer keeps no means (caustics).
    pub fn full_patch(&self, level: usize, gx: f32, gy: f32) -> Option<([[f32; 4]; 4], [f32; 2])> {
        let lv = &self.levels[level];
        if lv.w < 3 || lv.h < 3 || lv.means.len() != lv.texels.len() {
            return None;
        }
        let side = (1u32 << level) as f32;
        let (u, v) = (gx / side - 0.5, gy / side - 0.5);
        // The first of the four texels, moved by `shift` and into the grid, and the offset
        // past the centre of the second.
        let start = |u: f32, shift: isize, n: usize| {
            let first = (u.floor() as isize - 1 + shift).clamp(0, n.max(4) as isize - 4) as usize;
            let offset = if n < 4 {
                0.0
            } else {
                (u - (first + 1) as f32).clamp(0.0, 1.0)
            };
            (first, offset)
        };
        BLOCK_SHIFTS.iter().find_map(|&(di, dj)| {
            let ((i, fu), (j, fv)) = (start(u, di, lv.w), start(v, dj, lv.h));
            let mut m = [[0.0f32; 4]; 4];
            for (b, row) in m.iter_mut().enumerate() {
                let at = (j + b).min(lv.h - 1) * lv.w;
                for (a, mean) in row.iter_mut().enumerate() {
                    *mean = lv.means[at + (i + a).min(lv.w - 1)];
                    if mean.is_nan() {
                        return None;
                    }
                }
            }
            Some((m, [fu, fv]))
        })
    }

    /// The surface area (m²) within texel `i` of `level`.
    pub fn texel_area(&self, level: usize, i: usize) -> f32 {
        self.levels[level].texels[i].area
    }

    /// Kernel sums at `p` on every level, finest first.
    /// None in a dark cell ([`dark_cells`]).
    pub fn scales(&self, p: Vec3) -> impl Iterator<Item = ScaleEstimate> + '_ {
        let (gx, gy) = self.plane.grid_coords(p);
        let levels = if self.dark_at(gx, gy) { 0 } else { self.levels.len() };
        self.levels.iter().take(levels).enumerate().map(move |(level, lv)| {
            let s = (1u32 << level) as f32;
            ScaleEstimate {
                level,
                texel: lv.bilinear(gx / s, gy / s, s),
            }
        })
    }

    /// Where photon `p` lands in level 0: its cell and its offset from the cell's centre
    /// (fine cells); None for photons on the plane's other side (see `orient_to_the_light`)
    /// or outside it.
    fn landing(&self, p: &Photon) -> Option<Landing> {
        if !p.faces(self.plane.normal) {
            return None;
        }
        // Projected once (this runs for every photon of every pass); NaN: not on the plane.
        let (gx, gy) = self.plane.grid_coords(p.pos());
        if gx.is_nan() || gy.is_nan() {
            return None;
        }
        let cell = self.plane.grid_cell(gx, gy);
        let w = self.levels[0].w;
        let d = [gx - ((cell % w) as f32 + 0.5), gy - ((cell / w) as f32 + 0.5)];
        Some(Landing {
            cell: cell as u32,
            d,
            flux: p.power().to_array(),
        })
    }

    /// Add landed photons to level 0, in their order: each to the cell it landed in, or for
    /// caustics shared between the four cells around it ([`bilinear_shares`]).
    fn add_landed(&mut self, landed: &[Landing]) {
        let level = &mut self.levels[0];
        for l in landed {
            let f = Rgb::from_array(l.flux);
            if self.edges.shares_photons() {
                let (shares, n) = bilinear_shares(l, level);
                for &(cell, share, d) in &shares[..n] {
                    level.texels[cell].add_photon(f, d, share);
                }
            } else {
                level.texels[l.cell as usize].add_photon(f, l.d, 1.0);
            }
        }
    }

    /// Runs of [`COUNT_RUN_CELLS`] fine cells in level 0.
    fn count_runs(&self) -> usize {
        self.levels[0].texels.len().div_ceil(COUNT_RUN_CELLS)
    }

    /// Rebuild the coarser levels from level 0, up to one texel along the shorter side.
    fn rebuild(&mut self) {
        self.resolved = None;
        self.levels.truncate(1);
        if self.edges != Edges::Smooth {
            self.mark_dark();
        }
        while {
            let l = self.levels.last().expect("level 0");
            l.w > 1 && l.h > 1
        } {
            let side = (1u32 << (self.levels.len() - 1)) as f32;
            let next = self.levels.last().expect("level").coarser(side);
            self.levels.push(next);
        }
        if self.edges != Edges::Dark {
            for level in 0..self.levels.len() {
                let full = self.kernel_area(level) * FULL_COVERAGE;
                let lv = &mut self.levels[level];
                lv.means = lv
                    .texels
                    .iter()
                    .map(|t| if t.area >= full { t.mean() } else { f32::NAN })
                    .collect();
            }
        }
    }

    fn memory_bytes(&self) -> usize {
        self.levels
            .iter()
            .map(|l| l.texels.len() * std::mem::size_of::<Texel>() + l.means.len() * 4)
            .sum::<usize>()
            + self.dark.len()
            + self.stashed.len() * std::mem::size_of::<(u32, Coverage)>()
    }
}

/// A summed-area table of a `w × h` grid: the sum over any rectangle of cells in four reads
/// (f64, so that sums over a 128×128 grid of counts keep their units).
struct SummedArea {
    w: usize,
    s: Vec<f64>,
}

impl SummedArea {
    fn new(w: usize, h: usize, v: impl Fn(usize) -> f64) -> Self {
        let mut s = vec![0.0f64; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += v(y * w + x);
                s[(y + 1) * (w + 1) + x + 1] = s[y * (w + 1) + x + 1] + row;
            }
        }
        SummedArea { w, s }
    }

    /// The sum over cells `x0..x1` × `y0..y1`.
    fn sum(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> f64 {
        let w = self.w + 1;
        self.s[y1 * w + x1] - self.s[y0 * w + x1] - self.s[y1 * w + x0] + self.s[y0 * w + x0]
    }
}

/// Photons the cells around an edge cell must hold before their flux density says how much
/// of it is lit ([`edge_areas`]).
const EDGE_PHOTONS: f32 = 16.0;

/// The cells on the edge of the `dark` ones (not dark, with surface, a dark cell beside them)
/// and the surface each is taken to have: its flux (`lums`) over the flux density of the
/// covered cells around it that are neither dark nor on the edge, in the smallest square of
/// side 5, 9 or 17 cells that holds [`EDGE_PHOTONS`] of them (cells whose square never does
/// are left whole). Where the light is smooth up to the edge, that is the lit part of the
/// cell's surface in expectation, whatever the photons' noise.
fn edge_areas(w: usize, h: usize, dark: &[bool], lums: &[f32], counts: &[f32], areas: &[f32]) -> Vec<(usize, f32)> {
    let is_dark = |x: isize, y: isize| {
        x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h && dark[y as usize * w + x as usize]
    };
    let on_edge: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            !dark[i]
                && areas[i] > 0.0
                && (is_dark(x - 1, y) || is_dark(x + 1, y) || is_dark(x, y - 1) || is_dark(x, y + 1))
        })
        .collect();
    if !on_edge.iter().any(|&e| e) {
        return Vec::new();
    }
    let inner = |v: &[f32]| SummedArea::new(w, h, |i| if dark[i] || on_edge[i] { 0.0 } else { v[i] as f64 });
    let (sl, sn, sa) = (inner(lums), inner(counts), inner(areas));
    (0..w * h)
        .filter(|&i| on_edge[i])
        .filter_map(|i| {
            let (x, y) = (i % w, i / w);
            [2usize, 4, 8].into_iter().find_map(|r| {
                let (x0, y0, x1, y1) = (
                    x.saturating_sub(r),
                    y.saturating_sub(r),
                    (x + r + 1).min(w),
                    (y + r + 1).min(h),
                );
                let (n, a) = (sn.sum(x0, y0, x1, y1), sa.sum(x0, y0, x1, y1));
                (n >= EDGE_PHOTONS as f64 && a > 0.0).then(|| {
                    let density = sl.sum(x0, y0, x1, y1) / a;
                    (
                        i,
                        if density > 0.0 {
                            (lums[i] as f64 / density) as f32
                        } else {
                            areas[i]
                        },
                    )
                })
            })
        })
        .collect()
}

/// The lit share below which a point is on the dark side of an outline ([`on_dark_side`]):
/// one half, which cuts the corners of the cells' staircase as much as it adds beside them.
/// More (tried for the direct layer, whose outline cells are cut to their lit share) darkened
/// the lit side of a shadow edge in the failure-case suite, and took part of a caustic's
/// outline off (docs/multiscale.md, "Outlines drawn between the cells' centres").
const OUTLINE_CONTOUR: f32 = 0.5;

/// Whether fine grid coordinates `(gx, gy)` of `plane` lie on the dark side of the outline
/// of its `dark` cells: the lit share of the four cells around the point (not dark, and with
/// surface: `covered`, or dark), weighted bilinearly between their centres, is below
/// [`OUTLINE_CONTOUR`]. Taking the point's own cell instead drew every outline
/// that is not along the grid's axes as a staircase of cells, a few pixels a step where the
/// camera sees the cells up close (the pool floor's caustic outline beside the camera).
fn on_dark_side(plane: &Plane, dark: &[bool], covered: impl Fn(usize) -> bool, gx: f32, gy: f32) -> bool {
    let (mut lit, mut surface) = (0.0f32, 0.0f32);
    for (c, w) in plane.bilinear_at(gx, gy) {
        if dark[c] {
            surface += w;
        } else if covered(c) {
            surface += w;
            lit += w;
        }
    }
    surface > 0.0 && lit < OUTLINE_CONTOUR * surface
}

/// Photons a window of cells must be expected to hold, from the light in the ring of cells
/// around it, before its holding none marks it dark: a lit window is empty with probability
/// e^−24 ≈ 4·10⁻¹¹, so among the millions tested none is by chance.
const DARK_EXPECTED: f64 = 24.0;

/// Window sides tested (fine cells): the narrowest that is expected to hold
/// [`DARK_EXPECTED`] photons finds the edge; wider ones find dark places in dimmer light.
const DARK_WINDOWS: [usize; 12] = [1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64];

/// Per cell of a `w × h` grid of photon `counts` (cells with surface: `covered`): whether it
/// lies in a window of cells that holds no photon although the covered cells of the ring
/// around it (the window's side on every side) say it should hold [`DARK_EXPECTED`] — the
/// shadow of a point light, the outside of a caustic. Every cell of such a window is dark
/// (the union of empty windows: a morphological opening of the empty cells), so the
/// boundary is found to one cell whatever the window's size.
pub fn dark_cells(w: usize, h: usize, counts: &[f32], covered: &[bool]) -> Vec<bool> {
    let mut dark = vec![false; w * h];
    if counts.iter().all(|&c| c <= 0.0) {
        return dark;
    }
    let n = SummedArea::new(w, h, |i| counts[i] as f64);
    let a = SummedArea::new(w, h, |i| if covered[i] { 1.0 } else { 0.0 });
    // Most windows hold photons, and most empty ones lie in the dark far from any light: the
    // side of the largest empty square at each cell skips the first, the photons around them
    // (one read per run of windows, then per window) the second, before the areas are read.
    let empty_side = empty_squares(w, h, counts);
    for b in DARK_WINDOWS.into_iter().filter(|&b| b <= w && b <= h) {
        let (ww, wh) = (w - b + 1, h - b + 1);
        // Dark windows, by their top-left cell, a row at a time; a run of `b` windows whose
        // surroundings together hold no photon is skipped with one read.
        let mut windows = vec![false; ww * wh];
        windows.par_chunks_mut(ww).enumerate().for_each(|(y, row)| {
            let (y0, y1) = (y.saturating_sub(b), (y + 2 * b).min(h));
            for run in (0..ww).step_by(b) {
                if n.sum(run.saturating_sub(b), y0, (run + 3 * b).min(w), y1) <= 0.0 {
                    continue;
                }
                for x in run..(run + b).min(ww) {
                    if (empty_side[y * w + x] as usize) < b {
                        continue;
                    }
                    let (x0, x1) = (x.saturating_sub(b), (x + 2 * b).min(w));
                    let around = n.sum(x0, y0, x1, y1);
                    if around <= 0.0 {
                        continue;
                    }
                    let inside = a.sum(x, y, x + b, y + b);
                    if inside <= 0.0 {
                        continue;
                    }
                    let ring = a.sum(x0, y0, x1, y1) - inside;
                    row[x] = ring > 0.0 && around * inside / ring >= DARK_EXPECTED;
                }
            }
        });
        if windows.iter().any(|&d| d) {
            mark_windows(&mut dark, w, h, &windows, b, covered);
        }
    }
    dark
}

/// Per cell of a `w × h` grid, the side of the largest square of cells holding no photon
/// (`counts` 0) with that cell as its top-left corner.
fn empty_squares(w: usize, h: usize, counts: &[f32]) -> Vec<u16> {
    let mut side = vec![0u16; w * h];
    for y in (0..h).rev() {
        for x in (0..w).rev() {
            if counts[y * w + x] > 0.0 {
                continue;
            }
            let at = |x: usize, y: usize| if x < w && y < h { side[y * w + x] } else { 0 };
            side[y * w + x] = 1 + at(x + 1, y).min(at(x, y + 1)).min(at(x + 1, y + 1));
        }
    }
    side
}

/// Mark dark every `covered` cell of a `w × h` grid that a `b × b` window flagged in `windows`
/// (by top-left cell, `(w − b + 1) × (h − b + 1)` of them) contains: the flags dilated by the
/// window, along the rows and then along the columns.
fn mark_windows(dark: &mut [bool], w: usize, h: usize, windows: &[bool], b: usize, covered: &[bool]) {
    let (ww, wh) = (w - b + 1, h - b + 1);
    // Per row of windows, the cells some window of the row spans.
    let rows: Vec<bool> = windows
        .par_chunks(ww)
        .flat_map_iter(|row| {
            let mut spans = vec![false; w];
            let mut open = 0usize;
            for x in 0..w {
                if x < ww && row[x] {
                    open = b;
                }
                if open > 0 {
                    spans[x] = true;
                    open -= 1;
                }
            }
            spans
        })
        .collect();
    // Down each column, the rows of windows up to b − 1 above: prefix sums per column.
    let mut prefix = vec![0u32; (wh + 1) * w];
    for y in 0..wh {
        let (done, next) = prefix.split_at_mut((y + 1) * w);
        for ((p, &q), &s) in next[..w].iter_mut().zip(&done[y * w..]).zip(&rows[y * w..(y + 1) * w]) {
            *p = q + s as u32;
        }
    }
    dark.par_chunks_mut(w)
        .zip(covered.par_chunks(w))
        .enumerate()
        .for_each(|(y, (dark, covered))| {
            let (lo, hi) = ((y + 1).saturating_sub(b), (y + 1).min(wh));
            if lo >= hi {
                return;
            }
            let (top, bottom) = (&prefix[lo * w..(lo + 1) * w], &prefix[hi * w..(hi + 1) * w]);
            for x in 0..w {
                if bottom[x] > top[x] && covered[x] {
                    dark[x] = true;
                }
            }
        });
}

/// A scale's estimate at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleEstimate {
    /// Level (0: finest cells).
    pub level: usize,
    /// Kernel sums at the point (flux, variance, area).
    pub texel: Texel,
}

/// What the multiscale textures are built with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MultiscaleParams {
    /// Fine cells in all, over every plane and layer (about 70 bytes each with the pyramid).
    pub cell_budget: usize,
    /// Photons per fine cell where a plane's photons are densest: sets the finest scale.
    pub photons_per_cell: f32,
    /// Most cells along a plane's longer side.
    pub max_resolution: usize,
    /// The widest kernel's radius (m), as for every other gather (`Settings::max_radius`).
    pub max_radius: f32,
    /// Longest path, in segments (`--max-depth`; 0: unlimited): sorts photons too deep for
    /// final gathering into [`TAIL`].
    pub max_depth: u32,
    /// Every light is a point, spot or sun, so each direct and caustic photon lands where
    /// two numbers of a stratified point put it ([`crate::sampling::Stratified`]): those
    /// layers' counts scatter far less than Poisson's.
    pub stratified: bool,
}

impl Default for MultiscaleParams {
    fn default() -> Self {
        MultiscaleParams {
            cell_budget: 4 << 20,
            photons_per_cell: 2.0,
            max_resolution: 2048,
            max_radius: f32::INFINITY,
            max_depth: 0,
            stratified: false,
        }
    }
}

/// The multiscale textures of every plane and layer, accumulated over passes.
#[derive(Clone, Debug)]
pub struct MultiscaleGrids {
    /// The planes found (mirrors and glass excluded) and the triangle → plane map.
    pub set: PlaneSet,
    /// Per plane (same order as `set.planes`), per layer.
    pub textures: Vec<[LayerTexture; LAYERS]>,
    /// Passes accumulated.
    pub passes: u32,
    /// Per layer, the passes' photons relative to the first pass's, summed: each pass's
    /// flux is counted times its own share ([`Emitted::relative_to`]) and the sums divide by
    /// this, so every photon weighs the same whatever the size of its pass and a small last
    /// pass smooths the estimate instead of adding its larger noise at a full pass's weight.
    pub pass_weight: [f32; LAYERS],
    /// The photons the first pass emitted: what later passes are weighed against.
    reference: Option<Emitted>,
    /// Mean photon power (luminance) per layer over the photons counted, per pass: the
    /// variance floor of an empty kernel (one photon's worth of uncertainty).
    pub mean_power: [f32; LAYERS],
    /// Share of the global photons' power (direct and indirect layers) that lands on the
    /// planes, over all passes: how much of the light gathering finds the planes hold.
    pub plane_power_share: f32,
    /// The global photons' power (luminance) over all passes, on the planes or not.
    global_power: f64,
    /// The farthest a kernel may reach from its point (m): scales stop below it.
    pub max_radius: f32,
    /// Longest path in segments ([`MultiscaleParams::max_depth`]).
    pub max_depth: u32,
    /// Its direct and caustic photons land from stratified points ([`MultiscaleParams::stratified`]).
    pub stratified: bool,
    /// The factor by which every fine cell grew to fit the cell budget (`--grid-cells`; 1
    /// when the photons' sizes fit).
    pub cells_grown: f32,
    /// The resolved texels as a distribution for aiming gather rays (built with the resolved
    /// textures, [`MultiscaleGrids::resolve_for_gathering`]).
    pub bright: Option<crate::estimate::bright::BrightTexels>,
}

/// The photons a pass emitted: global ones (the direct and indirect layers) and those of the
/// caustic pass (the caustic layer).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Emitted {
    /// Global photon paths.
    pub global: usize,
    /// Caustic photon paths.
    pub caustic: usize,
}

impl Emitted {
    /// Each layer's photons relative to `reference`'s (1 where either emitted none): the
    /// weight of a pass's flux when its photons each carry `reference / self` times the
    /// power of the reference pass's.
    pub fn relative_to(self, reference: Emitted) -> [f32; LAYERS] {
        let ratio = |n: usize, r: usize| if n > 0 && r > 0 { n as f32 / r as f32 } else { 1.0 };
        let mut w = [1.0; LAYERS];
        w[CAUSTIC] = ratio(self.caustic, reference.caustic);
        w[DIRECT] = ratio(self.global, reference.global);
        w[INDIRECT] = w[DIRECT];
        w[TAIL] = w[DIRECT];
        w
    }
}

/// What the scene's geometry says about a point `p` of a plane with front normal `n`.
pub struct Probes<'a> {
    /// `p` lies inside a solid resting on the plane (under a box on the floor): such area
    /// never receives light nor is seen, so it is not counted as surface.
    pub buried: &'a (dyn Fn(Vec3, Vec3) -> bool + Sync),
    /// The open space in front of `p` (m): how far a kernel may reach there before it spans
    /// light that something standing near the plane changes. Only surfaces met at points the
    /// third argument accepts count.
    pub clearance: &'a Clearance<'a>,
}

/// [`Probes::clearance`]: the open space (m) in front of a point with a normal, counting the
/// surfaces met at points the filter accepts.
pub type Clearance<'a> = dyn Fn(Vec3, Vec3, &dyn Fn(Vec3) -> bool) -> f32 + Sync + 'a;

/// Whether `plane` has surface (`cells` with area) behind the point `hit` seen from `p`
/// within `reach` (m) of `p`: along the in-plane direction from `p` to `hit`'s foot, from one
/// cell past the foot (the foot's own cell is partly covered). A hit overhead (its foot
/// within half a cell of `p`) counts as standing.
fn stands_on_plane(plane: &Plane, cells: &[Texel], p: Vec3, hit: Vec3, reach: f32) -> bool {
    let (x0, y0) = plane.grid_coords(p);
    let (x1, y1) = plane.grid_coords(hit);
    let (dx, dy) = (x1 - x0, y1 - y0);
    let len = (dx * dx + dy * dy).sqrt();
    if !(len >= 0.5) {
        return true;
    }
    // Cells along the way, out to the farthest a kernel reaches from `p` (and one more).
    let cell = (plane.size_u / plane.res_u.max(1) as f32).min(plane.size_v / plane.res_v.max(1) as f32);
    let last = ((reach / cell).min(4096.0) + 1.0 - len).ceil().max(1.0) as usize;
    let (w, h) = (plane.res_u as f32, plane.res_v as f32);
    // A straight line that leaves the grid does not come back: stop there.
    (1..=last)
        .map(|k| (x1 + dx / len * k as f32, y1 + dy / len * k as f32))
        .take_while(|&(x, y)| x >= 0.0 && y >= 0.0 && x < w && y < h)
        .any(|(x, y)| cells[plane.grid_cell(x, y)].area > 0.0)
}

/// Fine cells per side of the blocks that share one clearance probe: the clearance bounds
/// kernels that reach 1.5 texels and more, so placing it to a few fine cells is enough, and
/// probing every cell (five rays each) took most of the grids' build.
const CLEARANCE_BLOCK: usize = 4;

/// The open space in front of each covered cell of `plane` (`Texel::clearance`) up to the
/// surfaces the plane runs on behind (a wall standing on a floor that continues past it, a
/// shelf board standing out of a wall, a box on the floor) or overhead, probed once per block
/// of [`CLEARANCE_BLOCK`]² cells at the centroid of its covered cells' centres. Light changes
/// across such an obstacle, and a kernel spanning it averages both sides (the wall under each
/// shelf board of shelf_objects read 25 % dark). A wall where the plane ends (a room's corner)
/// does not count: a kernel cut there by the plane's edge divides by its covered area and its
/// local-linear fit follows the light's slope towards the corner, while stopping it at the wall
/// left it few photons, a grainy band of final gathering along the foot of every wall
/// (docs/multiscale.md, "Walls where the plane ends").
fn set_clearance(plane: &Plane, cells: &mut [Texel], probes: &Probes<'_>, reach: f32) {
    let (w, h) = (plane.res_u, plane.res_v);
    let (bw, bh) = (w.div_ceil(CLEARANCE_BLOCK), h.div_ceil(CLEARANCE_BLOCK));
    let cells_of = |b: usize| {
        let (bx, by) = (b % bw * CLEARANCE_BLOCK, b / bw * CLEARANCE_BLOCK);
        (by..(by + CLEARANCE_BLOCK).min(h))
            .flat_map(move |y| (bx..(bx + CLEARANCE_BLOCK).min(w)).map(move |x| y * w + x))
    };
    let covered: &[Texel] = cells;
    let probed: Vec<f32> = (0..bw * bh)
        .into_par_iter()
        .map(|b| {
            let (mut sum, mut n) = ((0.0f32, 0.0f32), 0.0f32);
            for c in cells_of(b).filter(|&c| covered[c].area > 0.0) {
                sum.0 += (c % w) as f32 + 0.5;
                sum.1 += (c / w) as f32 + 0.5;
                n += 1.0;
            }
            if n == 0.0 {
                return 0.0;
            }
            let p = plane.grid_to_world(sum.0 / n, sum.1 / n);
            (probes.clearance)(p, plane.normal, &|hit| stands_on_plane(plane, covered, p, hit, reach))
        })
        .collect();
    for (b, &c) in probed.iter().enumerate() {
        for cell in cells_of(b) {
            if cells[cell].area > 0.0 {
                cells[cell].clearance = c;
            }
        }
    }
}

/// Turn each plane's normal towards the side most of its photons arrive on. A plane's
/// textures hold the light of that side only: a thin double-sided quad lit from above and
/// seen from below (a blocker, a shelf made of one quad) must not show its top's light
/// underneath; queries from the other side fall back to the photon map.
fn orient_to_the_light(set: &mut PlaneSet, photons: &[Photon], triangles: &[u32]) {
    let side = per_plane_blocks(
        set,
        photons,
        triangles,
        vec![0i64; set.planes.len()],
        |side, p, plane| {
            side[plane] += if p.normal().dot(set.planes[plane].normal) >= 0.0 {
                1
            } else {
                -1
            };
        },
    )
    .into_iter()
    .fold(vec![0i64; set.planes.len()], |mut a, b| {
        a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        a
    });
    for (plane, s) in set.planes.iter_mut().zip(side) {
        if s < 0 {
            plane.normal = -plane.normal;
        }
    }
}

/// `visit` every photon (landed on `triangles[i]`) that landed on a plane, with the plane's
/// index, in blocks of [`COUNT_BLOCK`] photons in parallel, each block into its own copy of
/// `empty`; the blocks' results in photon order.
fn per_plane_blocks<T: Clone + Send + Sync>(
    set: &PlaneSet,
    photons: &[Photon],
    triangles: &[u32],
    empty: T,
    visit: impl Fn(&mut T, &Photon, usize) + Sync,
) -> Vec<T> {
    photons
        .par_chunks(COUNT_BLOCK)
        .zip(triangles.par_chunks(COUNT_BLOCK))
        .map(|(ps, ts)| {
            let mut acc = empty.clone();
            for (p, &t) in ps.iter().zip(ts) {
                let plane = set.plane_of_triangle.get(t as usize).copied().unwrap_or(NO_PLANE);
                if plane != NO_PLANE {
                    visit(&mut acc, p, plane as usize);
                }
            }
            acc
        })
        .collect()
}

/// Per fine cell of `plane`: a photon landed in it or in one of its eight neighbours
/// (`landed`: the positions of the plane's photons, in blocks).
fn lit_cells(plane: &Plane, landed: &[&[Vec3]]) -> Vec<bool> {
    let (w, h) = (plane.res_u, plane.res_v);
    let mut hit = vec![false; w * h];
    for &x in landed.iter().copied().flatten() {
        if let Some(c) = plane.cell_of(x, f32::INFINITY) {
            hit[c] = true;
        }
    }
    let mut lit = vec![false; w * h];
    for j in 0..h {
        for i in 0..w {
            if hit[j * w + i] {
                for y in j.saturating_sub(1)..(j + 2).min(h) {
                    for x in i.saturating_sub(1)..(i + 2).min(w) {
                        lit[y * w + x] = true;
                    }
                }
            }
        }
    }
    lit
}

/// Every plane's layer textures at their fine resolutions `dims`: the surface under each
/// cell (of `tris`), less what is buried under something resting on the plane, and for global
/// light the open space in front; from the first pass's photons (landed on their triangles).
fn sized_textures(
    set: &PlaneSet,
    dims: &[[((usize, usize), Sizing); LAYERS]],
    tris: &[[Vec3; 3]],
    (photons, triangles): (&[Photon], &[u32]),
    params: &MultiscaleParams,
    probes: &Probes<'_>,
) -> Vec<[LayerTexture; LAYERS]> {
    // Where photons land, nothing rests on the plane: they veto the buried test, whose
    // rays can be fooled by open or one-sided meshes.
    let mut blocks = per_plane_blocks(
        set,
        photons,
        triangles,
        vec![Vec::new(); set.planes.len()],
        |l, p, plane| l[plane].push(p.pos()),
    );
    // The positions are held while every plane is sized: no room to spare.
    blocks.iter_mut().flatten().for_each(Vec::shrink_to_fit);
    let landed: Vec<Vec<&[Vec3]>> = (0..set.planes.len())
        .map(|plane| blocks.iter().map(|b: &Vec<Vec<Vec3>>| b[plane].as_slice()).collect())
        .collect();
    set.planes
        .par_iter()
        .zip(dims)
        .zip(&landed)
        .map(|((p, layer_dims), landed)| {
            std::array::from_fn(|l| {
                let ((ru, rv), sizing) = layer_dims[l];
                let plane = p.clone().with_resolution(ru, rv);
                let mut area = coverage(&plane, tris);
                let lit = lit_cells(&plane, landed);
                area.par_iter_mut().enumerate().for_each(|(cell, a)| {
                    if a.area > 0.0 && !lit[cell] && (probes.buried)(plane.cell_center(cell), plane.normal) {
                        *a = Texel::default();
                    }
                });
                // Global light changes next to what stands on the plane, so its
                // kernels stop at the open space in front; caustics choose their scale
                // from their own sharp structure.
                if l != CAUSTIC {
                    set_clearance(&plane, &mut area, probes, params.max_radius);
                }
                LayerTexture::new(plane, sizing, area, Edges::of_layer(l))
            })
        })
        .collect()
}

impl MultiscaleGrids {
    /// Size every plane's layers from the first pass's photons (landing on `triangles[i]`)
    /// and count them; `probes` find buried area and the clearance in front of the planes.
    pub fn build(
        mut set: PlaneSet,
        tris: &[[Vec3; 3]],
        photons: &[Photon],
        triangles: &[u32],
        params: &MultiscaleParams,
        probes: &Probes<'_>,
        emitted: Option<Emitted>,
    ) -> Self {
        orient_to_the_light(&mut set, photons, triangles);
        let (dims, cells_grown) = fine_resolutions(&set, photons, triangles, params);
        let started = std::time::Instant::now();
        let textures = sized_textures(&set, &dims, tris, (photons, triangles), params, probes);
        tracing::debug!(
            seconds = started.elapsed().as_secs_f64(),
            cells = textures
                .iter()
                .flatten()
                .map(|t| t.levels[0].texels.len())
                .sum::<usize>(),
            "multiscale textures sized, covered and probed"
        );
        let mut g = MultiscaleGrids {
            set,
            textures,
            passes: 0,
            pass_weight: [0.0; LAYERS],
            reference: emitted,
            mean_power: [0.0; LAYERS],
            plane_power_share: 0.0,
            global_power: 0.0,
            max_radius: params.max_radius,
            max_depth: params.max_depth,
            stratified: params.stratified,
            cells_grown,
            bright: None,
        };
        g.add(photons, triangles, emitted);
        g
    }

    /// Add one pass's photons (`emitted` of them; None: as many as the first pass's) and
    /// rebuild the pyramids.
    pub fn add(&mut self, photons: &[Photon], triangles: &[u32], emitted: Option<Emitted>) {
        let started = std::time::Instant::now();
        let weight = match (emitted, self.reference) {
            (Some(e), Some(r)) => e.relative_to(r),
            _ => [1.0; LAYERS],
        };
        let Counted { power, n } = self.count(photons, triangles, weight);
        self.passes += 1;
        self.update_plane_share(power[DIRECT] + power[INDIRECT]);
        for l in 0..LAYERS {
            // Mean (weighted) photon power over the passes, each weighed by its share.
            let mean = if n[l] > 0 { (power[l] / n[l] as f64) as f32 } else { 0.0 };
            self.pass_weight[l] += weight[l];
            self.mean_power[l] += (mean - self.mean_power[l]) * weight[l] / self.pass_weight[l];
        }
        let counted = started.elapsed().as_secs_f64();
        self.textures
            .par_iter_mut()
            .flat_map(|t| t.par_iter_mut())
            .for_each(LayerTexture::rebuild);
        tracing::debug!(
            counted,
            seconds = started.elapsed().as_secs_f64(),
            photons = photons.len(),
            "multiscale photons counted and pyramids rebuilt"
        );
    }

    /// Count one pass's photons into level 0 of the textures, each layer's flux times its
    /// `weight`; return every photon's power and count per layer (on the planes or not).
    fn count(&mut self, photons: &[Photon], triangles: &[u32], weight: [f32; LAYERS]) -> Counted {
        // Photons land all over the planes, whose texels can take hundreds of megabytes: a
        // chunk of them is read in blocks (in parallel), each block's landings are sorted
        // stably into runs of texels, and each texture adds its runs block by block. Every
        // texel still sums its photons in the order they were traced (a caustic photon's
        // share of a cell in a neighbouring run is added with its own run), so the result
        // does not depend on the threads.
        let mut run_base = vec![0usize];
        for tex in self.textures.iter().flatten() {
            run_base.push(run_base.last().copied().unwrap_or(0) + tex.count_runs());
        }
        let mut total = Counted::default();
        for chunk in (0..photons.len()).step_by(COUNT_CHUNK) {
            let blocks: Vec<LandedBlock> = (chunk..(chunk + COUNT_CHUNK).min(photons.len()))
                .step_by(COUNT_BLOCK)
                .collect::<Vec<_>>()
                .into_par_iter()
                .map(|b| {
                    let end = (b + COUNT_BLOCK).min(chunk + COUNT_CHUNK).min(photons.len());
                    // Photons without a triangle (none recorded) count, but land nowhere.
                    let tris = triangles.get(b..end.min(triangles.len())).unwrap_or(&[]);
                    self.land_block(&photons[b..end], tris, weight, &run_base)
                })
                .collect();
            for b in &blocks {
                total.add(&b.counted);
            }
            self.textures
                .iter_mut()
                .flatten()
                .enumerate()
                .collect::<Vec<_>>()
                .into_par_iter()
                .for_each(|(i, tex)| {
                    for b in &blocks {
                        let (lo, hi) = (b.start[run_base[i]], b.start[run_base[i + 1]]);
                        tex.add_landed(&b.landed[lo as usize..hi as usize]);
                    }
                });
        }
        total
    }

    /// Where a block of photons (landed on `triangles`) lands, sorted stably by run of
    /// texels (runs numbered from `run_base` per texture and layer), with their power.
    fn land_block(
        &self,
        photons: &[Photon],
        triangles: &[u32],
        weight: [f32; LAYERS],
        run_base: &[usize],
    ) -> LandedBlock {
        let runs = run_base.last().copied().unwrap_or(0);
        let mut counted = Counted::default();
        let mut landed: Vec<(u32, Landing)> = Vec::with_capacity(photons.len());
        for (k, p) in photons.iter().enumerate() {
            let layer = layer_of(p, self.max_depth);
            counted.power[layer] += (luminance(p.power()) * weight[layer]) as f64;
            counted.n[layer] += 1;
            let t = triangles.get(k).copied().unwrap_or(u32::MAX);
            let plane = self.set.plane_of_triangle.get(t as usize).copied().unwrap_or(NO_PLANE);
            let Some(tex) = self.textures.get(plane as usize) else {
                continue;
            };
            if let Some(mut l) = tex[layer].landing(p) {
                l.flux = l.flux.map(|f| f * weight[layer]);
                let run = run_base[plane as usize * LAYERS + layer] + l.cell as usize / COUNT_RUN_CELLS;
                landed.push((run as u32, l));
            }
        }
        let mut start = vec![0u32; runs + 1];
        for (run, _) in &landed {
            start[*run as usize + 1] += 1;
        }
        for r in 0..runs {
            start[r + 1] += start[r];
        }
        let mut next = start.clone();
        let mut sorted = vec![Landing::default(); landed.len()];
        for (run, l) in landed {
            let slot = &mut next[run as usize];
            sorted[*slot as usize] = l;
            *slot += 1;
        }
        LandedBlock {
            landed: sorted,
            start,
            counted,
        }
    }

    /// Add a pass's global photon power (luminance, on the planes or not) and update
    /// [`MultiscaleGrids::plane_power_share`] from what the textures hold.
    fn update_plane_share(&mut self, global_power: f64) {
        self.global_power += global_power;
        let on_planes: f64 = self
            .textures
            .par_iter()
            .flat_map(|t| [&t[DIRECT], &t[INDIRECT]])
            .map(|t| {
                t.levels[0]
                    .texels
                    .iter()
                    .map(|x| luminance(Rgb::from(x.flux)) as f64)
                    .sum::<f64>()
            })
            .sum();
        self.plane_power_share = if self.global_power > 0.0 {
            (on_planes / self.global_power).min(1.0) as f32
        } else {
            0.0
        };
    }

    /// The layer textures serving `triangle`, if any.
    pub fn texture_of(&self, triangle: u32) -> Option<&[LayerTexture; LAYERS]> {
        match self.set.plane_of_triangle.get(triangle as usize) {
            Some(&p) if p != NO_PLANE => self.textures.get(p as usize),
            _ => None,
        }
    }

    /// The layer textures serving the side of `triangle` that `normal` faces, if any: a
    /// plane's textures hold its lit side only (`orient_to_the_light`).
    pub fn texture_facing(&self, triangle: u32, normal: Vec3) -> Option<&[LayerTexture; LAYERS]> {
        self.texture_of(triangle)
            .filter(|t| crate::estimate::photon_map::faces(normal, t[0].plane.normal))
    }

    /// The plane serving the side of `triangle` that `normal` faces, if any
    /// ([`MultiscaleGrids::texture_facing`]).
    pub fn plane_facing(&self, triangle: u32, normal: Vec3) -> Option<usize> {
        self.texture_facing(triangle, normal)?;
        self.set.plane_of_triangle.get(triangle as usize).map(|&p| p as usize)
    }

    /// What `layer`'s flux sums divide by: [`MultiscaleGrids::pass_weight`] (1 before any
    /// pass).
    pub fn passes_of(&self, layer: usize) -> f32 {
        let w = self.pass_weight[layer];
        if w > 0.0 {
            w
        } else {
            1.0
        }
    }

    /// Photons of `layer` the planes have counted, over all passes.
    pub fn photons_counted(&self, layer: usize) -> f64 {
        self.textures
            .iter()
            .flat_map(|t| &t[layer].levels[0].texels)
            .map(|t| t.count as f64)
            .sum()
    }

    /// Memory of the textures.
    pub fn memory_bytes(&self) -> usize {
        self.textures.iter().flatten().map(LayerTexture::memory_bytes).sum()
    }

    /// One line per plane for reports: size, the side whose light it holds, and each layer's
    /// fine cells (sized for about `--cell-photons` photons where that layer is densest, within
    /// `--grid-cells`, indirect layers then moved so that a kernel reaches `--max-radius`) with
    /// its widest kernel under the cap and the texture final-gather rays read.
    pub fn describe(&self) -> Vec<String> {
        self.textures
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let p = &t[0].plane;
                let grown = if self.cells_grown > 1.0 {
                    format!(", then {:.2}× wider to fit --grid-cells", self.cells_grown)
                } else {
                    String::new()
                };
                let layer = |l: &LayerTexture| {
                    let read = l
                        .resolved
                        .as_ref()
                        .map(|r| {
                            let chosen = r.levels.iter().filter(|&&v| v != NO_LEVEL).map(|&v| v as usize);
                            let reach = match (chosen.clone().min(), chosen.max()) {
                                (Some(lo), Some(hi)) => format!(
                                    ", kernels chosen there reach {:.1}–{:.1} mm",
                                    l.kernel_reach(lo) * 1e3,
                                    l.kernel_reach(hi) * 1e3
                                ),
                                _ => String::new(),
                            };
                            format!(", gathering reads {}×{}{reach}", r.w, r.h)
                        })
                        .unwrap_or_default();
                    let dark = match l.dark_share() {
                        d if d > 0.0 => format!(", {:.1} % of it found dark (no light of this kind)", d * 100.0),
                        _ => String::new(),
                    };
                    // Indirect layers' cells are moved so that this is about the cap
                    // (`snap_to_reach`).
                    let widest = l
                        .widest_reach(self.max_radius)
                        .filter(|_| self.max_radius.is_finite())
                        .map(|r| {
                            format!(
                                ", widest kernel {:.1} mm of --max-radius {:.1} mm",
                                r * 1e3,
                                self.max_radius * 1e3
                            )
                        })
                        .unwrap_or_default();
                    format!(
                        "{}×{} cells of {:.1} mm ({}{grown}){widest}{dark}{read}",
                        l.plane.res_u,
                        l.plane.res_v,
                        l.cell_size() * 1e3,
                        l.sizing.describe()
                    )
                };
                let covered: f64 = t[INDIRECT].levels[0].texels.iter().map(|c| c.area as f64).sum();
                let n = p.normal;
                format!(
                    "plane {i}: {:.2} × {:.2} m, {:.3} m² receiving, lit side facing ({:.2}, {:.2}, {:.2}); \
                     caustic layer {}; indirect layer {}; direct layer {}",
                    p.size_u,
                    p.size_v,
                    covered,
                    n.x,
                    n.y,
                    n.z,
                    layer(&t[CAUSTIC]),
                    layer(&t[INDIRECT]),
                    layer(&t[DIRECT])
                )
            })
            .collect()
    }
}

/// Fine grid resolution per plane and layer and why: cells of about `photons_per_cell`
/// photons where the layer's photons on the plane are densest (the 99th percentile of a
/// coarse count), within the resolution cap and the overall cell budget. A layer with no
/// photons on a plane gets 16 cells along the longer side. Also returns the factor by which
/// every cell grew to fit the budget (1 when it fits).
#[allow(clippy::type_complexity)]
fn fine_resolutions(
    set: &PlaneSet,
    photons: &[Photon],
    triangles: &[u32],
    params: &MultiscaleParams,
) -> (Vec<[((usize, usize), Sizing); LAYERS]>, f32) {
    const COARSE: usize = 32;
    let coarse: Vec<Plane> = set
        .planes
        .iter()
        .map(|p| p.clone().with_resolution(COARSE, COARSE))
        .collect();
    let empty = vec![[[0u32; COARSE * COARSE]; LAYERS]; set.planes.len()];
    let counts = per_plane_blocks(set, photons, triangles, empty.clone(), |counts, p, plane| {
        if let Some(c) = coarse[plane].cell_of(p.pos(), f32::INFINITY) {
            counts[plane][layer_of(p, params.max_depth)][c] += 1;
        }
    })
    .into_iter()
    .fold(empty, |mut a, b| {
        for (x, y) in a.iter_mut().flatten().flatten().zip(b.iter().flatten().flatten()) {
            *x += y;
        }
        a
    });
    let mut cell: Vec<[(f32, Sizing); LAYERS]> = coarse
        .iter()
        .zip(&counts)
        .map(|(p, layers)| {
            let longest = p.size_u.max(p.size_v);
            std::array::from_fn(|l| {
                let mut sorted: Vec<u32> = layers[l].iter().copied().filter(|&n| n > 0).collect();
                sorted.sort_unstable();
                let dense = sorted
                    .get(sorted.len().saturating_sub(1) * 99 / 100)
                    .copied()
                    .unwrap_or(0);
                let density = dense as f32 / p.cell_area().max(1e-30);
                let (size, sizing) = if density > 0.0 {
                    ((params.photons_per_cell / density).sqrt(), Sizing::Densest)
                } else {
                    (longest / 16.0, Sizing::NoPhotons)
                };
                let (finest, coarsest) = (longest / params.max_resolution as f32, longest / 8.0);
                if size < finest {
                    (finest, Sizing::Finest)
                } else if size > coarsest {
                    (coarsest, Sizing::Coarsest)
                } else {
                    (size, sizing)
                }
            })
        })
        .collect();
    // Within the budget: grow every cell alike.
    let total = total_cells(&set.planes, &cell);
    let mut grow = 1.0;
    if total > params.cell_budget as f64 {
        grow = (total / params.cell_budget as f64).sqrt() as f32;
        cell.iter_mut().flatten().for_each(|c| c.0 *= grow);
    }
    snap_to_reach(&set.planes, &mut cell, params);
    let dims = set
        .planes
        .iter()
        .zip(&cell)
        .map(|(p, c)| {
            std::array::from_fn(|l| {
                let ru = ((p.size_u / c[l].0).ceil() as usize).clamp(1, params.max_resolution);
                let rv = ((p.size_v / c[l].0).ceil() as usize).clamp(1, params.max_resolution);
                ((ru, rv), c[l].1)
            })
        })
        .collect();
    (dims, grow)
}

/// How far a kernel reaches from its point, in texels of its level: bilinear weights over
/// texels span one and a half texels each way.
const REACH_TEXELS: f32 = 1.5;

/// How much under `--max-radius` a snapped cell puts its widest kernel's reach, so that
/// rounding never puts it past the cap (which would drop that level).
const SNAP_MARGIN: f32 = 1e-4;

/// Cells along a plane's sides for fine cells of side `c`.
fn cells_of(p: &Plane, c: f32) -> f64 {
    ((p.size_u / c).ceil() * (p.size_v / c).ceil()) as f64
}

/// Fine cells of every plane and layer for the cell sizes `cell`.
fn total_cells(planes: &[Plane], cell: &[[(f32, Sizing); LAYERS]]) -> f64 {
    planes
        .iter()
        .zip(cell)
        .flat_map(|(p, c)| c.iter().map(move |&(c, _)| cells_of(p, c)))
        .sum()
}

/// Move the indirect layers' fine cell sizes (and the tail's) so that one of their levels'
/// kernels reaches `params.max_radius` (a hair under it). A level's reach doubles from one
/// level to the next, so under the cap the widest kernel lands anywhere between half the cap
/// and the cap, by where the photon counts and the cell budget happen to put the cells. On
/// pool_caustic's floor a few per cent of cell size then cost the widest level, three quarters
/// of its photons, and with them the photons' indirect estimate everywhere: final gathering
/// took over, at twice the camera's cost and with a worse image (docs/multiscale.md, "The
/// widest kernel, a level short"). Each size goes to the nearer (within √2) of the two sizes
/// around it whose levels reach the cap; where sizes made finer break the cell budget, they go
/// to the coarser one instead, largest layer first. Sizes outside the resolution limits keep
/// their size. The caustic and direct layers keep the size their photons asked for: their
/// edges (a caustic's, a shadow's) need the resolution.
fn snap_to_reach(planes: &[Plane], cell: &mut [[(f32, Sizing); LAYERS]], params: &MultiscaleParams) {
    let cap = params.max_radius * (1.0 - SNAP_MARGIN);
    if !(cap.is_finite() && cap > 0.0) {
        return;
    }
    // The layers made finer: plane, layer, and the coarser size they may fall back to.
    let mut finer: Vec<(usize, usize, f32)> = Vec::new();
    for (i, (p, layers)) in planes.iter().zip(cell.iter_mut()).enumerate() {
        let longest = p.size_u.max(p.size_v);
        let (finest, coarsest) = (longest / params.max_resolution as f32, longest / 8.0);
        // A layer without photons has nothing to estimate.
        for (l, (c, _)) in layers
            .iter_mut()
            .enumerate()
            .filter(|(l, (_, sizing))| matches!(*l, INDIRECT | TAIL) && *sizing != Sizing::NoPhotons)
        {
            let levels = (cap / (REACH_TEXELS * *c)).log2();
            if !(levels >= 0.0) {
                continue; // even the finest kernel reaches past the cap
            }
            let coarse = cap / (REACH_TEXELS * levels.floor().exp2());
            let fine = coarse / 2.0;
            // The nearer of the two by ratio, where the resolution limits allow it (a tight
            // budget may already have grown the cells past the coarsest).
            let coarsest = coarsest.max(*c);
            if fine >= finest && (levels.fract() > 0.5 || coarse > coarsest) {
                finer.push((i, l, coarse));
                *c = fine;
            } else if coarse <= coarsest {
                *c = coarse;
            }
        }
    }
    let mut total = total_cells(planes, cell);
    finer.sort_by(|a, b| {
        let n = |&(i, l, _): &(usize, usize, f32)| cells_of(&planes[i], cell[i][l].0);
        n(b).total_cmp(&n(a))
    });
    for (i, l, coarse) in finer {
        if total <= params.cell_budget as f64 {
            break;
        }
        total -= cells_of(&planes[i], cell[i][l].0) - cells_of(&planes[i], coarse);
        cell[i][l].0 = coarse;
    }
}

/// Area of the plane's triangles inside each fine cell (m²) and its moments about the cell's
/// centre, by clipping each triangle (projected into the plane's grid coordinates) against
/// the cells it overlaps.
fn coverage(plane: &Plane, tris: &[[Vec3; 3]]) -> Vec<Texel> {
    let (ru, rv) = (plane.res_u, plane.res_v);
    let cell_area = plane.cell_area();
    let mut area = vec![Texel::default(); ru * rv];
    for &t in &plane.triangles {
        let g: [Vec2; 3] = tris[t as usize].map(|p| {
            let (x, y) = plane.grid_coords(p);
            Vec2::new(x, y)
        });
        let lo = g[0].min(g[1]).min(g[2]);
        let hi = g[0].max(g[1]).max(g[2]);
        let x0 = (lo.x.floor().max(0.0) as usize).min(ru - 1);
        let x1 = (hi.x.ceil().max(1.0) as usize).min(ru);
        let y0 = (lo.y.floor().max(0.0) as usize).min(rv - 1);
        let y1 = (hi.y.ceil().max(1.0) as usize).min(rv);
        // Edge functions signed to be positive inside, whichever way the triangle winds.
        let sign = if (g[1] - g[0]).perp_dot(g[2] - g[0]) < 0.0 {
            -1.0
        } else {
            1.0
        };
        let edge = |k: usize, q: Vec2| sign * (g[(k + 1) % 3] - g[k]).perp_dot(q - g[k]);
        const CORNERS: [(f32, f32); 4] = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)];
        for j in y0..y1 {
            for i in x0..x1 {
                let (x, y) = (i as f32, j as f32);
                let corner = |c: usize| Vec2::new(x + CORNERS[c].0, y + CORNERS[c].1);
                // A cell wholly outside one edge misses the triangle (half of a quad's
                // bounding box); one whose four corners are inside the (convex) triangle is
                // covered whole; only cells the outline crosses are clipped.
                if (0..3).any(|k| (0..4).all(|c| edge(k, corner(c)) < 0.0)) {
                    continue;
                }
                let whole = (0..4).all(|c| (0..3).all(|k| edge(k, corner(c)) >= 0.0));
                let m = if whole { WHOLE_CELL } else { clipped_moments(&g, x, y) };
                area[j * ru + i].add(&m, cell_area);
            }
        }
    }
    // Overlapping triangles (duplicates) must not count twice.
    for a in &mut area {
        if a.area > cell_area {
            let k = cell_area / a.area;
            a.area = cell_area;
            a.area_moment = a.area_moment.map(|m| m * k);
            a.area_moment2 = a.area_moment2.map(|m| m * k);
        }
    }
    area
}

/// A whole unit cell's area and moments about its centre.
const WHOLE_CELL: Texel = Texel {
    flux: [0.0; 3],
    var: 0.0,
    count: 0.0,
    area: 1.0,
    flux_moment: [0.0; 2],
    area_moment: [0.0; 2],
    area_moment2: [1.0 / 12.0, 0.0, 1.0 / 12.0],
    clearance: f32::INFINITY,
};

/// Area and moments (about the square's centre) of the polygon `poly` inside the unit square
/// `[x, x+1] × [y, y+1]` (Sutherland–Hodgman, then Green's theorem).
fn clipped_moments(poly: &[Vec2], x: f32, y: f32) -> Texel {
    // A triangle clipped by four half-planes has at most 7 vertices (each clip adds one);
    // rounding near a clip line may add another, hence the margin.
    const MAX: usize = 16;
    let mut p = [Vec2::ZERO; MAX];
    let mut len = poly.len().min(MAX);
    p[..len].copy_from_slice(&poly[..len]);
    let edges: [(Vec2, f32); 4] = [
        (Vec2::X, x),
        (-Vec2::X, -(x + 1.0)),
        (Vec2::Y, y),
        (-Vec2::Y, -(y + 1.0)),
    ];
    for (n, d) in edges {
        if len == 0 {
            return Texel::default();
        }
        let mut out = [Vec2::ZERO; MAX];
        let mut m = 0;
        for i in 0..len {
            let (a, b) = (p[i], p[(i + 1) % len]);
            let (da, db) = (n.dot(a) - d, n.dot(b) - d);
            debug_assert!(m + 2 <= MAX, "clipped polygon of {m} vertices");
            if da >= 0.0 && m < MAX {
                out[m] = a;
                m += 1;
            }
            if (da >= 0.0) != (db >= 0.0) && m < MAX {
                out[m] = a + (b - a) * (da / (da - db));
                m += 1;
            }
        }
        (p, len) = (out, m);
    }
    let p = &p[..len];
    let c = Vec2::new(x + 0.5, y + 0.5);
    let (mut a, mut sx, mut sy, mut ixx, mut ixy, mut iyy) = (0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..p.len() {
        let (u, v) = (p[i] - c, p[(i + 1) % p.len()] - c);
        let cr = u.x * v.y - v.x * u.y;
        a += cr;
        sx += (u.x + v.x) * cr;
        sy += (u.y + v.y) * cr;
        ixx += (u.x * u.x + u.x * v.x + v.x * v.x) * cr;
        iyy += (u.y * u.y + u.y * v.y + v.y * v.y) * cr;
        ixy += (u.x * v.y + 2.0 * u.x * u.y + 2.0 * v.x * v.y + v.x * u.y) * cr;
    }
    // Clockwise polygons give negative sums.
    let sign = if a < 0.0 { -1.0 } else { 1.0 };
    Texel {
        area: 0.5 * a * sign,
        area_moment: [sx * sign / 6.0, sy * sign / 6.0],
        area_moment2: [ixx * sign / 12.0, ixy * sign / 24.0, iyy * sign / 12.0],
        ..Texel::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::planes::{detect_planes, PlaneParams};
    use crate::sampling::Rng;

    /// The windows' test cell by cell with summed-area tables (the first implementation).
    fn dark_cells_reference(w: usize, h: usize, counts: &[f32], covered: &[bool]) -> Vec<bool> {
        let mut dark = vec![false; w * h];
        if counts.iter().all(|&c| c <= 0.0) {
            return dark;
        }
        let n = SummedArea::new(w, h, |i| counts[i] as f64);
        let a = SummedArea::new(w, h, |i| if covered[i] { 1.0 } else { 0.0 });
        for b in DARK_WINDOWS.into_iter().filter(|&b| b <= w && b <= h) {
            let (ww, wh) = (w - b + 1, h - b + 1);
            // Empty windows, by their top-left cell.
            let empty: Vec<f64> = (0..ww * wh)
                .into_par_iter()
                .map(|i| {
                    let (x, y) = (i % ww, i / ww);
                    let inside = a.sum(x, y, x + b, y + b);
                    if inside <= 0.0 || n.sum(x, y, x + b, y + b) > 0.0 {
                        return 0.0;
                    }
                    let (x0, y0) = (x.saturating_sub(b), y.saturating_sub(b));
                    let (x1, y1) = ((x + 2 * b).min(w), (y + 2 * b).min(h));
                    let ring = a.sum(x0, y0, x1, y1) - inside;
                    let expected = if ring > 0.0 {
                        n.sum(x0, y0, x1, y1) * inside / ring
                    } else {
                        0.0
                    };
                    if expected >= DARK_EXPECTED {
                        1.0
                    } else {
                        0.0
                    }
                })
                .collect();
            if empty.iter().all(|&e| e == 0.0) {
                continue;
            }
            // A cell is dark when a window containing it is.
            let se = SummedArea::new(ww, wh, |i| empty[i]);
            dark.par_iter_mut().enumerate().for_each(|(i, d)| {
                let (x, y) = (i % w, i / w);
                if *d || !covered[i] {
                    return;
                }
                let (x0, y0) = ((x + 1).saturating_sub(b), (y + 1).saturating_sub(b));
                let (x1, y1) = ((x + 1).min(ww), (y + 1).min(wh));
                if x1 > x0 && y1 > y0 && se.sum(x0, y0, x1, y1) > 0.0 {
                    *d = true;
                }
            });
        }
        dark
    }

    #[test]
    fn dark_cells_match_the_cell_by_cell_windows() {
        let mut rng = Rng::keyed(7, 0, 0);
        for (w, h, lit) in [
            (37, 23, 0.6),
            (64, 64, 0.9),
            (90, 50, 0.3),
            (90, 48, 0.4),
            (70, 4, 0.5),
            (40, 1, 0.5),
            (5, 70, 0.5),
        ] {
            // Light in blobs with holes, a shadow, and some cells without surface.
            let counts: Vec<f32> = (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f32, (i / w) as f32);
                    let shade = (x * 0.31).sin() * (y * 0.17).cos() > 0.2 || (x > 10.0 && x < 18.0);
                    if !shade && rng.uniform() < lit {
                        (rng.uniform() * 6.0).floor()
                    } else {
                        0.0
                    }
                })
                .collect();
            let covered: Vec<bool> = (0..w * h).map(|i| (i % w) + 2 < w || rng.uniform() < 0.5).collect();
            let fast = dark_cells(w, h, &counts, &covered);
            assert_eq!(fast, dark_cells_reference(w, h, &counts, &covered), "{w}×{h}");
            if w > 30 && h > 30 {
                assert!(fast.iter().any(|&d| d), "{w}×{h}: the test should find dark cells");
            }
        }
    }

    fn square(size: f32) -> Vec<[Vec3; 3]> {
        let p = |x: f32, z: f32| Vec3::new(x, 0.0, z);
        vec![
            [p(0.0, 0.0), p(0.0, size), p(size, size)],
            [p(0.0, 0.0), p(size, size), p(size, 0.0)],
        ]
    }

    /// 64 × 64 indirect photons on a lattice over `square(2.0)`, one every 3.125 cm.
    fn lattice_photons() -> Vec<Photon> {
        (0..64 * 64)
            .map(|i| {
                let p = Vec3::new((i % 64) as f32 + 0.5, 0.0, (i / 64) as f32 + 0.5) / 32.0;
                Photon::new(p, Rgb::ONE, Vec3::Y, Vec3::Y, PhotonKind::Indirect)
            })
            .collect()
    }

    /// Photons `per_cell` on average in the cells of a `w × h` grid where `lit` says so.
    fn poisson_counts(w: usize, h: usize, per_cell: f32, lit: impl Fn(usize, usize) -> bool) -> Vec<f32> {
        let mut counts = vec![0.0f32; w * h];
        let mut rng = Rng::keyed(3, 1, 4);
        for _ in 0..(per_cell * (w * h) as f32) as usize {
            let (x, y) = (
                ((rng.uniform() * w as f32) as usize).min(w - 1),
                ((rng.uniform() * h as f32) as usize).min(h - 1),
            );
            if lit(x, y) {
                counts[y * w + x] += 1.0;
            }
        }
        counts
    }

    /// A shadow's edge crossing a column of cells 0.6 lit: those cells, found on the edge,
    /// are taken as 0.6 of a cell on average (their whole area would darken kernels there),
    /// and cells that do not touch a dark one keep their area.
    #[test]
    fn cells_on_a_shadows_edge_are_taken_as_their_lit_share() {
        let (w, h, per_cell, edge) = (160, 400, 4.0f32, 80.4f32);
        let mut rng = Rng::keyed(5, 9, 2);
        let mut counts = vec![0.0f32; w * h];
        for _ in 0..(per_cell * (w * h) as f32) as usize {
            let (x, y) = (rng.uniform() * w as f32, rng.uniform() * h as f32);
            if x >= edge {
                counts[(y as usize).min(h - 1) * w + (x as usize).min(w - 1)] += 1.0;
            }
        }
        let areas = vec![1.0f32; w * h];
        let dark = dark_cells(w, h, &counts, &vec![true; w * h]);
        let cut = edge_areas(w, h, &dark, &counts, &counts, &areas);
        let column: Vec<f32> = cut.iter().filter(|(i, _)| i % w == 80).map(|c| c.1).collect();
        assert!(
            column.len() > h * 9 / 10,
            "{} of column 80's cells on the edge",
            column.len()
        );
        let mean = column.iter().sum::<f32>() / column.len() as f32;
        assert!((mean - 0.6).abs() < 0.06, "column 80 taken as {mean} of its area");
        // Only cells beside dark ones are cut.
        for &(i, _) in &cut {
            let x = i % w;
            assert!(
                !dark[i]
                    && (x == 0
                        || dark[i - 1]
                        || dark[i + 1]
                        || dark.get(i + w) == Some(&true)
                        || (i >= w && dark[i - w]))
            );
        }
        assert!(cut.iter().all(|&(i, _)| i % w >= 79));
    }

    /// A shadow's cells are found dark up to its edge, to one cell, and a lit field with as
    /// few as 3 photons per cell (a quarter of its cells empty, some 2×2 blocks too) has none.
    #[test]
    fn dark_cells_are_a_shadow_to_its_edge_and_never_lit_cells() {
        let (w, h) = (200, 120);
        let covered = vec![true; w * h];
        let lit = poisson_counts(w, h, 3.0, |_, _| true);
        assert!(lit.iter().filter(|&&c| c == 0.0).count() > w * h / 30);
        assert!(!dark_cells(w, h, &lit, &covered).iter().any(|&d| d));
        // Shadow for x < 80, and a strip 4 cells wide at x 140..144 (a thin blocker's; at 3
        // cells the ring around a window is too much shadow to expect 24 photons in it).
        let shadow = |x: usize| x < 80 || (140..144).contains(&x);
        let counts = poisson_counts(w, h, 3.0, |x, _| !shadow(x));
        let dark = dark_cells(w, h, &counts, &covered);
        for y in 0..h {
            for x in 0..w {
                let d = dark[y * w + x];
                if !shadow(x) {
                    assert!(!d, "lit cell ({x}, {y}) found dark");
                } else if x >= 50 {
                    assert!(d, "shadowed cell ({x}, {y}) not found dark");
                }
            }
        }
        // Cells without surface are never dark, and an empty texture has no dark cells.
        let mut holes = covered.clone();
        holes[10 * w + 70] = false;
        assert!(!dark_cells(w, h, &counts, &holes)[10 * w + 70]);
        assert!(!dark_cells(w, h, &vec![0.0; w * h], &covered).iter().any(|&d| d));
    }

    /// A straight outline at 0°, 20°, 30° and 45° from the grid's axes, at eight offsets
    /// across a cell, lit by 3 photons per cell on one side; points tested on a lattice of
    /// 10 × 10 per cell. The cell-by-cell test (a point is dark where its cell is) puts the
    /// outline 0.2 to 0.43 of a cell into the dark side on average, and finds 0.35 to 0.44 of
    /// a cell per unit length on the wrong side. The outline between the cells' centres
    /// ([`OUTLINE_CONTOUR`]) leaves the same surface on each side as the cells' on average,
    /// and less on the wrong side at every angle off the axes.
    #[test]
    fn the_outline_runs_straight_through_the_cells_it_crosses() {
        let (w, h, per_cell) = (120usize, 120usize, 3.0f32);
        let plane = detect_planes(&square(1.0), &PlaneParams::default()).planes[0]
            .clone()
            .with_resolution(w, h);
        let covered = vec![true; w * h];
        let lattice =
            |r: std::ops::Range<usize>| r.flat_map(|i| (0..10).map(move |j| i as f32 + (j as f32 + 0.5) / 10.0));
        for degrees in [0.0f32, 20.0, 30.0, 45.0] {
            let (sin, cos) = degrees.to_radians().sin_cos();
            // Per unit length of outline, over the middle rows and all offsets: the surface
            // found on the wrong side, signed (dark side found lit: positive) and not, by the
            // outline between the centres and by cells.
            let (mut signed, mut wrong) = ([0.0f32; 2], [0.0f32; 2]);
            let offsets = 8;
            let length = 40.0 / cos.max(sin) * offsets as f32;
            for k in 0..offsets {
                // Lit where (x, y) · (cos, sin) > c.
                let c = 60.0 * (cos + sin) + (k as f32 + 0.5) / offsets as f32;
                let lit = |x: f32, y: f32| x * cos + y * sin > c;
                let mut rng = Rng::keyed(7, degrees as u64, k);
                let mut counts = vec![0.0f32; w * h];
                for _ in 0..(per_cell * (w * h) as f32) as usize {
                    let (x, y) = (rng.uniform() * w as f32, rng.uniform() * h as f32);
                    if lit(x, y) {
                        counts[(y as usize).min(h - 1) * w + (x as usize).min(w - 1)] += 1.0;
                    }
                }
                let dark = dark_cells(w, h, &counts, &covered);
                for y in lattice(40..80) {
                    for x in lattice(20..100) {
                        let truth = lit(x, y);
                        let found = [on_dark_side(&plane, &dark, |_| true, x, y), dark[plane.grid_cell(x, y)]];
                        for m in 0..2 {
                            if found[m] == truth {
                                signed[m] += if truth { -0.01 } else { 0.01 } / length;
                                wrong[m] += 0.01 / length;
                            }
                        }
                    }
                }
            }
            let figures = format!("{degrees}°: off on average / found wrong {signed:?} / {wrong:?}");
            assert!((signed[0] - signed[1]).abs() < 0.01, "{figures}");
            assert!(
                wrong[0] <= wrong[1] && (degrees == 0.0 || wrong[0] < 0.95 * wrong[1]),
                "{figures}"
            );
        }
    }

    #[test]
    fn clipped_area_of_a_triangle() {
        let t = [Vec2::new(0.0, 0.0), Vec2::new(2.0, 0.0), Vec2::new(0.0, 2.0)];
        let whole = clipped_moments(&t, 0.0, 0.0);
        assert!((whole.area - 1.0).abs() < 1e-6);
        assert!(whole.area_moment.iter().all(|m| m.abs() < 1e-6));
        assert!((whole.area_moment2[0] - 1.0 / 12.0).abs() < 1e-6 && whole.area_moment2[1].abs() < 1e-6);
        // Half the cell [1, 2] × [0, 1], below the diagonal x + y = 2: centroid (−1/6, −1/6)
        // from the centre; the point reflection through the centre maps it onto the other
        // half and keeps x² and xy, so ∫x² = 1/24 and ∫xy = 0.
        let half = clipped_moments(&t, 1.0, 0.0);
        assert!((half.area - 0.5).abs() < 1e-6);
        for m in half.area_moment {
            assert!((m / half.area + 1.0 / 6.0).abs() < 1e-6, "{half:?}");
        }
        assert!((half.area_moment2[0] - 1.0 / 24.0).abs() < 1e-6, "{half:?}");
        assert!(half.area_moment2[1].abs() < 1e-6, "{half:?}");
        assert_eq!(clipped_moments(&t, 1.0, 1.0).area, 0.0);
    }

    #[test]
    fn the_outline_is_the_ring_of_texels_at_the_surface_edge() {
        let tris = square(2.0);
        let set = detect_planes(&tris, &PlaneParams::default());
        let photon = Photon::new(
            Vec3::new(1.0, 0.0, 1.0),
            Rgb::ONE,
            Vec3::Y,
            Vec3::Y,
            PhotonKind::Indirect,
        );
        let probes = Probes {
            buried: &|_, _| false,
            clearance: &|_, _, _| f32::INFINITY,
        };
        let g = MultiscaleGrids::build(set, &tris, &[photon], &[0], &MultiscaleParams::default(), &probes, None);
        let tex = &g.textures[0][INDIRECT];
        for level in 0..tex.level_count().min(4) {
            let lv = &tex.levels[level];
            let outline = tex.outline(level);
            for (i, &o) in outline.iter().enumerate() {
                let (x, y) = (i % lv.w, i / lv.w);
                let border = x == 0 || y == 0 || x + 1 == lv.w || y + 1 == lv.h;
                if border {
                    assert!(o, "level {level}: border texel ({x}, {y}) not on the outline");
                }
                // Inside the ring every texel is whole and surrounded by surface.
                let inner = x >= 2 && y >= 2 && x + 2 < lv.w && y + 2 < lv.h;
                if inner {
                    assert!(!o, "level {level}: inner texel ({x}, {y}) on the outline");
                }
            }
        }
    }

    #[test]
    fn photons_are_counted_in_the_order_they_were_traced() {
        // More photons than a counting block, of every layer and many powers, some without a
        // recorded triangle: every fine texel's sums are the ones a plain loop over the
        // photons in order gives (to the last bit where each photon has one cell; a caustic
        // photon's share of a cell in a neighbouring run of cells is added with its own run),
        // they do not depend on the threads, and the layers' mean powers count every photon,
        // landed or not.
        let mut rng = Rng::keyed(5, 1, 9);
        let kinds = [PhotonKind::Direct, PhotonKind::Indirect, PhotonKind::Caustic];
        let photons: Vec<Photon> = (0..COUNT_BLOCK * 2 + 1234)
            .map(|i| {
                let at = Vec3::new(2.0 * rng.uniform(), 0.0, 2.0 * rng.uniform());
                let power = Rgb::new(rng.uniform(), rng.uniform(), rng.uniform()) * 1e-3;
                Photon::new(at, power, Vec3::Y, Vec3::Y, kinds[i % 3])
            })
            .collect();
        let triangles = vec![0u32; photons.len() - 1000];
        let g = open_square_grids(&photons, &triangles, &MultiscaleParams::default());
        let one_thread = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("a thread pool")
            .install(|| open_square_grids(&photons, &triangles, &MultiscaleParams::default()));
        for layer in [DIRECT, INDIRECT, CAUSTIC] {
            let tex = &g.textures[0][layer];
            let mut want = vec![Texel::default(); tex.levels[0].texels.len()];
            let (mut power, mut n) = (0.0f64, 0usize);
            for (i, p) in photons.iter().enumerate() {
                if layer_of(p, g.max_depth) != layer {
                    continue;
                }
                power += luminance(p.power()) as f64;
                n += 1;
                let Some(l) = tex.landing(p).filter(|_| i < triangles.len()) else {
                    continue;
                };
                let f = Rgb::from_array(l.flux);
                if layer == CAUSTIC {
                    let (shares, n) = bilinear_shares(&l, &tex.levels[0]);
                    for &(cell, share, d) in &shares[..n] {
                        want[cell].add_photon(f, d, share);
                    }
                } else {
                    want[l.cell as usize].add_photon(f, l.d, 1.0);
                }
            }
            for (got, want) in tex.levels[0].texels.iter().zip(&want) {
                if layer == CAUSTIC {
                    let near = |a: f32, b: f32| (a - b).abs() <= 1e-6 * b.abs();
                    let sums = |t: &Texel| [t.flux[0], t.flux[1], t.flux[2], t.var, t.count];
                    let (a, b) = (sums(got), sums(want));
                    assert!(a.iter().zip(&b).all(|(a, b)| near(*a, *b)), "{a:?} vs {b:?}");
                } else {
                    assert_eq!((got.flux, got.var, got.count), (want.flux, want.var, want.count));
                }
            }
            for (got, one) in tex.levels[0]
                .texels
                .iter()
                .zip(&one_thread.textures[0][layer].levels[0].texels)
            {
                assert_eq!((got.flux, got.var, got.count), (one.flux, one.var, one.count));
            }
            let mean = (power / n as f64) as f32;
            assert!(
                (g.mean_power[layer] / mean - 1.0).abs() < 1e-6,
                "{} vs {mean}",
                g.mean_power[layer]
            );
        }
    }

    /// Grids over the 2 m square from the lattice's photons, nothing standing on it.
    fn lattice_grids(params: &MultiscaleParams) -> MultiscaleGrids {
        let photons = lattice_photons();
        open_square_grids(&photons, &vec![0; photons.len()], params)
    }

    #[test]
    fn a_caustic_photon_is_shared_between_the_four_cells_around_it() {
        // A 4 × 3 level, all on the surface but cell 7 (x 3, y 1).
        let mut level = Level {
            w: 4,
            h: 3,
            texels: vec![
                Texel {
                    area: 1.0,
                    ..Texel::default()
                };
                12
            ],
            means: Vec::new(),
        };
        level.texels[7].area = 0.0;
        let at = |cell: u32, d: [f32; 2]| Landing {
            cell,
            d,
            flux: [1.0; 3],
        };
        let position = |cell: usize, d: [f32; 2]| [(cell % 4) as f32 + 0.5 + d[0], (cell / 4) as f32 + 0.5 + d[1]];
        // Inside: bilinear weights; each share's offset places the photon where it landed.
        let l = at(5, [0.25, -0.5]);
        let (shares, n) = bilinear_shares(&l, &level);
        let mut got: Vec<(usize, f32)> = shares[..n].iter().map(|s| (s.0, s.1)).collect();
        got.sort_by_key(|s| s.0);
        assert_eq!(got, vec![(1, 0.375), (2, 0.125), (5, 0.375), (6, 0.125)]);
        for &(cell, _, d) in &shares[..n] {
            assert_eq!(position(cell, d), position(5, l.d));
        }
        // Beside a cell off the surface: the others' weights scaled to 1.
        let (shares, n) = bilinear_shares(&at(6, [0.5, 0.25]), &level);
        let total: f32 = shares[..n].iter().map(|s| s.1).sum();
        assert!(shares[..n].iter().all(|s| s.0 != 7) && n == 3, "{:?}", &shares[..n]);
        assert!((total - 1.0).abs() < 1e-6, "{total}");
        // At the level's corner the weight is held by the corner cell.
        let (shares, n) = bilinear_shares(&at(0, [-0.4, -0.3]), &level);
        assert_eq!((n, shares[0].0, shares[0].1), (1, 0, 1.0));
        // Added: flux and count are shared, the first moment kept about each centre.
        let mut t = Texel::default();
        t.add_photon(Rgb::new(2.0, 2.0, 2.0), [0.5, -0.25], 0.25);
        let near = |a: f32, b: f32| (a - b).abs() < 1e-6;
        assert_eq!((t.flux, t.count), ([0.5; 3], 0.25));
        let lum = luminance(Rgb::new(0.5, 0.5, 0.5));
        assert!(
            near(t.flux_moment[0], 0.5 * lum) && near(t.flux_moment[1], -0.25 * lum),
            "{:?}",
            t.flux_moment
        );
        let whole = luminance(Rgb::new(2.0, 2.0, 2.0));
        assert!(near(t.var, 0.25 * whole * whole), "{}", t.var);
    }

    /// Grids over the 2 m square from `photons` (landed on `triangles`), nothing standing on it.
    fn open_square_grids(photons: &[Photon], triangles: &[u32], params: &MultiscaleParams) -> MultiscaleGrids {
        let tris = square(2.0);
        let set = detect_planes(&tris, &PlaneParams::default());
        let probes = Probes {
            buried: &|_, _| false,
            clearance: &|_, _, _| f32::INFINITY,
        };
        MultiscaleGrids::build(set, &tris, photons, triangles, params, &probes, None)
    }

    #[test]
    fn each_layer_says_why_its_cells_have_their_size() {
        // 64 × 64 global photons on a lattice over the 4 m² square, no caustic photons: 4 per
        // coarse (32 × 32) cell, 1024 per m², so 2 per cell makes cells of √(2/1024) m.
        let g = lattice_grids(&MultiscaleParams::default());
        let t = &g.textures[0];
        assert_eq!(t[INDIRECT].sizing, Sizing::Densest);
        assert_eq!(
            t[INDIRECT].plane.res_u,
            (2.0 / (2.0f32 / 1024.0).sqrt()).ceil() as usize
        );
        assert_eq!((t[CAUSTIC].sizing, t[CAUSTIC].plane.res_u), (Sizing::NoPhotons, 16));
        assert_eq!(g.cells_grown, 1.0);
        let line = &g.describe()[0];
        assert!(
            line.contains("where this light is densest") && line.contains("no photons of this kind"),
            "{line}"
        );
        // A budget of 100 cells makes every cell wider, and the report says so.
        let tight = MultiscaleParams {
            cell_budget: 100,
            ..MultiscaleParams::default()
        };
        let g = lattice_grids(&tight);
        assert!(
            g.cells_grown > 1.0 && g.textures[0][INDIRECT].plane.res_u < 46,
            "{}",
            g.cells_grown
        );
        assert!(g.describe()[0].contains("wider to fit --grid-cells"));
    }

    #[test]
    fn the_widest_kernel_reaches_the_cap_wherever_the_cells_fall() {
        // The lattice asks for indirect cells of 44 mm. Without the snap, the widest level
        // under a cap of 0.37 m or 0.5 m reaches 265 mm (0.72 and 0.53 of the cap).
        let fine_cells = |g: &MultiscaleGrids| g.textures[0].iter().map(|t| t.levels[0].texels.len()).sum::<usize>();
        for cell_budget in [4 << 20, 100] {
            let uncapped = MultiscaleParams {
                cell_budget,
                ..MultiscaleParams::default()
            };
            let unsnapped = fine_cells(&lattice_grids(&uncapped));
            for max_radius in [0.3, 0.37, 0.5, 0.61, 0.8] {
                let g = lattice_grids(&MultiscaleParams { max_radius, ..uncapped });
                let t = &g.textures[0][INDIRECT];
                let widest = t.widest_reach(max_radius);
                // (100 cells make cells whose finest kernel reaches past every cap here.)
                if cell_budget > 100 {
                    let widest = widest.expect("a level under the cap");
                    assert!(widest > 0.85 * max_radius, "cap {max_radius}: widest {widest}");
                    assert!(g.describe()[0].contains("of --max-radius"), "{}", g.describe()[0]);
                }
                // Made finer only within the budget.
                let cells = fine_cells(&g);
                assert!(cells <= cell_budget.max(unsnapped), "{cells} cells against {unsnapped}");
            }
        }
    }

    #[test]
    fn texels_at_the_foot_of_a_wall_are_on_the_outline() {
        // A wall stands across the square at x = 1.1: the open space in front of the floor
        // is the distance a 45° probe travels to it.
        let tris = square(2.0);
        let set = detect_planes(&tris, &PlaneParams::default());
        // Photons everywhere, so that the fine grid has many texels.
        let photons = lattice_photons();
        let probes = Probes {
            buried: &|_, _| false,
            clearance: &|p: Vec3, _, _| (p.x - 1.1).abs() * std::f32::consts::SQRT_2,
        };
        let triangles = vec![0; photons.len()];
        let g = MultiscaleGrids::build(
            set,
            &tris,
            &photons,
            &triangles,
            &MultiscaleParams::default(),
            &probes,
            None,
        );
        let tex = &g.textures[0][INDIRECT];
        let (mut at_wall, mut away) = (0, 0);
        for level in 2..tex.level_count().min(5) {
            let lv = &tex.levels[level];
            let side = (1u32 << level) as f32;
            let outline = tex.outline(level);
            for (i, &o) in outline.iter().enumerate() {
                let (x, y) = (i % lv.w, i / lv.w);
                if x == 0 || y == 0 || x + 1 == lv.w || y + 1 == lv.h {
                    continue; // the ring at the square's edge
                }
                let a = tex.plane.grid_to_world(x as f32 * side, y as f32 * side).x;
                let b = tex.plane.grid_to_world((x + 1) as f32 * side, (y + 1) as f32 * side).x;
                let (lo, hi) = (a.min(b), a.max(b));
                if lo < 1.1 && hi > 1.1 {
                    assert!(o, "level {level}: texel ({x}, {y}) under the wall not on the outline");
                    at_wall += 1;
                } else if (if hi <= 1.1 { 1.1 - hi } else { lo - 1.1 }) > tex.kernel_reach(level) {
                    assert!(!o, "level {level}: texel ({x}, {y}) far from the wall on the outline");
                    away += 1;
                }
            }
        }
        assert!(at_wall > 0 && away > 0, "{at_wall} texels at the wall, {away} away");
    }

    #[test]
    fn global_kernels_stop_at_a_wall_the_plane_runs_on_behind_but_not_at_one_where_it_ends() {
        // A wall across x = `wall`, met by the 45° probe leaning towards it at the height of
        // the point's distance from it (the square's normal is +y).
        let clearance_at = |wall: f32, x: f32, layer: usize| {
            let probe = move |p: Vec3, _: Vec3, counts: &dyn Fn(Vec3) -> bool| {
                let d = (p.x - wall).abs();
                if counts(Vec3::new(wall, d, p.z)) {
                    d * std::f32::consts::SQRT_2
                } else {
                    f32::INFINITY
                }
            };
            let probes = Probes {
                buried: &|_, _| false,
                clearance: &probe,
            };
            let tris = square(2.0);
            let set = detect_planes(&tris, &PlaneParams::default());
            let photons = lattice_photons();
            let triangles = vec![0; photons.len()];
            let params = MultiscaleParams {
                max_radius: 0.5,
                ..MultiscaleParams::default()
            };
            let g = MultiscaleGrids::build(set, &tris, &photons, &triangles, &params, &probes, None);
            let t = &g.textures[0][layer];
            let cell = t.plane.cell_of(Vec3::new(x, 0.0, 1.0), 0.0).unwrap();
            eprintln!(
                "DBG layer {layer} res {} {} size {} {} cell {} gc {:?}",
                t.plane.res_u,
                t.plane.res_v,
                t.plane.size_u,
                t.plane.size_v,
                cell,
                t.plane.grid_coords(Vec3::new(2.0, 0.0, 1.0))
            );
            t.levels[0].texels[cell].clearance
        };
        // The floor runs on behind a wall standing across it: both layers stop there.
        for layer in [DIRECT, INDIRECT] {
            let c = clearance_at(1.1, 0.9, layer);
            assert!(
                c < 1.0,
                "layer {layer}: clearance {c} before a wall standing on the plane"
            );
        }
        // A wall at the floor's edge (a room's corner): kernels cut by the edge divide by
        // their covered area, so neither layer stops there.
        for layer in [DIRECT, INDIRECT, TAIL] {
            assert_eq!(clearance_at(2.0, 1.9, layer), f32::INFINITY, "layer {layer}");
        }
        assert!(clearance_at(1.1, 0.9, TAIL) < 1.0);
    }

    #[test]
    fn indirect_photons_too_deep_for_gathering_have_their_own_layer() {
        let at = |kind, depth| Photon::new(Vec3::ZERO, Rgb::ONE, Vec3::Y, Vec3::Y, kind).with_depth(depth);
        assert_eq!(layer_of(&at(PhotonKind::Indirect, 10), 12), INDIRECT);
        assert_eq!(layer_of(&at(PhotonKind::Indirect, 11), 12), TAIL);
        assert_eq!(layer_of(&at(PhotonKind::Indirect, 11), 0), INDIRECT);
        assert_eq!(layer_of(&at(PhotonKind::Caustic, 11), 12), CAUSTIC);
        assert_eq!(layer_of(&at(PhotonKind::Direct, 1), 2), DIRECT);
    }

    #[test]
    fn passes_weigh_by_their_photons() {
        // (Photon powers are stored with a shared exponent: sums are exact to 0.2 %.)
        // Pass 1: 40 000 photons of a 1 W/m² field on 4 m². Pass 2: a tenth of the photons
        // of a field twice as bright (each photon 20 times the power). Weighed by photons
        // the irradiance is (1 + 0.1 · 2) / 1.1; as two equal passes it would be 1.5.
        let tris = square(2.0);
        let set = detect_planes(&tris, &PlaneParams::default());
        let field = |n: usize, irradiance: f32, seed: u64| {
            let mut rng = Rng::keyed(seed, 1, 4);
            let power = Rgb::splat(4.0 * irradiance / n as f32);
            let photons: Vec<Photon> = (0..n)
                .map(|_| {
                    let p = Vec3::new(rng.uniform() * 2.0, 0.0, rng.uniform() * 2.0);
                    Photon::new(p, power, Vec3::Y, Vec3::Y, PhotonKind::Indirect)
                })
                .collect();
            let tri = photons
                .iter()
                .map(|p| u32::from(p.pos().z <= p.pos().x))
                .collect::<Vec<_>>();
            (photons, tri)
        };
        let probes = Probes {
            buried: &|_, _| false,
            clearance: &|_, _, _| f32::INFINITY,
        };
        let emitted = |n| Some(Emitted { global: n, caustic: 0 });
        let (p1, t1) = field(40_000, 1.0, 1);
        let mut g = MultiscaleGrids::build(
            set,
            &tris,
            &p1,
            &t1,
            &MultiscaleParams::default(),
            &probes,
            emitted(40_000),
        );
        let (p2, t2) = field(4_000, 2.0, 2);
        g.add(&p2, &t2, emitted(4_000));
        let tex = &g.textures[0][INDIRECT];
        let flux: f32 = tex.levels[0].texels.iter().map(|t| t.flux[1]).sum();
        let e = flux / (4.0 * g.passes_of(INDIRECT));
        assert!((e - 1.2 / 1.1).abs() < 5e-3, "{e}");
        assert_eq!(g.passes, 2);
        // The variance floor is a weighed photon's power: 1e-4 W in pass 1, 2e-3 × 0.1 in pass 2.
        let floor = (1e-4 + 0.1 * 2e-4) / 1.1;
        assert!(
            (g.mean_power[INDIRECT] / floor - 1.0).abs() < 5e-3,
            "{}",
            g.mean_power[INDIRECT]
        );
    }

    #[test]
    fn uniform_field_gives_its_irradiance_at_every_scale_and_edge() {
        let tris = square(2.0);
        let set = detect_planes(&tris, &PlaneParams::default());
        assert_eq!(set.planes.len(), 1);
        let mut rng = Rng::keyed(3, 1, 4);
        let n = 200_000;
        // 1 W/m² over 4 m²: 4 W in all.
        let power = Rgb::splat(4.0 / n as f32);
        let (mut photons, mut tri) = (Vec::new(), Vec::new());
        for _ in 0..n {
            let (x, z) = (rng.uniform() * 2.0, rng.uniform() * 2.0);
            photons.push(Photon::new(
                Vec3::new(x, 0.0, z),
                power,
                Vec3::Y,
                Vec3::Y,
                PhotonKind::Indirect,
            ));
            tri.push(if z > x { 0 } else { 1 });
        }
        let probes = Probes {
            buried: &|_, _| false,
            clearance: &|_, _, _| f32::INFINITY,
        };
        let g = MultiscaleGrids::build(set, &tris, &photons, &tri, &MultiscaleParams::default(), &probes, None);
        let tex = &g.textures[0][INDIRECT];
        let total: f64 = tex.levels[0].texels.iter().map(|t| t.area as f64).sum();
        let full = tex.levels[0].texels.iter().filter(|t| t.area > 0.0).count();
        assert!(
            (total - 4.0).abs() < 1e-3,
            "covered area {total}, {}×{} cells of {} m², {full} covered",
            tex.plane.res_u,
            tex.plane.res_v,
            tex.plane.cell_area()
        );
        for p in [
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(0.001, 0.0, 0.001),
            Vec3::new(1.999, 0.0, 0.5),
        ] {
            for s in tex.scales(p).skip(3) {
                let e = s.texel.flux[0] / s.texel.area;
                let sigma = s.texel.var.sqrt() / s.texel.area;
                // Within 4 σ of 1 W/m², corners included (the area counts only the surface).
                assert!(
                    (e - 1.0).abs() < 4.0 * sigma + 1e-3,
                    "{p} level {}: {e} ± {sigma}",
                    s.level
                );
            }
        }
    }
}
