//! The closed set of surface models a glTF material maps onto.

use crate::Rgb;
use glam::{Vec2, Vec4};

/// How a surface scatters light. Each glTF material maps to the smallest model that renders it
/// right; what does not fit is approximated and reported by the loader.
#[derive(Clone, Debug, PartialEq)]
pub enum Surface {
    /// Ideal diffuse reflector, BRDF `albedo / π` (glTF: metallic 0, no transmission,
    /// specularFactor 0).
    Lambert {
        /// Reflectance (baseColorFactor).
        albedo: Rgb,
        /// The base-colour texture multiplying `albedo`.
        texture: Option<TextureRef>,
    },
    /// Perfect mirror with Schlick Fresnel, `F0 = baseColor` (metallic 1, roughness 0).
    Mirror {
        /// Reflectance at normal incidence.
        f0: Rgb,
    },
    /// Smooth dielectric (glass): Fresnel reflection and refraction (transmission 1,
    /// roughness 0).
    Dielectric {
        /// Index of refraction inside (outside is 1).
        ior: f32,
        /// Colour of transmitted light (baseColor × transmission colour).
        tint: Rgb,
        /// Absorption coefficient σₐ [1/m] inside (Beer–Lambert), from KHR_materials_volume.
        absorption: Option<Rgb>,
    },
    /// The glTF 2.0 metallic-roughness BSDF with its textures (everything else):
    /// [`crate::bsdf::metallic_roughness`].
    Gltf(Box<MetallicRoughness>),
}

/// The factors and textures of a glTF metallic-roughness material (core spec plus
/// KHR_materials_specular, _ior, _transmission and _volume).
#[derive(Clone, Debug, PartialEq)]
pub struct MetallicRoughness {
    /// baseColorFactor (RGB).
    pub base_color: Rgb,
    /// baseColorTexture (sRGB).
    pub base_color_texture: Option<TextureRef>,
    /// metallicFactor.
    pub metallic: f32,
    /// roughnessFactor (perceptual: α = roughness²).
    pub roughness: f32,
    /// metallicRoughnessTexture (linear; B: metalness, G: roughness).
    pub metallic_roughness_texture: Option<TextureRef>,
    /// KHR_materials_specular specularFactor (1 without the extension).
    pub specular: f32,
    /// specularTexture (its alpha channel scales `specular`).
    pub specular_texture: Option<TextureRef>,
    /// specularColorFactor.
    pub specular_color: Rgb,
    /// specularColorTexture (sRGB).
    pub specular_color_texture: Option<TextureRef>,
    /// KHR_materials_ior (1.5 without it).
    pub ior: f32,
    /// KHR_materials_transmission transmissionFactor.
    pub transmission: f32,
    /// transmissionTexture (R channel, linear).
    pub transmission_texture: Option<TextureRef>,
    /// Absorption coefficient σₐ [1/m] inside, from KHR_materials_volume.
    pub absorption: Option<Rgb>,
}

/// A tangent-space normal map (glTF `normalTexture`).
#[derive(Clone, Debug, PartialEq)]
pub struct NormalMap {
    /// The texture (linear).
    pub texture: TextureRef,
    /// `normalTexture.scale`: scales the X and Y of the sampled normal.
    pub scale: f32,
}

/// How a material's alpha (baseColorFactor.a × baseColorTexture.a) is used.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha ignored.
    #[default]
    Opaque,
    /// Cut-out: the surface exists where alpha ≥ cutoff (camera, shadow rays and photons).
    Mask {
        /// alphaCutoff (0.5 by default).
        cutoff: f32,
    },
    /// Fractional coverage: rays pass with probability 1 − alpha; shadow rays are attenuated
    /// by 1 − alpha (Cycles' transparent shadows).
    Blend,
}

/// A material: a surface model plus emission, normal map and alpha.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name from the file (or `materials[i]`).
    pub name: String,
    /// Scattering model.
    pub surface: Surface,
    /// Emitted radiance [W/(m²·sr)] (zero for non-emitters).
    pub emission: Rgb,
    /// Emissive texture (sRGB) multiplying `emission`.
    pub emission_texture: Option<TextureRef>,
    /// Whether both faces emit (glTF doubleSided; Cycles emits from both).
    pub double_sided: bool,
    /// Tangent-space normal map.
    pub normal_map: Option<NormalMap>,
    /// How alpha is used.
    pub alpha_mode: AlphaMode,
    /// baseColorFactor.a.
    pub alpha: f32,
    /// The texture whose alpha channel multiplies `alpha` (the base-colour texture).
    pub alpha_texture: Option<TextureRef>,
}

impl Material {
    /// True if the material emits light.
    pub fn is_emissive(&self) -> bool {
        self.emission.max_element() > 0.0
    }

    /// True for mirror, glass and transmissive glTF materials: surfaces that redirect light
    /// into sharp caustics (the caustic pass aims at them). Light that a glTF reflection lobe
    /// redirects is blurred by its roughness, and the global pass's photons carry it (aiming a
    /// caustic pass at rough metal and plastic would cost as much again for little).
    pub fn is_specular(&self) -> bool {
        match &self.surface {
            Surface::Lambert { .. } => false,
            Surface::Mirror { .. } | Surface::Dielectric { .. } => true,
            Surface::Gltf(m) => m.transmission > 0.0 || m.transmission_texture.is_some(),
        }
    }

    /// True for glass and transmissive glTF materials: surfaces light passes through.
    pub fn transmits(&self) -> bool {
        match &self.surface {
            Surface::Lambert { .. } | Surface::Mirror { .. } => false,
            Surface::Dielectric { .. } => true,
            Surface::Gltf(m) => m.transmission > 0.0 || m.transmission_texture.is_some(),
        }
    }

    /// True if photons may be stored on the surface (Lambert, and glTF materials: their
    /// diffuse base and wide lobes are rendered from photons).
    pub fn receives_photons(&self) -> bool {
        match &self.surface {
            Surface::Lambert { .. } => true,
            Surface::Mirror { .. } | Surface::Dielectric { .. } => false,
            Surface::Gltf(m) => m.transmission < 1.0 || m.transmission_texture.is_some(),
        }
    }

    /// True if alpha can make the surface (partly) transparent.
    pub fn has_alpha(&self) -> bool {
        self.alpha_mode != AlphaMode::Opaque
    }

    /// The default material for primitives without one (glTF: white, metallic 1 roughness 1
    /// → rendered as a white Lambert since a rough metal is closer to diffuse than to a mirror).
    pub fn default_gltf() -> Self {
        Material {
            name: "default".into(),
            surface: Surface::Lambert {
                albedo: Rgb::ONE,
                texture: None,
            },
            ..Material::plain()
        }
    }

    /// A black, opaque, non-emitting Lambert material with no textures (for building others).
    pub fn plain() -> Self {
        Material {
            name: String::new(),
            surface: Surface::Lambert {
                albedo: Rgb::ZERO,
                texture: None,
            },
            emission: Rgb::ZERO,
            emission_texture: None,
            double_sided: false,
            normal_map: None,
            alpha_mode: AlphaMode::Opaque,
            alpha: 1.0,
            alpha_texture: None,
        }
    }

    /// Alpha at texture coordinates `uv`.
    pub fn alpha_at(&self, textures: &[Texture], uv: Vec2) -> f32 {
        match &self.alpha_texture {
            Some(t) => self.alpha * t.sample(textures, uv).w,
            None => self.alpha,
        }
    }

    /// Emitted radiance at `uv`.
    pub fn emission_at(&self, textures: &[Texture], uv: Vec2) -> Rgb {
        match &self.emission_texture {
            Some(t) => self.emission * t.sample(textures, uv).truncate(),
            None => self.emission,
        }
    }
}

/// How texture coordinates outside [0, 1] wrap (glTF sampler `wrapS`/`wrapT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Wrap {
    /// REPEAT (10497), the default.
    #[default]
    Repeat,
    /// CLAMP_TO_EDGE (33071).
    Clamp,
    /// MIRRORED_REPEAT (33648).
    Mirror,
}

impl Wrap {
    /// The texel index `i` of a row of `n` texels, wrapped.
    fn index(self, i: i64, n: i64) -> usize {
        (match self {
            Wrap::Repeat => i.rem_euclid(n),
            Wrap::Clamp => i.clamp(0, n - 1),
            Wrap::Mirror => {
                let k = i.rem_euclid(2 * n);
                if k < n {
                    k
                } else {
                    2 * n - 1 - k
                }
            }
        }) as usize
    }
}

/// A texture as a material uses it: which image, how it wraps, and the
/// `KHR_texture_transform` of its texture coordinates.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into [`crate::scene::Scene::textures`].
    pub texture: u32,
    /// Wrap along u and v.
    pub wrap: [Wrap; 2],
    /// `uv' = M · (u, v, 1)` with the 2×3 matrix `[[a, b, c], [d, e, f]]` of
    /// KHR_texture_transform (translation · rotation · scale); None: identity.
    pub transform: Option<[[f32; 3]; 2]>,
}

impl TextureRef {
    /// A plain reference: repeat, no transform.
    pub fn plain(texture: u32) -> Self {
        TextureRef {
            texture,
            wrap: [Wrap::Repeat; 2],
            transform: None,
        }
    }

    /// The texture coordinates after the transform.
    pub fn uv(&self, uv: Vec2) -> Vec2 {
        match &self.transform {
            None => uv,
            Some(m) => Vec2::new(
                m[0][0] * uv.x + m[0][1] * uv.y + m[0][2],
                m[1][0] * uv.x + m[1][1] * uv.y + m[1][2],
            ),
        }
    }

    /// Linear RGBA at `uv` (bilinear).
    pub fn sample(&self, textures: &[Texture], uv: Vec2) -> Vec4 {
        textures[self.texture as usize].sample_wrapped(self.uv(uv), self.wrap)
    }
}

/// An 8-bit RGBA image sampled bilinearly; colour textures are sRGB-encoded (decoded per
/// texel before filtering, as the glTF spec asks), data textures (metallic-roughness,
/// normal, transmission) linear. Alpha is always linear.
#[derive(Clone, Debug)]
pub struct Texture {
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// RGBA texels, row-major, top row first (glTF UV origin is the top-left).
    pub texels: Vec<[u8; 4]>,
    /// RGB is sRGB-encoded.
    pub srgb: bool,
}

impl Texture {
    /// A texture from linear-RGB values (tests and generated textures), stored sRGB.
    pub fn from_linear(width: usize, height: usize, rgb: &[Rgb]) -> Self {
        let enc = |v: f32| (linear_to_srgb(v.clamp(0.0, 1.0)) * 255.0).round() as u8;
        Texture {
            width,
            height,
            texels: rgb.iter().map(|c| [enc(c.x), enc(c.y), enc(c.z), 255]).collect(),
            srgb: true,
        }
    }

    fn texel(&self, i: usize, j: usize) -> Vec4 {
        let t = self.texels[j * self.width + i];
        let a = t[3] as f32 / 255.0;
        if self.srgb {
            Vec4::new(
                SRGB_LUT[t[0] as usize],
                SRGB_LUT[t[1] as usize],
                SRGB_LUT[t[2] as usize],
                a,
            )
        } else {
            Vec4::new(t[0] as f32 / 255.0, t[1] as f32 / 255.0, t[2] as f32 / 255.0, a)
        }
    }

    /// Bilinear lookup at `uv` with the given wrap modes (texel centres at half-integers).
    pub fn sample_wrapped(&self, uv: Vec2, wrap: [Wrap; 2]) -> Vec4 {
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        if !(x.is_finite() && y.is_finite()) {
            return self.texel(0, 0);
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (w, h) = (self.width as i64, self.height as i64);
        let (i, j) = (x0 as i64, y0 as i64);
        let (i0, i1) = (wrap[0].index(i, w), wrap[0].index(i + 1, w));
        let (j0, j1) = (wrap[1].index(j, h), wrap[1].index(j + 1, h));
        let top = self.texel(i0, j0) * (1.0 - fx) + self.texel(i1, j0) * fx;
        let bottom = self.texel(i0, j1) * (1.0 - fx) + self.texel(i1, j1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Bilinear linear-RGB lookup at `uv` (repeat wrap).
    pub fn sample(&self, uv: Vec2) -> Rgb {
        self.sample_wrapped(uv, [Wrap::Repeat; 2]).truncate()
    }
}

/// sRGB decoding of every 8-bit value.
static SRGB_LUT: std::sync::LazyLock<[f32; 256]> =
    std::sync::LazyLock::new(|| std::array::from_fn(|v| srgb_to_linear(v as u8)));

/// Linear → sRGB-encoded value in [0, 1].
pub fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.0031308 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
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
        let t = Texture::from_linear(2, 1, &[Rgb::ZERO, Rgb::ONE]);
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
