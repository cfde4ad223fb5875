//! The paper's grids and their 3D extension: planes found among the triangles with a
//! photon-count texture each (wavelet-filtered), and a sparse voxel grid for curved or small
//! receivers; from the counts follows the assumed radius of METHOD.md eq. (3).

mod noise;
pub mod planes;
pub mod radius;
pub mod voxels;
pub mod wavelet;

pub use radius::{assumed_radius, blended_radius, progressive_neighbours, GridQuantity, PlaneGrids};

use crate::photon::Photon;
use crate::scene::Scene;
use crate::settings::Settings;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use voxels::VoxelGrid;

/// Which grids the adaptive method uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum GridMode {
    /// Plane grids for planes; voxels only where enough receiving area is not planar.
    Auto,
    /// Plane grids only (the paper); other surfaces use plain kNN.
    Planes,
    /// One sparse voxel grid for every surface.
    Voxels,
    /// No grid: plain kNN everywhere.
    None,
}

/// Non-planar receiving area, as a share of the scene's, below which auto mode builds no
/// voxel grid (a few small curved objects do not pay for one).
pub const AUTO_VOXEL_MIN_AREA_SHARE: f32 = 0.05;

/// What the grids say about the radius at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Assumed {
    /// The assumed radius r_a.
    Radius(f32),
    /// Covered by a grid, but too few photons: use r_k (the paper's shadow fallback).
    Shadow,
    /// No grid covers the point: use r_k.
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
    /// Choose and build the grids for `settings.grid`, counting `photons` (landing on
    /// `triangles[i]`).
    pub fn build(scene: &Scene, photons: &[Photon], triangles: &[u32], settings: &Settings) -> Grids {
        let mut choice = Vec::new();
        let mode = settings.grid;
        let total_area = scene.surface_area().max(1e-12);
        let plane_set = matches!(mode, GridMode::Auto | GridMode::Planes)
            .then(|| PlaneGrids::detect(&scene.triangles, settings.grid_res));
        let mut on_plane = vec![false; scene.triangles.len()];
        if let Some(set) = &plane_set {
            for (t, p) in set.plane_of_triangle.iter().enumerate() {
                on_plane[t] = *p != planes::NO_PLANE;
            }
            let plane_area: f32 = set.planes.iter().map(|p| p.area).sum();
            choice.push(format!(
                "{} planes with {}-cell grids cover {:.1} % of the surface",
                set.planes.len(),
                settings.grid_res,
                100.0 * plane_area / total_area
            ));
        }
        let off_plane_area: f32 = scene
            .triangles
            .iter()
            .zip(&on_plane)
            .filter(|(_, on)| !**on)
            .map(|(t, _)| t.area())
            .sum();
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
            let mut g = PlaneGrids::count(set, photons, triangles, settings.grid_quantity, |_| true);
            g.filter(settings.wavelet(), settings.threshold(), settings.wavelet_levels);
            g
        });
        let voxels = want_voxels.then(|| {
            // In auto mode voxels cover only what planes do not.
            let served: Vec<usize> = (0..scene.triangles.len()).filter(|&t| !on_plane[t]).collect();
            let tris: Vec<[Vec3; 3]> = served.iter().map(|&t| scene.triangles[t].p).collect();
            let area: f32 = served.iter().map(|&t| scene.triangles[t].area()).sum();
            let share = area / total_area;
            // With no photons yet (`photongrid info`), size for the photons the settings ask for.
            let expected = if photons.is_empty() {
                settings.photons
            } else {
                photons.len()
            };
            let n = (expected as f32 * share) as usize;
            let size = VoxelGrid::suggest_voxel_size(n.max(1), settings.neighbours, area, scene.bounds.diagonal());
            let mut v = VoxelGrid::from_triangles(&tris, size);
            count_voxels(&mut v, scene, photons, triangles, &on_plane, settings);
            choice.push(format!(
                "voxel grid: {:.4} m voxels, {} occupied, {:.1} MB, for {:.1} % of the surface",
                size,
                v.occupied(),
                v.memory_bytes() as f64 / 1e6,
                100.0 * share
            ));
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
    pub fn add(&mut self, scene: &Scene, photons: &[Photon], triangles: &[u32], settings: &Settings) {
        if let Some(p) = &mut self.planes {
            let counted = PlaneGrids::count(p.set.clone(), photons, triangles, settings.grid_quantity, |_| true);
            p.accumulate(&counted);
            p.filter(settings.wavelet(), settings.threshold(), settings.wavelet_levels);
        }
        if let Some(v) = &mut self.voxels {
            count_voxels(v, scene, photons, triangles, &self.on_plane, settings);
        }
    }

    /// True if `triangle` is served by a plane grid.
    pub fn on_plane(&self, triangle: u32) -> bool {
        self.on_plane.get(triangle as usize).copied().unwrap_or(false)
    }

    /// The assumed radius for `k` neighbours at `p` on `triangle` (geometric front normal
    /// `normal`), or why there is none.
    pub fn assumed(&self, triangle: u32, p: Vec3, normal: Vec3, k: usize, shadow_count: f32) -> Assumed {
        if self.on_plane.get(triangle as usize).copied().unwrap_or(false) {
            if let Some((count, cell_area)) = self.planes.as_ref().and_then(|g| g.count_at(triangle, p)) {
                if count < shadow_count {
                    return Assumed::Shadow;
                }
                return Assumed::Radius(assumed_radius(k, cell_area, count));
            }
        } else if let Some(v) = &self.voxels {
            return match (v.count_at(p, normal), v.assumed_radius(p, normal, k)) {
                (Some(c), Some(r)) if c >= shadow_count && r.is_finite() => Assumed::Radius(r),
                (Some(_), _) => Assumed::Shadow,
                _ => Assumed::Uncovered,
            };
        }
        Assumed::Uncovered
    }

    /// Memory of all grids.
    pub fn memory_bytes(&self) -> usize {
        self.planes.as_ref().map(|p| p.memory_bytes()).unwrap_or(0)
            + self.voxels.as_ref().map(|v| v.memory_bytes()).unwrap_or(0)
    }
}

/// Count the photons of non-plane triangles into `v` (adding to what it holds), then filter.
fn count_voxels(
    v: &mut VoxelGrid,
    scene: &Scene,
    photons: &[Photon],
    triangles: &[u32],
    on_plane: &[bool],
    settings: &Settings,
) {
    // Voxel bins follow the triangle's winding normal, so count with it (not the facing one).
    let items: Vec<(Vec3, Vec3, f32)> = photons
        .iter()
        .zip(triangles)
        .filter(|(_, &t)| !on_plane[t as usize])
        .map(|(p, &t)| (p.pos(), scene.triangles[t as usize].cross(), 1.0))
        .collect();
    v.count_parallel(&items);
    if settings.wavelet().is_some() {
        v.denoise(1.0);
    }
}
