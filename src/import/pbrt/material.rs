//! Materials and textures (pbrt-v4 file format, "Materials" and "Textures"): the
//! `Material`, `MakeNamedMaterial`, `NamedMaterial` and `Texture` directives, the colour
//! and spectrum parameters they take, and each material type as a document material
//! (scene-import.md, "How faithful", says what is approximated).

use super::lexer::{Lexer, Pos};
use super::params::{self, Params, Values};
use super::{list_cap, ImportError, Importer, Reflectance};
use crate::import::texture::{self as image, Encoding};
use crate::scene::doc::{
    CoatedDiffuseDoc, ConductorDoc, DielectricDoc, DiffuseDoc, ImageTextureDoc, MaterialDoc,
    TextureDoc, WrapDoc,
};

/// Complex refractive indices (η, k) of pbrt-v4's named metal spectra as linear sRGB
/// triples. pbrt-v4 keeps the measured spectra; Glimpse renders in RGB, so it uses the
/// RGB reductions that RGB renderers commonly ship for these metals (the values
/// Bitterli's own scenes here write out for copper and aluminium).
const METALS: [(&str, [f64; 3], [f64; 3]); 5] = [
    (
        "Ag",
        [0.155_265, 0.116_723, 0.138_342],
        [4.828_35, 3.122_25, 2.146_96],
    ),
    (
        "Al",
        [1.657_46, 0.880_369, 0.521_229],
        [9.223_87, 6.269_52, 4.837],
    ),
    (
        "Au",
        [0.143_119, 0.374_957, 1.442_48],
        [3.983_16, 2.385_72, 1.603_22],
    ),
    (
        "Cu",
        [0.200_438, 0.924_033, 1.102_21],
        [3.912_95, 2.452_85, 2.142_19],
    ),
    ("CuZn", [0.444, 0.527, 1.094], [3.695, 2.765, 1.829]),
];

/// A linear RGB triple as the document stores it.
fn rgb(v: [f64; 3]) -> [f32; 3] {
    v.map(|c| c as f32)
}

impl Importer<'_> {
    /// `Material` (anonymous, made current), `MakeNamedMaterial` (named, not made
    /// current) and `NamedMaterial` (made current by name).
    pub(super) fn material_directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        match dir {
            "Material" => {
                let ty = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &list_cap)?;
                self.anonymous += 1;
                let name = format!("material-{}", self.anonymous);
                let m = self.material(&ty, &p, pos)?;
                self.materials.insert(name.clone(), m);
                self.state.material = name;
            }
            "MakeNamedMaterial" => {
                let name = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &list_cap)?;
                let ty = p
                    .string("type")?
                    .map(|(t, _)| t.to_string())
                    .ok_or_else(|| {
                        pos.error(format!("named material \"{name}\" has no \"string type\""))
                    })?;
                let m = self.material(&ty, &p, pos)?;
                self.materials.insert(name, m);
            }
            // `NamedMaterial`
            _ => {
                let name = Self::string(lx, pos, dir)?;
                if !self.materials.contains_key(&name) {
                    return Err(pos.error(format!(
                        "unknown material \"{name}\" (not made by MakeNamedMaterial before)"
                    )));
                }
                self.state.material = name;
            }
        }
        Ok(())
    }

    /// `Texture "name" "type" "class" params`.
    pub(super) fn texture_directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        let name = Self::string(lx, pos, dir)?;
        let _kind = Self::string(lx, pos, dir)?;
        let class = Self::string(lx, pos, dir)?;
        let p = params::parse(lx, &list_cap)?;
        let c = self.texture(&name, &class, &p, pos)?;
        self.textures.insert(name, c);
        Ok(())
    }

    /// An RGB parameter (`rgb`, or a named metal spectrum's RGB is not meant here).
    pub(super) fn spectrum(
        &self,
        p: &Params,
        name: &str,
        default: [f64; 3],
    ) -> Result<[f64; 3], ImportError> {
        let Some(param) = p.get(name) else {
            return Ok(default);
        };
        match (param.ty.as_str(), &param.values) {
            ("rgb" | "color", Values::Nums(v)) if v.len() == 3 => {
                if v.iter().any(|c| *c < 0.0) {
                    return Err(param.pos.error(format!("\"{name}\" must be ≥ 0, got {v:?}")));
                }
                Ok([v[0], v[1], v[2]])
            }
            ("float", Values::Nums(v)) if v.len() == 1 => Ok([v[0]; 3]),
            ("blackbody", _) => Err(param.pos.error(format!(
                "\"{name}\": blackbody emission is not supported; give \"rgb {name}\""
            ))),
            _ => Err(param.pos.error(format!(
                "\"{name}\" must be an \"rgb\" triple (spectra other than named metals are not supported)"
            ))),
        }
    }

    /// A reflectance: an RGB, a float, or a texture.
    fn reflectance(
        &self,
        p: &Params,
        name: &str,
        default: [f64; 3],
    ) -> Result<Reflectance, ImportError> {
        match p.get(name) {
            Some(param) if param.ty == "texture" => {
                let (t, pos) = p
                    .string(name)?
                    .ok_or_else(|| param.pos.error("texture name expected"))?;
                self.textures
                    .get(t)
                    .cloned()
                    .ok_or_else(|| pos.error(format!("unknown texture \"{t}\"")))
            }
            _ => self.spectrum(p, name, default).map(Reflectance::Rgb),
        }
    }

    /// η or k of a conductor: RGB or a named metal spectrum.
    fn metal(&self, p: &Params, name: &str, default: &str) -> Result<[f64; 3], ImportError> {
        let (spec, pos) = match p.get(name) {
            None => (default.to_string(), None),
            Some(param) => match (&param.ty[..], &param.values) {
                ("spectrum", Values::Strs(s)) if s.len() == 1 => (s[0].clone(), Some(&param.pos)),
                _ => return self.spectrum(p, name, [0.0; 3]),
            },
        };
        let err = || {
            let known: Vec<String> = METALS
                .iter()
                .map(|m| format!("metal-{}-{name}", m.0))
                .collect();
            let msg = format!("unknown spectrum \"{spec}\" (known: {})", known.join(", "));
            match pos {
                Some(p) => p.error(msg),
                None => ImportError::invalid("", msg),
            }
        };
        let metal = spec
            .strip_prefix("metal-")
            .and_then(|s| s.strip_suffix(&format!("-{name}")))
            .ok_or_else(err)?;
        let (_, eta, k) = METALS.iter().find(|m| m.0 == metal).ok_or_else(err)?;
        Ok(if name == "eta" { *eta } else { *k })
    }

    fn material(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<MaterialDoc, ImportError> {
        Ok(match ty {
            "diffuse" => match self.reflectance(p, "reflectance", [0.5; 3])? {
                Reflectance::Rgb(r) => MaterialDoc::Diffuse(DiffuseDoc {
                    albedo: Some(rgb(r.map(|c| c.min(1.0)))),
                    texture: None,
                }),
                Reflectance::Image(t) => MaterialDoc::Diffuse(DiffuseDoc {
                    albedo: None,
                    texture: Some(TextureDoc::Image(t)),
                }),
            },
            "conductor" => self.conductor(p, pos)?,
            "coateddiffuse" => self.coated_diffuse(p, pos)?,
            "dielectric" | "thindielectric" => self.dielectric(ty, p, pos)?,
            other => {
                self.warn(
                    pos,
                    format!("material \"{other}\" is not modelled: rendered as grey diffuse (0.5)"),
                );
                MaterialDoc::Diffuse(DiffuseDoc {
                    albedo: Some([0.5; 3]),
                    texture: None,
                })
            }
        })
    }

    fn conductor(&mut self, p: &Params, pos: &Pos) -> Result<MaterialDoc, ImportError> {
        if p.get("reflectance").is_some() {
            self.warn(
                pos,
                "conductor \"reflectance\" is not modelled: rendered with eta and k",
            );
        }
        let eta = self.metal(p, "eta", "metal-Cu-eta")?;
        let k = self.metal(p, "k", "metal-Cu-k")?;
        let roughness = self.roughness(p, pos)?;
        Ok(MaterialDoc::Conductor(ConductorDoc {
            eta: rgb(eta),
            k: rgb(k),
            roughness,
        }))
    }

    fn coated_diffuse(&mut self, p: &Params, pos: &Pos) -> Result<MaterialDoc, ImportError> {
        let eta = self.glass_eta(p)?;
        if eta.is_nan() || eta <= 0.0 {
            return Err(pos.error(format!("coateddiffuse eta must be > 0, got {eta}")));
        }
        if p.get("albedo").is_some() || p.get("g").is_some() {
            self.warn(pos, "coateddiffuse: the medium between coat and base (albedo, g, thickness) is not modelled: clear");
        }
        let roughness = self.roughness(p, pos)?;
        let (reflectance, texture) = match self.reflectance(p, "reflectance", [0.5; 3])? {
            Reflectance::Rgb(r) => (Some(rgb(r.map(|c| c.min(1.0)))), None),
            Reflectance::Image(t) => (None, Some(TextureDoc::Image(t))),
        };
        Ok(MaterialDoc::CoatedDiffuse(CoatedDiffuseDoc {
            reflectance,
            texture,
            roughness,
            ior: eta as f32,
        }))
    }

    fn dielectric(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<MaterialDoc, ImportError> {
        let eta = self.glass_eta(p)?;
        if self.roughness(p, pos)? > 0.0 {
            self.warn(pos, "rough dielectric: rendered smooth");
        }
        if ty == "thindielectric" {
            self.warn(pos, "thindielectric: rendered as a solid dielectric");
        }
        if eta.is_nan() || eta <= 0.0 {
            return Err(pos.error(format!("dielectric eta must be > 0, got {eta}")));
        }
        Ok(MaterialDoc::Dielectric(DielectricDoc {
            ior: eta as f32,
            tint: None,
        }))
    }

    /// A dielectric's η: a number, or a named glass spectrum read as 1.5 (Glimpse has
    /// no dispersion).
    fn glass_eta(&mut self, p: &Params) -> Result<f64, ImportError> {
        Ok(match p.get("eta") {
            Some(param) if matches!(param.values, Values::Strs(_)) => {
                self.warn(&param.pos, "named glass spectrum: rendered with η = 1.5");
                1.5
            }
            _ => p.float("eta", 1.5)?,
        })
    }

    /// pbrt's GGX alpha (after `remaproughness`) as Glimpse's roughness (alpha = r²).
    fn roughness(&mut self, p: &Params, pos: &Pos) -> Result<f32, ImportError> {
        let r = p.float("roughness", 0.0)?;
        let u = p.float("uroughness", r)?;
        let v = p.float("vroughness", r)?;
        if (u - v).abs() > 1e-9 {
            self.warn(pos, format!("anisotropic roughness ({u}, {v}): rendered isotropic with their geometric mean"));
        }
        let r = (u * v).max(0.0).sqrt();
        // pbrt-v4 RoughnessToAlpha: alpha = √roughness when remapped.
        let alpha = if p.boolean("remaproughness", true)? {
            r.sqrt()
        } else {
            r
        };
        Ok(alpha.sqrt().clamp(0.0, 1.0) as f32)
    }

    fn texture(
        &mut self,
        name: &str,
        class: &str,
        p: &Params,
        pos: &Pos,
    ) -> Result<Reflectance, ImportError> {
        match class {
            "imagemap" => self.image_texture(name, p, pos),
            "constant" => self.spectrum(p, "value", [1.0; 3]).map(Reflectance::Rgb),
            other => {
                self.warn(pos, format!("texture \"{name}\" of class \"{other}\" is not modelled: rendered as grey 0.5"));
                Ok(Reflectance::Rgb([0.5; 3]))
            }
        }
    }

    /// An `imagemap` texture: the image read and decoded, then its scale, wrap and
    /// (u, v) mapping. A missing image is a warning and grey 0.5.
    fn image_texture(
        &mut self,
        name: &str,
        p: &Params,
        pos: &Pos,
    ) -> Result<Reflectance, ImportError> {
        let (file, fpos) = p
            .string("filename")?
            .ok_or_else(|| pos.error(format!("texture \"{name}\" has no filename")))?;
        let (file, fpos) = (file.to_string(), fpos.clone());
        let lower = file.to_ascii_lowercase();
        // pbrt-v4 reads 8-bit PNGs as sRGB and TGAs as linear unless "encoding"
        // says otherwise.
        let encoding = match p.string("encoding")?.map(|(e, _)| e) {
            Some("linear") => Encoding::Linear,
            Some(_) => Encoding::Srgb,
            None if lower.ends_with(".tga") => Encoding::Linear,
            None => Encoding::Srgb,
        };
        let scale = p.float("scale", 1.0)?;
        let bytes = match self.open(&file, &fpos) {
            Ok(b) => b,
            Err(e) if e.too_large => return Err(e),
            Err(e) => {
                // Public scenes ship without some of their textures (veach-ajar):
                // the texture is greyed out rather than the scene refused.
                self.warn(
                    &fpos,
                    format!("{}: texture \"{name}\" rendered as grey 0.5", e.message),
                );
                return Ok(Reflectance::Rgb([0.5; 3]));
            }
        };
        let mut doc = image::image_texture(
            &file,
            None,
            &bytes,
            encoding,
            self.limits.max_texture_pixels,
        )
        .map_err(|e| fpos.error(format!("\"{file}\": {e}")))?;
        if !(0.0..=1.0).contains(&scale) {
            self.warn(
                pos,
                format!("texture \"{name}\": scale {scale} clamped to [0, 1] (a reflectance)"),
            );
        }
        doc.factor = [scale.clamp(0.0, 1.0) as f32; 3];
        if p.boolean("invert", false)? {
            self.warn(pos, format!("texture \"{name}\": invert is not modelled"));
        }
        self.texture_mapping(&mut doc, name, p, pos)?;
        Ok(Reflectance::Image(doc))
    }

    /// An image texture's wrap mode and (u, v) mapping.
    fn texture_mapping(
        &mut self,
        doc: &mut ImageTextureDoc,
        name: &str,
        p: &Params,
        pos: &Pos,
    ) -> Result<(), ImportError> {
        doc.wrap = match p.string("wrap")?.map(|(w, _)| w) {
            None | Some("repeat") => WrapDoc::Repeat,
            Some("black") => WrapDoc::Black,
            Some("clamp") => WrapDoc::Clamp,
            Some(other) => {
                self.warn(
                    pos,
                    format!("texture \"{name}\": wrap \"{other}\" rendered as repeat"),
                );
                WrapDoc::Repeat
            }
        };
        // pbrt-v4 UVMapping: (s, t) = (su·u + du, sv·v + dv), and ImageTexture reads
        // the image at (s, 1 − t) with (0, 0) its top-left corner; the document's
        // mapping is uv × uv_scale + uv_offset on the same image axes.
        let (su, sv) = (p.float("uscale", 1.0)?, p.float("vscale", 1.0)?);
        let (du, dv) = (p.float("udelta", 0.0)?, p.float("vdelta", 0.0)?);
        if let Some((m, _)) = p.string("mapping")?.filter(|(m, _)| *m != "uv") {
            self.warn(
                pos,
                format!("texture \"{name}\": mapping \"{m}\" rendered as uv"),
            );
        }
        doc.uv_scale = [su as f32, -sv as f32];
        doc.uv_offset = [du as f32, (1.0 - dv) as f32];
        Ok(())
    }
}
