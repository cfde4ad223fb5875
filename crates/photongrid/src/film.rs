//! The image being rendered: colour plus optional AOV layers.

use crate::Rgb;
use glam::Vec3;

/// Per-pixel auxiliary values, recorded at the first hit.
#[derive(Clone, Copy, Debug, Default)]
pub struct Aov {
    /// Diffuse albedo of the first diffuse surface.
    pub albedo: Rgb,
    /// Shading normal at the first hit (facing the camera).
    pub normal: Vec3,
    /// Depth of the first hit along the camera's viewing axis, as Blender's Z pass (distance
    /// along the ray times its cosine to the axis); 0 for none.
    pub depth: f32,
    /// Photon density at the first diffuse hit [photons/m²].
    pub density: f32,
    /// Radius used by the photon estimate at the first diffuse hit [m]: of the disc with the
    /// kernel's area on the surface where the estimate knows it (plane edges, off-plane edges).
    pub radius: f32,
}

/// A rendered image with AOVs, row-major, top row first.
#[derive(Clone, Debug)]
pub struct Film {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Radiance per pixel.
    pub color: Vec<Rgb>,
    /// AOVs per pixel.
    pub aov: Vec<Aov>,
}

impl Film {
    /// A black film.
    pub fn new(width: u32, height: u32) -> Self {
        let n = (width as usize) * (height as usize);
        Film {
            width,
            height,
            color: vec![Rgb::ZERO; n],
            aov: vec![Aov::default(); n],
        }
    }

    /// Mean of the colour channels over all pixels, summed in f64 (no overflow to infinity for
    /// very bright images). A non-finite value counts as 0, as the image writers write it
    /// ([`crate::output::encode_exr`]), so the mean is always a finite number.
    pub fn mean(&self) -> [f64; 3] {
        let mut s = [0.0f64; 3];
        for c in &self.color {
            for (a, v) in s.iter_mut().zip(c.to_array()) {
                if v.is_finite() {
                    *a += v as f64;
                }
            }
        }
        s.map(|v| v / self.color.len().max(1) as f64)
    }

    /// Pixels with NaN or infinity.
    pub fn nonfinite(&self) -> usize {
        self.color.iter().filter(|c| !c.is_finite()).count()
    }
}
