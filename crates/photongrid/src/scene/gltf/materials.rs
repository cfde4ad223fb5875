//! glTF materials → [`Material`]: Lambert, mirror or smooth glass where the material is exactly
//! that (specularFactor 0 and no metal; metallic 1 and roughness 0; transmission 1 and
//! roughness 0), the glTF metallic-roughness BSDF with its textures otherwise; plus emission,
//! normal map and alpha. What is still approximated or ignored is said in the report.

use super::budget::{human, Budget, BYTES_PER_TEXEL};
use super::uris::Source;
use super::{Inputs, LoadError, Loader};
use crate::scene::material::{AlphaMode, MetallicRoughness, NormalMap, TextureRef, Wrap};
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

/// Textures decoded so far: one per distinct image source and colour space, so an image used
/// by several materials (or several images naming one file) is decoded once.
#[derive(Default)]
pub(super) struct Textures {
    pub(super) list: Vec<Texture>,
    by_key: HashMap<(ImageKey, bool), u32>,
}

fn image_key(sources: &super::uris::Sources, i: usize) -> ImageKey {
    match &sources.images[i] {
        Source::File { path, .. } => ImageKey::File(path.clone()),
        _ => ImageKey::Image(i),
    }
}

/// The textures a material reads, with whether each is sRGB-encoded colour.
fn texture_infos<'a>(m: &gltf::Material<'a>) -> Vec<(gltf::Texture<'a>, bool)> {
    let pbr = m.pbr_metallic_roughness();
    let mut out = Vec::new();
    out.extend(pbr.base_color_texture().map(|i| (i.texture(), true)));
    out.extend(pbr.metallic_roughness_texture().map(|i| (i.texture(), false)));
    out.extend(m.normal_texture().map(|i| (i.texture(), false)));
    out.extend(m.emissive_texture().map(|i| (i.texture(), true)));
    if let Some(t) = m.transmission() {
        out.extend(t.transmission_texture().map(|i| (i.texture(), false)));
    }
    if let Some(s) = m.specular() {
        out.extend(s.specular_texture().map(|i| (i.texture(), false)));
        out.extend(s.specular_color_texture().map(|i| (i.texture(), true)));
    }
    out
}

fn wrap(mode: gltf::texture::WrappingMode) -> Wrap {
    match mode {
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
        gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
    }
}

/// The 2×3 matrix of KHR_texture_transform: `T · R · S` as the extension's GLSL writes it.
fn transform_matrix(offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> [[f32; 3]; 2] {
    let (s, c) = rotation.sin_cos();
    [
        [c * scale[0], -s * scale[1], offset[0]],
        [s * scale[0], c * scale[1], offset[1]],
    ]
}

/// The material being loaded: how messages name it, and where its textures are read from
/// and kept.
struct MaterialCx<'a, 'i> {
    element: String,
    name: String,
    inputs: &'a Inputs<'i>,
    textures: &'a mut Textures,
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
        let cx = &mut MaterialCx {
            element,
            name,
            inputs,
            textures,
        };
        let base = m.pbr_metallic_roughness().base_color_factor();
        let base_rgb = Rgb::new(base[0], base[1], base[2]);
        if !base_rgb.is_finite() || base_rgb.min_element() < 0.0 {
            return Err(self.invalid(&cx.element, "baseColorFactor must be finite and non-negative"));
        }
        let emission = self.emission(m, &cx.element)?;
        if m.occlusion_texture().is_some() {
            let what = format!(
                "{} '{}': occlusion texture ignored (light transport gives occlusion)",
                cx.element, cx.name
            );
            self.report.ignored.push(what);
        }
        let emission_texture = match m.emissive_texture() {
            Some(info) if emission.max_element() > 0.0 => {
                self.approximated(
                    &cx.element,
                    &cx.name,
                    "emissive texture: seen by the camera as is; lights the scene with its mean over each triangle",
                );
                Some(self.texture_ref(&info, true, cx)?)
            }
            _ => None,
        };
        let normal_map = self.normal_map(m, cx)?;
        let (alpha_mode, alpha_texture) = self.alpha(m, cx)?;
        if !m.double_sided() {
            self.approximated(
                &cx.element,
                &cx.name,
                "single-sided: back faces scatter light as the front faces (only emission is one-sided)",
            );
        }
        let surface = self.surface(m, base_rgb, cx)?;
        if let Surface::Lambert { albedo, .. } = &surface {
            if albedo.max_element() > 1.0 {
                self.approximated(&cx.element, &cx.name, "albedo > 1 reflects more than it receives");
            }
        }
        Ok(Material {
            name: std::mem::take(&mut cx.name),
            surface,
            emission,
            emission_texture,
            double_sided: m.double_sided(),
            normal_map,
            alpha_mode,
            alpha: base[3].clamp(0.0, 1.0),
            alpha_texture,
        })
    }

    /// The emitted radiance (factor × strength), refused when negative, not finite or beyond
    /// what the renderer's sums can carry.
    fn emission(&self, m: &gltf::Material, element: &str) -> Result<Rgb, LoadError> {
        let emission = units::emission_radiance(m.emissive_factor(), m.emissive_strength());
        if !emission.is_finite() || emission.min_element() < 0.0 {
            return Err(self.invalid(element, "emissive factor × strength must be finite and non-negative"));
        }
        if emission.max_element() > MAX_RADIANCE {
            return Err(self.invalid(
                element,
                format!(
                    "emissive factor × strength is {:e} W/(m²·sr), more than the {MAX_RADIANCE:e} the renderer's 32-bit sums can carry; lower the emission strength",
                    emission.max_element()
                ),
            ));
        }
        Ok(emission)
    }

    /// The normal texture and its scale, if any.
    fn normal_map(&mut self, m: &gltf::Material, cx: &mut MaterialCx) -> Result<Option<NormalMap>, LoadError> {
        let Some(n) = m.normal_texture() else {
            return Ok(None);
        };
        if n.tex_coord() != 0 {
            self.approximated(
                &cx.element,
                &cx.name,
                "normal texture uses TEXCOORD_1+: read with TEXCOORD_0",
            );
        }
        let texture = n.texture();
        let scale = n.scale();
        if !scale.is_finite() {
            return Err(self.invalid(&cx.element, "normalTexture.scale must be finite"));
        }
        Ok(Some(NormalMap {
            texture: self.texture_of(&texture, None, false, cx.inputs, cx.textures)?,
            scale,
        }))
    }

    /// The alpha mode, and the base colour texture whose alpha it reads (unless opaque).
    fn alpha(&mut self, m: &gltf::Material, cx: &mut MaterialCx) -> Result<(AlphaMode, Option<TextureRef>), LoadError> {
        let mode = match m.alpha_mode() {
            gltf::material::AlphaMode::Opaque => return Ok((AlphaMode::Opaque, None)),
            gltf::material::AlphaMode::Mask => AlphaMode::Mask {
                cutoff: m.alpha_cutoff().unwrap_or(0.5),
            },
            gltf::material::AlphaMode::Blend => {
                self.approximated(
                    &cx.element,
                    &cx.name,
                    "alpha BLEND rendered as stochastic coverage (shadows attenuated by 1 − alpha)",
                );
                AlphaMode::Blend
            }
        };
        let texture = match m.pbr_metallic_roughness().base_color_texture() {
            Some(info) => Some(self.texture_ref(&info, true, cx)?),
            None => None,
        };
        Ok((mode, texture))
    }

    /// Lambert, mirror or smooth glass where the material is exactly that, else the glTF
    /// metallic-roughness BSDF.
    fn surface(&mut self, m: &gltf::Material, base_rgb: Rgb, cx: &mut MaterialCx) -> Result<Surface, LoadError> {
        let mr = self.metallic_roughness(m, base_rgb, cx)?;
        let (element, name) = (cx.element.as_str(), cx.name.as_str());
        let plain = mr.base_color_texture.is_none() && mr.metallic_roughness_texture.is_none();
        let opaque = mr.transmission <= 0.0 && mr.transmission_texture.is_none();
        if !opaque {
            if mr.transmission >= 1.0
                && mr.transmission_texture.is_none()
                && mr.roughness <= 0.0
                && mr.metallic <= 0.0
                && plain
            {
                return Ok(Surface::Dielectric {
                    ior: mr.ior,
                    tint: base_rgb,
                    absorption: mr.absorption,
                });
            }
            if m.volume().is_none() {
                self.approximated(
                    element,
                    name,
                    "transmission without KHR_materials_volume rendered as a solid (as Blender does), not thin-walled",
                );
            }
            return Ok(Surface::Gltf(Box::new(mr)));
        }
        if mr.metallic >= 1.0 && mr.roughness <= 0.0 && plain {
            return Ok(Surface::Mirror { f0: base_rgb });
        }
        let specular_zero = mr.specular <= 0.0;
        if mr.metallic <= 0.0 && specular_zero {
            return Ok(Surface::Lambert {
                albedo: base_rgb,
                texture: mr.base_color_texture,
            });
        }
        Ok(Surface::Gltf(Box::new(mr)))
    }

    /// The factors and textures of the material's metallic-roughness model.
    fn metallic_roughness(
        &mut self,
        m: &gltf::Material,
        base_rgb: Rgb,
        cx: &mut MaterialCx,
    ) -> Result<MetallicRoughness, LoadError> {
        let pbr = m.pbr_metallic_roughness();
        let unit = |v: f32| if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        let tex = |this: &mut Self, info: Option<gltf::texture::Info>, srgb: bool, cx: &mut MaterialCx| match info {
            Some(i) => this.texture_ref(&i, srgb, cx).map(Some),
            None => Ok(None),
        };
        let base_color_texture = tex(self, pbr.base_color_texture(), true, cx)?;
        let metallic_roughness_texture = tex(self, pbr.metallic_roughness_texture(), false, cx)?;
        let (specular, specular_texture, specular_color, specular_color_texture) = match m.specular() {
            Some(s) => {
                let color = Rgb::from(s.specular_color_factor());
                if !color.is_finite() || color.min_element() < 0.0 {
                    return Err(self.invalid(
                        &cx.element,
                        "KHR_materials_specular: specularColorFactor must be finite and non-negative",
                    ));
                }
                (
                    unit(s.specular_factor()),
                    tex(self, s.specular_texture(), false, cx)?,
                    color,
                    tex(self, s.specular_color_texture(), true, cx)?,
                )
            }
            None => (1.0, None, Rgb::ONE, None),
        };
        let (transmission, transmission_texture) = match m.transmission() {
            Some(t) => (
                unit(t.transmission_factor()),
                tex(self, t.transmission_texture(), false, cx)?,
            ),
            None => (0.0, None),
        };
        let ior = m.ior().unwrap_or(1.5);
        if !(ior.is_finite() && ior >= 1.0) {
            return Err(self.invalid(&cx.element, format!("KHR_materials_ior: ior {ior} must be ≥ 1")));
        }
        let absorption = m.volume().and_then(|v| {
            let d = v.attenuation_distance();
            let c = Rgb::from(v.attenuation_color());
            (d.is_finite() && d > 0.0).then(|| -c.max(Rgb::splat(1e-6)).min(Rgb::ONE).map(f32::ln) / d)
        });
        Ok(MetallicRoughness {
            base_color: base_rgb,
            base_color_texture,
            metallic: unit(pbr.metallic_factor()),
            roughness: unit(pbr.roughness_factor()),
            metallic_roughness_texture,
            specular,
            specular_texture,
            specular_color,
            specular_color_texture,
            ior,
            transmission,
            transmission_texture,
            absorption,
        })
    }

    /// A texture reference: the image decoded on first use, its sampler and transform.
    fn texture_ref(
        &mut self,
        info: &gltf::texture::Info,
        srgb: bool,
        cx: &mut MaterialCx,
    ) -> Result<TextureRef, LoadError> {
        let (element, name) = (cx.element.as_str(), cx.name.as_str());
        if info.tex_coord() != 0 {
            self.approximated(element, name, "a texture uses TEXCOORD_1+: read with TEXCOORD_0");
        }
        let transform = info.texture_transform().map(|t| {
            if t.tex_coord().is_some_and(|c| c != 0) {
                self.approximated(element, name, "KHR_texture_transform texCoord override ignored");
            }
            transform_matrix(t.offset(), t.rotation(), t.scale())
        });
        let transform = transform.filter(|m| m.iter().flatten().all(|v| v.is_finite()));
        self.texture_of(&info.texture(), transform, srgb, cx.inputs, cx.textures)
    }

    fn texture_of(
        &mut self,
        texture: &gltf::Texture,
        transform: Option<[[f32; 3]; 2]>,
        srgb: bool,
        inputs: &Inputs,
        textures: &mut Textures,
    ) -> Result<TextureRef, LoadError> {
        let sampler = texture.sampler();
        let wrap = [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())];
        let i = texture.source().index();
        let key = (image_key(inputs.sources, i), srgb);
        let t = match textures.by_key.get(&key) {
            Some(&t) => t,
            None => {
                let mut tex = self.decode_image(inputs, i)?;
                tex.srgb = srgb;
                textures.list.push(tex);
                let t = (textures.list.len() - 1) as u32;
                textures.by_key.insert(key, t);
                t
            }
        };
        Ok(TextureRef {
            texture: t,
            wrap,
            transform,
        })
    }

    /// Read the header of every image a material will decode and add the decoded textures to
    /// the budget, before any is decoded.
    pub(super) fn estimate_textures(&self, inputs: &Inputs, budget: &mut Budget) -> Result<(), LoadError> {
        let mut keys = std::collections::HashSet::new();
        let mut seen = Vec::new();
        for m in inputs.doc.materials() {
            for (texture, srgb) in texture_infos(&m) {
                let i = texture.source().index();
                if keys.insert((image_key(inputs.sources, i), srgb)) {
                    let bytes = self.image_bytes(inputs.root(), inputs.sources, inputs.buffers, i, budget.left())?;
                    let format = self.image_format(inputs, i, &bytes)?;
                    let (w, h, pixel) = probe(&bytes, format).map_err(|e| self.cannot_decode(i, e))?;
                    seen.push((i, w, h, pixel, bytes.len() as u64));
                }
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
        Surface::Gltf(g) => describe_gltf(g),
    };
    let mut extra = Vec::new();
    if m.normal_map.is_some() {
        extra.push("normal map (tangents from TEXCOORD_0)".to_string());
    }
    match m.alpha_mode {
        AlphaMode::Opaque => {}
        AlphaMode::Mask { cutoff } => extra.push(format!("alpha cut-out at {cutoff}")),
        AlphaMode::Blend => extra.push(format!("alpha blend ({:.3} × texture)", m.alpha)),
    }
    let s = if extra.is_empty() {
        s
    } else {
        format!("{s}; {}", extra.join(", "))
    };
    if m.is_emissive() {
        format!(
            "{s}, emits {:.3?} W/(m²·sr){}{}",
            m.emission.to_array(),
            if m.emission_texture.is_some() {
                " × texture"
            } else {
                ""
            },
            if m.double_sided { " (both faces)" } else { "" }
        )
    } else {
        s
    }
}

/// What a glTF metallic-roughness material renders as, in words.
fn describe_gltf(g: &MetallicRoughness) -> String {
    let mut s = format!(
        "glTF metallic-roughness (GGX, Smith, Schlick): base {:.3?}, metallic {}, roughness {} (α {:.3})",
        g.base_color.to_array(),
        g.metallic,
        g.roughness,
        g.roughness * g.roughness
    );
    if g.specular != 1.0 || g.specular_color != Rgb::ONE {
        s += &format!(", specular {} colour {:.3?}", g.specular, g.specular_color.to_array());
    }
    if g.ior != 1.5 {
        s += &format!(", IOR {}", g.ior);
    }
    if g.transmission > 0.0 || g.transmission_texture.is_some() {
        s += &format!(
            ", transmission {} (rough dielectric, Walter et al. 2007, with the exact Fresnel)",
            g.transmission
        );
    }
    let textures: Vec<&str> = [
        (g.base_color_texture.is_some(), "base colour"),
        (g.metallic_roughness_texture.is_some(), "metallic-roughness"),
        (g.specular_texture.is_some(), "specular"),
        (g.specular_color_texture.is_some(), "specular colour"),
        (g.transmission_texture.is_some(), "transmission"),
    ]
    .into_iter()
    .filter_map(|(on, n)| on.then_some(n))
    .collect();
    if !textures.is_empty() {
        s += &format!("; textures: {}", textures.join(", "));
    }
    let r = crate::bsdf::GLOSSY_ROUGHNESS;
    let (dielectric, metal) = (g.metallic < 1.0, g.metallic > 0.0 || g.specular > 0.0);
    let lobes = match (g.metallic_roughness_texture.is_some(), g.roughness >= r) {
        (true, _) => format!("photons stored where roughness ≥ {r}, reflections traced below"),
        (false, true) => "photons stored, reflection estimated from them".to_string(),
        (false, false) => format!("reflection traced (roughness < {r})"),
    };
    s += &format!(
        "; {}{}",
        if metal || dielectric { lobes } else { String::new() },
        if g.transmission > 0.0 {
            ", transmission traced"
        } else {
            ""
        }
    );
    s
}

fn texture_from_image(image: &DynamicImage) -> Option<Texture> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w == 0 || h == 0 {
        return None;
    }
    let rgba = image.to_rgba8();
    let texels: Vec<[u8; 4]> = rgba.pixels().map(|p| p.0).collect();
    (texels.len() == w * h).then_some(Texture {
        width: w,
        height: h,
        texels,
        srgb: true,
    })
}
