//! Pinhole camera (scene-format.md `camera`).

use crate::scene::Camera;
use glam::{Vec2, Vec3};

/// Precomputed pinhole: image-plane axes scaled by tan(fov_y / 2) and the aspect ratio.
#[derive(Clone, Copy, Debug)]
pub struct Pinhole {
    pub origin: Vec3,
    forward: Vec3,
    /// Right axis × tan(fov/2)·aspect.
    right: Vec3,
    /// Up axis × tan(fov/2).
    up: Vec3,
    inv_w: f32,
    inv_h: f32,
}

impl Pinhole {
    /// `fov_y_deg` is the full vertical field of view; aspect = width / height; pixel (0, 0)
    /// is the top-left, +x right, y down in the image.
    #[must_use]
    pub fn new(cam: &Camera, width: u32, height: u32) -> Self {
        let forward = (cam.look_at - cam.position).normalize_or(Vec3::NEG_Z);
        // Validation refuses `up` parallel to the view; fall back to any perpendicular
        // axis rather than produce NaN if one slips through.
        let right = forward
            .cross(cam.up)
            .try_normalize()
            .unwrap_or_else(|| forward.any_orthonormal_vector());
        let up = right.cross(forward);
        let w = width.max(1) as f32;
        let h = height.max(1) as f32;
        let tan_half = (cam.fov_y_deg.to_radians() * 0.5).tan();
        Self {
            origin: cam.position,
            forward,
            right: right * tan_half * (w / h),
            up: up * tan_half,
            inv_w: 1.0 / w,
            inv_h: 1.0 / h,
        }
    }

    /// Unit direction through image position (x + jitter.x, y + jitter.y) in pixels.
    #[inline]
    #[must_use]
    pub fn direction(&self, x: u32, y: u32, jitter: Vec2) -> Vec3 {
        let sx = 2.0 * ((x as f32 + jitter.x) * self.inv_w) - 1.0;
        let sy = 1.0 - 2.0 * ((y as f32 + jitter.y) * self.inv_h);
        (self.forward + self.right * sx + self.up * sy).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            position: Vec3::ZERO,
            look_at: Vec3::NEG_Z,
            up: Vec3::Y,
            fov_y_deg: 90.0,
        }
    }

    #[test]
    fn centre_corners_and_orientation() {
        let c = Pinhole::new(&cam(), 4, 2);
        let d = c.direction(2, 1, Vec2::ZERO);
        assert!((d - Vec3::NEG_Z).length() < 1e-6, "{d}");
        // Top-left corner: fov 90 => tan = 1, aspect 2 => x = -2, y = +1.
        let tl = c.direction(0, 0, Vec2::ZERO);
        let e = Vec3::new(-2.0, 1.0, -1.0).normalize();
        assert!((tl - e).length() < 1e-6, "{tl}");
        // +x right, y down.
        assert!(c.direction(3, 0, Vec2::splat(0.5)).x > 0.0);
        assert!(c.direction(0, 1, Vec2::splat(0.5)).y < 0.0);
    }
}
