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

    /// Where world point `p` lands on the image: (x, y) in pixels as [`Pinhole::direction`]
    /// numbers them (pixel `(i, j)` spans `[i, i+1) × [j, j+1)`) and its depth along the
    /// view axis. `None` when the point is not in front of the camera (depth ≤ 0), where
    /// the projection does not exist. In f64: callers bound screen regions with it
    /// (tracer::primary) and want its own rounding far below their margins.
    #[must_use]
    pub fn project(&self, p: Vec3) -> Option<(f64, f64, f64)> {
        let d = |a: Vec3, b: Vec3| {
            f64::from(a.x) * f64::from(b.x)
                + f64::from(a.y) * f64::from(b.y)
                + f64::from(a.z) * f64::from(b.z)
        };
        let q = p - self.origin;
        let z = d(q, self.forward);
        if z.is_nan() || z <= 0.0 {
            return None;
        }
        // `right` and `up` are orthogonal to `forward` and to each other, so q's
        // coordinates along them give the image coordinates of `direction` directly.
        let sx = d(q, self.right) / (d(self.right, self.right) * z);
        let sy = d(q, self.up) / (d(self.up, self.up) * z);
        let x = (sx + 1.0) * 0.5 / f64::from(self.inv_w);
        let y = (1.0 - sy) * 0.5 / f64::from(self.inv_h);
        Some((x, y, z))
    }

    /// Depth of `p` along the view axis (negative behind the camera).
    #[must_use]
    pub fn depth(&self, p: Vec3) -> f64 {
        let q = p - self.origin;
        f64::from(q.x) * f64::from(self.forward.x)
            + f64::from(q.y) * f64::from(self.forward.y)
            + f64::from(q.z) * f64::from(self.forward.z)
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
