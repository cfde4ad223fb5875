//! Lights: KHR_lights_punctual (point, spot, sun) in photometric units → radiometric
//! [`Light`]s, and the emissive triangles gathered into one area light.

use super::{LoadError, Loader, MAX_COORDINATE};
use crate::scene::light::EmitterTriangle;
use crate::scene::{units, Bounds, Light, Material, Texture, Triangle};
use crate::Rgb;
use glam::{Mat4, Vec3};

/// Most power a light (or all lights together) may emit, W: far above any real scene, far
/// enough below f32's 3.4e38 that fluxes, their sums and pixel values cannot overflow.
pub(super) const MAX_POWER: f32 = 1e24;

pub(super) enum PunctualType {
    Point,
    Spot { inner: f32, outer: f32 },
    Directional,
}

/// A KHR_lights_punctual light as the file gives it.
pub(super) struct PunctualKind {
    index: usize,
    color: [f32; 3],
    intensity: f32,
    range: Option<f32>,
    kind: PunctualType,
}

pub(super) fn light_of(l: &gltf::khr_lights_punctual::Light) -> PunctualKind {
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

impl Loader<'_> {
    /// The punctual lights, then the emissive triangles as one light; an error if nothing emits.
    pub(super) fn lights(
        &mut self,
        punctual: Vec<(usize, Option<String>, PunctualKind, Mat4)>,
        triangles: &[Triangle],
        materials: &[Material],
        textures: &[Texture],
        bounds: &Bounds,
    ) -> Result<Vec<Light>, LoadError> {
        let mut lights = Vec::new();
        for (node, name, kind, world) in punctual {
            let element = format!("nodes[{node}] (KHR_lights_punctual.lights[{}])", kind.index);
            let l = self.light(&element, name, kind, world, bounds)?;
            self.check_power(&element, &l)?;
            self.report.lights.push(l.describe());
            lights.push(l);
        }
        if let Some(l) = Light::emissive(emitters(triangles, materials, textures)) {
            self.check_power("emissive materials", &l)?;
            self.report.lights.push(l.describe());
            lights.push(l);
        }
        let total = lights.iter().map(|l| l.power()).sum::<Rgb>();
        if !(total.max_element() <= MAX_POWER) {
            let what = format!(
                "together emit {:.3e} W, more than {MAX_POWER:e} W; lower their intensities",
                total.max_element()
            );
            return Err(self.invalid("lights", what));
        }
        if lights.iter().all(|l| l.power().max_element() <= 0.0) {
            return Err(LoadError::NoLights {
                path: self.path.to_path_buf(),
            });
        }
        Ok(lights)
    }

    /// A light's power must be finite and below [`MAX_POWER`] (photon fluxes, pixel sums and
    /// the emitters' distribution are 32-bit).
    fn check_power(&self, element: &str, light: &Light) -> Result<(), LoadError> {
        let power = light.power();
        if power.max_element() <= MAX_POWER && power.is_finite() {
            return Ok(());
        }
        Err(self.invalid(
            element,
            format!(
                "emits {:.3e} W, more than the {MAX_POWER:e} W the renderer's 32-bit sums can carry; lower the light's intensity or emission strength (or the scene's size, for a sun)",
                power.max_element()
            ),
        ))
    }

    fn light(
        &mut self,
        element: &str,
        name: Option<String>,
        kind: PunctualKind,
        world: Mat4,
        bounds: &Bounds,
    ) -> Result<Light, LoadError> {
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
        if !(position.abs().max_element() < MAX_COORDINATE) {
            let what = format!("lies at {position}: coordinates must stay below {MAX_COORDINATE:e} in magnitude");
            return Err(self.invalid(element, what));
        }
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
                    scene_radius: 0.5 * bounds.diagonal().max(f32::MIN_POSITIVE),
                }
            }
        })
    }
}

/// Mean emitted radiance of a triangle with an emissive texture: the texture averaged over
/// the triangle's texture coordinates (16 × 16 stratified barycentric samples).
fn mean_emission(t: &Triangle, m: &Material, textures: &[Texture]) -> Rgb {
    if m.emission_texture.is_none() {
        return m.emission;
    }
    let n = 16;
    let mut sum = Rgb::ZERO;
    for i in 0..n {
        for j in 0..n {
            let u = glam::Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
            let (b1, b2) = crate::sampling::uniform_triangle(u);
            sum += m.emission_at(textures, t.lerp(t.uv, b1, b2));
        }
    }
    sum / (n * n) as f32
}

/// The triangles whose material emits, as area-light pieces (an emissive texture by its
/// mean over each triangle).
fn emitters(triangles: &[Triangle], materials: &[Material], textures: &[Texture]) -> Vec<EmitterTriangle> {
    triangles
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
                radiance: mean_emission(t, m, textures),
                double_sided: m.double_sided,
                triangle: i as u32,
            }
        })
        .collect()
}
