//! glTF cameras → [`Camera`]: the projection from the camera object, the placement from the
//! node that carries it.

use super::{LoadError, Loader, MAX_COORDINATE};
use crate::scene::{camera, Camera, Projection};
use glam::{Mat4, Vec3};

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
        let to_world = camera::rigid_part(world);
        self.check_placement(&element, &name, node.index(), world, to_world)?;
        Ok(Camera {
            name,
            index: cam.index(),
            to_world,
            projection,
        })
    }

    /// The camera's node must give it an orientation (no zero scale, no singular matrix) and a
    /// position in range: otherwise every ray would be degenerate and the image black.
    fn check_placement(
        &self,
        element: &str,
        name: &str,
        node: usize,
        world: Mat4,
        to_world: Mat4,
    ) -> Result<(), LoadError> {
        let element = format!("{element} '{name}' (nodes[{node}])");
        let axes = [to_world.x_axis, to_world.y_axis, to_world.z_axis].map(|a| a.truncate());
        let oriented = to_world.is_finite() && axes.iter().all(|a| (a.length() - 1.0).abs() < 1e-3);
        if !oriented {
            let (x, y) = (world.x_axis.truncate(), world.y_axis.truncate());
            return Err(self.invalid(
                element,
                format!(
                    "the node's transform has zero scale or is singular (camera X axis {x}, Y axis {y}), so the camera has no orientation; give the camera object a non-zero scale"
                ),
            ));
        }
        let position: Vec3 = to_world.w_axis.truncate();
        if !(position.abs().max_element() < MAX_COORDINATE) {
            return Err(self.invalid(
                element,
                format!("lies at {position}: coordinates must stay below {MAX_COORDINATE:e} in magnitude"),
            ));
        }
        Ok(())
    }
}
