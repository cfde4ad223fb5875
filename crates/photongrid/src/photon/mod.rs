//! Photons: compact records and the tracer that shoots them from the lights (the index the
//! render pass searches them with is [`crate::spatial`]).

pub mod caustic;
pub mod store;
pub mod trace;

pub use store::{Photon, PhotonKind};
pub use trace::{trace_photons, PhotonStats, Sequences, TraceSettings};
