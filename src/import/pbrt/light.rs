//! Lights (pbrt-v4 file format, "Lights" and "Area lights"): `AreaLightSource` makes the
//! shapes that follow emissive; `LightSource` adds a point, spot, distant or infinite
//! light at the current transform.

use glam::{DMat4, DVec3};

use super::lexer::{Lexer, Pos};
use super::params::{self, Params};
use super::{list_cap, Emission, ImportError, Importer};
use crate::scene::doc::{
    DirectionalLightDoc, EnvironmentLightDoc, FalloffDoc, LightDoc, PointLightDoc, SpotLightDoc,
};

impl Importer<'_> {
    /// `AreaLightSource "diffuse"`: the emission of the shapes that follow in this
    /// attribute block.
    pub(super) fn area_light(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        let ty = Self::string(lx, pos, dir)?;
        let p = params::parse(lx, &list_cap)?;
        if ty != "diffuse" {
            return Err(pos.error(format!(
                "area light \"{ty}\" is not supported (only \"diffuse\")"
            )));
        }
        if p.get("filename").is_some() {
            return Err(pos.error("image area lights (filename) are not supported"));
        }
        let l = self.spectrum(&p, "L", [1.0; 3])?;
        let s = p.float("scale", 1.0)?;
        self.state.area = Some(Emission {
            radiance: l.map(|c| c * s),
            two_sided: p.boolean("twosided", false)?,
        });
        Ok(())
    }

    /// `LightSource`: one light of the document, placed by the current transform.
    pub(super) fn light_source(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        let ty = Self::string(lx, pos, dir)?;
        let p = params::parse(lx, &list_cap)?;
        let scale = p.float("scale", 1.0)?;
        let m = self.state.ctm;
        let (light, frame) = match ty.as_str() {
            "point" => self.point_light(&p, &m, scale, pos)?,
            "spot" => self.spot_light(&p, &m, scale, pos)?,
            "distant" => self.distant_light(&p, &m, scale, pos)?,
            "infinite" => self.infinite_light(&p, scale, pos)?,
            other => {
                return Err(pos.error(format!(
                    "light \"{other}\" is not supported (point, spot, distant, infinite)"
                )))
            }
        };
        self.lights.push(light);
        self.light_frames.push(frame);
        Ok(())
    }

    fn point_light(
        &mut self,
        p: &Params,
        m: &DMat4,
        scale: f64,
        pos: &Pos,
    ) -> Result<(LightDoc, Frame), ImportError> {
        if p.get("power").is_some() {
            self.warn(pos, "light \"power\" ignored: the intensity I is used");
        }
        let i = self.spectrum(p, "I", [1.0; 3])?;
        let from = p.triple("from")?.unwrap_or([0.0; 3]);
        let at = m.transform_point3(DVec3::from(from));
        let light = LightDoc::Point(PointLightDoc {
            position: at.as_vec3().to_array(),
            intensity: i.map(|c| (c * scale) as f32),
        });
        Ok((light, (Some(at), None)))
    }

    fn spot_light(
        &mut self,
        p: &Params,
        m: &DMat4,
        scale: f64,
        pos: &Pos,
    ) -> Result<(LightDoc, Frame), ImportError> {
        if p.get("power").is_some() {
            self.warn(pos, "light \"power\" ignored: the intensity I is used");
        }
        let i = self.spectrum(p, "I", [1.0; 3])?;
        let from = DVec3::from(p.triple("from")?.unwrap_or([0.0; 3]));
        let to = DVec3::from(p.triple("to")?.unwrap_or([0.0, 0.0, 1.0]));
        let at = m.transform_point3(from);
        let d = m
            .transform_vector3(to - from)
            .try_normalize()
            .ok_or_else(|| pos.error("spot light: from and to coincide"))?;
        // pbrt-v4 SpotLight: full intensity within coneangle − conedelta of the
        // axis, smoothstep in cos θ down to zero at coneangle.
        let cone = p.float("coneangle", 30.0)?;
        let delta = p.float("conedelta", 5.0)?;
        if !(0.0..=180.0).contains(&cone) || delta.is_nan() || delta < 0.0 {
            return Err(pos.error(format!(
                "spot light: coneangle must be in [0, 180] and conedelta ≥ 0, got {cone} and {delta}"
            )));
        }
        let light = LightDoc::Spot(SpotLightDoc {
            position: at.as_vec3().to_array(),
            direction: d.as_vec3().to_array(),
            intensity: i.map(|c| (c * scale) as f32),
            outer_angle: cone as f32,
            inner_angle: (cone - delta).max(0.0) as f32,
            falloff: FalloffDoc::Smoothstep,
        });
        Ok((light, (Some(at), Some(d))))
    }

    fn distant_light(
        &mut self,
        p: &Params,
        m: &DMat4,
        scale: f64,
        pos: &Pos,
    ) -> Result<(LightDoc, Frame), ImportError> {
        let l = self.spectrum(p, "L", [1.0; 3])?;
        let from = DVec3::from(p.triple("from")?.unwrap_or([0.0; 3]));
        let to = DVec3::from(p.triple("to")?.unwrap_or([0.0, 0.0, 1.0]));
        // The light travels from `from` toward `to`.
        let d = m
            .transform_vector3(to - from)
            .try_normalize()
            .ok_or_else(|| pos.error("distant light: from and to coincide"))?;
        let light = LightDoc::Directional(DirectionalLightDoc {
            direction: d.as_vec3().to_array(),
            irradiance: l.map(|c| (c * scale) as f32),
        });
        Ok((light, (None, Some(d))))
    }

    fn infinite_light(
        &mut self,
        p: &Params,
        scale: f64,
        pos: &Pos,
    ) -> Result<(LightDoc, Frame), ImportError> {
        if p.get("filename").is_some() {
            return Err(
                pos.error("environment maps (infinite light with filename) are not supported")
            );
        }
        let l = self.spectrum(p, "L", [1.0; 3])?;
        let light = LightDoc::Environment(EnvironmentLightDoc {
            radiance: l.map(|c| (c * scale) as f32),
        });
        Ok((light, (None, None)))
    }
}

/// A light in pbrt's world, before any mirroring: (position, direction).
type Frame = (Option<DVec3>, Option<DVec3>);
