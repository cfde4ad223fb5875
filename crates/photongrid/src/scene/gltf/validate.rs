//! Validation of the glTF JSON before any reader of the `gltf` crate runs: those readers index,
//! slice and `unreachable!()` on what they assume, and do their bounds arithmetic in `usize`
//! without overflow checks. Everything a reader will touch is checked here, with checked
//! arithmetic, and reported with the element that is wrong:
//!
//! - every index (scene, node, mesh, accessor, bufferView, buffer, image, texture, sampler,
//!   material, camera, light) in range;
//! - bufferViews inside their buffer; accessors (and their sparse parts) inside their
//!   bufferView, with `byteStride` ≥ the element, a count ≥ 1, and the componentType and type
//!   the reader of each attribute semantic (and of indices) expects;
//! - images with exactly one source; cameras and lights with the object their type names;
//! - node transforms finite; the node graph free of cycles, not too deep, and its instancing
//!   counted (node instances, triangles) before anything is expanded.
//!
//! [`Loader::validate_data`] checks what needs the buffers' bytes (sparse indices) once they are
//! read, still before any reader runs.

use super::{LoadError, Loader};
use gltf::json::accessor::{ComponentType, Type};
use gltf::json::mesh::{Mode, Semantic};
use gltf::json::validation::Checked;
use gltf::json::{self, Root};

/// Deepest node nesting accepted (root nodes are at depth 0).
pub(super) const MAX_DEPTH: usize = 256;
/// Most node instances (a node counted once per path from the scene's roots) accepted.
pub(super) const MAX_NODE_INSTANCES: u64 = 1_000_000;
/// Most elements in one accessor (the readers count elements in `u32`).
const MAX_COUNT: u64 = u32::MAX as u64;

/// What a mesh, or a node's subtree, expands to.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Cost {
    /// Node instances.
    pub(super) instances: u64,
    /// Triangles (before degenerate ones are dropped).
    pub(super) triangles: u64,
    /// Vertex attributes and indices read (a mesh is read again for each instance).
    pub(super) reads: u64,
    /// Levels of nodes below.
    height: usize,
}

impl Cost {
    fn add(self, other: Cost) -> Cost {
        Cost {
            instances: self.instances.saturating_add(other.instances),
            triangles: self.triangles.saturating_add(other.triangles),
            reads: self.reads.saturating_add(other.reads),
            height: self.height.max(other.height),
        }
    }
}

/// What the validated file will expand to, for the memory estimate.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Expansion {
    /// The scene's nodes after instancing.
    pub(super) cost: Cost,
    /// Bytes needed while the largest primitive is read (vertices, indices, triangles).
    pub(super) largest_primitive: u64,
    /// Bytes of all buffers as declared.
    pub(super) buffer_bytes: u64,
}

/// The layout one reader expects of an accessor.
#[derive(Clone, Copy)]
struct Expect {
    types: &'static [Type],
    components: &'static [ComponentType],
    /// "FLOAT VEC3", for the message.
    describe: &'static str,
}

const VEC3_FLOAT: Expect = Expect {
    types: &[Type::Vec3],
    components: &[ComponentType::F32],
    describe: "VEC3 of FLOAT (5126)",
};
const TEXCOORD: Expect = Expect {
    types: &[Type::Vec2],
    components: &[ComponentType::F32, ComponentType::U8, ComponentType::U16],
    describe: "VEC2 of FLOAT (5126), UNSIGNED_BYTE (5121) or UNSIGNED_SHORT (5123)",
};
const INDICES: Expect = Expect {
    types: &[Type::Scalar],
    components: &[ComponentType::U8, ComponentType::U16, ComponentType::U32],
    describe: "SCALAR of UNSIGNED_BYTE (5121), UNSIGNED_SHORT (5123) or UNSIGNED_INT (5125)",
};

/// glTF name of an accessor type.
fn type_name(t: Type) -> &'static str {
    match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

/// glTF name of a component type.
fn component_name(c: ComponentType) -> String {
    let name = match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    };
    format!("{} ({name})", c.as_gl_enum())
}

/// The scene a load renders: `scene`, else the first.
pub(super) fn scene_index(root: &Root) -> Option<usize> {
    match &root.scene {
        Some(s) => Some(s.value()),
        None => (!root.scenes.is_empty()).then_some(0),
    }
}

/// Triangles a primitive of `mode` makes from `n` vertices (or indices).
pub(super) fn triangles_of(mode: Mode, n: u64) -> u64 {
    match mode {
        Mode::Triangles => n / 3,
        Mode::TriangleStrip | Mode::TriangleFan => n.saturating_sub(2),
        _ => 0,
    }
}

impl Loader<'_> {
    /// All checks that need only the JSON; returns what the file expands to.
    pub(super) fn validate(&self, root: &Root) -> Result<Expansion, LoadError> {
        self.check_references(root)?;
        self.check_views(root)?;
        let (meshes, largest_primitive) = self.check_meshes(root)?;
        self.check_images(root)?;
        self.check_cameras_and_lights(root)?;
        self.check_transforms(root)?;
        let mut expansion = Expansion {
            cost: self.check_node_graph(root, &meshes)?,
            largest_primitive,
            ..Default::default()
        };
        expansion.buffer_bytes = root
            .buffers
            .iter()
            .fold(0u64, |sum, b| sum.saturating_add(b.byte_length.0));
        Ok(expansion)
    }

    /// `index` must be below `len`: `element` refers to `what[index]`.
    fn in_range(
        &self,
        element: impl FnOnce() -> String,
        what: &str,
        index: usize,
        len: usize,
    ) -> Result<(), LoadError> {
        if index < len {
            return Ok(());
        }
        Err(self.invalid(
            element(),
            format!("refers to {what}[{index}], but the file has {len} {what}"),
        ))
    }

    fn check_references(&self, root: &Root) -> Result<(), LoadError> {
        if let Some(s) = &root.scene {
            self.in_range(|| "scene".into(), "scenes", s.value(), root.scenes.len())?;
        }
        for (s, scene) in root.scenes.iter().enumerate() {
            for (k, n) in scene.nodes.iter().enumerate() {
                self.in_range(
                    || format!("scenes[{s}].nodes[{k}]"),
                    "nodes",
                    n.value(),
                    root.nodes.len(),
                )?;
            }
        }
        self.check_node_references(root)?;
        self.check_mesh_references(root)?;
        self.check_material_references(root)?;
        for (a, acc) in root.accessors.iter().enumerate() {
            let views = root.buffer_views.len();
            if let Some(v) = &acc.buffer_view {
                self.in_range(|| format!("accessors[{a}].bufferView"), "bufferViews", v.value(), views)?;
            }
            if let Some(s) = &acc.sparse {
                let (i, v) = (s.indices.buffer_view.value(), s.values.buffer_view.value());
                self.in_range(
                    || format!("accessors[{a}].sparse.indices.bufferView"),
                    "bufferViews",
                    i,
                    views,
                )?;
                self.in_range(
                    || format!("accessors[{a}].sparse.values.bufferView"),
                    "bufferViews",
                    v,
                    views,
                )?;
            }
        }
        for (v, view) in root.buffer_views.iter().enumerate() {
            let b = view.buffer.value();
            self.in_range(|| format!("bufferViews[{v}].buffer"), "buffers", b, root.buffers.len())?;
        }
        for (i, image) in root.images.iter().enumerate() {
            if let Some(v) = &image.buffer_view {
                let n = root.buffer_views.len();
                self.in_range(|| format!("images[{i}].bufferView"), "bufferViews", v.value(), n)?;
            }
        }
        for (t, texture) in root.textures.iter().enumerate() {
            let s = texture.source.value();
            self.in_range(|| format!("textures[{t}].source"), "images", s, root.images.len())?;
            if let Some(s) = &texture.sampler {
                let n = root.samplers.len();
                self.in_range(|| format!("textures[{t}].sampler"), "samplers", s.value(), n)?;
            }
        }
        Ok(())
    }

    fn check_node_references(&self, root: &Root) -> Result<(), LoadError> {
        let lights = light_count(root);
        for (i, node) in root.nodes.iter().enumerate() {
            for (k, c) in node.children.iter().flatten().enumerate() {
                let n = root.nodes.len();
                self.in_range(|| format!("nodes[{i}].children[{k}]"), "nodes", c.value(), n)?;
            }
            if let Some(m) = &node.mesh {
                self.in_range(|| format!("nodes[{i}].mesh"), "meshes", m.value(), root.meshes.len())?;
            }
            if let Some(c) = &node.camera {
                self.in_range(
                    || format!("nodes[{i}].camera"),
                    "cameras",
                    c.value(),
                    root.cameras.len(),
                )?;
            }
            if let Some(s) = &node.skin {
                self.in_range(|| format!("nodes[{i}].skin"), "skins", s.value(), root.skins.len())?;
            }
            if let Some(l) = node_light(node) {
                let element = || format!("nodes[{i}].extensions.KHR_lights_punctual.light");
                self.in_range(element, "KHR_lights_punctual lights", l, lights)?;
            }
        }
        Ok(())
    }

    fn check_mesh_references(&self, root: &Root) -> Result<(), LoadError> {
        let accessors = root.accessors.len();
        for (m, mesh) in root.meshes.iter().enumerate() {
            for (p, prim) in mesh.primitives.iter().enumerate() {
                let at = format!("meshes[{m}].primitives[{p}]");
                for (semantic, a) in &prim.attributes {
                    let element = || format!("{at}.attributes.{}", semantic_name(semantic));
                    self.in_range(element, "accessors", a.value(), accessors)?;
                }
                if let Some(a) = &prim.indices {
                    self.in_range(|| format!("{at}.indices"), "accessors", a.value(), accessors)?;
                }
                if let Some(mat) = &prim.material {
                    let n = root.materials.len();
                    self.in_range(|| format!("{at}.material"), "materials", mat.value(), n)?;
                }
                for (t, target) in prim.targets.iter().flatten().enumerate() {
                    for (name, a) in [
                        ("POSITION", &target.positions),
                        ("NORMAL", &target.normals),
                        ("TANGENT", &target.tangents),
                    ] {
                        if let Some(a) = a {
                            let element = || format!("{at}.targets[{t}].{name}");
                            self.in_range(element, "accessors", a.value(), accessors)?;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn check_material_references(&self, root: &Root) -> Result<(), LoadError> {
        for (m, material) in root.materials.iter().enumerate() {
            for (name, index) in material_textures(material) {
                let element = || format!("materials[{m}].{name}.index");
                self.in_range(element, "textures", index, root.textures.len())?;
            }
        }
        Ok(())
    }

    /// Every bufferView inside its buffer, with a byteStride glTF allows.
    fn check_views(&self, root: &Root) -> Result<(), LoadError> {
        for (v, view) in root.buffer_views.iter().enumerate() {
            let element = || format!("bufferViews[{v}]{}", view_users(root, v));
            let b = view.buffer.value();
            let buffer_len = root.buffers[b].byte_length.0;
            let offset = view.byte_offset.map(|o| o.0).unwrap_or(0);
            let length = view.byte_length.0;
            let Some(end) = offset.checked_add(length) else {
                let what = format!("byteOffset {offset} + byteLength {length} overflows 64 bits");
                return Err(self.invalid(element(), what));
            };
            if end > buffer_len {
                return Err(self.invalid(
                    element(),
                    format!("spans bytes {offset}..{end} but buffers[{b}] has {buffer_len} (its byteLength)"),
                ));
            }
            if let Some(stride) = view.byte_stride {
                if !(4..=252).contains(&stride.0) {
                    let what = format!("byteStride {} is outside the 4..252 glTF allows", stride.0);
                    return Err(self.invalid(element(), what));
                }
            }
        }
        Ok(())
    }

    /// The accessors of every triangle primitive; returns the cost of reading each mesh once
    /// and the bytes needed to read the largest primitive.
    fn check_meshes(&self, root: &Root) -> Result<(Vec<Cost>, u64), LoadError> {
        let mut costs = Vec::with_capacity(root.meshes.len());
        let mut largest = 0u64;
        for (m, mesh) in root.meshes.iter().enumerate() {
            let mut sum = Cost::default();
            for (p, prim) in mesh.primitives.iter().enumerate() {
                let (cost, bytes) = self.check_primitive(root, prim, &format!("meshes[{m}].primitives[{p}]"))?;
                sum = sum.add(cost);
                largest = largest.max(bytes);
            }
            costs.push(sum);
        }
        Ok((costs, largest))
    }

    /// One primitive: its cost and the bytes its vertex data takes while read.
    fn check_primitive(&self, root: &Root, prim: &json::mesh::Primitive, at: &str) -> Result<(Cost, u64), LoadError> {
        let Checked::Valid(mode) = prim.mode else {
            return Err(self.invalid(at, "mode is not one of the glTF primitive modes 0..6"));
        };
        if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
            return Ok((Cost::default(), 0)); // Not read: reported as ignored by the mesh reader.
        }
        let count = |semantic: &Semantic| {
            prim.attributes
                .get(&Checked::Valid(semantic.clone()))
                .map(|a| root.accessors[a.value()].count.0)
                .unwrap_or(0)
        };
        let (positions, normals, uvs) = (
            count(&Semantic::Positions),
            count(&Semantic::Normals),
            count(&Semantic::TexCoords(0)),
        );
        if !prim.attributes.contains_key(&Checked::Valid(Semantic::Positions)) {
            return Err(self.invalid(at, "has no POSITION attribute"));
        }
        for (semantic, a) in &prim.attributes {
            let name = semantic_name(semantic);
            let expect = match semantic {
                Checked::Valid(Semantic::Positions) | Checked::Valid(Semantic::Normals) => Some(VEC3_FLOAT),
                Checked::Valid(Semantic::TexCoords(0)) => Some(TEXCOORD),
                _ => None,
            };
            self.check_accessor(root, a.value(), &format!("{name} of {at}"), expect)?;
        }
        let indices = match &prim.indices {
            Some(a) => {
                self.check_accessor(root, a.value(), &format!("indices of {at}"), Some(INDICES))?;
                root.accessors[a.value()].count.0
            }
            None => positions,
        };
        let triangles = triangles_of(mode, indices);
        // Positions and world positions, normals twice, uvs, indices, index triples.
        let bytes = [(positions, 24), (normals, 24), (uvs, 8), (indices, 4), (triangles, 12)]
            .iter()
            .fold(0u64, |sum, &(n, size)| sum.saturating_add(n.saturating_mul(size)));
        let reads = [positions, normals, uvs, indices]
            .iter()
            .fold(0u64, |s, n| s.saturating_add(*n));
        let cost = Cost {
            triangles,
            reads,
            ..Default::default()
        };
        Ok((cost, bytes))
    }

    /// An accessor's types, count and bytes (`role`: what it is read as, for the message).
    fn check_accessor(&self, root: &Root, a: usize, role: &str, expect: Option<Expect>) -> Result<(), LoadError> {
        let acc = &root.accessors[a];
        let element = format!("accessors[{a}] ({role})");
        let (Checked::Valid(component), Checked::Valid(kind)) = (acc.component_type, acc.type_) else {
            let what = "componentType or type is not one the glTF specification defines";
            return Err(self.invalid(element, what));
        };
        let component = component.0;
        if let Some(e) = expect {
            if !e.types.contains(&kind) || !e.components.contains(&component) {
                let what = format!(
                    "is {} of {}, but {} must be {}",
                    type_name(kind),
                    component_name(component),
                    role.split(' ').next().unwrap_or(role),
                    e.describe
                );
                return Err(self.invalid(element, what));
            }
        }
        let count = acc.count.0;
        if count == 0 || count > MAX_COUNT {
            let what = format!("count {count} must be between 1 and {MAX_COUNT}");
            return Err(self.invalid(element, what));
        }
        let size = (component.size() * kind.multiplicity()) as u64;
        let offset = acc.byte_offset.map(|o| o.0).unwrap_or(0);
        match (&acc.buffer_view, &acc.sparse) {
            (Some(v), _) => self.check_span(root, v.value(), offset, count, size, &element)?,
            (None, None) => {
                let what = "accessor has no bufferView (zero-filled accessors are not supported)";
                return Err(self.invalid(element, what));
            }
            (None, Some(_)) => {}
        }
        if let Some(sparse) = &acc.sparse {
            self.check_sparse(root, sparse, count, size, &element)?;
        }
        Ok(())
    }

    /// `count` elements of `size` bytes from `offset` in bufferView `v` (stride from the view)
    /// must lie inside the view, computed without wrapping.
    fn check_span(
        &self,
        root: &Root,
        v: usize,
        offset: u64,
        count: u64,
        size: u64,
        element: &str,
    ) -> Result<(), LoadError> {
        let view = &root.buffer_views[v];
        let stride = view.byte_stride.map(|s| s.0 as u64).unwrap_or(size);
        if stride < size {
            let what = format!("byteStride {stride} (of bufferViews[{v}]) is smaller than the element ({size} bytes)");
            return Err(self.invalid(element, what));
        }
        let end = stride
            .checked_mul(count - 1)
            .and_then(|n| n.checked_add(offset))
            .and_then(|n| n.checked_add(size));
        let length = view.byte_length.0;
        match end {
            Some(end) if end <= length => Ok(()),
            Some(end) => Err(self.invalid(
                element,
                format!("needs {end} bytes ({count} elements of {size} bytes, stride {stride}, from byte {offset}) but bufferViews[{v}] has {length}"),
            )),
            None => Err(self.invalid(
                element,
                format!("{count} elements of stride {stride} from byte {offset} overflow 64 bits"),
            )),
        }
    }

    fn check_sparse(
        &self,
        root: &Root,
        sparse: &json::accessor::sparse::Sparse,
        count: u64,
        size: u64,
        element: &str,
    ) -> Result<(), LoadError> {
        let n = sparse.count.0;
        if n == 0 || n > count {
            let what = format!("sparse.count {n} must be between 1 and the accessor's count {count}");
            return Err(self.invalid(element, what));
        }
        let Checked::Valid(index_type) = sparse.indices.component_type else {
            let what = "sparse.indices.componentType must be 5121, 5123 or 5125";
            return Err(self.invalid(element, what));
        };
        let (i, v) = (&sparse.indices, &sparse.values);
        let index_size = index_type.0.size() as u64;
        let at = format!("{element}.sparse.indices");
        self.check_span(root, i.buffer_view.value(), i.byte_offset.0, n, index_size, &at)?;
        let at = format!("{element}.sparse.values");
        self.check_span(root, v.buffer_view.value(), v.byte_offset.0, n, size, &at)
    }

    /// Images have exactly one source.
    fn check_images(&self, root: &Root) -> Result<(), LoadError> {
        for (i, image) in root.images.iter().enumerate() {
            match (&image.uri, &image.buffer_view) {
                (None, None) => return Err(self.invalid(format!("images[{i}]"), "has neither a uri nor a bufferView")),
                (Some(_), Some(_)) => {
                    return Err(self.invalid(format!("images[{i}]"), "has both a uri and a bufferView"))
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// Cameras and lights carry the object their type names.
    fn check_cameras_and_lights(&self, root: &Root) -> Result<(), LoadError> {
        use json::camera::Type as CameraType;
        for (c, cam) in root.cameras.iter().enumerate() {
            let ok = match cam.type_ {
                Checked::Valid(CameraType::Perspective) => cam.perspective.is_some(),
                Checked::Valid(CameraType::Orthographic) => cam.orthographic.is_some(),
                Checked::Invalid => false,
            };
            if !ok {
                let what = "type must be \"perspective\" or \"orthographic\", with the object of that name";
                return Err(self.invalid(format!("cameras[{c}]"), what));
            }
        }
        let lights = root.extensions.as_ref().and_then(|e| e.khr_lights_punctual.as_ref());
        for (l, light) in lights.iter().flat_map(|x| x.lights.iter()).enumerate() {
            use json::extensions::scene::khr_lights_punctual::Type as LightType;
            let ok = match light.type_ {
                Checked::Valid(LightType::Spot) => light.spot.is_some(),
                Checked::Valid(_) => true,
                Checked::Invalid => false,
            };
            if !ok {
                let what = "type must be \"point\", \"spot\" (with a \"spot\" object) or \"directional\"";
                return Err(self.invalid(format!("KHR_lights_punctual.lights[{l}]"), what));
            }
        }
        Ok(())
    }

    /// Node transforms are finite (JSON numbers beyond ±3.4e38 become infinite in 32 bits).
    fn check_transforms(&self, root: &Root) -> Result<(), LoadError> {
        for (i, node) in root.nodes.iter().enumerate() {
            let parts: [(&str, &[f32]); 4] = [
                ("matrix", node.matrix.as_ref().map(|m| &m[..]).unwrap_or(&[])),
                ("translation", node.translation.as_ref().map(|t| &t[..]).unwrap_or(&[])),
                ("rotation", node.rotation.as_ref().map(|r| &r.0[..]).unwrap_or(&[])),
                ("scale", node.scale.as_ref().map(|s| &s[..]).unwrap_or(&[])),
            ];
            for (name, values) in parts {
                if let Some(x) = values.iter().find(|x| !x.is_finite()) {
                    let what = format!("{name} has the value {x}: numbers must be finite 32-bit floats (|x| < 3.4e38)");
                    return Err(self.invalid(format!("nodes[{i}]"), what));
                }
            }
        }
        Ok(())
    }
}

impl Loader<'_> {
    /// The node graph of the scene that is rendered: no cycles, at most [`MAX_DEPTH`] levels,
    /// and its expansion (a node under k parents is expanded k times) counted without expanding.
    fn check_node_graph(&self, root: &Root, meshes: &[Cost]) -> Result<Cost, LoadError> {
        let Some(s) = scene_index(root) else {
            return Err(self.invalid("scenes", "the file has no scene"));
        };
        let nodes = self.node_expansions(root, s, meshes)?;
        let mut total = Cost::default();
        for r in &root.scenes[s].nodes {
            let cost = nodes[r.value()];
            if cost.height > MAX_DEPTH {
                let what = format!(
                    "node hierarchy is nested {} levels deep (cyclic or absurdly deep; at most {MAX_DEPTH} are supported)",
                    cost.height
                );
                return Err(self.invalid(format!("nodes[{}]", r.value()), what));
            }
            total = total.add(cost);
        }
        if total.instances > MAX_NODE_INSTANCES {
            let what = format!(
                "{}; at most {MAX_NODE_INSTANCES} node instances are supported",
                expands(&total)
            );
            return Err(self.invalid(format!("scenes[{s}]"), what));
        }
        Ok(total)
    }

    /// The work of a load (vertex attributes and indices read, a mesh once per instance) must
    /// stay below `max_reads`; checked after the memory estimate, which explains a single huge
    /// mesh better.
    pub(super) fn check_reads(&self, root: &Root, total: &Cost, max_reads: u64) -> Result<(), LoadError> {
        if total.reads <= max_reads {
            return Ok(());
        }
        let what = format!(
            "{}, which would read {} vertex attributes and indices; at most {max_reads} are read in one load",
            expands(total),
            total.reads
        );
        Err(self.invalid(format!("scenes[{}]", scene_index(root).unwrap_or(0)), what))
    }

    /// The cost of each node's subtree for the nodes reachable from scene `s`, by an iterative
    /// depth-first walk that visits each node once and stops at the first cycle.
    fn node_expansions(&self, root: &Root, s: usize, meshes: &[Cost]) -> Result<Vec<Cost>, LoadError> {
        const NEW: u8 = 0;
        const OPEN: u8 = 1;
        let children = |i: usize| root.nodes[i].children.as_deref().unwrap_or(&[]);
        let mut state = vec![NEW; root.nodes.len()];
        let mut costs = vec![Cost::default(); root.nodes.len()];
        for r in &root.scenes[s].nodes {
            if state[r.value()] != NEW {
                continue;
            }
            state[r.value()] = OPEN;
            let mut stack: Vec<(usize, usize)> = vec![(r.value(), 0)];
            while let Some(top) = stack.last_mut() {
                let (node, next) = *top;
                if let Some(child) = children(node).get(next) {
                    top.1 += 1;
                    let c = child.value();
                    if state[c] == OPEN {
                        return Err(self.cycle(&stack, c));
                    }
                    if state[c] == NEW {
                        state[c] = OPEN;
                        stack.push((c, 0));
                    }
                    continue;
                }
                stack.pop();
                state[node] = 2; // done
                let own = Cost {
                    instances: 1,
                    ..root.nodes[node].mesh.map(|m| meshes[m.value()]).unwrap_or_default()
                };
                costs[node] = children(node).iter().fold(own, |sum, c| {
                    let below = costs[c.value()];
                    sum.add(Cost {
                        height: below.height + 1,
                        ..below
                    })
                });
            }
        }
        Ok(costs)
    }

    /// The error for a cycle closed by an edge back to `to`, which is on the walk's `stack`.
    fn cycle(&self, stack: &[(usize, usize)], to: usize) -> LoadError {
        let start = stack.iter().position(|&(n, _)| n == to).unwrap_or(0);
        let mut path: Vec<String> = stack[start..].iter().map(|&(n, _)| format!("nodes[{n}]")).collect();
        if path.len() > 8 {
            path.drain(4..path.len() - 3);
            path.insert(4, "…".into());
        }
        path.push(format!("nodes[{to}]"));
        self.invalid(
            format!("nodes[{to}]"),
            format!(
                "node hierarchy is cyclic: {} (a node cannot contain itself)",
                path.join(" → ")
            ),
        )
    }

    /// Checks that need the buffers' bytes, before any reader runs: the indices of sparse
    /// accessors of triangle primitives lie below the accessor's count and strictly increase.
    pub(super) fn validate_data(&self, root: &Root, buffers: &[Vec<u8>]) -> Result<(), LoadError> {
        for (m, mesh) in root.meshes.iter().enumerate() {
            for (p, prim) in mesh.primitives.iter().enumerate() {
                if !matches!(
                    prim.mode,
                    Checked::Valid(Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan)
                ) {
                    continue; // Not read.
                }
                let accessors = prim.attributes.values().chain(prim.indices.iter());
                for a in accessors {
                    let acc = &root.accessors[a.value()];
                    if let Some(sparse) = &acc.sparse {
                        let element = format!(
                            "accessors[{}] (of meshes[{m}].primitives[{p}]).sparse.indices",
                            a.value()
                        );
                        self.check_sparse_indices(root, sparse, acc.count.0, buffers, &element)?;
                    }
                }
            }
        }
        Ok(())
    }

    fn check_sparse_indices(
        &self,
        root: &Root,
        sparse: &json::accessor::sparse::Sparse,
        count: u64,
        buffers: &[Vec<u8>],
        element: &str,
    ) -> Result<(), LoadError> {
        let Checked::Valid(kind) = sparse.indices.component_type else {
            return Ok(()); // Refused by `validate`.
        };
        let view = &root.buffer_views[sparse.indices.buffer_view.value()];
        let size = kind.0.size();
        let stride = view.byte_stride.map(|s| s.0).unwrap_or(size);
        let start = view.byte_offset.map(|o| o.0).unwrap_or(0) + sparse.indices.byte_offset.0;
        let data = buffers.get(view.buffer.value()).map(|b| b.as_slice()).unwrap_or(&[]);
        let mut previous: Option<u64> = None;
        for k in 0..sparse.count.0 {
            let at = (start + k * stride as u64) as usize;
            let Some(bytes) = data.get(at..at + size) else {
                return Err(self.invalid(element, format!("index {k} lies outside its buffer")));
            };
            let index = bytes.iter().rev().fold(0u64, |v, &b| v << 8 | b as u64);
            if index >= count || previous.is_some_and(|p| index <= p) {
                let what = format!("index {k} is {index}: sparse indices must increase strictly and stay below the accessor's count {count}");
                return Err(self.invalid(element, what));
            }
            previous = Some(index);
        }
        Ok(())
    }
}

/// What a scene's node hierarchy expands to, for messages.
fn expands(total: &Cost) -> String {
    format!(
        "the node hierarchy expands to {} node instances and {} triangles (nodes used as children of several parents multiply their subtrees)",
        total.instances, total.triangles
    )
}

/// ` (accessors[2], images[0])`: what reads bufferView `v`, for messages.
fn view_users(root: &Root, v: usize) -> String {
    let mut users: Vec<String> = Vec::new();
    for (a, acc) in root.accessors.iter().enumerate() {
        let sparse = acc
            .sparse
            .as_ref()
            .map(|s| [s.indices.buffer_view.value(), s.values.buffer_view.value()]);
        if acc.buffer_view.map(|b| b.value()) == Some(v) || sparse.is_some_and(|s| s.contains(&v)) {
            users.push(format!("accessors[{a}]"));
        }
    }
    for (i, image) in root.images.iter().enumerate() {
        if image.buffer_view.map(|b| b.value()) == Some(v) {
            users.push(format!("images[{i}]"));
        }
    }
    if users.len() > 4 {
        let more = users.len() - 3;
        users.truncate(3);
        users.push(format!("{more} more"));
    }
    match users.is_empty() {
        true => String::new(),
        false => format!(" ({})", users.join(", ")),
    }
}

/// The KHR_lights_punctual light a node carries.
pub(super) fn node_light(node: &json::Node) -> Option<usize> {
    let ext = node.extensions.as_ref()?.khr_lights_punctual.as_ref()?;
    Some(ext.light.value())
}

fn light_count(root: &Root) -> usize {
    root.extensions
        .as_ref()
        .and_then(|e| e.khr_lights_punctual.as_ref())
        .map(|l| l.lights.len())
        .unwrap_or(0)
}

/// The textures a material refers to, by property name.
fn material_textures(m: &json::Material) -> Vec<(&'static str, usize)> {
    let pbr = &m.pbr_metallic_roughness;
    let mut out = Vec::new();
    let mut add = |name: &'static str, index: Option<usize>| {
        if let Some(i) = index {
            out.push((name, i));
        }
    };
    add(
        "pbrMetallicRoughness.baseColorTexture",
        pbr.base_color_texture.as_ref().map(|t| t.index.value()),
    );
    add(
        "pbrMetallicRoughness.metallicRoughnessTexture",
        pbr.metallic_roughness_texture.as_ref().map(|t| t.index.value()),
    );
    add("normalTexture", m.normal_texture.as_ref().map(|t| t.index.value()));
    add(
        "occlusionTexture",
        m.occlusion_texture.as_ref().map(|t| t.index.value()),
    );
    add("emissiveTexture", m.emissive_texture.as_ref().map(|t| t.index.value()));
    if let Some(ext) = &m.extensions {
        let tex = |t: &Option<json::texture::Info>| t.as_ref().map(|t| t.index.value());
        add(
            "extensions.KHR_materials_transmission.transmissionTexture",
            ext.transmission.as_ref().and_then(|t| tex(&t.transmission_texture)),
        );
        add(
            "extensions.KHR_materials_volume.thicknessTexture",
            ext.volume.as_ref().and_then(|v| tex(&v.thickness_texture)),
        );
        add(
            "extensions.KHR_materials_specular.specularTexture",
            ext.specular.as_ref().and_then(|s| tex(&s.specular_texture)),
        );
        add(
            "extensions.KHR_materials_specular.specularColorTexture",
            ext.specular.as_ref().and_then(|s| tex(&s.specular_color_texture)),
        );
    }
    out
}

/// glTF spelling of an attribute semantic.
fn semantic_name(s: &Checked<Semantic>) -> String {
    match s {
        Checked::Valid(s) => s.to_string(),
        Checked::Invalid => "(unknown semantic)".into(),
    }
}
