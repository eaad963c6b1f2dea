//! Sampling routines, frames and robust ray offsets.

use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// An orthonormal frame around a unit normal (Duff et al. 2017, "Building an
/// Orthonormal Basis, Revisited"): branch-free and continuous except at one pole.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub t: Vec3,
    pub b: Vec3,
    pub n: Vec3,
}

impl Frame {
    #[inline]
    #[must_use]
    pub fn new(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let t = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let bb = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Self { t, b: bb, n }
    }
    #[inline]
    #[must_use]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }
    #[inline]
    #[must_use]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.t * v.x + self.b * v.y + self.n * v.z
    }
}

/// Concentric square-to-disk map (Shirley & Chiu 1997).
#[inline]
#[must_use]
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, (PI / 4.0) * (o.y / o.x))
    } else {
        (o.y, PI / 2.0 - (PI / 4.0) * (o.x / o.y))
    };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Cosine-weighted hemisphere around +z (Malley's method); pdf = cos θ / π.
#[inline]
#[must_use]
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// Uniform direction on the unit sphere; pdf = 1 / (4π).
#[inline]
#[must_use]
pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Uniform direction in the cone of half-angle acos(cos_max) around +z;
/// pdf = 1 / (2π (1 − cos_max)).
#[inline]
#[must_use]
pub fn uniform_cone(u: Vec2, cos_max: f32) -> Vec3 {
    let cos_t = 1.0 - u.x * (1.0 - cos_max);
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)
}

/// Uniform barycentrics on a triangle (the square-root parametrisation, pbrt-v3 §13.6.5).
#[inline]
#[must_use]
pub fn uniform_triangle(u: Vec2) -> (f32, f32) {
    let su = u.x.sqrt();
    (1.0 - su, u.y * su)
}

/// Veach's power heuristic (β = 2) for one sample from each of two strategies.
#[inline]
#[must_use]
pub fn power_heuristic(pdf_a: f32, pdf_b: f32) -> f32 {
    let a = pdf_a * pdf_a;
    let b = pdf_b * pdf_b;
    if a == 0.0 {
        return 0.0;
    }
    if !b.is_finite() {
        return 0.0;
    }
    if !a.is_finite() {
        return 1.0;
    }
    a / (a + b)
}

/// Moves a hit point off its surface along `n` (geometric normal, on the side the new
/// ray leaves) so that the new ray cannot re-hit the surface it starts on.
///
/// Wächter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection"
/// (Ray Tracing Gems, ch. 6): the offset is a fixed number of ulps of each coordinate,
/// so it scales with the magnitude of the position (a scene 1e5 units from the origin
/// works as well as one at the origin); near the origin a small absolute offset is used.
#[inline]
#[must_use]
pub fn offset_ray_origin(p: Vec3, n: Vec3) -> Vec3 {
    const ORIGIN: f32 = 1.0 / 32.0;
    const FLOAT_SCALE: f32 = 1.0 / 65536.0;
    const INT_SCALE: f32 = 256.0;
    let of_i = [
        (INT_SCALE * n.x) as i32,
        (INT_SCALE * n.y) as i32,
        (INT_SCALE * n.z) as i32,
    ];
    let step = |pc: f32, o: i32| -> f32 {
        let bits = pc.to_bits() as i32;
        let moved = if pc < 0.0 {
            bits.wrapping_sub(o)
        } else {
            bits.wrapping_add(o)
        };
        f32::from_bits(moved as u32)
    };
    let p_i = Vec3::new(step(p.x, of_i[0]), step(p.y, of_i[1]), step(p.z, of_i[2]));
    Vec3::new(
        if p.x.abs() < ORIGIN {
            p.x + FLOAT_SCALE * n.x
        } else {
            p_i.x
        },
        if p.y.abs() < ORIGIN {
            p.y + FLOAT_SCALE * n.y
        } else {
            p_i.y
        },
        if p.z.abs() < ORIGIN {
            p.z + FLOAT_SCALE * n.z
        } else {
            p_i.z
        },
    )
}

/// Luminance-like average used for light-selection power and Russian roulette.
#[inline]
#[must_use]
pub fn average(c: Vec3) -> f32 {
    (c.x + c.y + c.z) * (1.0 / 3.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_for_awkward_normals() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.0, 0.0, -0.999_999).normalize(),
            Vec3::ONE.normalize(),
        ] {
            let f = Frame::new(n);
            assert!((f.t.length() - 1.0).abs() < 1e-5);
            assert!((f.b.length() - 1.0).abs() < 1e-5);
            assert!(
                f.t.dot(f.b).abs() < 1e-5 && f.t.dot(n).abs() < 1e-5 && f.b.dot(n).abs() < 1e-5
            );
            let v = Vec3::new(0.3, -0.2, 0.9);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
        }
    }

    #[test]
    fn cosine_hemisphere_mean_cos_is_two_thirds() {
        // E[cos θ] under pdf cos θ/π is 2/3.
        let mut rng = crate::tracer::rng::Rng::new(3);
        let n = 20000;
        let mut s = 0.0f64;
        for _ in 0..n {
            let d = cosine_hemisphere(rng.next_2d());
            assert!(d.z >= 0.0 && (d.length() - 1.0).abs() < 1e-4);
            s += f64::from(d.z);
        }
        assert!((s / f64::from(n) - 2.0 / 3.0).abs() < 0.01);
    }

    #[test]
    fn offset_scales_with_magnitude() {
        let n = Vec3::Y;
        for p in [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1e5, 1e5, 1e5),
            Vec3::new(-3e7, -2e5, 4.0),
        ] {
            let q = offset_ray_origin(p, n);
            assert!(q.y > p.y, "{p} -> {q}");
            assert_eq!(q.x, p.x);
            // At 1e5 one ulp is ~0.0078; the offset is 256 ulps, still tiny relative to p.
            assert!((q.y - p.y).abs() <= 1e-3 * p.y.abs().max(1.0));
        }
    }

    #[test]
    fn power_heuristic_limits() {
        assert_eq!(power_heuristic(0.0, 1.0), 0.0);
        assert_eq!(power_heuristic(1.0, 0.0), 1.0);
        assert_eq!(power_heuristic(f32::INFINITY, 1.0), 1.0);
        assert!((power_heuristic(1.0, 1.0) - 0.5).abs() < 1e-6);
    }
}
