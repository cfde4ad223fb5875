//! The node hierarchy and its meshes: transforms, primitives and accessors → world-space
//! [`Triangle`]s; cameras and punctual lights are collected on the way.

use super::lights::{light_of, PunctualKind};
use super::tangents;
use super::{Inputs, LoadError, Loader, MAX_COORDINATE};
use crate::scene::{Camera, Material, Triangle};
use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};
use gltf::mesh::Mode;

/// What the walk over the node hierarchy found.
pub(super) struct NodeContent {
    /// World-space triangles.
    pub(super) triangles: Vec<Triangle>,
    /// Their tangents (see [`crate::scene::Scene::tangents`]).
    pub(super) tangents: Vec<[Vec4; 3]>,
    /// Cameras, in the order their nodes were visited.
    pub(super) cameras: Vec<Camera>,
    /// Punctual lights: node index, node name, light, world transform.
    pub(super) punctual: Vec<(usize, Option<String>, PunctualKind, Mat4)>,
}

/// One placement of a mesh: the node that carries it and the node's world transform.
struct Instance<'n, 'a> {
    node: &'n gltf::Node<'a>,
    world: Mat4,
    default_material: u32,
    /// Materials with a normal map (their primitives need tangents); empty if none has one.
    normal_mapped: &'n [bool],
}

impl Instance<'_, '_> {
    /// `nodes[3] 'Floor'`, for messages.
    fn describe(&self) -> String {
        match self.node.name() {
            Some(name) => format!("nodes[{}] '{name}'", self.node.index()),
            None => format!("nodes[{}]", self.node.index()),
        }
    }
}

/// One primitive's vertex data as read from its accessors.
struct Vertices {
    positions: Vec<Vec3>,
    normals: Option<Vec<Vec3>>,
    uvs: Option<Vec<Vec2>>,
    tangents: Option<Vec<Vec4>>,
    indices: Vec<u32>,
}

impl Loader<'_> {
    /// Walk the default scene's node tree (validated: acyclic, bounded depth and expansion).
    pub(super) fn nodes(
        &mut self,
        inputs: &Inputs,
        default_material: u32,
        triangles: usize,
        materials: &[Material],
    ) -> Result<NodeContent, LoadError> {
        let normal_mapped: Vec<bool> = if materials.iter().any(|m| m.normal_map.is_some()) {
            materials.iter().map(|m| m.normal_map.is_some()).collect()
        } else {
            Vec::new()
        };
        let doc = inputs.doc;
        let scene = doc
            .default_scene()
            .or_else(|| doc.scenes().next())
            .ok_or_else(|| self.invalid("scenes", "the file has no scene"))?;
        let mut out = NodeContent {
            triangles: Vec::with_capacity(triangles),
            tangents: Vec::new(),
            cameras: Vec::new(),
            punctual: Vec::new(),
        };
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
                let instance = Instance {
                    node: &node,
                    world,
                    default_material,
                    normal_mapped: &normal_mapped,
                };
                self.mesh(&mesh, &instance, inputs.buffers, &mut out)?;
            }
            if let Some(cam) = node.camera() {
                out.cameras.push(self.camera(&node, &cam, world)?);
            }
            if let Some(light) = node.light() {
                out.punctual
                    .push((node.index(), node.name().map(str::to_string), light_of(&light), world));
            }
            for child in node.children() {
                stack.push((child, world, depth + 1));
            }
        }
        Ok(out)
    }

    fn mesh(
        &mut self,
        mesh: &gltf::Mesh,
        instance: &Instance,
        buffers: &[Vec<u8>],
        out: &mut NodeContent,
    ) -> Result<(), LoadError> {
        for prim in mesh.primitives() {
            let element = format!("meshes[{}].primitives[{}]", mesh.index(), prim.index());
            let mode = prim.mode();
            if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                self.report
                    .ignored
                    .push(format!("{element}: mode {mode:?} is not triangles"));
                continue;
            }
            let vertices = self.read_vertices(&prim, buffers, &element)?;
            let tris = self.triangulate(mode, &vertices.indices, &element);
            let material = prim.material().index().map(|i| i as u32);
            let material = material.unwrap_or(instance.default_material);
            let tangents = match instance.normal_mapped.get(material as usize) {
                Some(true) => Some(self.tangents(&vertices, &tris, &element)),
                _ => None,
            };
            let first = out.triangles.len();
            let placed = self.place(&vertices, &tris, instance, material, &element, &mut out.triangles)?;
            if !instance.normal_mapped.is_empty() {
                let world = Mat3::from_mat4(instance.world);
                let sign = world.determinant().signum();
                for (k, &t) in placed.iter().enumerate() {
                    let tan = match &tangents {
                        Some(ts) => {
                            let mut v = ts[t].map(|c| {
                                let xyz = (world * c.truncate()).normalize_or_zero();
                                xyz.extend(c.w * sign)
                            });
                            if sign < 0.0 {
                                v.swap(1, 2); // as the triangle's vertices
                            }
                            v
                        }
                        None => [Vec4::ZERO; 3],
                    };
                    debug_assert_eq!(out.tangents.len(), first + k);
                    out.tangents.push(tan);
                }
            }
        }
        Ok(())
    }

    /// Read POSITION, NORMAL, TEXCOORD_0 and the indices of a primitive.
    fn read_vertices(&self, prim: &gltf::Primitive, buffers: &[Vec<u8>], element: &str) -> Result<Vertices, LoadError> {
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| d.as_slice()));
        let positions: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| {
                self.invalid(
                    element,
                    "POSITION is missing or has no bufferView (zero-filled accessors are not supported)",
                )
            })?
            .map(Vec3::from)
            .collect();
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(self.invalid(element, format!("POSITION[{i}] is not finite ({})", positions[i])));
        }
        let n = positions.len();
        let normals: Option<Vec<Vec3>> = reader.read_normals().map(|it| it.map(Vec3::from).collect());
        if let Some(ns) = &normals {
            if ns.len() != n {
                return Err(self.invalid(element, format!("NORMAL has {} entries, POSITION {n}", ns.len())));
            }
            if let Some(i) = ns.iter().position(|v| !v.is_finite()) {
                return Err(self.invalid(element, format!("NORMAL[{i}] is not finite ({})", ns[i])));
            }
        }
        let uvs: Option<Vec<Vec2>> = reader
            .read_tex_coords(0)
            .map(|it| it.into_f32().map(Vec2::from).collect());
        if let Some(i) = uvs.iter().flatten().position(|uv| !uv.is_finite()) {
            let uv = uvs.as_ref().map(|u| u[i]).unwrap_or_default();
            return Err(self.invalid(element, format!("TEXCOORD_0[{i}] is not finite ({uv})")));
        }
        let tangents: Option<Vec<Vec4>> = reader
            .read_tangents()
            .map(|it| it.map(Vec4::from).collect())
            .filter(|t: &Vec<Vec4>| t.len() == n && t.iter().all(|v| v.is_finite()));
        let indices: Vec<u32> = match reader.read_indices() {
            Some(it) => it.into_u32().collect(),
            None => (0..n as u32).collect(),
        };
        if let Some((k, &i)) = indices.iter().enumerate().find(|(_, &i)| i as usize >= n) {
            return Err(self.invalid(element, format!("index {i} (indices[{k}]) >= vertex count {n}")));
        }
        Ok(Vertices {
            positions,
            normals,
            uvs,
            tangents,
            indices,
        })
    }

    /// Tangents at the corners of each triangle of `tris` (object space, handedness in w): the
    /// file's TANGENT attribute if it has one, else MikkTSpace's from positions, normals and
    /// TEXCOORD_0 ([`super::tangents`]; written here because the MikkTSpace crate was tried and
    /// panics on degenerate meshes the fuzzer generates).
    fn tangents(&mut self, v: &Vertices, tris: &[[u32; 3]], element: &str) -> Vec<[Vec4; 3]> {
        if let Some(ts) = &v.tangents {
            return tris
                .iter()
                .map(|t| t.map(|i| ts.get(i as usize).copied().unwrap_or(Vec4::ZERO)))
                .collect();
        }
        let Some(uvs) = &v.uvs else {
            self.report.ignored.push(format!(
                "{element}: normal map ignored: no TEXCOORD_0 to build tangents from"
            ));
            return vec![[Vec4::ZERO; 3]; tris.len()];
        };
        let generated = tangents::generate(&tangents::Mesh {
            positions: &v.positions,
            normals: v.normals.as_deref(),
            uvs,
            tris,
        });
        if generated.from_neighbours > 0 {
            self.report.approximated.push(format!(
                "{element}: normal map on {} triangles whose positions or TEXCOORD_0 are degenerate: tangents taken from the neighbouring triangles ({} with a corner that has none: from the normal alone)",
                generated.from_neighbours, generated.from_normal
            ));
        }
        generated.tangents
    }

    /// Triangles of a list, strip or fan.
    fn triangulate(&mut self, mode: Mode, indices: &[u32], element: &str) -> Vec<[u32; 3]> {
        match mode {
            Mode::Triangles => {
                if !indices.len().is_multiple_of(3) {
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
        }
    }

    /// Transform a primitive's triangles to world space and append them (skipping zero-area
    /// ones); coordinates and areas must stay in the range 32-bit floats and the BVH handle.
    fn place(
        &mut self,
        v: &Vertices,
        tris: &[[u32; 3]],
        instance: &Instance,
        material: u32,
        element: &str,
        out: &mut Vec<Triangle>,
    ) -> Result<Vec<usize>, LoadError> {
        let world = instance.world;
        let mut placed = Vec::with_capacity(tris.len());
        let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
        let flip = Mat3::from_mat4(world).determinant() < 0.0;
        let world_p = self.world_positions(v, instance, element)?;
        let world_n: Option<Vec<Vec3>> = v
            .normals
            .as_ref()
            .map(|ns| ns.iter().map(|n| (normal_matrix * *n).normalize_or_zero()).collect());
        let degenerate_before = self.report.degenerate_triangles;
        for (k, &t) in tris.iter().enumerate() {
            let mut t = t;
            if flip {
                t.swap(1, 2);
            }
            let p = t.map(|i| world_p[i as usize]);
            let cross = (p[1] - p[0]).cross(p[2] - p[0]);
            let len = cross.length();
            if len.is_infinite() {
                return Err(self.invalid(
                    format!("{} → {element}", instance.describe()),
                    format!(
                        "a triangle at {} is too large: its area overflows 32-bit floats (edges beyond ~1e9 m); scale the scene down",
                        p[0]
                    ),
                ));
            }
            // Zero area, or below the float noise of its edges' cross product (relative, so
            // that a scene at 1e-7 m keeps its triangles; never above the old 1e-14 m²).
            let noise = ((p[1] - p[0]).length() * (p[2] - p[0]).length() * f32::EPSILON).min(1e-14);
            if !(len > noise) {
                self.report.degenerate_triangles += 1;
                continue;
            }
            let ng = cross / len;
            let nrm = corner_normals(world_n.as_deref(), t, ng);
            let uv = match &v.uvs {
                Some(u) => t.map(|i| u.get(i as usize).copied().unwrap_or(Vec2::ZERO)),
                None => [Vec2::ZERO; 3],
            };
            out.push(Triangle {
                p,
                n: nrm,
                uv,
                material,
            });
            placed.push(k);
        }
        let degenerate = self.report.degenerate_triangles - degenerate_before;
        if degenerate > 0 {
            self.report.ignored.push(format!(
                "{element}: {degenerate} degenerate (zero-area) triangles skipped"
            ));
        }
        Ok(placed)
    }

    /// The primitive's positions in world space, refused beyond [`MAX_COORDINATE`].
    fn world_positions(&self, v: &Vertices, instance: &Instance, element: &str) -> Result<Vec<Vec3>, LoadError> {
        let world = instance.world;
        let world_p: Vec<Vec3> = v.positions.iter().map(|p| world.transform_point3(*p)).collect();
        if let Some(i) = world_p.iter().position(|p| !(p.abs().max_element() < MAX_COORDINATE)) {
            return Err(self.invalid(
                format!("{} → {element}", instance.describe()),
                format!(
                    "POSITION[{i}] lies at {} after the node transforms: coordinates must stay below {MAX_COORDINATE:e} in magnitude; scale the scene down (or check the node's scale)",
                    world_p[i]
                ),
            ));
        }
        Ok(world_p)
    }
}

/// The shading normals at a triangle's corners: the file's (in world space) where usable,
/// else the geometric normal `ng`.
fn corner_normals(world_n: Option<&[Vec3]>, t: [u32; 3], ng: Vec3) -> [Vec3; 3] {
    match world_n {
        Some(ns) => t.map(|i| {
            let n = ns[i as usize];
            // A zero or wild normal falls back to the geometric one.
            if n.is_finite() && n.length_squared() > 0.5 {
                n
            } else {
                ng
            }
        }),
        None => [ng; 3],
    }
}
