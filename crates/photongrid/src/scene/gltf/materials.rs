//! glTF materials → [`Material`]: Lambert, mirror or glass, with emission and the base-colour
//! texture; everything else is approximated or ignored, and said so in the report.

use super::budget::{human, Budget, BYTES_PER_TEXEL};
use super::uris::Source;
use super::{Inputs, LoadError, Loader};
use crate::scene::material::srgb_to_linear;
use crate::scene::{units, Material, Surface, Texture};
use crate::Rgb;
use image::{DynamicImage, ImageDecoder, ImageFormat};
use std::collections::HashMap;
use std::path::PathBuf;

/// Emitted radiance above which a material is refused, W/(m²·sr): 10⁷ times the sun's disc;
/// beyond it, sums of radiance and power in 32 bits come near overflow (f32 max 3.4e38).
pub(super) const MAX_RADIANCE: f32 = 1e15;

/// What identifies the bytes of an image: the file it is read from, else its index.
#[derive(Clone, Debug, Hash, PartialEq, Eq)]
enum ImageKey {
    File(PathBuf),
    Image(usize),
}

/// Textures decoded so far: one per distinct image source, so an image used by several
/// materials (or several images naming one file) is decoded once.
#[derive(Default)]
pub(super) struct Textures {
    pub(super) list: Vec<Texture>,
    by_key: HashMap<ImageKey, u32>,
}

fn image_key(sources: &super::uris::Sources, i: usize) -> ImageKey {
    match &sources.images[i] {
        Source::File { path, .. } => ImageKey::File(path.clone()),
        _ => ImageKey::Image(i),
    }
}

/// True if the material becomes a Lambert surface with a base-colour texture (the only
/// texture that is decoded).
fn decodes_base_texture(m: &gltf::Material) -> bool {
    let transmission = m.transmission().map(|t| t.transmission_factor()).unwrap_or(0.0);
    let metallic = m.pbr_metallic_roughness().metallic_factor();
    !(transmission > 0.0) && !(metallic >= 0.5) && m.pbr_metallic_roughness().base_color_texture().is_some()
}

impl Loader<'_> {
    /// All materials of the file, in order, and the textures they use.
    pub(super) fn materials(&mut self, inputs: &Inputs) -> Result<(Vec<Material>, Vec<Texture>), LoadError> {
        let mut textures = Textures::default();
        let mut materials = Vec::new();
        for m in inputs.doc.materials() {
            let mat = self.material(&m, inputs, &mut textures)?;
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
        inputs: &Inputs,
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
        if emission.max_element() > MAX_RADIANCE {
            return Err(self.invalid(
                &element,
                format!(
                    "emissive factor × strength is {:e} W/(m²·sr), more than the {MAX_RADIANCE:e} the renderer's 32-bit sums can carry; lower the emission strength",
                    emission.max_element()
                ),
            ));
        }
        self.report_unused_textures(m, &element, &name);
        if m.emissive_texture().is_some() {
            self.approximated(&element, &name, "emissive texture ignored (emissiveFactor used)");
        }
        if pbr.metallic_roughness_texture().is_some() {
            self.approximated(&element, &name, "metallic-roughness texture ignored (factors used)");
        }
        if m.alpha_mode() != gltf::material::AlphaMode::Opaque {
            self.approximated(&element, &name, "alpha mode ignored: rendered opaque");
        }
        let surface = self.surface(m, base_rgb, &element, &name, inputs, textures)?;
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
        inputs: &Inputs,
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
            Some(info) => Some(self.base_color_texture(&info, element, name, inputs, textures)?),
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
        inputs: &Inputs,
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
        let texture = info.texture();
        let wrap = (texture.sampler().wrap_s(), texture.sampler().wrap_t());
        if wrap != (gltf::texture::WrappingMode::Repeat, gltf::texture::WrappingMode::Repeat) {
            let what = format!("texture wrap mode {wrap:?} rendered as Repeat");
            self.approximated(element, name, what);
        }
        let i = texture.source().index();
        let key = image_key(inputs.sources, i);
        if let Some(&t) = textures.by_key.get(&key) {
            return Ok(t);
        }
        let tex = self.decode_image(inputs, i)?;
        textures.list.push(tex);
        let t = (textures.list.len() - 1) as u32;
        textures.by_key.insert(key, t);
        Ok(t)
    }

    /// Materials' textures that are not rendered, for the report.
    fn report_unused_textures(&mut self, m: &gltf::Material, element: &str, name: &str) {
        if m.normal_texture().is_some() {
            let what = format!("{element} '{name}': normal texture ignored (the mesh's normals are used)");
            self.report.ignored.push(what);
        }
        if m.occlusion_texture().is_some() {
            let what = format!("{element} '{name}': occlusion texture ignored (light transport gives occlusion)");
            self.report.ignored.push(what);
        }
    }

    /// Read the header of every image a material will decode and add the decoded textures to
    /// the budget, before any is decoded.
    pub(super) fn estimate_textures(&self, inputs: &Inputs, budget: &mut Budget) -> Result<(), LoadError> {
        let mut keys = std::collections::HashSet::new();
        let mut seen = Vec::new();
        for m in inputs.doc.materials().filter(decodes_base_texture) {
            let Some(info) = m.pbr_metallic_roughness().base_color_texture() else {
                continue;
            };
            let i = info.texture().source().index();
            if keys.insert(image_key(inputs.sources, i)) {
                let bytes = self.image_bytes(inputs.root(), inputs.sources, inputs.buffers, i, budget.left())?;
                let format = self.image_format(inputs, i, &bytes)?;
                let (w, h, pixel) = probe(&bytes, format).map_err(|e| self.cannot_decode(i, e))?;
                seen.push((i, w, h, pixel, bytes.len() as u64));
            }
        }
        let mut texels = 0u64;
        let mut decoding = 0u64;
        for &(i, w, h, pixel, encoded) in &seen {
            let n = w as u64 * h as u64;
            texels = texels.saturating_add(n.saturating_mul(BYTES_PER_TEXEL));
            decoding = decoding.max(n.saturating_mul(pixel).saturating_add(encoded));
            if n.saturating_mul(BYTES_PER_TEXEL) > budget.limit() {
                let what = format!(
                    "is {w}×{h}: its {} decoded alone exceed the memory budget of {}; use a smaller texture",
                    human(n * BYTES_PER_TEXEL),
                    human(budget.limit())
                );
                return Err(self.invalid(format!("images[{i}]"), what));
            }
        }
        budget.add(format!("{} decoded textures", seen.len()), texels);
        budget.add("decoding the largest texture", decoding);
        budget.check(self.path)
    }

    fn cannot_decode(&self, i: usize, e: image::ImageError) -> LoadError {
        let what = match e {
            image::ImageError::Limits(_) => {
                "cannot decode: the decoded image would exceed the decoder's limit of 512 MiB; use a smaller texture"
                    .into()
            }
            e => format!("cannot decode: {e}"),
        };
        self.invalid(format!("images[{i}]"), what)
    }

    /// PNG or JPEG: from the data: URI's media type, the mimeType, the file name's extension,
    /// or the first bytes.
    fn image_format(&self, inputs: &Inputs, i: usize, bytes: &[u8]) -> Result<ImageFormat, LoadError> {
        let image = &inputs.root().images[i];
        let declared = match &inputs.sources.images[i] {
            Source::Data { media_type, .. } => Some(*media_type),
            _ => image.mime_type.as_ref().map(|m| m.0.as_str()),
        };
        let by_extension = || match image.uri.as_deref().and_then(|u| u.rsplit('.').next()) {
            Some("png") => Some(ImageFormat::Png),
            Some("jpg") | Some("jpeg") => Some(ImageFormat::Jpeg),
            _ => None,
        };
        let format = match declared {
            Some("image/png") => Some(ImageFormat::Png),
            Some("image/jpeg") => Some(ImageFormat::Jpeg),
            _ => by_extension(),
        };
        let sniffed = || {
            image::guess_format(bytes)
                .ok()
                .filter(|f| matches!(f, ImageFormat::Png | ImageFormat::Jpeg))
        };
        format.or_else(sniffed).ok_or_else(|| {
            self.invalid(
                format!("images[{i}]"),
                "unsupported image encoding: only PNG and JPEG images are read",
            )
        })
    }

    /// Decode image `i` into a linear-RGB texture.
    fn decode_image(&self, inputs: &Inputs, i: usize) -> Result<Texture, LoadError> {
        let bytes = self.image_bytes(inputs.root(), inputs.sources, inputs.buffers, i, u64::MAX)?;
        let format = self.image_format(inputs, i, &bytes)?;
        let image = image::load_from_memory_with_format(&bytes, format).map_err(|e| self.cannot_decode(i, e))?;
        drop(bytes);
        texture_from_image(&image).ok_or_else(|| {
            let what = format!(
                "unsupported pixel format {:?} (8-bit grey, grey+alpha, RGB or RGBA are read)",
                image.color()
            );
            self.invalid(format!("images[{i}]"), what)
        })
    }
}

/// Width, height and bytes per pixel of an encoded image, from its header.
fn probe(bytes: &[u8], format: ImageFormat) -> image::ImageResult<(u32, u32, u64)> {
    let decoder = image::ImageReader::with_format(std::io::Cursor::new(bytes), format).into_decoder()?;
    let (w, h) = decoder.dimensions();
    Ok((w, h, decoder.color_type().bytes_per_pixel() as u64))
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

fn texture_from_image(image: &DynamicImage) -> Option<Texture> {
    let channels = match image {
        DynamicImage::ImageLuma8(_) => 1,
        DynamicImage::ImageLumaA8(_) => 2,
        DynamicImage::ImageRgb8(_) => 3,
        DynamicImage::ImageRgba8(_) => 4,
        _ => return None,
    };
    let (w, h) = (image.width() as usize, image.height() as usize);
    let pixels = image.as_bytes();
    if w == 0 || h == 0 || pixels.len() < w * h * channels {
        return None;
    }
    let texels = pixels
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
