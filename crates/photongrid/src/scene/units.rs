//! Blender's glTF light units → radiometric quantities (`../shared/scenes/UNITS.md`).
//!
//! The one place for 683 lm/W and the spot profile: punctual lights carry the photometric
//! factor (the exporter multiplied by 683), emission does not.

use crate::Rgb;

/// Luminous efficacy the Blender exporter uses (`PBR_WATTS_TO_LUMENS`).
pub const LUMENS_PER_WATT: f32 = 683.0;

/// Point/spot `intensity` in candela → radiant intensity in W/sr (UNITS.md §3).
pub fn candela_to_radiant_intensity(candela: f32) -> f32 {
    candela / LUMENS_PER_WATT
}

/// Directional `intensity` in lux → irradiance on a surface facing the light, W/m².
pub fn lux_to_irradiance(lux: f32) -> f32 {
    lux / LUMENS_PER_WATT
}

/// Emitted radiance of a material: `emissiveFactor × emissiveStrength`, no 683 (UNITS.md §3).
pub fn emission_radiance(factor: [f32; 3], strength: Option<f32>) -> Rgb {
    Rgb::from(factor) * strength.unwrap_or(1.0)
}

/// Blend of a glTF spot as Blender defines it: `1 − inner/outer`.
pub fn spot_blend(inner_cone: f32, outer_cone: f32) -> f32 {
    if outer_cone <= 0.0 {
        0.0
    } else {
        (1.0 - inner_cone / outer_cone).clamp(0.0, 1.0)
    }
}

/// `3x² − 2x³` on [0, 1], clamped outside.
pub fn smoothstep(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// Cycles' spot profile: `smoothstep((cosθ − cos outer) / ((1 − cos outer)·blend))`, 0 outside.
pub fn spot_mask(cos_theta: f32, cos_outer: f32, blend: f32) -> f32 {
    if cos_theta <= cos_outer {
        return 0.0;
    }
    let width = (1.0 - cos_outer) * blend;
    if width <= 0.0 {
        1.0
    } else {
        smoothstep((cos_theta - cos_outer) / width)
    }
}

/// Total flux of a spot of peak intensity `i0` [W/sr]: `2π I0 ∫ mask(c) dc`, in closed form
/// `2π I0 (1 − cos outer)(1 − blend/2)` since ∫₀¹ smoothstep = 1/2.
pub fn spot_flux(i0: f32, cos_outer: f32, blend: f32) -> f32 {
    2.0 * std::f32::consts::PI * i0 * (1.0 - cos_outer) * (1.0 - 0.5 * blend)
}

/// Total flux of an isotropic point light of intensity `i` [W/sr]: `4π I`.
pub fn point_flux(i: f32) -> f32 {
    4.0 * std::f32::consts::PI * i
}

/// Flux leaving one face of a Lambertian emitter of radiance `l` and area `a`: `π L A`.
pub fn lambert_emitter_flux(l: f32, area: f32) -> f32 {
    std::f32::consts::PI * l * area
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blender_point_light_round_trip() {
        // 30 W point exported as W/(4π)·683 cd (cornell_glass: 1630.5423919764678 cd).
        let i = candela_to_radiant_intensity(1_630.542_4);
        assert!((point_flux(i) - 30.0).abs() < 1e-3, "{}", point_flux(i));
    }

    #[test]
    fn sun_units() {
        assert!((lux_to_irradiance(1366.0) - 2.0).abs() < 1e-6);
    }

    #[test]
    fn spot_flux_matches_numeric_integral() {
        let cos_outer = (20f32).to_radians().cos();
        for blend in [0.0, 0.15, 0.5, 1.0] {
            let n = 200_000;
            let mut sum = 0.0f64;
            for s in 0..n {
                let c = cos_outer + (1.0 - cos_outer) * (s as f32 + 0.5) / n as f32;
                sum += spot_mask(c, cos_outer, blend) as f64;
            }
            let numeric = 2.0 * std::f64::consts::PI * sum * (1.0 - cos_outer) as f64 / n as f64;
            let closed = spot_flux(1.0, cos_outer, blend) as f64;
            assert!(
                (numeric / closed - 1.0).abs() < 1e-4,
                "blend {blend}: {numeric} vs {closed}"
            );
        }
    }

    #[test]
    fn spot_mask_edges() {
        let co = 0.9;
        assert_eq!(spot_mask(0.89, co, 0.2), 0.0);
        assert_eq!(spot_mask(1.0, co, 0.2), 1.0);
        assert_eq!(spot_mask(0.95, co, 0.0), 1.0);
        assert!((spot_blend(0.17, 0.2) - 0.15).abs() < 1e-6);
    }

    #[test]
    fn emission_has_no_683() {
        assert_eq!(
            emission_radiance([1.0, 0.5, 0.0], Some(40.0)),
            Rgb::new(40.0, 20.0, 0.0)
        );
        assert_eq!(emission_radiance([0.2, 0.2, 0.2], None), Rgb::splat(0.2));
    }
}
