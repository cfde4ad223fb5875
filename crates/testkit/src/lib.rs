//! A small glTF 2.0 writer for the integration tests: meshes, nodes, materials, punctual lights
//! and cameras → `.gltf` (JSON with an embedded base64 `data:` buffer, or an external `.bin`)
//! or `.glb`. It writes what it is given without validating it, so tests can also build broken
//! files; [`Gltf::json`] gives the document for further hand edits.
#![allow(dead_code)]

pub mod harness;

use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

// ---------------------------------------------------------------------------------------------
// Temporary folders.

/// A fresh folder under the system temp dir, removed (with its contents) on drop.
pub struct TempDir {
    path: PathBuf,
}

impl TempDir {
    /// A new empty folder whose name contains `tag`, the process id and a counter.
    pub fn new(tag: &str) -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let path = std::env::temp_dir().join(format!("photongrid-test-{}-{n}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).expect("create temp dir");
        TempDir { path }
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A path inside the folder.
    pub fn join(&self, name: &str) -> PathBuf {
        self.path.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

// ---------------------------------------------------------------------------------------------
// Base64.

/// Standard base64 with padding (RFC 4648).
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let v = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(ALPHABET[(v >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Scene description.

/// Index data of a primitive.
#[derive(Clone, Debug)]
pub enum Indices {
    /// UNSIGNED_SHORT indices.
    U16(Vec<u16>),
    /// UNSIGNED_INT indices.
    U32(Vec<u32>),
}

/// glTF primitive modes.
pub mod mode {
    /// POINTS.
    pub const POINTS: u32 = 0;
    /// LINES.
    pub const LINES: u32 = 1;
    /// TRIANGLES (the default).
    pub const TRIANGLES: u32 = 4;
    /// TRIANGLE_STRIP.
    pub const TRIANGLE_STRIP: u32 = 5;
    /// TRIANGLE_FAN.
    pub const TRIANGLE_FAN: u32 = 6;
}

/// One mesh primitive.
#[derive(Clone, Debug)]
pub struct Prim {
    /// POSITION.
    pub positions: Vec<[f32; 3]>,
    /// NORMAL.
    pub normals: Option<Vec<[f32; 3]>>,
    /// TEXCOORD_0.
    pub texcoords: Option<Vec<[f32; 2]>>,
    /// Index buffer.
    pub indices: Option<Indices>,
    /// Primitive mode ([`mode`]).
    pub mode: u32,
    /// Material index.
    pub material: Option<usize>,
}

impl Prim {
    /// Non-indexed triangles from positions.
    pub fn new(positions: Vec<[f32; 3]>) -> Self {
        Prim {
            positions,
            normals: None,
            texcoords: None,
            indices: None,
            mode: mode::TRIANGLES,
            material: None,
        }
    }
    /// With normals.
    pub fn normals(mut self, n: Vec<[f32; 3]>) -> Self {
        self.normals = Some(n);
        self
    }
    /// With texture coordinates.
    pub fn texcoords(mut self, uv: Vec<[f32; 2]>) -> Self {
        self.texcoords = Some(uv);
        self
    }
    /// With u16 indices.
    pub fn indices_u16(mut self, i: Vec<u16>) -> Self {
        self.indices = Some(Indices::U16(i));
        self
    }
    /// With u32 indices.
    pub fn indices_u32(mut self, i: Vec<u32>) -> Self {
        self.indices = Some(Indices::U32(i));
        self
    }
    /// With a primitive mode.
    pub fn mode(mut self, m: u32) -> Self {
        self.mode = m;
        self
    }
    /// With a material.
    pub fn material(mut self, m: usize) -> Self {
        self.material = Some(m);
        self
    }
}

/// A material (metallic-roughness plus the extensions Blender writes).
#[derive(Clone, Debug)]
pub struct Material {
    /// Name.
    pub name: Option<String>,
    /// baseColorFactor.
    pub base_color: [f32; 4],
    /// metallicFactor (the builder always writes it; glTF's default would be 1 = mirror).
    pub metallic: f32,
    /// roughnessFactor.
    pub roughness: f32,
    /// emissiveFactor.
    pub emissive: [f32; 3],
    /// KHR_materials_emissive_strength.
    pub emissive_strength: Option<f32>,
    /// KHR_materials_transmission.
    pub transmission: Option<f32>,
    /// KHR_materials_ior.
    pub ior: Option<f32>,
    /// KHR_materials_volume: (thicknessFactor, attenuationDistance, attenuationColor).
    pub volume: Option<(f32, f32, [f32; 3])>,
    /// doubleSided.
    pub double_sided: bool,
    /// KHR_materials_specular specularFactor: `Some(0.0)` by default, so that the builder's
    /// dielectrics are Lambert surfaces (glTF's default without the extension is 1, a GGX layer
    /// over the diffuse base); None writes no extension.
    pub specular: Option<f32>,
    /// alphaMode (`"MASK"` or `"BLEND"`) and alphaCutoff; None: OPAQUE.
    pub alpha_mode: Option<(&'static str, Option<f32>)>,
    /// normalTexture: one tangent-space normal (x, y, z in [−1, 1], +y up the image) as a
    /// uniform 2×2 PNG; the primitive needs TEXCOORD_0 (tangents are generated from it).
    pub normal_map: Option<[f32; 3]>,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            name: None,
            base_color: [1.0; 4],
            metallic: 0.0,
            roughness: 1.0,
            emissive: [0.0; 3],
            emissive_strength: None,
            transmission: None,
            ior: None,
            volume: None,
            double_sided: false,
            specular: Some(0.0),
            alpha_mode: None,
            normal_map: None,
        }
    }
}

impl Material {
    /// A grey Lambert surface (metallic 0, roughness 1).
    pub fn lambert(albedo: f32) -> Self {
        Material {
            base_color: [albedo, albedo, albedo, 1.0],
            ..Default::default()
        }
    }
    /// A black surface emitting `factor × strength`.
    pub fn emitter(factor: [f32; 3], strength: Option<f32>) -> Self {
        Material {
            base_color: [0.0, 0.0, 0.0, 1.0],
            emissive: factor,
            emissive_strength: strength,
            ..Default::default()
        }
    }
    /// Clear glass.
    pub fn glass(ior: Option<f32>) -> Self {
        Material {
            roughness: 0.0,
            transmission: Some(1.0),
            ior,
            ..Default::default()
        }
    }
}

/// A KHR_lights_punctual light.
#[derive(Clone, Debug)]
pub enum Light {
    /// Point light, intensity in candela.
    Point {
        /// cd.
        intensity: f32,
        /// Linear colour.
        color: [f32; 3],
    },
    /// Spot light, intensity in candela, cone half-angles in radians.
    Spot {
        /// cd.
        intensity: f32,
        /// Linear colour.
        color: [f32; 3],
        /// innerConeAngle.
        inner: f32,
        /// outerConeAngle.
        outer: f32,
    },
    /// Sun, intensity in lux.
    Directional {
        /// lx.
        intensity: f32,
        /// Linear colour.
        color: [f32; 3],
    },
}

impl Light {
    /// White point light.
    pub fn point(candela: f32) -> Self {
        Light::Point {
            intensity: candela,
            color: [1.0; 3],
        }
    }
    /// White spot light.
    pub fn spot(candela: f32, inner: f32, outer: f32) -> Self {
        Light::Spot {
            intensity: candela,
            color: [1.0; 3],
            inner,
            outer,
        }
    }
    /// White sun.
    pub fn directional(lux: f32) -> Self {
        Light::Directional {
            intensity: lux,
            color: [1.0; 3],
        }
    }
}

/// A camera.
#[derive(Clone, Debug)]
pub enum Camera {
    /// Perspective (yfov in radians, optional aspect ratio).
    Perspective {
        /// Vertical field of view.
        yfov: f32,
        /// aspectRatio.
        aspect: Option<f32>,
    },
    /// Orthographic (half extents).
    Orthographic {
        /// xmag.
        xmag: f32,
        /// ymag.
        ymag: f32,
    },
}

/// A node's local transform.
#[derive(Clone, Debug, Default)]
pub enum Transform {
    /// Identity (nothing written).
    #[default]
    None,
    /// Translation, rotation quaternion (x, y, z, w), scale.
    Trs {
        /// translation.
        t: [f32; 3],
        /// rotation.
        r: [f32; 4],
        /// scale.
        s: [f32; 3],
    },
    /// Column-major 4×4 matrix.
    Matrix([f32; 16]),
}

impl Transform {
    /// Translation only.
    pub fn translation(t: [f32; 3]) -> Self {
        Transform::Trs {
            t,
            r: [0.0, 0.0, 0.0, 1.0],
            s: [1.0; 3],
        }
    }
    /// Translation and rotation.
    pub fn tr(t: [f32; 3], r: [f32; 4]) -> Self {
        Transform::Trs { t, r, s: [1.0; 3] }
    }
}

/// A node.
#[derive(Clone, Debug, Default)]
pub struct Node {
    /// Name.
    pub name: Option<String>,
    /// Local transform.
    pub transform: Transform,
    /// Mesh index.
    pub mesh: Option<usize>,
    /// Camera index.
    pub camera: Option<usize>,
    /// Light index (KHR_lights_punctual).
    pub light: Option<usize>,
    /// Child node indices.
    pub children: Vec<usize>,
}

/// Where the binary buffer goes.
#[derive(Clone, Debug)]
pub enum BufferMode {
    /// `data:application/octet-stream;base64,...` in the JSON.
    Embedded,
    /// An external file with this URI (the caller decides whether to write it).
    External(String),
    /// The GLB binary chunk.
    Glb,
}

/// A glTF document under construction.
#[derive(Clone, Debug, Default)]
pub struct Gltf {
    bin: Vec<u8>,
    buffer_views: Vec<Value>,
    accessors: Vec<Value>,
    meshes: Vec<Value>,
    materials: Vec<Value>,
    lights: Vec<Value>,
    cameras: Vec<Value>,
    nodes: Vec<Value>,
    roots: Vec<usize>,
    extensions: Vec<&'static str>,
    images: Vec<Value>,
    textures: Vec<Value>,
}

const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

impl Gltf {
    /// An empty document.
    pub fn new() -> Self {
        Self::default()
    }

    fn use_extension(&mut self, e: &'static str) {
        if !self.extensions.contains(&e) {
            self.extensions.push(e);
        }
    }

    /// Append bytes as a buffer view (4-byte aligned); returns the view index.
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.buffer_views.push(v);
        self.buffer_views.len() - 1
    }

    fn accessor(
        &mut self,
        view: usize,
        component: u32,
        count: usize,
        kind: &str,
        minmax: Option<(Value, Value)>,
    ) -> usize {
        let mut a = json!({"bufferView": view, "componentType": component, "count": count, "type": kind});
        if let Some((min, max)) = minmax {
            a["min"] = min;
            a["max"] = max;
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    fn vec3_accessor(&mut self, data: &[[f32; 3]], with_bounds: bool) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        let bounds = with_bounds.then(|| {
            // Finite values only: serde_json would write NaN as null.
            let mut min = [f32::INFINITY; 3];
            let mut max = [f32::NEG_INFINITY; 3];
            for p in data {
                for k in 0..3 {
                    if p[k].is_finite() {
                        min[k] = min[k].min(p[k]);
                        max[k] = max[k].max(p[k]);
                    }
                }
            }
            let fix = |v: [f32; 3]| json!(v.map(|x| if x.is_finite() { x } else { 0.0 }));
            (fix(min), fix(max))
        });
        self.accessor(view, FLOAT, data.len(), "VEC3", bounds)
    }

    /// Add a mesh with these primitives; returns the mesh index.
    pub fn mesh(&mut self, prims: Vec<Prim>) -> usize {
        let mut out = Vec::new();
        for p in prims {
            let mut attributes = Map::new();
            let pos = self.vec3_accessor(&p.positions, true);
            attributes.insert("POSITION".into(), json!(pos));
            if let Some(n) = &p.normals {
                let a = self.vec3_accessor(n, false);
                attributes.insert("NORMAL".into(), json!(a));
            }
            if let Some(uv) = &p.texcoords {
                let bytes: Vec<u8> = uv.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
                let view = self.view(&bytes, Some(ARRAY_BUFFER));
                let a = self.accessor(view, FLOAT, uv.len(), "VEC2", None);
                attributes.insert("TEXCOORD_0".into(), json!(a));
            }
            let mut prim = json!({"attributes": attributes, "mode": p.mode});
            if let Some(ix) = &p.indices {
                let (bytes, component, count): (Vec<u8>, u32, usize) = match ix {
                    Indices::U16(v) => (
                        v.iter().flat_map(|i| i.to_le_bytes()).collect(),
                        UNSIGNED_SHORT,
                        v.len(),
                    ),
                    Indices::U32(v) => (v.iter().flat_map(|i| i.to_le_bytes()).collect(), UNSIGNED_INT, v.len()),
                };
                let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
                let a = self.accessor(view, component, count, "SCALAR", None);
                prim["indices"] = json!(a);
            }
            if let Some(m) = p.material {
                prim["material"] = json!(m);
            }
            out.push(prim);
        }
        self.meshes.push(json!({ "primitives": out }));
        self.meshes.len() - 1
    }

    /// Add a material; returns its index.
    pub fn material(&mut self, m: Material) -> usize {
        let mut v = json!({
            "pbrMetallicRoughness": {
                "baseColorFactor": m.base_color,
                "metallicFactor": m.metallic,
                "roughnessFactor": m.roughness,
            },
            "doubleSided": m.double_sided,
        });
        if let Some(n) = &m.name {
            v["name"] = json!(n);
        }
        if let Some((mode, cutoff)) = m.alpha_mode {
            v["alphaMode"] = json!(mode);
            if let Some(c) = cutoff {
                v["alphaCutoff"] = json!(c);
            }
        }
        if m.emissive != [0.0; 3] {
            v["emissiveFactor"] = json!(m.emissive);
        }
        if let Some(n) = m.normal_map {
            let texel = n.map(|c| ((c.clamp(-1.0, 1.0) * 0.5 + 0.5) * 255.0).round() as u8);
            v["normalTexture"] = json!({ "index": self.uniform_png(texel) });
        }
        let mut ext = Map::new();
        if let Some(s) = m.emissive_strength {
            self.use_extension("KHR_materials_emissive_strength");
            ext.insert(
                "KHR_materials_emissive_strength".into(),
                json!({ "emissiveStrength": s }),
            );
        }
        if let Some(t) = m.transmission {
            self.use_extension("KHR_materials_transmission");
            ext.insert("KHR_materials_transmission".into(), json!({ "transmissionFactor": t }));
        }
        if let Some(f) = m.specular {
            self.use_extension("KHR_materials_specular");
            ext.insert("KHR_materials_specular".into(), json!({ "specularFactor": f }));
        }
        if let Some(i) = m.ior {
            self.use_extension("KHR_materials_ior");
            ext.insert("KHR_materials_ior".into(), json!({ "ior": i }));
        }
        if let Some((thickness, distance, color)) = m.volume {
            self.use_extension("KHR_materials_volume");
            ext.insert(
                "KHR_materials_volume".into(),
                json!({"thicknessFactor": thickness, "attenuationDistance": distance, "attenuationColor": color}),
            );
        }
        if !ext.is_empty() {
            v["extensions"] = Value::Object(ext);
        }
        self.materials.push(v);
        self.materials.len() - 1
    }

    /// A 2×2 PNG of one RGB colour as an image and texture in the buffer; returns the texture.
    fn uniform_png(&mut self, rgb: [u8; 3]) -> usize {
        let img = image::RgbImage::from_pixel(2, 2, image::Rgb(rgb));
        let mut png = std::io::Cursor::new(Vec::new());
        img.write_to(&mut png, image::ImageFormat::Png)
            .expect("PNG encodes in memory");
        let view = self.view(png.get_ref(), None);
        self.images.push(json!({"bufferView": view, "mimeType": "image/png"}));
        self.textures.push(json!({"source": self.images.len() - 1}));
        self.textures.len() - 1
    }

    /// Add a punctual light; returns its index (attach it with [`Node::light`]).
    pub fn light(&mut self, l: Light) -> usize {
        self.use_extension("KHR_lights_punctual");
        let v = match l {
            Light::Point { intensity, color } => json!({"type": "point", "intensity": intensity, "color": color}),
            Light::Spot {
                intensity,
                color,
                inner,
                outer,
            } => json!({"type": "spot", "intensity": intensity, "color": color,
                        "spot": {"innerConeAngle": inner, "outerConeAngle": outer}}),
            Light::Directional { intensity, color } => {
                json!({"type": "directional", "intensity": intensity, "color": color})
            }
        };
        self.lights.push(v);
        self.lights.len() - 1
    }

    /// Add a camera; returns its index.
    pub fn camera(&mut self, c: Camera) -> usize {
        let v = match c {
            Camera::Perspective { yfov, aspect } => {
                let mut p = json!({"yfov": yfov, "znear": 0.05, "zfar": 100.0});
                if let Some(a) = aspect {
                    p["aspectRatio"] = json!(a);
                }
                json!({"type": "perspective", "perspective": p})
            }
            Camera::Orthographic { xmag, ymag } => json!({"type": "orthographic",
                "orthographic": {"xmag": xmag, "ymag": ymag, "znear": 0.01, "zfar": 1000.0}}),
        };
        self.cameras.push(v);
        self.cameras.len() - 1
    }

    /// Add a node (not yet in the scene; see [`Gltf::root`]); returns its index.
    pub fn node(&mut self, n: Node) -> usize {
        let mut v = json!({});
        if let Some(name) = &n.name {
            v["name"] = json!(name);
        }
        match n.transform {
            Transform::None => {}
            Transform::Trs { t, r, s } => {
                v["translation"] = json!(t);
                v["rotation"] = json!(r);
                v["scale"] = json!(s);
            }
            Transform::Matrix(m) => v["matrix"] = json!(m),
        }
        if let Some(m) = n.mesh {
            v["mesh"] = json!(m);
        }
        if let Some(c) = n.camera {
            v["camera"] = json!(c);
        }
        if let Some(l) = n.light {
            v["extensions"] = json!({"KHR_lights_punctual": {"light": l}});
        }
        if !n.children.is_empty() {
            v["children"] = json!(n.children);
        }
        self.nodes.push(v);
        self.nodes.len() - 1
    }

    /// Add a node and put it at the root of the scene.
    pub fn root(&mut self, n: Node) -> usize {
        let i = self.node(n);
        self.roots.push(i);
        i
    }

    /// Put an existing node at the root of the scene.
    pub fn add_root(&mut self, i: usize) {
        self.roots.push(i);
    }

    /// The binary buffer.
    pub fn bin(&self) -> &[u8] {
        &self.bin
    }

    /// The JSON document with the buffer stored as `mode` says.
    pub fn json(&self, mode: &BufferMode) -> Value {
        let mut buffer = json!({ "byteLength": self.bin.len() });
        match mode {
            BufferMode::Embedded => {
                buffer["uri"] = json!(format!("data:application/octet-stream;base64,{}", base64(&self.bin)))
            }
            BufferMode::External(uri) => buffer["uri"] = json!(uri),
            BufferMode::Glb => {}
        }
        let mut doc = json!({
            "asset": {"version": "2.0", "generator": "photongrid tests"},
            "scene": 0,
            "scenes": [{"nodes": self.roots}],
            "nodes": self.nodes,
        });
        let mut put = |key: &str, v: &Vec<Value>| {
            if !v.is_empty() {
                doc[key] = json!(v);
            }
        };
        put("meshes", &self.meshes);
        put("materials", &self.materials);
        put("images", &self.images);
        put("textures", &self.textures);
        put("cameras", &self.cameras);
        put("accessors", &self.accessors);
        put("bufferViews", &self.buffer_views);
        if !self.bin.is_empty() {
            doc["buffers"] = json!([buffer]);
        }
        if !self.lights.is_empty() {
            doc["extensions"] = json!({"KHR_lights_punctual": {"lights": self.lights}});
        }
        if !self.extensions.is_empty() {
            doc["extensionsUsed"] = json!(self.extensions);
        }
        if self.extensions.contains(&"KHR_lights_punctual") {
            doc["extensionsRequired"] = json!(["KHR_lights_punctual"]);
        }
        doc
    }

    /// Write `<dir>/<name>` as a .gltf with the buffer embedded as base64.
    pub fn write_gltf(&self, dir: &Path, name: &str) -> PathBuf {
        let path = dir.join(name);
        let text = serde_json::to_string_pretty(&self.json(&BufferMode::Embedded)).unwrap();
        std::fs::write(&path, text).expect("write .gltf");
        path
    }

    /// Write `<dir>/<name>` as a .gltf referring to the external buffer `bin_name`; the .bin is
    /// written too if `write_bin`.
    pub fn write_gltf_external(&self, dir: &Path, name: &str, bin_name: &str, write_bin: bool) -> PathBuf {
        let path = dir.join(name);
        let text = serde_json::to_string_pretty(&self.json(&BufferMode::External(bin_name.into()))).unwrap();
        std::fs::write(&path, text).expect("write .gltf");
        if write_bin {
            std::fs::write(dir.join(bin_name), &self.bin).expect("write .bin");
        }
        path
    }

    /// Write `<dir>/<name>` as a binary .glb.
    pub fn write_glb(&self, dir: &Path, name: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, glb_bytes(&self.json(&BufferMode::Glb), &self.bin)).expect("write .glb");
        path
    }
}

/// Pack a JSON document and a binary chunk as GLB.
pub fn glb_bytes(doc: &Value, bin: &[u8]) -> Vec<u8> {
    let mut json = serde_json::to_vec(doc).unwrap();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Handy pieces.

/// Rotation quaternion (x, y, z, w) of `angle` radians about a unit `axis`.
pub fn quat(axis: [f32; 3], angle: f32) -> [f32; 4] {
    let (s, c) = (0.5 * angle).sin_cos();
    [axis[0] * s, axis[1] * s, axis[2] * s, c]
}

/// The rotation `a` after `b` (the quaternion product a·b; (x, y, z, w) as [`quat`]).
pub fn quat_mul(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    let ([ax, ay, az, aw], [bx, by, bz, bw]) = (a, b);
    [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]
}

/// The rotation that turns a node's −Z (where cameras and lights point) to straight down (−Y).
pub fn look_down() -> [f32; 4] {
    quat([1.0, 0.0, 0.0], -std::f32::consts::FRAC_PI_2)
}

/// A horizontal square of half-size `h` at height `y`, facing +Y, as two triangles.
pub fn floor_quad(h: f32, y: f32) -> Prim {
    Prim::new(vec![[-h, y, -h], [-h, y, h], [h, y, h], [h, y, -h]])
        .normals(vec![[0.0, 1.0, 0.0]; 4])
        .indices_u16(vec![0, 1, 2, 0, 2, 3])
}

/// A closed UV sphere with outward faces and normals.
pub fn uv_sphere(center: [f32; 3], radius: f32, rings: u32, segments: u32) -> Prim {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for i in 0..=rings {
        let theta = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..=segments {
            let phi = 2.0 * std::f32::consts::PI * j as f32 / segments as f32;
            let n = [theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()];
            normals.push(n);
            positions.push([
                center[0] + radius * n[0],
                center[1] + radius * n[1],
                center[2] + radius * n[2],
            ]);
        }
    }
    let row = segments + 1;
    let mut idx = Vec::new();
    for i in 0..rings {
        for j in 0..segments {
            let a = i * row + j;
            let b = a + row;
            // Counter-clockwise seen from outside; the poles' zero-area triangles are skipped.
            if i != 0 {
                idx.extend_from_slice(&[a, a + 1, b]);
            }
            if i != rings - 1 {
                idx.extend_from_slice(&[a + 1, b + 1, b]);
            }
        }
    }
    Prim::new(positions).normals(normals).indices_u32(idx)
}

/// A test scene: a 20 m Lambert floor (albedo 0.5) at y = 0, a point light of `candela` at
/// height 3 and a perspective camera looking at it.
pub fn simple_scene(candela: f32) -> Gltf {
    let mut g = Gltf::new();
    let m = g.material(Material::lambert(0.5));
    let mesh = g.mesh(vec![floor_quad(10.0, 0.0).material(m)]);
    g.root(Node {
        name: Some("Floor".into()),
        mesh: Some(mesh),
        ..Default::default()
    });
    let l = g.light(Light::point(candela));
    g.root(Node {
        name: Some("Lamp".into()),
        transform: Transform::translation([0.0, 3.0, 0.0]),
        light: Some(l),
        ..Default::default()
    });
    let c = g.camera(Camera::Perspective {
        yfov: 0.8,
        aspect: Some(4.0 / 3.0),
    });
    g.root(Node {
        name: Some("Camera".into()),
        transform: Transform::tr([0.0, 5.0, 0.0], look_down()),
        camera: Some(c),
        ..Default::default()
    });
    g
}

/// The repository's root folder (where `samples/` and `docs/` are).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Path of a file in the repository's `samples/` folder.
pub fn sample(name: &str) -> PathBuf {
    repo_root().join("samples").join(name)
}

/// Split a GLB into its JSON document and its binary chunk (empty if none); `None` if the
/// bytes are not a well-formed GLB. With [`glb_bytes`] it allows hand edits of existing files.
pub fn glb_parts(bytes: &[u8]) -> Option<(Value, Vec<u8>)> {
    let u32_at = |i: usize| Some(u32::from_le_bytes(bytes.get(i..i + 4)?.try_into().ok()?) as usize);
    if bytes.get(0..4)? != b"glTF" {
        return None;
    }
    let json_len = u32_at(12)?;
    let json: Value = serde_json::from_slice(bytes.get(20..20 + json_len)?).ok()?;
    let bin_at = 20 + json_len;
    let bin = match u32_at(bin_at) {
        Some(len) => bytes.get(bin_at + 8..bin_at + 8 + len)?.to_vec(),
        None => Vec::new(),
    };
    Some((json, bin))
}

/// The base scene of the hostile-input corpus (issue 12): a floor and a wall quad, a 2000 cd
/// point light and a camera at (0, 1.5, 5) looking at the wall.
pub fn hostile_base() -> Gltf {
    let mut g = Gltf::new();
    let m = g.material(Material::lambert(0.7));
    let wall = Prim::new(vec![
        [-2.0, 0.0, -2.0],
        [2.0, 0.0, -2.0],
        [2.0, 3.0, -2.0],
        [-2.0, 3.0, -2.0],
    ])
    .normals(vec![[0.0, 0.0, 1.0]; 4])
    .texcoords(vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    .indices_u16(vec![0, 1, 2, 0, 2, 3])
    .material(m);
    let mesh = g.mesh(vec![floor_quad(3.0, 0.0).material(m), wall]);
    g.root(Node {
        name: Some("Room".into()),
        mesh: Some(mesh),
        ..Default::default()
    });
    let l = g.light(Light::point(2000.0));
    g.root(Node {
        name: Some("Lamp".into()),
        transform: Transform::translation([0.0, 2.5, 1.0]),
        light: Some(l),
        ..Default::default()
    });
    let c = g.camera(Camera::Perspective {
        yfov: 0.7,
        aspect: Some(4.0 / 3.0),
    });
    g.root(Node {
        name: Some("Camera".into()),
        transform: Transform::translation([0.0, 1.5, 5.0]),
        camera: Some(c),
        ..Default::default()
    });
    g
}

// ---------------------------------------------------------------------------------------------
// PNG.

/// CRC-32 (IEEE) as PNG chunks use it.
fn crc32(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// A PNG with the IHDR of a `width × height` 8-bit image of `channels` (1 grey, 2 grey+alpha,
/// 3 RGB, 4 RGBA) and `idat` as its compressed data, verbatim.
fn png_with_idat(width: u32, height: u32, channels: u8, idat: &[u8]) -> Vec<u8> {
    let color = match channels {
        1 => 0,
        2 => 4,
        3 => 2,
        _ => 6,
    };
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, color, 0, 0, 0]);
    png_chunk(&mut out, b"IHDR", &ihdr);
    png_chunk(&mut out, b"IDAT", idat);
    png_chunk(&mut out, b"IEND", &[]);
    out
}

/// An uncompressed (stored) PNG of `width × height` 8-bit pixels with `channels` channels,
/// rows top first; `pixels` has `width × height × channels` bytes.
pub fn png_bytes(width: u32, height: u32, channels: u8, pixels: &[u8]) -> Vec<u8> {
    let row = width as usize * channels as usize;
    let mut raw = Vec::with_capacity((row + 1) * height as usize);
    for r in pixels.chunks(row).take(height as usize) {
        raw.push(0); // filter: none
        raw.extend_from_slice(r);
    }
    // zlib: header, stored deflate blocks of at most 65535 bytes, Adler-32.
    let mut z = vec![0x78, 0x01];
    let blocks: Vec<&[u8]> = raw.chunks(65535).collect();
    for (i, block) in blocks.iter().enumerate() {
        z.push((i + 1 == blocks.len()) as u8);
        z.extend_from_slice(&(block.len() as u16).to_le_bytes());
        z.extend_from_slice(&(!(block.len() as u16)).to_le_bytes());
        z.extend_from_slice(block);
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &x in &raw {
        a = (a + x as u32) % 65521;
        b = (b + a) % 65521;
    }
    z.extend_from_slice(&(b << 16 | a).to_be_bytes());
    png_with_idat(width, height, channels, &z)
}

/// A PNG whose header declares `width × height` RGBA pixels but which holds (almost) no pixel
/// data: a tiny file that would decode to a huge image.
pub fn png_header_only(width: u32, height: u32) -> Vec<u8> {
    png_with_idat(
        width,
        height,
        4,
        &[0x78, 0x01, 0x01, 0x00, 0x00, 0xff, 0xff, 0, 0, 0, 1],
    )
}

/// What a run of a binary printed and how it ended.
pub struct Run {
    /// Exit code (None: killed by a signal).
    pub code: Option<i32>,
    /// Standard output.
    pub stdout: String,
    /// Standard error.
    pub stderr: String,
    /// Wall time.
    pub seconds: f64,
}

impl Run {
    /// Exit code 0.
    pub fn ok(&self) -> bool {
        self.code == Some(0)
    }
}

/// Run `binary` with `args`, stdout and stderr into files of `dir` (so a chatty child cannot
/// block), killed after 120 s so a hang (a FIFO opened for writing) fails the test instead of
/// stalling it.
pub fn run_binary(binary: &std::path::Path, dir: &TempDir, args: &[&str]) -> Run {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    static N: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let out_path = dir.join(&format!("stdout-{n}.txt"));
    let err_path = dir.join(&format!("stderr-{n}.txt"));
    let start = Instant::now();
    let mut child = Command::new(binary)
        .args(args)
        .env_remove("RUST_LOG")
        .env("RUST_BACKTRACE", "0")
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("start the binary");
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{} {args:?} did not finish within 120 s", binary.display());
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Run {
        code: status.code(),
        stdout: std::fs::read_to_string(&out_path).unwrap_or_default(),
        stderr: std::fs::read_to_string(&err_path).unwrap_or_default(),
        seconds: start.elapsed().as_secs_f64(),
    }
}
