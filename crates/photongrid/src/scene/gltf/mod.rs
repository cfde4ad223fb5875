//! glTF 2.0 (.glb / .gltf) → [`Scene`], as Blender's exporter writes it.
//!
//! Every problem is reported with the file and the element (`meshes[3].primitives[0]: …`);
//! nothing in a file can make the loader panic or silently produce an empty scene.
//!
//! The loader is split along the concepts of the format: [`uris`] (buffer and image URIs, the
//! files they name), [`materials`] (materials and their textures), [`meshes`] (primitives,
//! accessors, transforms and the node hierarchy), [`lights`] (KHR_lights_punctual and emissive
//! triangles) and [`cameras`]; this module holds the entry points and puts the scene together.

mod cameras;
mod lights;
mod materials;
mod meshes;
mod uris;

use super::{Bounds, Camera, LoadReport, Scene};
use std::path::{Path, PathBuf};

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

/// The state of one load: the file, its folder, the options and the report being written.
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
        self.report_extensions(&doc);
        self.check_uris(&doc)?;
        let buffers = gltf::import_buffers(&doc, Some(&self.base), blob).map_err(|e| self.buffer_error(&doc, e))?;
        let (mut materials, textures) = self.materials(&doc, &buffers)?;
        let default_material = materials.len() as u32;
        materials.push(super::Material::default_gltf());

        let nodes = self.nodes(&doc, &buffers, default_material)?;
        if nodes.triangles.is_empty() {
            return Err(LoadError::NoGeometry {
                path: self.path.to_path_buf(),
                degenerate: self.report.degenerate_triangles,
            });
        }
        let mut bounds = Bounds::empty();
        for t in &nodes.triangles {
            for p in t.p {
                bounds.grow(p);
            }
        }
        let lights = self.lights(nodes.punctual, &nodes.triangles, &materials, &bounds)?;
        let cameras = self.sorted_cameras(nodes.cameras);
        Ok(Scene {
            source: self.path.to_path_buf(),
            triangles: nodes.triangles,
            materials,
            textures,
            lights,
            cameras,
            bounds,
            report: self.report,
        })
    }

    fn report_extensions(&mut self, doc: &gltf::Document) {
        for ext in doc.extensions_used() {
            if !SUPPORTED_EXTENSIONS.contains(&ext) {
                self.report
                    .ignored
                    .push(format!("extension {ext}: not supported, ignored"));
            }
        }
    }

    fn sorted_cameras(&mut self, mut cameras: Vec<Camera>) -> Vec<Camera> {
        cameras.sort_by_key(|c: &Camera| c.index);
        for c in &cameras {
            self.report
                .cameras
                .push(format!("{} '{}': {:?}", c.index, c.name, c.projection));
        }
        cameras
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
