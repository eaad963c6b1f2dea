//! The graphics state pbrt-v4's file format keeps while reading: the current transform
//! (`Translate` … `CoordSysTransform`), `ReverseOrientation`, the attribute blocks that
//! save and restore it, `Include`/`Import`, and `WorldBegin` (which resets the transform).

use glam::{DMat3, DMat4, DVec3, DVec4};

use super::lexer::{Lexer, Pos};
use super::{ImportError, Importer};

/// Includes may nest this deep (a file including itself is refused here).
const MAX_INCLUDE_DEPTH: usize = 16;

/// Attribute blocks may nest this deep (each level holds a copy of the graphics state).
const MAX_ATTRIBUTE_DEPTH: usize = 4096;

impl Importer<'_> {
    /// `Identity`, `Translate`, `Scale`, `Rotate`, `LookAt`, `Transform`,
    /// `ConcatTransform`, `CoordinateSystem` and `CoordSysTransform`.
    pub(super) fn transform_directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        match dir {
            "Identity" => self.state.ctm = DMat4::IDENTITY,
            "Translate" => {
                let v = Self::numbers(lx, 3, pos, dir)?;
                let m = DMat4::from_translation(DVec3::new(v[0], v[1], v[2]));
                self.concat(m, pos, dir)?;
            }
            "Scale" => self.scale(pos, lx)?,
            "Rotate" => self.rotate(pos, lx)?,
            "LookAt" => self.look_at(pos, lx)?,
            "Transform" | "ConcatTransform" => self.matrix(dir, pos, lx)?,
            "CoordinateSystem" => {
                let n = Self::string(lx, pos, dir)?;
                self.named_coords.insert(n, self.state.ctm);
            }
            // `CoordSysTransform`
            _ => {
                let n = Self::string(lx, pos, dir)?;
                self.state.ctm = *self
                    .named_coords
                    .get(&n)
                    .ok_or_else(|| pos.error(format!("unknown coordinate system \"{n}\"")))?;
            }
        }
        Ok(())
    }

    fn scale(&mut self, pos: &Pos, lx: &mut Lexer) -> Result<(), ImportError> {
        let v = Self::numbers(lx, 3, pos, "Scale")?;
        let m = DMat4::from_scale(DVec3::new(v[0], v[1], v[2]));
        invertible(
            &m,
            pos,
            &format!("`Scale {} {} {}`", num(v[0]), num(v[1]), num(v[2])),
        )?;
        self.concat(m, pos, "Scale")
    }

    fn rotate(&mut self, pos: &Pos, lx: &mut Lexer) -> Result<(), ImportError> {
        let v = Self::numbers(lx, 4, pos, "Rotate")?;
        let axis = DVec3::new(v[1], v[2], v[3]);
        let axis = axis
            .try_normalize()
            .ok_or_else(|| pos.error("`Rotate` needs a non-zero axis"))?;
        self.concat(
            DMat4::from_axis_angle(axis, v[0].to_radians()),
            pos,
            "Rotate",
        )
    }

    fn look_at(&mut self, pos: &Pos, lx: &mut Lexer) -> Result<(), ImportError> {
        let v = Self::numbers(lx, 9, pos, "LookAt")?;
        let m = look_at(
            DVec3::new(v[0], v[1], v[2]),
            DVec3::new(v[3], v[4], v[5]),
            DVec3::new(v[6], v[7], v[8]),
        )
        .ok_or_else(|| {
            pos.error("`LookAt`: the eye equals the target or `up` is parallel to the view")
        })?;
        self.concat(m, pos, "LookAt")
    }

    /// `Transform` (replaces the current transform) or `ConcatTransform` (multiplies it).
    fn matrix(&mut self, dir: &str, pos: &Pos, lx: &mut Lexer) -> Result<(), ImportError> {
        let v = Self::numbers(lx, 16, pos, dir)?;
        let mut a = [0.0; 16];
        a.copy_from_slice(&v);
        // The list is pbrt's matrix transposed, i.e. column-major: glam's order.
        let m = DMat4::from_cols_array(&a);
        invertible(&m, pos, &format!("the matrix of `{dir}`"))?;
        if dir == "Transform" {
            self.state.ctm = m;
            Ok(())
        } else {
            self.concat(m, pos, dir)
        }
    }

    /// The current transform times `m`; refused if the product has no inverse (factors
    /// each invertible can still underflow to a zero determinant).
    fn concat(&mut self, m: DMat4, pos: &Pos, dir: &str) -> Result<(), ImportError> {
        let ctm = self.state.ctm * m;
        invertible(&ctm, pos, &format!("the transform after `{dir}`"))?;
        self.state.ctm = ctm;
        Ok(())
    }

    /// `ReverseOrientation` and the blocks that save the graphics state
    /// (`AttributeBegin`/`End`) or only its transform (`TransformBegin`/`End`).
    pub(super) fn attribute_directive(&mut self, dir: &str, pos: &Pos) -> Result<(), ImportError> {
        match dir {
            "ReverseOrientation" => self.state.reverse = !self.state.reverse,
            "AttributeBegin" | "TransformBegin" => {
                if self.stack.len() >= MAX_ATTRIBUTE_DEPTH {
                    return Err(pos.error("attribute blocks nest deeper than 4096"));
                }
                self.stack.push((self.state.clone(), pos.clone()));
            }
            // `AttributeEnd` or `TransformEnd`
            _ => {
                let (s, _) = self
                    .stack
                    .pop()
                    .ok_or_else(|| pos.error(format!("`{dir}` without a matching begin")))?;
                if dir == "TransformEnd" {
                    self.state.ctm = s.ctm;
                } else {
                    self.state = s;
                }
            }
        }
        Ok(())
    }

    /// `Include` or `Import`: the named file read in place, `depth` files deep.
    pub(super) fn include(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
        depth: usize,
    ) -> Result<(), ImportError> {
        let name = Self::string(lx, pos, dir)?;
        if depth + 1 > MAX_INCLUDE_DEPTH {
            return Err(pos.error(format!(
                "includes nest deeper than {MAX_INCLUDE_DEPTH} (does \"{name}\" include itself?)"
            )));
        }
        let bytes = self.open(&name, pos)?;
        let text = String::from_utf8(bytes)
            .map_err(|_| pos.error(format!("\"{name}\" is not UTF-8 text")))?;
        self.run(&name, &text, depth + 1)
    }

    /// `WorldBegin`: the transform resets to the identity, which is also the named
    /// coordinate system "world".
    pub(super) fn world_begin(&mut self) -> Result<(), ImportError> {
        self.world = true;
        self.named_coords.insert("world".into(), DMat4::IDENTITY);
        self.state.ctm = DMat4::IDENTITY;
        Ok(())
    }
}

/// Refuses a transform without an inverse (a zero scale, a matrix of determinant 0, a
/// product that underflows): the shapes it places would be flat or a point, their normals
/// (the inverse transpose) and a camera's world-from-camera undefined. pbrt-v4 accepts it
/// and renders NaNs or nothing; an error at the directive says why.
fn invertible(m: &DMat4, pos: &Pos, what: &str) -> Result<(), ImportError> {
    let det = DMat3::from_mat4(*m).determinant();
    if det == 0.0 || !det.is_finite() || !m.inverse().is_finite() {
        return Err(pos.error(format!(
            "{what} is degenerate (determinant {det}): it has no inverse"
        )));
    }
    Ok(())
}

/// A number as a message shows it: plain, or in exponent form when very small or large.
fn num(x: f64) -> String {
    if x == 0.0 || (1e-4..1e9).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// pbrt's `LookAt`: camera-from-world for an eye at `pos` looking at `look` (pbrt-v4
/// `transform.cpp`: right = up × dir, a left-handed frame).
fn look_at(pos: DVec3, look: DVec3, up: DVec3) -> Option<DMat4> {
    let dir = (look - pos).try_normalize()?;
    let right = up.try_normalize()?.cross(dir).try_normalize()?;
    let new_up = dir.cross(right);
    let world_from_camera = DMat4::from_cols(
        right.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        DVec4::new(pos.x, pos.y, pos.z, 1.0),
    );
    Some(world_from_camera.inverse())
}
