//! The `lights` section of scene-format.md.

use super::*;

pub(super) fn check_light(cx: &mut Ctx, p: &str, l: &LightDoc) -> Light {
    match l {
        LightDoc::Point(pl) => Light::Point {
            position: world_position(cx, &format!("{p}.position"), pl.position),
            intensity: cx.emission3(&format!("{p}.intensity"), pl.intensity),
        },
        LightDoc::Directional(d) => {
            let dp = format!("{p}.direction");
            let dir = cx.vec3(&dp, d.direction);
            // Normalised here so the tracer can rely on a unit vector.
            let direction = dir.normalize_or_zero();
            if dir.is_finite() && direction == Vec3::ZERO {
                cx.err(&dp, "must be non-zero");
            }
            Light::Directional {
                direction,
                irradiance: cx.emission3(&format!("{p}.irradiance"), d.irradiance),
            }
        }
        LightDoc::Environment(e) => Light::Environment {
            radiance: cx.emission3(&format!("{p}.radiance"), e.radiance),
        },
        LightDoc::Spot(s) => {
            let dp = format!("{p}.direction");
            let dir = cx.vec3(&dp, s.direction);
            let direction = dir.normalize_or_zero();
            if dir.is_finite() && direction == Vec3::ZERO {
                cx.err(&dp, "must be non-zero");
            }
            let (outer, inner) = (s.outer_angle, s.inner_angle);
            let op = format!("{p}.outer_angle");
            if cx.finite(&op, outer) && !(0.0..=180.0).contains(&outer) {
                cx.err(&op, format!("must be in [0, 180] degrees, got {outer}"));
            }
            let ip = format!("{p}.inner_angle");
            if cx.finite(&ip, inner) && !(0.0..=outer.max(0.0)).contains(&inner) {
                cx.err(
                    &ip,
                    format!("must be in [0, outer_angle = {outer}] degrees, got {inner}"),
                );
            }
            Light::Spot {
                position: world_position(cx, &format!("{p}.position"), s.position),
                direction,
                intensity: cx.emission3(&format!("{p}.intensity"), s.intensity),
                cos_inner: inner.to_radians().cos(),
                cos_outer: outer.to_radians().cos(),
                falloff: match s.falloff {
                    FalloffDoc::Smoothstep => SpotFalloff::Smoothstep,
                    FalloffDoc::SquaredLinear => SpotFalloff::SquaredLinear,
                },
            }
        }
    }
}
