//! glTF 2.0 (.glb / .gltf) → [`Scene`], as Blender's exporter writes it.
//!
//! Every problem is reported with the file and the element (`meshes[3].primitives[0]: …`);
//! nothing in a file can make the loader panic or silently produce an empty scene.

use super::light::EmitterTriangle;
use super::material::srgb_to_linear;
use super::{
    camera, units, Bounds, Camera, Light, LoadReport, Material, Projection, Scene, Surface, Texture, Triangle,
};
use crate::Rgb;
use glam::{Mat3, Mat4, Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

/// Why a scene could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The file could not be read.
    #[error("{path}: cannot read the file: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not valid glTF (truncated, bad JSON, dangling references...).
    #[error("{path}: not a valid glTF 2.0 file: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// An element of the file is invalid or unsupported.
    #[error("{path}: {element}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// The element, e.g. `meshes[3].primitives[0]`.
        element: String,
        /// What is wrong and what to do.
        message: String,
    },
    /// Nothing emits light: the image would be black.
    #[error("{path}: the scene has no lights: export lights (Blender: Include > Punctual Lights) or give a material an emission strength > 0")]
    NoLights {
        /// The file.
        path: PathBuf,
    },
    /// No triangles at all.
    #[error("{path}: the scene has no triangles to render ({degenerate} degenerate triangles skipped)")]
    NoGeometry {
        /// The file.
        path: PathBuf,
        /// Zero-area triangles that were skipped.
        degenerate: usize,
    },
}

/// Options of the loader.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Allow buffers and images outside the scene's folder (off: such URIs are an error).
    pub allow_external_uris: bool,
}

/// Load a `.glb` or `.gltf` file.
pub fn load(path: &Path) -> Result<Scene, LoadError> {
    load_with(path, &LoadOptions::default())
}

/// Load with options.
pub fn load_with(path: &Path, options: &LoadOptions) -> Result<Scene, LoadError> {
    if path.is_dir() {
        return Err(LoadError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "is a folder, not a .glb or .gltf file",
            ),
        });
    }
    let bytes = std::fs::read(path).map_err(|source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if let Some(message) = truncation(&bytes) {
        return Err(LoadError::Parse {
            path: path.to_path_buf(),
            message,
        });
    }
    // The checks below should make a panic impossible; this turns any that slips through in a
    // dependency into an error naming the file instead of a crash.
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| Loader::new(path, options).load(&bytes)));
    match result {
        Ok(r) => r,
        Err(p) => Err(LoadError::Parse {
            path: path.to_path_buf(),
            message: format!(
                "the reader failed on malformed data ({}); the file is probably corrupt",
                p.downcast_ref::<String>()
                    .map(|s| s.as_str())
                    .or(p.downcast_ref::<&str>().copied())
                    .unwrap_or("unknown")
            ),
        }),
    }
}

/// An empty file, or a GLB shorter than its header says: the parser's own messages for these
/// ("EOF while parsing", "could not completely read the object") do not say what happened.
fn truncation(bytes: &[u8]) -> Option<String> {
    if bytes.is_empty() {
        return Some("the file is empty (0 bytes)".into());
    }
    if !bytes.starts_with(b"glTF") {
        return None;
    }
    if bytes.len() < 12 {
        return Some(format!(
            "the file has {} bytes, less than the 12-byte GLB header: the file is truncated",
            bytes.len()
        ));
    }
    let declared = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
    (declared > bytes.len()).then(|| {
        format!(
            "the GLB header declares {declared} bytes but the file has {}: the file is truncated",
            bytes.len()
        )
    })
}

struct Loader<'a> {
    path: &'a Path,
    base: PathBuf,
    options: &'a LoadOptions,
    report: LoadReport,
}

impl<'a> Loader<'a> {
    fn new(path: &'a Path, options: &'a LoadOptions) -> Self {
        let base = path.parent().map(|p| p.to_path_buf()).unwrap_or_default();
        Loader {
            path,
            base,
            options,
            report: LoadReport::default(),
        }
    }

    fn invalid(&self, element: impl Into<String>, message: impl Into<String>) -> LoadError {
        LoadError::Invalid {
            path: self.path.to_path_buf(),
            element: element.into(),
            message: message.into(),
        }
    }

    fn load(mut self, bytes: &[u8]) -> Result<Scene, LoadError> {
        let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| LoadError::Parse {
            path: self.path.to_path_buf(),
            message: e.to_string(),
        })?;
        let doc = gltf.document;
        let blob = gltf.blob;
        for ext in doc.extensions_used() {
            if !SUPPORTED_EXTENSIONS.contains(&ext) {
                self.report
                    .ignored
                    .push(format!("extension {ext}: not supported, ignored"));
            }
        }
        self.check_uris(&doc)?;
        let buffers = gltf::import_buffers(&doc, Some(&self.base), blob).map_err(|e| self.buffer_error(&doc, e))?;

        let mut textures = Vec::new();
        let mut texture_of_image = HashMap::new();
        let mut materials = Vec::new();
        for m in doc.materials() {
            let mat = self.material(&m, &buffers, &mut textures, &mut texture_of_image)?;
            self.report.materials.push(format!(
                "materials[{}] '{}': {}",
                m.index().unwrap_or(0),
                mat.name,
                describe_material(&mat)
            ));
            materials.push(mat);
        }
        let default_material = materials.len() as u32;
        materials.push(Material::default_gltf());

        let scene = doc
            .default_scene()
            .or_else(|| doc.scenes().next())
            .ok_or_else(|| self.invalid("scenes", "the file has no scene"))?;

        // Walk the node tree (iteratively, with a depth limit against cyclic files).
        let mut triangles = Vec::new();
        let mut cameras = Vec::new();
        let mut punctual = Vec::new();
        let mut stack: Vec<(gltf::Node, Mat4, usize)> = scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect();
        let mut visits = 0usize;
        while let Some((node, parent, depth)) = stack.pop() {
            visits += 1;
            if depth > 256 || visits > 1_000_000 {
                return Err(self.invalid(
                    format!("nodes[{}]", node.index()),
                    "node hierarchy is cyclic or absurdly deep",
                ));
            }
            let local = Mat4::from_cols_array_2d(&node.transform().matrix());
            let world = parent * local;
            if !world.is_finite() {
                return Err(self.invalid(format!("nodes[{}]", node.index()), "transform is not finite"));
            }
            if let Some(mesh) = node.mesh() {
                self.mesh(&mesh, world, &buffers, default_material, &mut triangles)?;
            }
            if let Some(cam) = node.camera() {
                cameras.push(self.camera(&node, &cam, world)?);
            }
            if let Some(light) = node.light() {
                punctual.push((node.index(), node.name().map(str::to_string), light_of(&light), world));
            }
            for child in node.children() {
                stack.push((child, world, depth + 1));
            }
        }
        if triangles.is_empty() {
            return Err(LoadError::NoGeometry {
                path: self.path.to_path_buf(),
                degenerate: self.report.degenerate_triangles,
            });
        }
        let mut bounds = Bounds::empty();
        for t in &triangles {
            for p in t.p {
                bounds.grow(p);
            }
        }

        let mut lights = Vec::new();
        for (node, name, kind, world) in punctual {
            let l = self.light(node, name, kind, world, &bounds)?;
            self.report.lights.push(l.describe());
            lights.push(l);
        }
        let emitters: Vec<EmitterTriangle> = triangles
            .iter()
            .enumerate()
            .filter(|(_, t)| materials[t.material as usize].is_emissive())
            .map(|(i, t)| {
                let m = &materials[t.material as usize];
                let c = t.cross();
                EmitterTriangle {
                    p0: t.p[0],
                    e1: t.p[1] - t.p[0],
                    e2: t.p[2] - t.p[0],
                    normal: c.normalize(),
                    area: 0.5 * c.length(),
                    radiance: m.emission,
                    double_sided: m.double_sided,
                    triangle: i as u32,
                }
            })
            .collect();
        if let Some(l) = Light::emissive(emitters) {
            self.report.lights.push(l.describe());
            lights.push(l);
        }
        if lights.iter().all(|l| l.power().max_element() <= 0.0) {
            return Err(LoadError::NoLights {
                path: self.path.to_path_buf(),
            });
        }
        cameras.sort_by_key(|c: &Camera| c.index);
        for c in &cameras {
            self.report
                .cameras
                .push(format!("{} '{}': {:?}", c.index, c.name, c.projection));
        }
        Ok(Scene {
            source: self.path.to_path_buf(),
            triangles,
            materials,
            textures,
            lights,
            cameras,
            bounds,
            report: self.report,
        })
    }

    /// External URIs must stay inside the scene's folder and exist.
    fn check_uris(&self, doc: &gltf::Document) -> Result<(), LoadError> {
        let mut uris = Vec::new();
        for b in doc.buffers() {
            if let gltf::buffer::Source::Uri(u) = b.source() {
                uris.push((format!("buffers[{}]", b.index()), u.to_string()));
            }
        }
        for i in doc.images() {
            if let gltf::image::Source::Uri { uri, .. } = i.source() {
                uris.push((format!("images[{}]", i.index()), uri.to_string()));
            }
        }
        for (element, uri) in uris {
            if uri.starts_with("data:") {
                continue;
            }
            if uri.contains("://") {
                return Err(self.invalid(
                    element,
                    format!(
                        "URI '{uri}' points outside the file system; only relative file names and data: URIs are read"
                    ),
                ));
            }
            let decoded = urlencoding_decode(&uri);
            let rel = Path::new(&decoded);
            let escapes = rel.is_absolute()
                || rel
                    .components()
                    .try_fold(0i32, |depth, c| match c {
                        Component::ParentDir => (depth > 0).then_some(depth - 1),
                        Component::Normal(_) => Some(depth + 1),
                        Component::CurDir => Some(depth),
                        _ => None,
                    })
                    .is_none();
            if escapes && !self.options.allow_external_uris {
                return Err(self.invalid(
                    element,
                    format!("URI '{uri}' leaves the scene's folder; copy the file next to the scene (or pass --allow-external-uris)"),
                ));
            }
            let full = self.base.join(rel);
            if !full.is_file() {
                return Err(self.invalid(element, format!("file '{}' not found", full.display())));
            }
        }
        Ok(())
    }

    fn buffer_error(&self, doc: &gltf::Document, e: gltf::Error) -> LoadError {
        match e {
            gltf::Error::BufferLength {
                buffer,
                expected,
                actual,
            } => self.invalid(
                format!("buffers[{buffer}]"),
                format!("declares {expected} bytes but only {actual} are present: the file is truncated"),
            ),
            gltf::Error::MissingBlob => self.invalid(
                "buffers[0]",
                "refers to the GLB binary chunk, which is missing: the file is truncated",
            ),
            other => self.invalid(format!("buffers (of {})", doc.buffers().len()), other.to_string()),
        }
    }

    fn material(
        &mut self,
        m: &gltf::Material,
        buffers: &[gltf::buffer::Data],
        textures: &mut Vec<Texture>,
        texture_of_image: &mut HashMap<usize, u32>,
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
        let metallic = pbr.metallic_factor();
        let roughness = pbr.roughness_factor();
        let transmission = m.transmission().map(|t| t.transmission_factor()).unwrap_or(0.0);
        let emission = units::emission_radiance(m.emissive_factor(), m.emissive_strength());
        if !emission.is_finite() || emission.min_element() < 0.0 {
            return Err(self.invalid(&element, "emissive factor × strength must be finite and non-negative"));
        }
        let mut approx = |what: String| self.report.approximated.push(format!("{element} '{name}': {what}"));
        if m.emissive_texture().is_some() {
            approx("emissive texture ignored (emissiveFactor used)".into());
        }
        if pbr.metallic_roughness_texture().is_some() {
            approx("metallic-roughness texture ignored (factors used)".into());
        }
        if m.alpha_mode() != gltf::material::AlphaMode::Opaque {
            approx("alpha mode ignored: rendered opaque".into());
        }
        let surface = if transmission > 0.0 {
            if transmission < 0.5 {
                approx(format!("transmission {transmission} < 0.5 rendered as Lambert"));
                Surface::Lambert {
                    albedo: base_rgb,
                    texture: None,
                }
            } else {
                if transmission < 1.0 {
                    approx(format!("transmission {transmission} rendered as fully transmissive"));
                }
                if roughness > 0.0 {
                    approx(format!("roughness {roughness} on glass rendered as smooth glass"));
                }
                let ior = m.ior().unwrap_or(1.5);
                if !(ior.is_finite() && ior >= 1.0) {
                    return Err(self.invalid(&element, format!("KHR_materials_ior: ior {ior} must be ≥ 1")));
                }
                let absorption = m.volume().and_then(|v| {
                    let d = v.attenuation_distance();
                    let c = Rgb::from(v.attenuation_color());
                    (d.is_finite() && d > 0.0).then(|| -c.max(Rgb::splat(1e-6)).min(Rgb::ONE).map(f32::ln) / d)
                });
                Surface::Dielectric {
                    ior,
                    tint: base_rgb,
                    absorption,
                }
            }
        } else if metallic >= 0.5 {
            if metallic < 1.0 {
                approx(format!("metallic {metallic} rendered as a full mirror"));
            }
            if roughness > 0.0 {
                approx(format!("roughness {roughness} on metal rendered as a perfect mirror"));
            }
            Surface::Mirror { f0: base_rgb }
        } else {
            if metallic > 0.0 {
                approx(format!("metallic {metallic} < 0.5 rendered as Lambert"));
            }
            if let Some(s) = m.specular() {
                if s.specular_factor() > 0.0 && roughness < 1.0 {
                    approx("specular layer ignored (pure Lambert)".into());
                }
            } else if roughness < 1.0 {
                approx("default specular layer ignored (pure Lambert)".into());
            }
            let texture = match pbr.base_color_texture() {
                Some(info) => {
                    if info.tex_coord() != 0 {
                        approx("base colour texture uses TEXCOORD_1+: read with TEXCOORD_0".into());
                    }
                    if info.texture_transform().is_some() {
                        approx("KHR_texture_transform ignored".into());
                    }
                    let image = info.texture().source();
                    let key = image.index();
                    if let Some(&t) = texture_of_image.get(&key) {
                        Some(t)
                    } else {
                        let data = gltf::image::Data::from_source(image.source(), Some(&self.base), buffers)
                            .map_err(|e| self.invalid(format!("images[{key}]"), format!("cannot decode: {e}")))?;
                        let tex = texture_from_image(&data).ok_or_else(|| {
                            self.invalid(
                                format!("images[{key}]"),
                                format!("unsupported pixel format {:?}", data.format),
                            )
                        })?;
                        textures.push(tex);
                        let t = (textures.len() - 1) as u32;
                        texture_of_image.insert(key, t);
                        Some(t)
                    }
                }
                None => None,
            };
            Surface::Lambert {
                albedo: base_rgb,
                texture,
            }
        };
        if let Surface::Lambert { albedo, .. } = &surface {
            if albedo.max_element() > 1.0 {
                self.report
                    .approximated
                    .push(format!("{element} '{name}': albedo > 1 reflects more than it receives"));
            }
        }
        Ok(Material {
            name,
            surface,
            emission,
            double_sided: m.double_sided(),
        })
    }

    fn mesh(
        &mut self,
        mesh: &gltf::Mesh,
        world: Mat4,
        buffers: &[gltf::buffer::Data],
        default_material: u32,
        out: &mut Vec<Triangle>,
    ) -> Result<(), LoadError> {
        let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
        let flip = Mat3::from_mat4(world).determinant() < 0.0;
        for prim in mesh.primitives() {
            let element = format!("meshes[{}].primitives[{}]", mesh.index(), prim.index());
            use gltf::mesh::Mode;
            let mode = prim.mode();
            if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                self.report
                    .ignored
                    .push(format!("{element}: mode {mode:?} is not triangles"));
                continue;
            }
            for (sem, acc) in prim.attributes() {
                self.check_accessor(
                    &acc,
                    buffers,
                    &format!("{element}.attributes.{sem:?} (accessors[{}])", acc.index()),
                )?;
            }
            if let Some(acc) = prim.indices() {
                self.check_accessor(
                    &acc,
                    buffers,
                    &format!("{element}.indices (accessors[{}])", acc.index()),
                )?;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| d.0.as_slice()));
            let positions: Vec<Vec3> = reader
                .read_positions()
                .ok_or_else(|| {
                    self.invalid(
                        &element,
                        "POSITION is missing or has no bufferView (zero-filled accessors are not supported)",
                    )
                })?
                .map(Vec3::from)
                .collect();
            if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
                return Err(self.invalid(&element, format!("POSITION[{i}] is not finite ({})", positions[i])));
            }
            let n = positions.len();
            let normals: Option<Vec<Vec3>> = reader.read_normals().map(|it| it.map(Vec3::from).collect());
            if let Some(ns) = &normals {
                if ns.len() != n {
                    return Err(self.invalid(&element, format!("NORMAL has {} entries, POSITION {n}", ns.len())));
                }
            }
            let uvs: Option<Vec<Vec2>> = reader
                .read_tex_coords(0)
                .map(|it| it.into_f32().map(Vec2::from).collect());
            let indices: Vec<u32> = match reader.read_indices() {
                Some(it) => it.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            if let Some((k, &i)) = indices.iter().enumerate().find(|(_, &i)| i as usize >= n) {
                return Err(self.invalid(&element, format!("index {i} (indices[{k}]) >= vertex count {n}")));
            }
            let tris: Vec<[u32; 3]> = match mode {
                Mode::Triangles => {
                    if indices.len() % 3 != 0 {
                        self.report.ignored.push(format!(
                            "{element}: {} trailing indices (not a multiple of 3)",
                            indices.len() % 3
                        ));
                    }
                    indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
                }
                Mode::TriangleStrip => (0..indices.len().saturating_sub(2))
                    .map(|i| {
                        if i % 2 == 0 {
                            [indices[i], indices[i + 1], indices[i + 2]]
                        } else {
                            [indices[i + 1], indices[i], indices[i + 2]]
                        }
                    })
                    .collect(),
                _ => (0..indices.len().saturating_sub(2))
                    .map(|i| [indices[i + 1], indices[i + 2], indices[0]])
                    .collect(),
            };
            let material = prim.material().index().map(|i| i as u32).unwrap_or(default_material);
            let world_p: Vec<Vec3> = positions.iter().map(|p| world.transform_point3(*p)).collect();
            let world_n: Option<Vec<Vec3>> =
                normals.map(|ns| ns.iter().map(|v| (normal_matrix * *v).normalize_or_zero()).collect());
            let degenerate_before = self.report.degenerate_triangles;
            for mut t in tris {
                if flip {
                    t.swap(1, 2);
                }
                let p = t.map(|i| world_p[i as usize]);
                let cross = (p[1] - p[0]).cross(p[2] - p[0]);
                let len = cross.length();
                if !(len > 1e-14) {
                    self.report.degenerate_triangles += 1;
                    continue;
                }
                let ng = cross / len;
                let nrm = match &world_n {
                    Some(ns) => t.map(|i| {
                        let v = ns[i as usize];
                        // A zero or wild normal falls back to the geometric one.
                        if v.is_finite() && v.length_squared() > 0.5 {
                            v
                        } else {
                            ng
                        }
                    }),
                    None => [ng; 3],
                };
                let uv = match &uvs {
                    Some(u) => t.map(|i| u.get(i as usize).copied().unwrap_or(Vec2::ZERO)),
                    None => [Vec2::ZERO; 3],
                };
                out.push(Triangle {
                    p,
                    n: nrm,
                    uv,
                    material,
                });
            }
            let degenerate = self.report.degenerate_triangles - degenerate_before;
            if degenerate > 0 {
                self.report.ignored.push(format!(
                    "{element}: {degenerate} degenerate (zero-area) triangles skipped"
                ));
            }
        }
        Ok(())
    }

    /// An accessor's bytes must lie inside its buffer view and buffer.
    fn check_accessor(
        &self,
        acc: &gltf::Accessor,
        buffers: &[gltf::buffer::Data],
        element: &str,
    ) -> Result<(), LoadError> {
        let Some(view) = acc.view() else {
            if acc.sparse().is_none() {
                return Err(self.invalid(
                    element,
                    "accessor has no bufferView (zero-filled accessors are not supported)",
                ));
            }
            return Ok(());
        };
        let buffer_len = buffers.get(view.buffer().index()).map(|b| b.len()).unwrap_or(0);
        if view.offset() + view.length() > buffer_len {
            return Err(self.invalid(
                element,
                format!(
                    "bufferViews[{}] spans bytes {}..{} but buffer {} has {buffer_len}",
                    view.index(),
                    view.offset(),
                    view.offset() + view.length(),
                    view.buffer().index()
                ),
            ));
        }
        let elem = acc.size();
        let stride = view.stride().unwrap_or(elem);
        if acc.count() > 0 {
            let need = acc.offset() + stride * (acc.count() - 1) + elem;
            if need > view.length() {
                return Err(self.invalid(
                    element,
                    format!(
                        "needs {need} bytes but bufferViews[{}] has {}",
                        view.index(),
                        view.length()
                    ),
                ));
            }
        }
        Ok(())
    }

    fn camera(&mut self, node: &gltf::Node, cam: &gltf::Camera, world: Mat4) -> Result<Camera, LoadError> {
        let element = format!("cameras[{}]", cam.index());
        let projection = match cam.projection() {
            gltf::camera::Projection::Perspective(p) => {
                let yfov = p.yfov();
                if !(yfov > 0.0 && yfov < std::f32::consts::PI) {
                    return Err(self.invalid(element, format!("yfov {yfov} must be in (0, π)")));
                }
                Projection::Perspective {
                    yfov,
                    aspect: p.aspect_ratio().filter(|a| a.is_finite() && *a > 0.0),
                }
            }
            gltf::camera::Projection::Orthographic(o) => {
                let (xmag, ymag) = (o.xmag().abs(), o.ymag().abs());
                if !(xmag > 0.0 && ymag > 0.0 && xmag.is_finite() && ymag.is_finite()) {
                    return Err(self.invalid(element, "orthographic xmag and ymag must be non-zero"));
                }
                Projection::Orthographic { xmag, ymag }
            }
        };
        let name = node
            .name()
            .or(cam.name())
            .map(str::to_string)
            .unwrap_or_else(|| element.clone());
        Ok(Camera {
            name,
            index: cam.index(),
            to_world: camera::rigid_part(world),
            projection,
        })
    }

    fn light(
        &mut self,
        node: usize,
        name: Option<String>,
        kind: PunctualKind,
        world: Mat4,
        bounds: &Bounds,
    ) -> Result<Light, LoadError> {
        let element = format!("nodes[{node}] (KHR_lights_punctual.lights[{}])", kind.index);
        let name = name.unwrap_or_else(|| format!("light {}", kind.index));
        let color = Rgb::from(kind.color);
        if !(kind.intensity.is_finite() && kind.intensity >= 0.0 && color.is_finite() && color.min_element() >= 0.0) {
            return Err(self.invalid(element, "intensity and color must be finite and non-negative"));
        }
        if kind.range.is_some() {
            self.report
                .approximated
                .push(format!("{element}: range ignored (physical inverse-square falloff)"));
        }
        let position = world.transform_point3(Vec3::ZERO);
        let direction = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
        Ok(match kind.kind {
            PunctualType::Point => Light::Point {
                name,
                position,
                intensity: color * units::candela_to_radiant_intensity(kind.intensity),
            },
            PunctualType::Spot { inner, outer } => {
                if direction == Vec3::ZERO {
                    return Err(self.invalid(element, "spot direction is degenerate (zero scale?)"));
                }
                let outer = outer.clamp(1e-4, std::f32::consts::FRAC_PI_2);
                Light::Spot {
                    name,
                    position,
                    direction,
                    intensity: color * units::candela_to_radiant_intensity(kind.intensity),
                    cos_outer: outer.cos(),
                    blend: units::spot_blend(inner.clamp(0.0, outer), outer),
                }
            }
            PunctualType::Directional => {
                if direction == Vec3::ZERO {
                    return Err(self.invalid(element, "sun direction is degenerate (zero scale?)"));
                }
                Light::Directional {
                    name,
                    direction,
                    irradiance: color * units::lux_to_irradiance(kind.intensity),
                    scene_center: bounds.center(),
                    scene_radius: 0.5 * bounds.diagonal().max(1e-3),
                }
            }
        })
    }
}

const SUPPORTED_EXTENSIONS: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_materials_volume",
    "KHR_materials_emissive_strength",
    "KHR_materials_specular",
    "KHR_texture_transform",
];

enum PunctualType {
    Point,
    Spot { inner: f32, outer: f32 },
    Directional,
}

struct PunctualKind {
    index: usize,
    color: [f32; 3],
    intensity: f32,
    range: Option<f32>,
    kind: PunctualType,
}

fn light_of(l: &gltf::khr_lights_punctual::Light) -> PunctualKind {
    use gltf::khr_lights_punctual::Kind;
    PunctualKind {
        index: l.index(),
        color: l.color(),
        intensity: l.intensity(),
        range: l.range(),
        kind: match l.kind() {
            Kind::Point => PunctualType::Point,
            Kind::Directional => PunctualType::Directional,
            Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => PunctualType::Spot {
                inner: inner_cone_angle,
                outer: outer_cone_angle,
            },
        },
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

/// Percent-decoding of URIs (glTF URIs are RFC 3986).
fn urlencoding_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        // Hex digits are read from the bytes: slicing the str could split a UTF-8 character.
        let hex = |b: u8| (b as char).to_digit(16);
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            if let (Some(hi), Some(lo)) = (hex(bytes[i + 1]), hex(bytes[i + 2])) {
                out.push((hi * 16 + lo) as u8);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}
