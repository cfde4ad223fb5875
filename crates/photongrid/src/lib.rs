//! photongrid: photon mapping for Blender-exported glTF, with the grid-adaptive radius of
//! Watanabe, Fujishiro and Ohno ("Adaptive Photon Mapping with Reference to Grid Structures").
//!
//! The modules follow the data: [`scene`] (glTF → triangles, materials, lights, cameras) →
//! [`accel`] (BVH) → [`photon`] (tracing, storage) → [`estimate`] (radiance from photons,
//! found with the [`spatial`] index) → [`render`] (camera pass) → [`film`] → [`output`]
//! (EXR/PNG). [`pipeline`] runs them in order; [`settings`] is the one set of options every
//! front end shares.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod accel;
pub mod bsdf;
pub mod estimate;
pub mod film;
pub mod grid;
pub mod memory;
pub mod output;
pub mod photon;
pub mod pipeline;
pub mod progress;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod settings;
pub mod spatial;
pub mod surface;
#[cfg(test)]
pub(crate) mod test_util;

/// Linear RGB in Rec.709 primaries (radiance, flux or reflectance depending on context).
pub type Rgb = glam::Vec3;

/// Luminance of a linear Rec. 709 colour.
pub fn luminance(c: Rgb) -> f32 {
    c.dot(Rgb::new(0.2126, 0.7152, 0.0722))
}

pub use pipeline::{prepare, render_camera, PhaseTimes, Prepared, RenderError};
pub use scene::gltf::{load, LoadError};
pub use settings::Settings;
