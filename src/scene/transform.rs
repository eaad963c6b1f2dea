//! Object transforms (scene-format.md `objects[].transform`): scale, then rotate about x,
//! then y, then z (degrees, right-handed, counter-clockwise looking down the axis), then
//! translate. As a matrix acting on column vectors: `M = T · Rz · Ry · Rx · S`.

use glam::{Mat3, Mat4, Vec3};

use super::doc::{ScaleDoc, TransformDoc};

/// A resolved transform: the point matrix, the normal matrix (inverse transpose of the
/// linear part) and whether it mirrors space (negative determinant).
#[derive(Clone, Copy, Debug)]
pub struct Xform {
    pub point: Mat4,
    pub normal: Mat3,
    /// A mirroring transform turns `(b − a) × (c − a)` to the inside; triangles are then
    /// re-wound so the geometric normal stays the transformed normal (one-sided emitters
    /// keep emitting on the side the document meant).
    pub mirrors: bool,
    /// The per-axis scale factors, for the sphere rule (`validate`).
    pub scale: Vec3,
}

impl Xform {
    pub const IDENTITY: Xform = Xform {
        point: Mat4::IDENTITY,
        normal: Mat3::IDENTITY,
        mirrors: false,
        scale: Vec3::ONE,
    };

    /// Builds the transform. The caller has checked that the numbers are finite and the
    /// scale non-zero, so the linear part is invertible.
    #[must_use]
    pub fn from_doc(t: Option<&TransformDoc>) -> Xform {
        let Some(t) = t else { return Self::IDENTITY };
        let scale = match t.scale {
            None => Vec3::ONE,
            Some(ScaleDoc::Uniform(s)) => Vec3::splat(s),
            Some(ScaleDoc::Axes(a)) => Vec3::from(a),
        };
        let rx = t.rotate_x.unwrap_or(0.0).to_radians();
        let ry = t.rotate_y.unwrap_or(0.0).to_radians();
        let rz = t.rotate_z.unwrap_or(0.0).to_radians();
        let translate = Vec3::from(t.translate.unwrap_or([0.0; 3]));
        let point = Mat4::from_translation(translate)
            * Mat4::from_rotation_z(rz)
            * Mat4::from_rotation_y(ry)
            * Mat4::from_rotation_x(rx)
            * Mat4::from_scale(scale);
        let linear = Mat3::from_mat4(point);
        Xform {
            point,
            normal: linear.inverse().transpose(),
            mirrors: linear.determinant() < 0.0,
            scale,
        }
    }

    #[must_use]
    pub fn point(&self, p: Vec3) -> Vec3 {
        self.point.transform_point3(p)
    }

    /// Transforms a normal by the inverse transpose and renormalises it.
    #[must_use]
    pub fn normal(&self, n: Vec3) -> Vec3 {
        (self.normal * n).normalize_or_zero()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).length() < 1e-5
    }

    #[test]
    fn order_is_scale_then_x_y_z_then_translate() {
        let t = TransformDoc {
            translate: Some([10.0, 0.0, 0.0]),
            scale: Some(ScaleDoc::Axes([2.0, 1.0, 1.0])),
            rotate_x: None,
            rotate_y: None,
            rotate_z: Some(90.0),
        };
        let x = Xform::from_doc(Some(&t));
        // (1,0,0) → scale (2,0,0) → rotate z 90° (0,2,0) → translate (10,2,0).
        assert!(
            close(x.point(Vec3::X), Vec3::new(10.0, 2.0, 0.0)),
            "{}",
            x.point(Vec3::X)
        );
        // Rotations compose x first, then y: (0,1,0) → Rx 90 → (0,0,1) → Ry 90 → (1,0,0).
        let t = TransformDoc {
            translate: None,
            scale: None,
            rotate_x: Some(90.0),
            rotate_y: Some(90.0),
            rotate_z: None,
        };
        let x = Xform::from_doc(Some(&t));
        assert!(close(x.point(Vec3::Y), Vec3::X), "{}", x.point(Vec3::Y));
    }

    #[test]
    fn normals_use_the_inverse_transpose_and_mirrors_are_detected() {
        let t = TransformDoc {
            scale: Some(ScaleDoc::Axes([1.0, 4.0, 1.0])),
            ..TransformDoc::default()
        };
        let x = Xform::from_doc(Some(&t));
        // The plane x + y = 0 has normal (1,1,0); stretched 4× along y it becomes
        // x + y/4 = 0 with normal ∝ (1, 1/4, 0).
        let n = x.normal(Vec3::new(1.0, 1.0, 0.0));
        assert!(close(n, Vec3::new(1.0, 0.25, 0.0).normalize()), "{n}");
        assert!(!x.mirrors);
        let m = TransformDoc {
            scale: Some(ScaleDoc::Uniform(-1.0)),
            ..TransformDoc::default()
        };
        assert!(Xform::from_doc(Some(&m)).mirrors);
    }
}
