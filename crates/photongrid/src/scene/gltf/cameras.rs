//! glTF cameras → [`Camera`]: the projection from the camera object, the placement from the
//! node that carries it.

use super::{LoadError, Loader};
use crate::scene::{camera, Camera, Projection};
use glam::Mat4;

impl Loader<'_> {
    pub(super) fn camera(&mut self, node: &gltf::Node, cam: &gltf::Camera, world: Mat4) -> Result<Camera, LoadError> {
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
}
