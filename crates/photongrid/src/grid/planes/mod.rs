//! Plane detection and per-plane photon-count grids.

mod detection;

pub use detection::*;
