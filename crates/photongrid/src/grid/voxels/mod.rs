//! Sparse 3D voxel grid of receiving-surface area and photon counts: the 3D extension of the
//! per-plane photon-count grids (Watanabe et al.) for curved and cluttered scenes.
//!
//! For every occupied voxel and every normal bin the grid stores the exact surface area `A`
//! of the scene triangles inside the voxel (whose normal falls in that bin), the number of
//! photons `N` that landed there and their summed flux weight. The assumed kNN radius is
//! `r_a² = n·A/(N·π)`, i.e. `r_a = sqrt(n / (π·ρ))` with the photon density `ρ = N/A`.
//!
//! `grid` holds the grid itself (occupied voxels, normal bins, counting, density and radius),
//! `clip` the exact area of a triangle in each voxel, `denoise` the filtering of the counts.

mod clip;
mod denoise;
mod grid;
#[cfg(test)]
mod tests;

pub use denoise::DenoiseStats;
pub use grid::{bin_direction, normal_bin, VoxelGrid, NORMAL_BINS, SNAP_FRACTION, SUGGEST_C};
