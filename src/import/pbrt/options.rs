//! pbrt-v4's scene-wide rendering options, read before `WorldBegin`: the camera, film,
//! sampler, integrator and pixel filter, and the settings that do not change the picture
//! (scene-import.md, "How faithful"). Directives for what Glimpse does not model
//! (participating media) are skipped with a warning.

use super::lexer::{Lexer, Pos, Tok};
use super::params::{self, Params};
use super::{list_cap, ImportError, Importer, MAX_LIST};
use crate::scene::SamplerKind;

impl Importer<'_> {
    /// `Camera`: a perspective camera's field of view, at the current transform
    /// (camera-from-world), which is also the named coordinate system "camera".
    pub(super) fn camera(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        let ty = Self::string(lx, pos, dir)?;
        let p = params::parse(lx, &list_cap)?;
        if ty != "perspective" {
            return Err(pos.error(format!(
                "camera \"{ty}\" is not supported (Glimpse has a pinhole perspective camera)"
            )));
        }
        if p.float("lensradius", 0.0)? > 0.0 {
            self.warn(
                pos,
                "depth of field (lensradius) is not modelled: rendered as a pinhole",
            );
        }
        let fov = p.float("fov", 90.0)?;
        if !(fov > 0.0 && fov < 180.0) {
            return Err(pos.error(format!("fov must be in (0, 180), got {fov}")));
        }
        let inv = self.state.ctm.inverse();
        if !inv.is_finite() {
            return Err(pos.error("the camera transform is not invertible"));
        }
        self.named_coords.insert("camera".into(), inv);
        self.camera = Some((self.state.ctm, fov));
        Ok(())
    }

    /// `Film`, `Sampler`, `Integrator` and `PixelFilter`: a type name, then parameters.
    pub(super) fn render_option(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        let ty = Self::string(lx, pos, dir)?;
        let p = params::parse(lx, &list_cap)?;
        match dir {
            "Film" => self.film(&p, pos),
            "Sampler" => self.sampler(&ty, &p, pos),
            "Integrator" => self.integrator(&ty, &p, pos),
            // `PixelFilter`
            _ => {
                if ty != "box" {
                    self.warn(pos, format!("pixel filter \"{ty}\": Glimpse averages each pixel's samples (a box filter)"));
                }
                Ok(())
            }
        }
    }

    fn film(&mut self, p: &Params, pos: &Pos) -> Result<(), ImportError> {
        let w = p.float("xresolution", 1280.0)?;
        let h = p.float("yresolution", 720.0)?;
        if !(w >= 1.0 && h >= 1.0) {
            return Err(pos.error(format!("the film must be at least 1×1, got {w}×{h}")));
        }
        self.size = (w as u64, h as u64);
        if p.get("cropwindow").is_some() {
            self.warn(pos, "Film cropwindow ignored: the whole image is rendered");
        }
        Ok(())
    }

    fn sampler(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<(), ImportError> {
        let n = p.float("pixelsamples", 16.0)?;
        if n < 1.0 {
            return Err(pos.error(format!("pixelsamples must be ≥ 1, got {n}")));
        }
        self.spp = n as u64;
        self.sampler = match ty {
            "independent" => SamplerKind::Independent,
            "zsobol" => SamplerKind::ZSobol,
            "sobol" | "paddedsobol" => SamplerKind::Sobol,
            // Low-discrepancy samplers Glimpse does not have: the closest it has, said.
            other => {
                self.warn(
                    pos,
                    format!("Sampler \"{other}\": rendered with Glimpse's Sobol sampler (same image, other noise)"),
                );
                SamplerKind::Sobol
            }
        };
        Ok(())
    }

    fn integrator(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<(), ImportError> {
        let d = p.float("maxdepth", 5.0)?;
        if d < 0.0 {
            return Err(pos.error(format!("maxdepth must be ≥ 0, got {d}")));
        }
        self.max_depth = d as u64;
        if !matches!(ty, "path" | "volpath") {
            self.warn(pos, format!("integrator \"{ty}\": rendered with Glimpse's path tracer (same image, other noise)"));
        }
        Ok(())
    }

    /// `ColorSpace`, `Option` and `Accelerator`: only settings that do not change the
    /// picture in RGB (a `ColorSpace` other than sRGB would, and is refused).
    pub(super) fn setting(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        if dir == "ColorSpace" {
            let cs = Self::string(lx, pos, dir)?;
            if cs != "srgb" {
                return Err(pos.error(format!("color space \"{cs}\" is not supported (sRGB only)")));
            }
        } else if dir == "Option" {
            let _ = params::parse(lx, &list_cap)?;
        } else {
            let _ = Self::string(lx, pos, dir)?;
            let _ = params::parse(lx, &list_cap)?;
        }
        Ok(())
    }

    /// `MakeNamedMedium`, `MediumInterface` and `Attribute`: participating media and
    /// attribute defaults are not modelled. Their parameters are skipped up to the next
    /// directive (a bare word other than a bool); their numbers count against the list
    /// cap too.
    pub(super) fn unmodelled(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        let mut n = 0usize;
        while let Some((t, p)) = lx.peek()? {
            if matches!(t, Tok::Word(w) if w != "true" && w != "false") {
                break;
            }
            n += 1;
            if n > MAX_LIST {
                return Err(ImportError::limit(
                    p.to_string(),
                    format!("`{dir}` holds more than {MAX_LIST} values"),
                ));
            }
            lx.take()?;
        }
        self.warn(pos, format!("`{dir}` is not modelled: ignored"));
        Ok(())
    }
}
