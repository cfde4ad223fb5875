//! The paper's grids: planes found among the triangles, a photon-count texture per plane,
//! wavelet filtering of the counts, and the assumed radius they imply.

pub mod planes;
pub mod radius;
pub mod wavelet;

pub use radius::{assumed_radius, blended_radius, progressive_neighbours, GridQuantity, PlaneGrids};
pub mod voxels;
