//! Sparse 3D voxel grid of receiving-surface area and photon counts.

mod grid;

pub use grid::*;
