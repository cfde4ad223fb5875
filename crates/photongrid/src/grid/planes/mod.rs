//! Plane detection and per-plane photon-count grids.
//!
//! Following Watanabe et al., *Adaptive Photon Mapping with Reference to Grid
//! Structures*, every plane of the scene carries a grid of cells that counts the
//! photons landing in each cell. A Blender glTF export is only a triangle soup,
//! so the planes have to be *found*: `detection` groups connected, coplanar
//! triangles (with `weld` joining duplicated vertices) and rejects facets of
//! curved meshes; `hull` fits each plane's tight rectangle; `geometry` maps
//! world points to grid coordinates, cells and bilinear interpolation weights.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod detection;
mod geometry;
mod hull;
#[cfg(test)]
mod tests;
mod weld;

pub use detection::{detect_planes, PlaneParams, SMOOTH_BOUNDARY_FRACTION, SMOOTH_RADIUS_RATIO};
pub use geometry::{bilinear_axis, Plane, PlaneSet, CELL_OF_ROUNDING_SLACK, NO_PLANE, RECT_MARGIN_REL};
