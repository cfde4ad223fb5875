//! glTF 2.0 (.glb / .gltf) → [`Scene`], as Blender's exporter writes it.
//!
//! Every problem is reported with the file and the element (`meshes[3].primitives[0]: …`);
//! nothing in a file can make the loader panic, hang, allocate without bound or silently
//! produce an empty or black scene. A load runs in this order:
//!
//! 1. [`uris`]: the scene file is read if it is a regular file within the memory budget;
//! 2. the JSON is parsed without the `gltf` crate's validation, and [`validate`] checks
//!    everything its readers will touch (indices, types, byte ranges with checked arithmetic,
//!    the node graph and its expansion); then the crate's own validation runs;
//! 3. [`budget`]: the memory the scene needs (file, buffers, triangles after instancing) is
//!    estimated and refused if over the budget, before anything large is allocated;
//! 4. [`uris`]: buffer and image URIs are resolved (only `data:` and relative paths, confined
//!    to the scene's folder, regular files only) and buffers read up to their declared length;
//! 5. [`materials`]: image headers are read and the decoded textures added to the budget,
//!    then the materials are built, each distinct image decoded once;
//! 6. [`meshes`] walks the node hierarchy into world-space triangles (coordinates in range,
//!    finite attributes), [`cameras`] and [`lights`] place cameras and lights (finite power).

mod budget;
mod cameras;
mod lights;
mod materials;
mod meshes;
mod tangents;
mod uris;
mod validate;

use super::{Bounds, Camera, LoadReport, Scene};
use budget::Budget;
use std::path::{Path, PathBuf};
use uris::Sources;

/// Largest coordinate magnitude accepted after the node transforms (meshes, lights, cameras),
/// in metres: the BVH builder fails beyond about 1e19, and the grids need headroom above the
/// scene's size.
const MAX_COORDINATE: f32 = 1e18;

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
    /// Loading would need more memory than the budget ([`LoadOptions::memory_budget_bytes`]).
    #[error("{path}: {message}")]
    OverBudget {
        /// The file.
        path: PathBuf,
        /// Estimated bytes the load needs.
        needed: u64,
        /// The budget in bytes.
        budget: u64,
        /// The estimate item by item, the limit and what to change.
        message: String,
    },
}

/// Options of the loader.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Allow buffers and images outside the scene's folder (off: such URIs are an error).
    pub allow_external_uris: bool,
    /// Most memory a load may need, in bytes; `None`: half of the machine's RAM (8 GiB if
    /// that cannot be read). A scene estimated to need more is refused before it is expanded.
    pub memory_budget_bytes: Option<u64>,
}

/// Load a `.glb` or `.gltf` file.
pub fn load(path: &Path) -> Result<Scene, LoadError> {
    load_with(path, &LoadOptions::default())
}

/// Load with options.
pub fn load_with(path: &Path, options: &LoadOptions) -> Result<Scene, LoadError> {
    let mut budget = Budget::new(options);
    let bytes = uris::read_regular_file(path, budget.limit()).map_err(|source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if let Some(message) = truncation(&bytes) {
        return Err(LoadError::Parse {
            path: path.to_path_buf(),
            message,
        });
    }
    budget.add("the file and its parsed JSON", parse_estimate(&bytes));
    budget.check(path)?;
    // Validation runs before every reader, so no panic is expected; should one slip through in
    // a dependency all the same, it becomes an error naming the file rather than a crash.
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        Loader::new(path, options).load(bytes, budget)
    }));
    match result {
        Ok(r) => r,
        Err(p) => Err(LoadError::Parse {
            path: path.to_path_buf(),
            message: format!(
                "internal error: a check of the loader is missing for this file ({}); please report it",
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
    if declared < 12 {
        return Some(format!(
            "the GLB header declares {declared} bytes, less than the 12-byte header itself: the file is corrupt"
        ));
    }
    (declared > bytes.len()).then(|| {
        format!(
            "the GLB header declares {declared} bytes but the file has {}: the file is truncated",
            bytes.len()
        )
    })
}

/// Bytes the file and its parsed JSON take: parsing turns each JSON object into a struct of a
/// few hundred bytes and each array element into up to 32, so `[{},{},…]` or `[0,0,…]` in a
/// large file would outgrow the file many times over. Counted outside strings (base64 buffers
/// have no braces or commas).
fn parse_estimate(bytes: &[u8]) -> u64 {
    let json = if bytes.starts_with(b"glTF") && bytes.len() >= 20 {
        let len = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]) as usize;
        &bytes[20..bytes.len().min(20usize.saturating_add(len))]
    } else {
        bytes
    };
    let (mut objects, mut elements, mut in_string, mut escaped) = (0u64, 0u64, false, false);
    for &b in json {
        if in_string {
            (escaped, in_string) = (!escaped && b == b'\\', escaped || b != b'"');
        } else {
            match b {
                b'"' => in_string = true,
                b'{' => objects += 1,
                b',' | b'[' => elements += 1,
                _ => {}
            }
        }
    }
    (bytes.len() as u64)
        .saturating_add(objects.saturating_mul(512))
        .saturating_add(elements.saturating_mul(32))
}

/// What the readers read from, once validated: the document, where each buffer and image comes
/// from, and the buffers' bytes.
struct Inputs<'a> {
    doc: &'a gltf::Document,
    sources: &'a Sources<'a>,
    buffers: &'a [Vec<u8>],
}

impl Inputs<'_> {
    fn root(&self) -> &gltf::json::Root {
        self.doc.as_json()
    }
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

    fn parse_error(&self, e: gltf::Error) -> LoadError {
        LoadError::Parse {
            path: self.path.to_path_buf(),
            message: e.to_string(),
        }
    }

    /// Steps 2–6 of the module's description.
    fn load(mut self, bytes: Vec<u8>, mut budget: Budget) -> Result<Scene, LoadError> {
        let gltf = gltf::Gltf::from_slice_without_validation(&bytes).map_err(|e| self.parse_error(e))?;
        drop(bytes);
        let blob = gltf.blob;
        let root = gltf.document.into_json();
        let expansion = self.validate(&root)?;
        let doc = gltf::Document::from_json(root).map_err(|e| self.parse_error(e))?;
        self.report_ignored(&doc);
        budget.add("buffers, as declared", expansion.buffer_bytes);
        let cost = expansion.cost;
        budget.add(
            format!(
                "{} triangles after instancing ({} node instances), with their BVH",
                cost.triangles, cost.instances
            ),
            cost.triangles.saturating_mul(budget::BYTES_PER_TRIANGLE),
        );
        budget.add("reading the largest primitive", expansion.largest_primitive);
        budget.check(self.path)?;
        self.check_reads(doc.as_json(), &cost, budget.max_reads())?;
        let sources = self.resolve_uris(doc.as_json())?;
        let buffers = self.read_buffers(doc.as_json(), &sources, blob)?;
        self.validate_data(doc.as_json(), &buffers)?;
        let inputs = Inputs {
            doc: &doc,
            sources: &sources,
            buffers: &buffers,
        };
        self.estimate_textures(&inputs, &mut budget)?;
        self.build(&inputs, cost.triangles)
    }

    /// Materials, triangles, lights and cameras of validated inputs (`triangles` after
    /// instancing, as counted by the validation: within the budget).
    fn build(mut self, inputs: &Inputs, triangles: u64) -> Result<Scene, LoadError> {
        let (mut materials, textures) = self.materials(inputs)?;
        let default_material = materials.len() as u32;
        materials.push(super::Material::default_gltf());
        let nodes = self.nodes(inputs, default_material, triangles as usize, &materials)?;
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
        let lights = self.lights(nodes.punctual, &nodes.triangles, &materials, &textures, &bounds)?;
        let cameras = self.sorted_cameras(nodes.cameras);
        let scene = Scene {
            source: self.path.to_path_buf(),
            triangles: nodes.triangles,
            materials,
            textures,
            tangents: nodes.tangents,
            glossy_roughness: crate::bsdf::GLOSSY_ROUGHNESS,
            lights,
            cameras,
            bounds,
            report: self.report,
        };
        if !(scene.surface_area().is_finite() && scene.bounds.diagonal().is_finite()) {
            return Err(LoadError::Invalid {
                path: scene.source,
                element: "meshes".into(),
                message: "the scene's total surface area or size overflows 32-bit floats; scale the scene down".into(),
            });
        }
        Ok(scene)
    }

    /// Extensions and features the renderer does not use, for the report.
    fn report_ignored(&mut self, doc: &gltf::Document) {
        for ext in doc.extensions_used() {
            if !SUPPORTED_EXTENSIONS.contains(&ext) {
                self.report
                    .ignored
                    .push(format!("extension {ext}: not supported, ignored"));
            }
        }
        let root = doc.as_json();
        if !root.animations.is_empty() {
            let what = format!(
                "{} animations ignored (the scene is rendered as the file places it)",
                root.animations.len()
            );
            self.report.ignored.push(what);
        }
        if !root.skins.is_empty() {
            let what = format!(
                "{} skins ignored (meshes are rendered in their bind pose)",
                root.skins.len()
            );
            self.report.ignored.push(what);
        }
        for mesh in doc.meshes() {
            for prim in mesh.primitives() {
                let element = format!("meshes[{}].primitives[{}]", mesh.index(), prim.index());
                if prim.morph_targets().len() > 0 {
                    let what = format!("{element}: morph targets ignored (the base shape is rendered)");
                    self.report.ignored.push(what);
                }
                if prim.get(&gltf::Semantic::Colors(0)).is_some() {
                    self.report
                        .ignored
                        .push(format!("{element}: vertex colours (COLOR_0) ignored"));
                }
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
