//! Photons: compact records, the tracer that shoots them from the lights, and the spatial
//! index the render pass searches.

pub mod caustic;
pub mod neighbours;
pub mod store;
pub mod trace;

pub use store::{Photon, PhotonKind};
pub use trace::{trace_photons, PhotonStats, TraceSettings};
