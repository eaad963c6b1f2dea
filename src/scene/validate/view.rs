//! The `camera` and `display` sections of scene-format.md.

use super::*;

pub(super) fn check_camera(cx: &mut Ctx, c: &CameraDoc) -> Camera {
    let position = world_position(cx, "camera.position", c.position);
    let look_at = world_position(cx, "camera.look_at", c.look_at);
    let up = cx.vec3("camera.up", c.up);
    if cx.finite("camera.fov_y", c.fov_y) && !(c.fov_y > 0.0 && c.fov_y < 180.0) {
        cx.err(
            "camera.fov_y",
            format!("must be in (0, 180) degrees, got {}", c.fov_y),
        );
    }
    let view = look_at - position;
    if position.is_finite() && look_at.is_finite() && up.is_finite() {
        if view.length_squared() == 0.0 || !view.length_squared().is_finite() {
            cx.err(
                "camera.look_at",
                "must differ from camera.position (no viewing direction)",
            );
        } else if up.length_squared() == 0.0 {
            cx.err("camera.up", "must be non-zero");
        } else if view.normalize().cross(up.normalize()).length() < PARALLEL_SIN {
            cx.err(
                "camera.up",
                "must not be parallel to the viewing direction (look_at − position)",
            );
        }
    }
    Camera {
        position,
        look_at,
        up,
        fov_y_deg: c.fov_y,
    }
}

pub(super) fn check_display(cx: &mut Ctx, d: &DisplayDoc) -> Display {
    if cx.finite("display.black_luminance", d.black_luminance) && d.black_luminance < 0.0 {
        cx.err(
            "display.black_luminance",
            format!("must be ≥ 0, got {}", d.black_luminance),
        );
    }
    if cx.finite("display.peak_luminance", d.peak_luminance)
        && d.black_luminance.is_finite()
        && d.peak_luminance <= d.black_luminance
    {
        cx.err(
            "display.peak_luminance",
            format!(
                "must be greater than black_luminance ({}), got {}",
                d.black_luminance, d.peak_luminance
            ),
        );
    }
    cx.positive("display.exposure", d.exposure);
    cx.positive("display.pixels_per_degree", d.pixels_per_degree);
    Display {
        peak_luminance: d.peak_luminance,
        black_luminance: d.black_luminance,
        exposure: d.exposure,
        pixels_per_degree: d.pixels_per_degree,
    }
}
