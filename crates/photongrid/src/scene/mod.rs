//! The scene as the renderer sees it: world-space triangles, materials, lights and cameras.
//! The loader ([`gltf`]) builds it; nothing downstream knows about glTF.

pub mod camera;
pub mod gltf;
pub mod light;
pub mod material;
pub mod units;

pub use camera::{Camera, Projection};
pub use light::Light;
pub use material::{Material, Surface, Texture};

use crate::Rgb;
use glam::{Vec2, Vec3, Vec4};
use serde::Serialize;
use std::path::PathBuf;

/// One world-space triangle with shading attributes.
#[derive(Clone, Debug)]
pub struct Triangle {
    /// Vertices, counter-clockwise seen from the front.
    pub p: [Vec3; 3],
    /// Unit shading normals per vertex.
    pub n: [Vec3; 3],
    /// Texture coordinates per vertex (zero when absent).
    pub uv: [Vec2; 3],
    /// Index into [`Scene::materials`].
    pub material: u32,
}

impl Triangle {
    /// Unnormalised geometric normal (its length is twice the area).
    pub fn cross(&self) -> Vec3 {
        (self.p[1] - self.p[0]).cross(self.p[2] - self.p[0])
    }

    /// Area in m².
    pub fn area(&self) -> f32 {
        0.5 * self.cross().length()
    }

    /// Interpolate a per-vertex attribute with barycentrics (b1, b2).
    pub fn lerp<T>(&self, a: [T; 3], b1: f32, b2: f32) -> T
    where
        T: std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T> + Copy,
    {
        a[0] * (1.0 - b1 - b2) + a[1] * b1 + a[2] * b2
    }
}

/// Axis-aligned bounds.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Bounds {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Bounds {
    /// Empty bounds (min > max).
    pub fn empty() -> Self {
        Bounds {
            min: Vec3::splat(f32::INFINITY),
            max: Vec3::splat(f32::NEG_INFINITY),
        }
    }
    /// Grow to include `p`.
    pub fn grow(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
    /// Length of the diagonal.
    pub fn diagonal(&self) -> f32 {
        (self.max - self.min).length()
    }
    /// Centre.
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }
}

/// What the loader did with each part of the file: for `photongrid info` and warnings.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LoadReport {
    /// Materials and the model each was mapped to.
    pub materials: Vec<String>,
    /// Lights, in radiometric units.
    pub lights: Vec<String>,
    /// Cameras.
    pub cameras: Vec<String>,
    /// Features approximated by a nearby model (the user should know).
    pub approximated: Vec<String>,
    /// Parts ignored, with the reason.
    pub ignored: Vec<String>,
    /// Triangles skipped as degenerate (zero area).
    pub degenerate_triangles: usize,
}

/// A loaded scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The file it came from.
    pub source: PathBuf,
    /// World-space triangles.
    pub triangles: Vec<Triangle>,
    /// Materials referenced by the triangles.
    pub materials: Vec<Material>,
    /// The textures materials read.
    pub textures: Vec<Texture>,
    /// Per triangle, the tangents (xyz, handedness w) at its vertices, for normal maps
    /// (from TEXCOORD_0 when the file has none); empty when no material has a normal map.
    pub tangents: Vec<[Vec4; 3]>,
    /// Roughness from which glTF reflection lobes are rendered from photons
    /// ([`crate::bsdf::GLOSSY_ROUGHNESS`] unless changed).
    pub glossy_roughness: f32,
    /// Lights (emissive triangles are gathered into one [`Light::Emissive`]).
    pub lights: Vec<Light>,
    /// Cameras.
    pub cameras: Vec<Camera>,
    /// Bounds of all triangles.
    pub bounds: Bounds,
    /// What was mapped, approximated or ignored.
    pub report: LoadReport,
}

impl Scene {
    /// Total emitted power of all lights (W, per channel).
    pub fn total_power(&self) -> Rgb {
        self.lights.iter().map(|l| l.power()).sum()
    }

    /// True if any material is a mirror or glass (so caustics can exist).
    pub fn has_specular(&self) -> bool {
        self.materials.iter().any(|m| m.is_specular())
    }

    /// True if any material has alpha (cut-outs or blending): rays then test coverage.
    pub fn has_alpha(&self) -> bool {
        self.materials.iter().any(|m| m.has_alpha())
    }

    /// Total surface area of all triangles.
    pub fn surface_area(&self) -> f32 {
        self.triangles.iter().map(|t| t.area()).sum()
    }

    /// Find a camera by name or glTF camera index; the error lists what exists.
    pub fn camera(&self, key: &str) -> Result<&Camera, String> {
        if let Some(c) = self.cameras.iter().find(|c| c.name == key) {
            return Ok(c);
        }
        if let Ok(i) = key.parse::<usize>() {
            if let Some(c) = self.cameras.iter().find(|c| c.index == i) {
                return Ok(c);
            }
        }
        let list: Vec<String> = self
            .cameras
            .iter()
            .map(|c| format!("{} ({})", c.index, c.name))
            .collect();
        Err(format!(
            "no camera '{key}' in {}; available: {}",
            self.source.display(),
            list.join(", ")
        ))
    }
}
