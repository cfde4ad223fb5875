//! `photongrid info`: cameras described as people read them (`perspective, yfov 40.0°,
//! aspect 4:3`), in text and as structured JSON.

use photongrid::scene::{Camera, Projection};
use serde_json::{json, Value};

/// `4:3`, `16:9`, `1:1` for ratios of small whole numbers, else the ratio with three decimals.
/// The tolerance covers f32 rounding of the file's value, not near misses: 2.39 is not 43:18.
pub fn aspect_text(aspect: f32) -> String {
    if aspect.is_finite() && aspect > 0.0 {
        for d in 1..=16u32 {
            let n = (aspect * d as f32).round();
            if n >= 1.0 && (n / d as f32 - aspect).abs() <= 1e-5 * aspect {
                return format!("{}:{d}", n as u32);
            }
        }
    }
    format!("{aspect:.3}")
}

/// One line: `perspective, yfov 40.0°, aspect 4:3` or `orthographic, 4.000 × 3.000 m, aspect 4:3`.
pub fn describe(camera: &Camera) -> String {
    match camera.projection {
        Projection::Perspective { yfov, aspect } => format!(
            "perspective, yfov {:.1}°, aspect {}",
            yfov.to_degrees(),
            aspect.map(aspect_text).unwrap_or_else(|| "of the image".into())
        ),
        Projection::Orthographic { xmag, ymag } => format!(
            "orthographic, {:.3} × {:.3} m, aspect {}",
            2.0 * xmag,
            2.0 * ymag,
            aspect_text(xmag / ymag)
        ),
    }
}

/// The camera as JSON fields: index, name, projection and its parameters.
pub fn camera_json(camera: &Camera) -> Value {
    let mut v = json!({"index": camera.index, "name": camera.name});
    match camera.projection {
        Projection::Perspective { yfov, aspect } => {
            v["projection"] = json!("perspective");
            v["yfov_degrees"] = json!((yfov.to_degrees() as f64 * 1e4).round() / 1e4);
            v["aspect"] = json!(aspect);
            v["aspect_ratio"] = json!(aspect.map(aspect_text));
        }
        Projection::Orthographic { xmag, ymag } => {
            v["projection"] = json!("orthographic");
            v["width_m"] = json!(2.0 * xmag);
            v["height_m"] = json!(2.0 * ymag);
            v["aspect"] = json!(xmag / ymag);
            v["aspect_ratio"] = json!(aspect_text(xmag / ymag));
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aspects_and_lines() {
        assert_eq!(aspect_text(1.333_333_4), "4:3");
        assert_eq!(aspect_text(16.0 / 9.0), "16:9");
        assert_eq!(aspect_text(1.0), "1:1");
        assert_eq!(aspect_text(2.39), "2.390");
        let c = Camera {
            name: "Camera".into(),
            index: 0,
            to_world: glam::Mat4::IDENTITY,
            projection: Projection::Perspective {
                yfov: 40f32.to_radians(),
                aspect: Some(1.333_333_4),
            },
        };
        assert_eq!(describe(&c), "perspective, yfov 40.0°, aspect 4:3");
        let j = camera_json(&c);
        assert_eq!(
            (j["projection"].as_str(), j["yfov_degrees"].as_f64()),
            (Some("perspective"), Some(40.0))
        );
        assert_eq!(j["aspect_ratio"], "4:3");
    }
}
