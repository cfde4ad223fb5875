//! The paper's grids and their 3D extension: planes found among the triangles with a
//! photon-count texture each (wavelet-filtered), and a sparse voxel grid for curved or small
//! receivers; from the counts follows the assumed radius of METHOD.md eq. (3).

pub mod multiscale;
mod noise;
pub mod planes;
pub mod textures;
pub mod voxels;
pub mod wavelet;

pub use textures::PlaneGrids;

use crate::photon::Photon;
use crate::scene::Scene;
use crate::settings::{GridMode, GridQuantity, Settings, ThresholdChoice, WaveletChoice};
use glam::Vec3;
use voxels::VoxelGrid;
use wavelet::{Threshold, Wavelet};

/// What the grids are built with (from [`Settings`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridParams {
    /// Which grids.
    pub mode: GridMode,
    /// Cells along a plane's longer side.
    pub resolution: usize,
    /// What a cell accumulates.
    pub quantity: GridQuantity,
    /// Wavelet of the count textures (none: no filtering).
    pub wavelet: Option<Wavelet>,
    /// Thresholding of the wavelet details.
    pub threshold: Threshold,
    /// Wavelet levels at most.
    pub levels: usize,
    /// Photon paths per pass (sizes the voxels before any photon is counted).
    pub photons: usize,
    /// Neighbours per estimate (sizes the voxels).
    pub neighbours: usize,
}

impl From<&Settings> for GridParams {
    fn from(s: &Settings) -> Self {
        GridParams {
            mode: s.grid,
            resolution: s.grid_res,
            quantity: s.grid_quantity,
            wavelet: match s.wavelet {
                WaveletChoice::None => None,
                WaveletChoice::Haar => Some(Wavelet::Haar),
                WaveletChoice::Cdf53 => Some(Wavelet::Cdf53),
                WaveletChoice::Cdf97 => Some(Wavelet::Cdf97),
            },
            threshold: match s.threshold {
                ThresholdChoice::None => Threshold::None,
                ThresholdChoice::Fixed => Threshold::Fixed {
                    value: s.threshold_value,
                    soft: false,
                },
                ThresholdChoice::Universal => Threshold::Universal { soft: false },
                ThresholdChoice::UniversalSoft => Threshold::Universal { soft: true },
                ThresholdChoice::Bayes => Threshold::BayesShrink,
            },
            levels: s.wavelet_levels,
            photons: s.photons,
            neighbours: s.neighbours,
        }
    }
}

/// Non-planar receiving area, as a share of the scene's, below which auto mode builds no
/// voxel grid (a few small curved objects do not pay for one).
pub const AUTO_VOXEL_MIN_AREA_SHARE: f32 = 0.05;

/// What the grids know at a point: the filtered photon count of its cell (plane) or voxel bin,
/// and the photon density there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GridSample {
    /// Covered by a grid.
    Covered {
        /// Filtered photons per cell (or per voxel bin): the shadow test's quantity.
        count: f32,
        /// Filtered photons per m².
        density: f32,
    },
    /// No grid covers the point.
    Uncovered,
}

/// The grids of one render, and why they were chosen.
pub struct Grids {
    /// Plane grids, if built.
    pub planes: Option<PlaneGrids>,
    /// Voxel grid, if built.
    pub voxels: Option<VoxelGrid>,
    /// Per triangle: served by a plane grid.
    on_plane: Vec<bool>,
    /// What was chosen and why (for `info` and `--stats`).
    pub choice: Vec<String>,
}

impl Grids {
    /// Choose and build the grids for `params.mode`, counting `photons` (landing on
    /// `triangles[i]`).
    pub fn build(scene: &Scene, photons: &[Photon], triangles: &[u32], params: &GridParams) -> Grids {
        let mut choice = Vec::new();
        let mode = params.mode;
        let (receives, total_area) = receivers(scene);
        let plane_set = matches!(mode, GridMode::Auto | GridMode::Planes)
            .then(|| PlaneGrids::detect_receivers(scene, params.resolution));
        let mut on_plane = vec![false; scene.triangles.len()];
        if let Some(set) = &plane_set {
            for (t, p) in set.plane_of_triangle.iter().enumerate() {
                on_plane[t] = *p != planes::NO_PLANE;
            }
            let plane_area: f32 = set.planes.iter().map(|p| p.area).sum();
            choice.push(format!(
                "{} planes with {}-cell grids cover {:.1} % of the receiving surface (mirrors and glass get no grid)",
                set.planes.len(),
                params.resolution,
                100.0 * plane_area / total_area
            ));
        }
        let off_plane_area: f32 = scene
            .triangles
            .iter()
            .zip(on_plane.iter().zip(&receives))
            .filter(|(_, (on, r))| !**on && **r)
            .map(|(t, _)| t.area())
            .sum::<f32>()
            .abs(); // an empty sum is -0.0
        let want_voxels = match mode {
            GridMode::Voxels => true,
            GridMode::Auto => off_plane_area / total_area >= AUTO_VOXEL_MIN_AREA_SHARE,
            _ => false,
        };
        if mode == GridMode::Auto && !want_voxels {
            choice.push(format!(
                "no voxel grid: non-planar surfaces are {:.1} % of the area (< {:.0} %), they use kNN",
                100.0 * off_plane_area / total_area,
                100.0 * AUTO_VOXEL_MIN_AREA_SHARE
            ));
        }
        let planes = plane_set.map(|set| {
            let mut g = PlaneGrids::count(set, photons, triangles, params.quantity, |_| true);
            g.filter(params.wavelet, params.threshold, params.levels);
            g
        });
        let voxels = want_voxels.then(|| {
            let (v, why) = build_voxels(scene, photons, triangles, params, &on_plane, &receives, total_area);
            choice.push(why);
            v
        });
        if mode == GridMode::None {
            choice.push("no grid: plain kNN".into());
        }
        Grids {
            planes,
            voxels,
            on_plane,
            choice,
        }
    }

    /// Add a further pass's photons to the counts and refilter (progressive rendering: the
    /// textures then hold every pass's photons so far).
    pub fn add(&mut self, scene: &Scene, photons: &[Photon], triangles: &[u32], params: &GridParams) {
        if let Some(p) = &mut self.planes {
            let counted = PlaneGrids::count(p.set.clone(), photons, triangles, params.quantity, |_| true);
            p.accumulate(&counted);
            p.filter(params.wavelet, params.threshold, params.levels);
        }
        if let Some(v) = &mut self.voxels {
            count_voxels(v, scene, photons, triangles, &self.on_plane, params);
        }
    }

    /// True if `triangle` is served by a plane grid.
    pub fn on_plane(&self, triangle: u32) -> bool {
        self.on_plane.get(triangle as usize).copied().unwrap_or(false)
    }

    /// The filtered count and density at `p` on `triangle` (geometric front normal `normal`).
    pub fn sample(&self, triangle: u32, p: Vec3, normal: Vec3) -> GridSample {
        if self.on_plane.get(triangle as usize).copied().unwrap_or(false) {
            if let Some((count, cell_area)) = self.planes.as_ref().and_then(|g| g.count_at(triangle, p)) {
                return GridSample::Covered {
                    count,
                    density: count / cell_area,
                };
            }
        } else if let Some(v) = &self.voxels {
            if let Some(count) = v.count_at(p, normal) {
                let density = v.density_at(p, normal).unwrap_or(0.0);
                return GridSample::Covered { count, density };
            }
        }
        GridSample::Uncovered
    }

    /// Memory of all grids.
    pub fn memory_bytes(&self) -> usize {
        self.planes.as_ref().map(|p| p.memory_bytes()).unwrap_or(0)
            + self.voxels.as_ref().map(|v| v.memory_bytes()).unwrap_or(0)
    }
}

/// Which triangles receive photons, and their area (at least the smallest positive float).
/// Mirrors and glass store no photons: they get no grid and do not count as surface.
fn receivers(scene: &Scene) -> (Vec<bool>, f32) {
    let receives: Vec<bool> = scene
        .triangles
        .iter()
        .map(|t| scene.materials[t.material as usize].receives_photons())
        .collect();
    let total_area = scene
        .triangles
        .iter()
        .zip(&receives)
        .filter(|(_, r)| **r)
        .map(|(t, _)| t.area())
        .sum::<f32>()
        .max(f32::MIN_POSITIVE);
    (receives, total_area)
}

/// The voxel grid over the receiving triangles off the planes, sized for the photons they
/// are expected to get, with `photons` counted; and the line saying what was built.
fn build_voxels(
    scene: &Scene,
    photons: &[Photon],
    triangles: &[u32],
    params: &GridParams,
    on_plane: &[bool],
    receives: &[bool],
    total_area: f32,
) -> (VoxelGrid, String) {
    // In auto mode voxels cover only what planes do not.
    let served: Vec<usize> = (0..scene.triangles.len())
        .filter(|&t| !on_plane[t] && receives[t])
        .collect();
    let tris: Vec<[Vec3; 3]> = served.iter().map(|&t| scene.triangles[t].p).collect();
    let area: f32 = served.iter().map(|&t| scene.triangles[t].area()).sum();
    let share = area / total_area;
    // With no photons yet (`photongrid info`), size for the photons the settings ask for.
    let expected = if photons.is_empty() {
        params.photons
    } else {
        photons.len()
    };
    let n = (expected as f32 * share) as usize;
    let size = VoxelGrid::suggest_voxel_size(n.max(1), params.neighbours, area, scene.bounds.diagonal());
    let mut v = VoxelGrid::from_triangles(&tris, size);
    count_voxels(&mut v, scene, photons, triangles, on_plane, params);
    let why = format!(
        "voxel grid: {:.4} m voxels, {} occupied, {:.1} MB, for {:.1} % of the surface",
        size,
        v.occupied(),
        v.memory_bytes() as f64 / 1e6,
        100.0 * share
    );
    (v, why)
}

/// Count the photons of non-plane triangles into `v` (adding to what it holds), then filter.
fn count_voxels(
    v: &mut VoxelGrid,
    scene: &Scene,
    photons: &[Photon],
    triangles: &[u32],
    on_plane: &[bool],
    params: &GridParams,
) {
    // Voxel bins follow the triangle's winding normal, so count with it (not the facing one).
    let items: Vec<(Vec3, Vec3, f32)> = photons
        .iter()
        .zip(triangles)
        .filter(|(_, &t)| !on_plane[t as usize])
        .map(|(p, &t)| (p.pos(), scene.triangles[t as usize].cross(), 1.0))
        .collect();
    v.count_parallel(&items);
    if params.wavelet.is_some() {
        v.denoise(1.0);
    }
}
