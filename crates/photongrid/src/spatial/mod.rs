//! Spatial index of points: a uniform grid with adaptive sub-grids that answers exact
//! k-nearest-neighbour and fixed-radius queries, for photons and for precomputed irradiance
//! points alike (anything [`Positioned`]).
//!
//! `point_grid` holds the grid and its construction (with `cell_sort`), `traverse` the walk
//! over the cells a search sphere cuts, `knn` and `range` the two kinds of query on top of it.

mod cell_sort;
mod knn;
mod point_grid;
mod range;
#[cfg(test)]
mod tests;
mod traverse;

pub use knn::KnnBuffer;
pub use point_grid::{suggest_cell_size, PointGrid, Positioned};
