//! Spatial index of points (photons, precomputed irradiance points): a uniform grid with
//! adaptive sub-grids answering exact k-nearest-neighbour and fixed-radius queries.

mod point_grid;

pub use point_grid::*;
