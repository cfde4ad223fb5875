//! Cameras: perspective and orthographic, looking down their local −Z as glTF defines.

use glam::{Mat4, Vec2, Vec3};

/// The projection of a camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Pinhole with a vertical field of view (radians) and an optional authored aspect ratio.
    Perspective {
        /// Vertical field of view.
        yfov: f32,
        /// Width / height the file asks for (used for the default resolution).
        aspect: Option<f32>,
    },
    /// Parallel projection with half-extents in metres.
    Orthographic {
        /// Half width.
        xmag: f32,
        /// Half height.
        ymag: f32,
    },
}

/// A camera placed in the world.
#[derive(Clone, Debug)]
pub struct Camera {
    /// Node name (or the camera's name, or `cameras[i]`).
    pub name: String,
    /// Index of the glTF camera object (the `--camera INDEX` users pass).
    pub index: usize,
    /// Rigid camera-to-world transform (scale removed).
    pub to_world: Mat4,
    /// Projection.
    pub projection: Projection,
}

impl Camera {
    /// Width / height implied by the file, if any.
    pub fn aspect(&self) -> Option<f32> {
        match self.projection {
            Projection::Perspective { aspect, .. } => aspect,
            Projection::Orthographic { xmag, ymag } => Some(xmag / ymag),
        }
    }

    /// Default resolution: 480 lines, width from the camera's aspect (640×480 for 4:3).
    pub fn default_resolution(&self) -> (u32, u32) {
        let aspect = self.aspect().filter(|a| a.is_finite() && *a > 0.0).unwrap_or(4.0 / 3.0);
        (((480.0 * aspect).round() as u32).max(1), 480)
    }

    /// The resolution the camera renders at with the width and height asked for, if any: a
    /// missing side follows the other at the default aspect.
    pub fn resolution(&self, width: Option<u32>, height: Option<u32>) -> (u32, u32) {
        let (dw, dh) = self.default_resolution();
        match (width, height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, ((w as f32 * dh as f32 / dw as f32).round() as u32).max(1)),
            (None, Some(h)) => (((h as f32 * dw as f32 / dh as f32).round() as u32).max(1), h),
            (None, None) => (dw, dh),
        }
    }

    /// The unit viewing direction (the camera's −Z axis in the world).
    pub fn forward(&self) -> Vec3 {
        self.to_world.transform_vector3(Vec3::NEG_Z).normalize()
    }

    /// Radius of a pixel's footprint `t` metres along a ray of a `height`-line image, on a
    /// surface facing the camera: half a pixel's width there.
    pub fn pixel_footprint(&self, t: f32, height: u32) -> f32 {
        let h = height.max(1) as f32;
        match self.projection {
            Projection::Perspective { yfov, .. } => t * (0.5 * yfov).tan() / h,
            Projection::Orthographic { ymag, .. } => ymag / h,
        }
    }

    /// World-space ray (origin, unit direction) through film position `film` in pixels
    /// (x right, y down) of a `width × height` image.
    pub fn generate_ray(&self, film: Vec2, width: u32, height: u32) -> (Vec3, Vec3) {
        let aspect = width as f32 / height as f32;
        // NDC in [-1, 1], y up.
        let ndc = Vec2::new(2.0 * film.x / width as f32 - 1.0, 1.0 - 2.0 * film.y / height as f32);
        let (o, d) = match self.projection {
            Projection::Perspective { yfov, .. } => {
                let t = (0.5 * yfov).tan();
                (Vec3::ZERO, Vec3::new(ndc.x * t * aspect, ndc.y * t, -1.0).normalize())
            }
            Projection::Orthographic { ymag, .. } => {
                // Keep the vertical extent and fill the image's aspect horizontally.
                (Vec3::new(ndc.x * ymag * aspect, ndc.y * ymag, 0.0), Vec3::NEG_Z)
            }
        };
        (
            self.to_world.transform_point3(o),
            self.to_world.transform_vector3(d).normalize(),
        )
    }
}

/// Remove scale (and shear) from a node's world matrix, keeping rotation and translation.
pub fn rigid_part(m: Mat4) -> Mat4 {
    let x = m.x_axis.truncate();
    let y = m.y_axis.truncate();
    let z = x.cross(y).normalize_or_zero();
    let x = x.normalize_or_zero();
    let y = z.cross(x);
    // Keep the camera looking down the authored −Z even under a negative scale.
    let z = if z.dot(m.z_axis.truncate()) < 0.0 { -z } else { z };
    let y = if y.dot(m.y_axis.truncate()) < 0.0 { -y } else { y };
    Mat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), m.w_axis)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_ray_looks_down_minus_z() {
        let c = Camera {
            name: "c".into(),
            index: 0,
            to_world: Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0)),
            projection: Projection::Perspective {
                yfov: 1.0,
                aspect: Some(4.0 / 3.0),
            },
        };
        let (o, d) = c.generate_ray(Vec2::new(320.0, 240.0), 640, 480);
        assert!((o - Vec3::new(1.0, 2.0, 3.0)).length() < 1e-6);
        assert!((d - Vec3::NEG_Z).length() < 1e-6);
        // Top edge of the image is yfov/2 above the axis.
        let (_, d) = c.generate_ray(Vec2::new(320.0, 0.0), 640, 480);
        assert!((d.y.atan2(-d.z) - 0.5).abs() < 1e-5);
        assert_eq!(c.default_resolution(), (640, 480));
    }

    #[test]
    fn rigid_part_removes_scale() {
        let m =
            Mat4::from_scale_rotation_translation(Vec3::new(2.0, 3.0, 0.5), glam::Quat::from_rotation_y(0.7), Vec3::X);
        let r = rigid_part(m);
        let expect = Mat4::from_rotation_translation(glam::Quat::from_rotation_y(0.7), Vec3::X);
        assert!(r.abs_diff_eq(expect, 1e-5));
    }
}
