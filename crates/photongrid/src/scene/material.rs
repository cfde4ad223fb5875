//! The closed set of surface models a glTF material maps onto.

use crate::Rgb;
use glam::Vec2;

/// How a surface scatters light. Each glTF material maps to the smallest model that renders it
/// right; what does not fit is approximated and reported by the loader.
#[derive(Clone, Debug, PartialEq)]
pub enum Surface {
    /// Ideal diffuse reflector, BRDF `albedo / π`.
    Lambert {
        /// Reflectance (baseColorFactor).
        albedo: Rgb,
        /// Index into [`crate::scene::Scene::textures`] multiplying `albedo`.
        texture: Option<u32>,
    },
    /// Perfect mirror with Schlick Fresnel, `F0 = baseColor` (metallic materials).
    Mirror {
        /// Reflectance at normal incidence.
        f0: Rgb,
    },
    /// Smooth dielectric (glass): Fresnel reflection and refraction.
    Dielectric {
        /// Index of refraction inside (outside is 1).
        ior: f32,
        /// Colour of transmitted light (baseColor × transmission colour).
        tint: Rgb,
        /// Absorption coefficient σₐ [1/m] inside (Beer–Lambert), from KHR_materials_volume.
        absorption: Option<Rgb>,
    },
}

/// A material: a surface model plus emission.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name from the file (or `materials[i]`).
    pub name: String,
    /// Scattering model.
    pub surface: Surface,
    /// Emitted radiance [W/(m²·sr)] (zero for non-emitters).
    pub emission: Rgb,
    /// Whether both faces emit (glTF doubleSided; Cycles emits from both).
    pub double_sided: bool,
}

impl Material {
    /// True if the material emits light.
    pub fn is_emissive(&self) -> bool {
        self.emission.max_element() > 0.0
    }

    /// True for mirror and glass: surfaces that photons and camera rays pass through specularly.
    pub fn is_specular(&self) -> bool {
        !matches!(self.surface, Surface::Lambert { .. })
    }

    /// The default material for primitives without one (glTF: white, metallic 1 roughness 1 →
    /// rendered as a white Lambert since a rough metal is closer to diffuse than to a mirror).
    pub fn default_gltf() -> Self {
        Material {
            name: "default".into(),
            surface: Surface::Lambert {
                albedo: Rgb::ONE,
                texture: None,
            },
            emission: Rgb::ZERO,
            double_sided: false,
        }
    }
}

/// A linear-RGB texture sampled bilinearly with repeat wrapping.
#[derive(Clone, Debug)]
pub struct Texture {
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// Linear RGB texels, row-major, top row first (glTF UV origin is the top-left).
    pub texels: Vec<Rgb>,
}

impl Texture {
    /// Bilinear lookup at `uv` (repeat wrap).
    pub fn sample(&self, uv: Vec2) -> Rgb {
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let w = self.width as i64;
        let h = self.height as i64;
        let at = |i: i64, j: i64| self.texels[(j.rem_euclid(h) * w + i.rem_euclid(w)) as usize];
        let (i, j) = (x0 as i64, y0 as i64);
        let top = at(i, j) * (1.0 - fx) + at(i + 1, j) * fx;
        let bottom = at(i, j + 1) * (1.0 - fx) + at(i + 1, j + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// sRGB-encoded 8-bit value → linear (glTF baseColor textures are sRGB).
pub fn srgb_to_linear(v: u8) -> f32 {
    let c = v as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_bilinear_and_wrap() {
        let t = Texture {
            width: 2,
            height: 1,
            texels: vec![Rgb::ZERO, Rgb::ONE],
        };
        assert!((t.sample(Vec2::new(0.25, 0.5)) - Rgb::ZERO).length() < 1e-6);
        assert!((t.sample(Vec2::new(0.75, 0.5)) - Rgb::ONE).length() < 1e-6);
        assert!((t.sample(Vec2::new(0.5, 0.5)) - Rgb::splat(0.5)).length() < 1e-6);
        // x = 0 lies halfway between the last and the first texel when wrapping.
        assert!((t.sample(Vec2::new(0.0, 0.5)) - Rgb::splat(0.5)).length() < 1e-6);
    }

    #[test]
    fn srgb_decode() {
        assert_eq!(srgb_to_linear(0), 0.0);
        assert!((srgb_to_linear(255) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(188) - 0.5029).abs() < 1e-3);
    }
}
