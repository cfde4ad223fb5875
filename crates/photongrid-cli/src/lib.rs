//! The `photongrid` command line's parts, as a library so tests can reach them: batch jobs,
//! the error-against-time bench, image metrics, progress display, output paths and scene
//! descriptions, and the throughput measurement. The renderer itself is the `photongrid` crate; everything here is a
//! client of it.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod batch;
pub mod bench;
pub mod info;
pub mod metrics;
pub mod paths;
pub mod progress;
pub mod stdout;
pub mod throughput;
