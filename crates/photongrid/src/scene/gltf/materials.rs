//! glTF materials → [`Material`]: Lambert, mirror or glass, with emission and the base-colour
//! texture; everything else is approximated or ignored, and said so in the report.

use super::{LoadError, Loader};
use crate::scene::material::srgb_to_linear;
use crate::scene::{units, Material, Surface, Texture};
use crate::Rgb;
use std::collections::HashMap;

/// Textures decoded so far, by image index (an image used by several materials is decoded once).
#[derive(Default)]
pub(super) struct Textures {
    pub(super) list: Vec<Texture>,
    of_image: HashMap<usize, u32>,
}

impl Loader<'_> {
    /// All materials of the file, in order, and the textures they use.
    pub(super) fn materials(
        &mut self,
        doc: &gltf::Document,
        buffers: &[gltf::buffer::Data],
    ) -> Result<(Vec<Material>, Vec<Texture>), LoadError> {
        let mut textures = Textures::default();
        let mut materials = Vec::new();
        for m in doc.materials() {
            let mat = self.material(&m, buffers, &mut textures)?;
            self.report.materials.push(format!(
                "materials[{}] '{}': {}",
                m.index().unwrap_or(0),
                mat.name,
                describe_material(&mat)
            ));
            materials.push(mat);
        }
        Ok((materials, textures.list))
    }

    fn approximated(&mut self, element: &str, name: &str, what: impl std::fmt::Display) {
        self.report.approximated.push(format!("{element} '{name}': {what}"));
    }

    fn material(
        &mut self,
        m: &gltf::Material,
        buffers: &[gltf::buffer::Data],
        textures: &mut Textures,
    ) -> Result<Material, LoadError> {
        let index = m.index().unwrap_or(0);
        let element = format!("materials[{index}]");
        let name = m.name().map(str::to_string).unwrap_or_else(|| element.clone());
        let pbr = m.pbr_metallic_roughness();
        let base = pbr.base_color_factor();
        let base_rgb = Rgb::new(base[0], base[1], base[2]);
        if !base_rgb.is_finite() || base_rgb.min_element() < 0.0 {
            return Err(self.invalid(&element, "baseColorFactor must be finite and non-negative"));
        }
        let emission = units::emission_radiance(m.emissive_factor(), m.emissive_strength());
        if !emission.is_finite() || emission.min_element() < 0.0 {
            return Err(self.invalid(&element, "emissive factor × strength must be finite and non-negative"));
        }
        if m.emissive_texture().is_some() {
            self.approximated(&element, &name, "emissive texture ignored (emissiveFactor used)");
        }
        if pbr.metallic_roughness_texture().is_some() {
            self.approximated(&element, &name, "metallic-roughness texture ignored (factors used)");
        }
        if m.alpha_mode() != gltf::material::AlphaMode::Opaque {
            self.approximated(&element, &name, "alpha mode ignored: rendered opaque");
        }
        let surface = self.surface(m, base_rgb, &element, &name, buffers, textures)?;
        if let Surface::Lambert { albedo, .. } = &surface {
            if albedo.max_element() > 1.0 {
                self.approximated(&element, &name, "albedo > 1 reflects more than it receives");
            }
        }
        Ok(Material {
            name,
            surface,
            emission,
            double_sided: m.double_sided(),
        })
    }

    /// Glass if transmissive, a mirror if metallic, Lambert otherwise.
    fn surface(
        &mut self,
        m: &gltf::Material,
        base_rgb: Rgb,
        element: &str,
        name: &str,
        buffers: &[gltf::buffer::Data],
        textures: &mut Textures,
    ) -> Result<Surface, LoadError> {
        let pbr = m.pbr_metallic_roughness();
        let metallic = pbr.metallic_factor();
        let roughness = pbr.roughness_factor();
        let transmission = m.transmission().map(|t| t.transmission_factor()).unwrap_or(0.0);
        if transmission > 0.0 {
            if transmission < 0.5 {
                let what = format!("transmission {transmission} < 0.5 rendered as Lambert");
                self.approximated(element, name, what);
                return Ok(Surface::Lambert {
                    albedo: base_rgb,
                    texture: None,
                });
            }
            return self.glass(m, base_rgb, transmission, roughness, element, name);
        }
        if metallic >= 0.5 {
            if metallic < 1.0 {
                self.approximated(element, name, format!("metallic {metallic} rendered as a full mirror"));
            }
            if roughness > 0.0 {
                let what = format!("roughness {roughness} on metal rendered as a perfect mirror");
                self.approximated(element, name, what);
            }
            return Ok(Surface::Mirror { f0: base_rgb });
        }
        if metallic > 0.0 {
            self.approximated(element, name, format!("metallic {metallic} < 0.5 rendered as Lambert"));
        }
        if let Some(s) = m.specular() {
            if s.specular_factor() > 0.0 && roughness < 1.0 {
                self.approximated(element, name, "specular layer ignored (pure Lambert)");
            }
        } else if roughness < 1.0 {
            self.approximated(element, name, "default specular layer ignored (pure Lambert)");
        }
        let texture = match pbr.base_color_texture() {
            Some(info) => Some(self.base_color_texture(&info, element, name, buffers, textures)?),
            None => None,
        };
        Ok(Surface::Lambert {
            albedo: base_rgb,
            texture,
        })
    }

    fn glass(
        &mut self,
        m: &gltf::Material,
        base_rgb: Rgb,
        transmission: f32,
        roughness: f32,
        element: &str,
        name: &str,
    ) -> Result<Surface, LoadError> {
        if transmission < 1.0 {
            let what = format!("transmission {transmission} rendered as fully transmissive");
            self.approximated(element, name, what);
        }
        if roughness > 0.0 {
            self.approximated(
                element,
                name,
                format!("roughness {roughness} on glass rendered as smooth glass"),
            );
        }
        let ior = m.ior().unwrap_or(1.5);
        if !(ior.is_finite() && ior >= 1.0) {
            return Err(self.invalid(element, format!("KHR_materials_ior: ior {ior} must be ≥ 1")));
        }
        let absorption = m.volume().and_then(|v| {
            let d = v.attenuation_distance();
            let c = Rgb::from(v.attenuation_color());
            (d.is_finite() && d > 0.0).then(|| -c.max(Rgb::splat(1e-6)).min(Rgb::ONE).map(f32::ln) / d)
        });
        Ok(Surface::Dielectric {
            ior,
            tint: base_rgb,
            absorption,
        })
    }

    /// The texture of a base-colour texture reference, decoded on first use.
    fn base_color_texture(
        &mut self,
        info: &gltf::texture::Info,
        element: &str,
        name: &str,
        buffers: &[gltf::buffer::Data],
        textures: &mut Textures,
    ) -> Result<u32, LoadError> {
        if info.tex_coord() != 0 {
            self.approximated(
                element,
                name,
                "base colour texture uses TEXCOORD_1+: read with TEXCOORD_0",
            );
        }
        if info.texture_transform().is_some() {
            self.approximated(element, name, "KHR_texture_transform ignored");
        }
        let image = info.texture().source();
        let key = image.index();
        if let Some(&t) = textures.of_image.get(&key) {
            return Ok(t);
        }
        let data = gltf::image::Data::from_source(image.source(), Some(&self.base), buffers)
            .map_err(|e| self.invalid(format!("images[{key}]"), format!("cannot decode: {e}")))?;
        let tex = texture_from_image(&data).ok_or_else(|| {
            self.invalid(
                format!("images[{key}]"),
                format!("unsupported pixel format {:?}", data.format),
            )
        })?;
        textures.list.push(tex);
        let t = (textures.list.len() - 1) as u32;
        textures.of_image.insert(key, t);
        Ok(t)
    }
}

fn describe_material(m: &Material) -> String {
    let s = match &m.surface {
        Surface::Lambert { albedo, texture } => {
            format!(
                "Lambert albedo {:.3?}{}",
                albedo.to_array(),
                if texture.is_some() { " × texture" } else { "" }
            )
        }
        Surface::Mirror { f0 } => format!("mirror (Schlick, F0 {:.3?})", f0.to_array()),
        Surface::Dielectric { ior, tint, absorption } => format!(
            "glass IOR {ior}, tint {:.3?}{}",
            tint.to_array(),
            absorption
                .map(|a| format!(", absorption {:.3?}/m", a.to_array()))
                .unwrap_or_default()
        ),
    };
    if m.is_emissive() {
        format!(
            "{s}, emits {:.3?} W/(m²·sr){}",
            m.emission.to_array(),
            if m.double_sided { " (both faces)" } else { "" }
        )
    } else {
        s
    }
}

fn texture_from_image(d: &gltf::image::Data) -> Option<Texture> {
    use gltf::image::Format;
    let channels = match d.format {
        Format::R8 => 1,
        Format::R8G8 => 2,
        Format::R8G8B8 => 3,
        Format::R8G8B8A8 => 4,
        _ => return None,
    };
    let (w, h) = (d.width as usize, d.height as usize);
    if w == 0 || h == 0 || d.pixels.len() < w * h * channels {
        return None;
    }
    let texels = d
        .pixels
        .chunks_exact(channels)
        .take(w * h)
        .map(|c| match channels {
            1 | 2 => Rgb::splat(srgb_to_linear(c[0])),
            _ => Rgb::new(srgb_to_linear(c[0]), srgb_to_linear(c[1]), srgb_to_linear(c[2])),
        })
        .collect();
    Some(Texture {
        width: w,
        height: h,
        texels,
    })
}
