//! The pbrt-v4 importer: the directives, shapes, materials, textures and lights public
//! pbrt-v4 scenes use (scene-import.md), read by our own tokenizer ([`lexer`]) and
//! parameter reader ([`params`]). Every error names the file, line and column.
//!
//! Conventions carried over from pbrt-v4 (pbrt-v4 source and file-format documentation):
//! - the transform current at `Camera` is camera-from-world; `Transform` and
//!   `ConcatTransform` take the matrix column by column (pbrt transposes what it reads);
//! - pbrt's camera space is left-handed (x right, y up, z forward); Glimpse's camera
//!   takes right = forward × up. When the camera-to-world rotation keeps handedness (a
//!   `LookAt` without a mirroring `Scale`), the world is mirrored across the camera's
//!   vertical plane so the picture is the same, not its mirror image;
//! - a triangle's surface normal is its winding's, flipped when the shape's transform
//!   swaps handedness or `ReverseOrientation` is set, and turned toward the shading
//!   normals when the mesh has them; one-sided area lights emit on that side, so each
//!   triangle is re-wound to make Glimpse's geometric normal that normal;
//! - `fov` is the field of view of the image's shorter axis;
//! - `maxdepth` counts scattering events, as Glimpse's `max_bounces` does.

pub mod lexer;
pub mod params;

use std::collections::{BTreeMap, HashMap};

use glam::{DMat3, DMat4, DVec3, DVec4};

use self::lexer::{Pos, Tok};
use self::params::{Params, Values};
use super::texture::Encoding;
use super::{FileSource, ImportError, ImportLimits, Imported};
use crate::scene::doc::{
    CameraDoc, CoatedDiffuseDoc, ConductorDoc, DielectricDoc, DiffuseDoc, DirectionalLightDoc,
    EmissiveDoc, EnvironmentLightDoc, FalloffDoc, ImageTextureDoc, LightDoc, MaterialDoc, MeshDoc,
    ObjectDoc, PointLightDoc, RenderDoc, SceneDoc, SphereDoc, SpotLightDoc, TextureDoc, WrapDoc,
};

/// Includes may nest this deep (a file including itself is refused here).
const MAX_INCLUDE_DEPTH: usize = 16;

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

/// What a shape is made of: a material by key, and an area light's emission if one is
/// active (an area light's shape becomes an emissive object).
#[derive(Clone, Debug, PartialEq)]
struct Emission {
    radiance: [f64; 3],
    two_sided: bool,
}

/// A material's colour parameter: a constant or an image texture.
#[derive(Clone, Debug)]
enum Reflectance {
    Rgb([f64; 3]),
    Image(ImageTextureDoc),
}

/// The graphics state pbrt saves with `AttributeBegin`.
#[derive(Clone, Debug)]
struct State {
    ctm: DMat4,
    reverse: bool,
    material: String,
    area: Option<Emission>,
}

/// A shape in pbrt's world space.
#[derive(Clone, Debug)]
enum Prim {
    Mesh {
        positions: Vec<DVec3>,
        normals: Option<Vec<DVec3>>,
        /// pbrt's own (u, v) per point, untransformed.
        uvs: Option<Vec<[f32; 2]>>,
        indices: Vec<[u32; 3]>,
        /// Surface normal = −winding normal (the transform swaps handedness xor
        /// `ReverseOrientation`); ignored when there are normals.
        flip: bool,
        material: String,
        emission: Option<Emission>,
    },
    Sphere {
        center: DVec3,
        radius: f64,
        material: String,
        emission: Option<Emission>,
    },
}

struct Importer<'a> {
    files: &'a dyn FileSource,
    limits: &'a ImportLimits,
    state: State,
    stack: Vec<(State, Pos)>,
    named_coords: HashMap<String, DMat4>,
    materials: BTreeMap<String, MaterialDoc>,
    /// Texture name → a colour or an image.
    textures: HashMap<String, Reflectance>,
    anonymous: usize,
    camera: Option<(DMat4, f64)>,
    size: (u64, u64),
    spp: u64,
    max_depth: u64,
    world: bool,
    prims: Vec<Prim>,
    instances: HashMap<String, Vec<Prim>>,
    defining: Option<(String, Vec<Prim>)>,
    lights: Vec<LightDoc>,
    /// Lights in pbrt's world, before any mirroring: (position, direction).
    light_frames: Vec<(Option<DVec3>, Option<DVec3>)>,
    triangles: usize,
    files_opened: usize,
    warnings: Vec<String>,
}

/// Imports the pbrt scene `text` (the contents of `name`).
pub fn import(
    name: &str,
    text: &str,
    files: &dyn FileSource,
    limits: &ImportLimits,
) -> Result<Imported, ImportError> {
    let mut im = Importer {
        files,
        limits,
        state: State {
            ctm: DMat4::IDENTITY,
            reverse: false,
            material: String::new(),
            area: None,
        },
        stack: Vec::new(),
        named_coords: HashMap::new(),
        materials: BTreeMap::new(),
        textures: HashMap::new(),
        anonymous: 0,
        camera: None,
        size: (1280, 720),
        spp: 16,
        max_depth: 5,
        world: false,
        prims: Vec::new(),
        instances: HashMap::new(),
        defining: None,
        lights: Vec::new(),
        light_frames: Vec::new(),
        triangles: 0,
        files_opened: 0,
        warnings: Vec::new(),
    };
    im.run(name, text, 0)?;
    if let Some((s, pos)) = im.stack.last() {
        let _ = s;
        return Err(pos.error("`AttributeBegin` without a matching `AttributeEnd`"));
    }
    im.finish(name)
}

impl Importer<'_> {
    fn warn(&mut self, pos: &Pos, msg: impl Into<String>) {
        self.warnings.push(format!("{pos}: {}", msg.into()));
    }

    fn run(&mut self, file: &str, text: &str, depth: usize) -> Result<(), ImportError> {
        let toks = lexer::tokenize(file, text)?;
        let mut at = 0;
        while let Some((tok, pos)) = toks.get(at) {
            at += 1;
            let Tok::Word(dir) = tok else {
                return Err(pos.error(format!("expected a directive, got {}", tok.describe())));
            };
            self.directive(dir, pos, &toks, &mut at, depth)?;
        }
        Ok(())
    }

    /// `n` numbers, bare or in brackets.
    fn numbers(
        toks: &[(Tok, Pos)],
        at: &mut usize,
        n: usize,
        pos: &Pos,
        dir: &str,
    ) -> Result<Vec<f64>, ImportError> {
        let bracket = matches!(toks.get(*at), Some((Tok::Open, _)));
        if bracket {
            *at += 1;
        }
        let mut out = Vec::with_capacity(n);
        while out.len() < n {
            match toks.get(*at) {
                Some((Tok::Num(v), _)) => {
                    out.push(*v);
                    *at += 1;
                }
                _ => return Err(pos.error(format!("`{dir}` takes {n} numbers, got {}", out.len()))),
            }
        }
        if bracket {
            match toks.get(*at) {
                Some((Tok::Close, _)) => *at += 1,
                _ => return Err(pos.error(format!("`{dir}`: `]` expected after {n} numbers"))),
            }
        }
        Ok(out)
    }

    fn string(
        toks: &[(Tok, Pos)],
        at: &mut usize,
        pos: &Pos,
        dir: &str,
    ) -> Result<String, ImportError> {
        match toks.get(*at) {
            Some((Tok::Str(s), _)) => {
                *at += 1;
                Ok(s.clone())
            }
            _ => Err(pos.error(format!("`{dir}` needs a quoted name"))),
        }
    }

    fn directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        toks: &[(Tok, Pos)],
        at: &mut usize,
        depth: usize,
    ) -> Result<(), ImportError> {
        match dir {
            "Identity" => self.state.ctm = DMat4::IDENTITY,
            "Translate" => {
                let v = Self::numbers(toks, at, 3, pos, dir)?;
                self.concat(DMat4::from_translation(DVec3::new(v[0], v[1], v[2])));
            }
            "Scale" => {
                let v = Self::numbers(toks, at, 3, pos, dir)?;
                self.concat(DMat4::from_scale(DVec3::new(v[0], v[1], v[2])));
            }
            "Rotate" => {
                let v = Self::numbers(toks, at, 4, pos, dir)?;
                let axis = DVec3::new(v[1], v[2], v[3]);
                let axis = axis
                    .try_normalize()
                    .ok_or_else(|| pos.error("`Rotate` needs a non-zero axis"))?;
                self.concat(DMat4::from_axis_angle(axis, v[0].to_radians()));
            }
            "LookAt" => {
                let v = Self::numbers(toks, at, 9, pos, dir)?;
                let m = look_at(
                    DVec3::new(v[0], v[1], v[2]),
                    DVec3::new(v[3], v[4], v[5]),
                    DVec3::new(v[6], v[7], v[8]),
                )
                .ok_or_else(|| {
                    pos.error("`LookAt`: the eye equals the target or `up` is parallel to the view")
                })?;
                self.concat(m);
            }
            "Transform" | "ConcatTransform" => {
                let v = Self::numbers(toks, at, 16, pos, dir)?;
                let mut a = [0.0; 16];
                a.copy_from_slice(&v);
                // The list is pbrt's matrix transposed, i.e. column-major: glam's order.
                let m = DMat4::from_cols_array(&a);
                if dir == "Transform" {
                    self.state.ctm = m;
                } else {
                    self.concat(m);
                }
            }
            "CoordinateSystem" => {
                let n = Self::string(toks, at, pos, dir)?;
                self.named_coords.insert(n, self.state.ctm);
            }
            "CoordSysTransform" => {
                let n = Self::string(toks, at, pos, dir)?;
                self.state.ctm = *self
                    .named_coords
                    .get(&n)
                    .ok_or_else(|| pos.error(format!("unknown coordinate system \"{n}\"")))?;
            }
            "ReverseOrientation" => self.state.reverse = !self.state.reverse,
            "AttributeBegin" | "TransformBegin" => {
                if self.stack.len() >= 4096 {
                    return Err(pos.error("attribute blocks nest deeper than 4096"));
                }
                self.stack.push((self.state.clone(), pos.clone()));
            }
            "AttributeEnd" | "TransformEnd" => {
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
            "Include" | "Import" => {
                let name = Self::string(toks, at, pos, dir)?;
                if depth + 1 > MAX_INCLUDE_DEPTH {
                    return Err(pos.error(format!(
                        "includes nest deeper than {MAX_INCLUDE_DEPTH} (does \"{name}\" include itself?)"
                    )));
                }
                let bytes = self.open(&name, pos)?;
                let text = String::from_utf8(bytes)
                    .map_err(|_| pos.error(format!("\"{name}\" is not UTF-8 text")))?;
                self.run(&name, &text, depth + 1)?;
            }
            "WorldBegin" => {
                self.world = true;
                self.named_coords.insert("world".into(), DMat4::IDENTITY);
                self.state.ctm = DMat4::IDENTITY;
            }
            "WorldEnd" => {}
            "Camera" => {
                let ty = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
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
            }
            "Film" => {
                let _ = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                let w = p.float("xresolution", 1280.0)?;
                let h = p.float("yresolution", 720.0)?;
                if !(w >= 1.0 && h >= 1.0) {
                    return Err(pos.error(format!("the film must be at least 1×1, got {w}×{h}")));
                }
                self.size = (w as u64, h as u64);
                if p.get("cropwindow").is_some() {
                    self.warn(pos, "Film cropwindow ignored: the whole image is rendered");
                }
            }
            "Sampler" => {
                let _ = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                let n = p.float("pixelsamples", 16.0)?;
                if n < 1.0 {
                    return Err(pos.error(format!("pixelsamples must be ≥ 1, got {n}")));
                }
                self.spp = n as u64;
            }
            "Integrator" => {
                let ty = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                let d = p.float("maxdepth", 5.0)?;
                if d < 0.0 {
                    return Err(pos.error(format!("maxdepth must be ≥ 0, got {d}")));
                }
                self.max_depth = d as u64;
                if !matches!(ty.as_str(), "path" | "volpath") {
                    self.warn(pos, format!("integrator \"{ty}\": rendered with Glimpse's path tracer (same image, other noise)"));
                }
            }
            "PixelFilter" => {
                let ty = Self::string(toks, at, pos, dir)?;
                let _ = params::parse(toks, at)?;
                if ty != "box" {
                    self.warn(pos, format!("pixel filter \"{ty}\": Glimpse averages each pixel's samples (a box filter)"));
                }
            }
            "ColorSpace" | "Option" | "Accelerator" => {
                // Only settings that do not change the picture in RGB (ColorSpace other
                // than sRGB would, and is refused).
                if dir == "ColorSpace" {
                    let cs = Self::string(toks, at, pos, dir)?;
                    if cs != "srgb" {
                        return Err(
                            pos.error(format!("color space \"{cs}\" is not supported (sRGB only)"))
                        );
                    }
                } else if dir == "Option" {
                    let _ = params::parse(toks, at)?;
                } else {
                    let _ = Self::string(toks, at, pos, dir)?;
                    let _ = params::parse(toks, at)?;
                }
            }
            "MakeNamedMedium" | "MediumInterface" | "Attribute" => {
                // Participating media and attribute defaults are not modelled.
                while matches!(toks.get(*at), Some((Tok::Str(_), _))) {
                    let save = *at;
                    if params::parse(toks, at).is_err() || *at == save {
                        *at = save + 1;
                    }
                }
                self.warn(pos, format!("`{dir}` is not modelled: ignored"));
            }
            "Material" => {
                let ty = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                self.anonymous += 1;
                let name = format!("material-{}", self.anonymous);
                let m = self.material(&ty, &p, pos)?;
                self.materials.insert(name.clone(), m);
                self.state.material = name;
            }
            "MakeNamedMaterial" => {
                let name = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                let ty = p
                    .string("type")?
                    .map(|(t, _)| t.to_string())
                    .ok_or_else(|| {
                        pos.error(format!("named material \"{name}\" has no \"string type\""))
                    })?;
                let m = self.material(&ty, &p, pos)?;
                self.materials.insert(name, m);
            }
            "NamedMaterial" => {
                let name = Self::string(toks, at, pos, dir)?;
                if !self.materials.contains_key(&name) {
                    return Err(pos.error(format!(
                        "unknown material \"{name}\" (not made by MakeNamedMaterial before)"
                    )));
                }
                self.state.material = name;
            }
            "Texture" => {
                let name = Self::string(toks, at, pos, dir)?;
                let _kind = Self::string(toks, at, pos, dir)?;
                let class = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                let c = self.texture(&name, &class, &p, pos)?;
                self.textures.insert(name, c);
            }
            "AreaLightSource" => {
                let ty = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
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
            }
            "LightSource" => {
                let ty = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                self.light(&ty, &p, pos)?;
            }
            "Shape" => {
                let ty = Self::string(toks, at, pos, dir)?;
                let p = params::parse(toks, at)?;
                self.shape(&ty, &p, pos)?;
            }
            "ObjectBegin" => {
                let name = Self::string(toks, at, pos, dir)?;
                if self.defining.is_some() {
                    return Err(pos.error("`ObjectBegin` inside another object definition"));
                }
                self.stack.push((self.state.clone(), pos.clone()));
                self.defining = Some((name, Vec::new()));
            }
            "ObjectEnd" => {
                let (name, prims) = self
                    .defining
                    .take()
                    .ok_or_else(|| pos.error("`ObjectEnd` without `ObjectBegin`"))?;
                self.instances.insert(name, prims);
                let (s, _) = self
                    .stack
                    .pop()
                    .ok_or_else(|| pos.error("`ObjectEnd` without `ObjectBegin`"))?;
                self.state = s;
            }
            "ObjectInstance" => {
                let name = Self::string(toks, at, pos, dir)?;
                let prims = self
                    .instances
                    .get(&name)
                    .ok_or_else(|| pos.error(format!("unknown object \"{name}\"")))?;
                let count: usize = prims.iter().map(prim_triangles).sum();
                let m = self.state.ctm;
                let placed: Vec<Prim> = prims.iter().map(|p| transform_prim(p, &m)).collect();
                self.count_triangles(count, pos)?;
                self.emit_prims(placed);
            }
            _ => return Err(pos.error(format!("unknown directive `{dir}`"))),
        }
        Ok(())
    }

    fn concat(&mut self, m: DMat4) {
        self.state.ctm *= m;
    }

    fn open(&mut self, name: &str, pos: &Pos) -> Result<Vec<u8>, ImportError> {
        self.files_opened += 1;
        if self.files_opened > self.limits.max_files {
            return Err(ImportError::limit(
                pos.to_string(),
                format!("more than {} files named", self.limits.max_files),
            ));
        }
        self.files
            .read(name, self.limits.max_file_bytes)
            .map_err(|e| pos.error(e))
    }

    fn count_triangles(&mut self, n: usize, pos: &Pos) -> Result<(), ImportError> {
        self.triangles = self.triangles.saturating_add(n);
        if self.triangles > self.limits.max_triangles {
            return Err(ImportError::limit(
                pos.to_string(),
                format!(
                    "the scene has more than the limit of {} triangles",
                    self.limits.max_triangles
                ),
            ));
        }
        Ok(())
    }

    fn emit_prims(&mut self, prims: Vec<Prim>) {
        match &mut self.defining {
            Some((_, list)) => list.extend(prims),
            None => self.prims.extend(prims),
        }
    }

    /// An RGB parameter (`rgb`, or a named metal spectrum's RGB is not meant here).
    fn spectrum(&self, p: &Params, name: &str, default: [f64; 3]) -> Result<[f64; 3], ImportError> {
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
        let rgb = |v: [f64; 3]| v.map(|c| c as f32);
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
            "conductor" => {
                if p.get("reflectance").is_some() {
                    self.warn(
                        pos,
                        "conductor \"reflectance\" is not modelled: rendered with eta and k",
                    );
                }
                let eta = self.metal(p, "eta", "metal-Cu-eta")?;
                let k = self.metal(p, "k", "metal-Cu-k")?;
                let roughness = self.roughness(p, pos)?;
                MaterialDoc::Conductor(ConductorDoc {
                    eta: rgb(eta),
                    k: rgb(k),
                    roughness,
                })
            }
            "coateddiffuse" => {
                let eta = match p.get("eta") {
                    Some(param) if matches!(param.values, Values::Strs(_)) => {
                        self.warn(&param.pos, "named glass spectrum: rendered with η = 1.5");
                        1.5
                    }
                    _ => p.float("eta", 1.5)?,
                };
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
                MaterialDoc::CoatedDiffuse(CoatedDiffuseDoc {
                    reflectance,
                    texture,
                    roughness,
                    ior: eta as f32,
                })
            }
            "dielectric" | "thindielectric" => {
                let eta = match p.get("eta") {
                    Some(param) if matches!(param.values, Values::Strs(_)) => {
                        self.warn(&param.pos, "named glass spectrum: rendered with η = 1.5");
                        1.5
                    }
                    _ => p.float("eta", 1.5)?,
                };
                if self.roughness(p, pos)? > 0.0 {
                    self.warn(pos, "rough dielectric: rendered smooth");
                }
                if ty == "thindielectric" {
                    self.warn(pos, "thindielectric: rendered as a solid dielectric");
                }
                if eta.is_nan() || eta <= 0.0 {
                    return Err(pos.error(format!("dielectric eta must be > 0, got {eta}")));
                }
                MaterialDoc::Dielectric(DielectricDoc {
                    ior: eta as f32,
                    tint: None,
                })
            }
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
            "imagemap" => {
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
                let mut doc = super::texture::image_texture(
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
                        format!(
                            "texture \"{name}\": scale {scale} clamped to [0, 1] (a reflectance)"
                        ),
                    );
                }
                doc.factor = [scale.clamp(0.0, 1.0) as f32; 3];
                if p.boolean("invert", false)? {
                    self.warn(pos, format!("texture \"{name}\": invert is not modelled"));
                }
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
                Ok(Reflectance::Image(doc))
            }
            "constant" => self.spectrum(p, "value", [1.0; 3]).map(Reflectance::Rgb),
            other => {
                self.warn(pos, format!("texture \"{name}\" of class \"{other}\" is not modelled: rendered as grey 0.5"));
                Ok(Reflectance::Rgb([0.5; 3]))
            }
        }
    }

    fn light(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<(), ImportError> {
        let scale = p.float("scale", 1.0)?;
        let m = self.state.ctm;
        match ty {
            "point" => {
                if p.get("power").is_some() {
                    self.warn(pos, "light \"power\" ignored: the intensity I is used");
                }
                let i = self.spectrum(p, "I", [1.0; 3])?;
                let from = p.triple("from")?.unwrap_or([0.0; 3]);
                let at = m.transform_point3(DVec3::from(from));
                self.lights.push(LightDoc::Point(PointLightDoc {
                    position: at.as_vec3().to_array(),
                    intensity: i.map(|c| (c * scale) as f32),
                }));
                self.light_frames.push((Some(at), None));
            }
            "spot" => {
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
                self.lights.push(LightDoc::Spot(SpotLightDoc {
                    position: at.as_vec3().to_array(),
                    direction: d.as_vec3().to_array(),
                    intensity: i.map(|c| (c * scale) as f32),
                    outer_angle: cone as f32,
                    inner_angle: (cone - delta).max(0.0) as f32,
                    falloff: FalloffDoc::Smoothstep,
                }));
                self.light_frames.push((Some(at), Some(d)));
            }
            "distant" => {
                let l = self.spectrum(p, "L", [1.0; 3])?;
                let from = DVec3::from(p.triple("from")?.unwrap_or([0.0; 3]));
                let to = DVec3::from(p.triple("to")?.unwrap_or([0.0, 0.0, 1.0]));
                // The light travels from `from` toward `to`.
                let d = m
                    .transform_vector3(to - from)
                    .try_normalize()
                    .ok_or_else(|| pos.error("distant light: from and to coincide"))?;
                self.lights.push(LightDoc::Directional(DirectionalLightDoc {
                    direction: d.as_vec3().to_array(),
                    irradiance: l.map(|c| (c * scale) as f32),
                }));
                self.light_frames.push((None, Some(d)));
            }
            "infinite" => {
                if p.get("filename").is_some() {
                    return Err(pos.error(
                        "environment maps (infinite light with filename) are not supported",
                    ));
                }
                let l = self.spectrum(p, "L", [1.0; 3])?;
                self.lights.push(LightDoc::Environment(EnvironmentLightDoc {
                    radiance: l.map(|c| (c * scale) as f32),
                }));
                self.light_frames.push((None, None));
            }
            other => {
                return Err(pos.error(format!(
                    "light \"{other}\" is not supported (point, spot, distant, infinite)"
                )))
            }
        }
        Ok(())
    }

    fn shape(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<(), ImportError> {
        if !self.world {
            return Err(pos.error("`Shape` before `WorldBegin`"));
        }
        if p.get("alpha").is_some() {
            self.warn(
                pos,
                "shape alpha (cut-outs) is not modelled: the shape is opaque",
            );
        }
        let m = self.state.ctm;
        let flip = self.state.reverse ^ (DMat3::from_mat4(m).determinant() < 0.0);
        let material = self.state.material.clone();
        if material.is_empty() {
            // pbrt's default material is diffuse 0.5.
            self.materials
                .entry("default".into())
                .or_insert(MaterialDoc::Diffuse(DiffuseDoc {
                    albedo: Some([0.5; 3]),
                    texture: None,
                }));
        }
        let material = if material.is_empty() {
            "default".into()
        } else {
            material
        };
        let emission = self.state.area.clone();
        if emission.is_some() && self.defining.is_some() {
            self.warn(
                pos,
                "area lights inside an object instance do not emit (as in pbrt-v4)",
            );
        }
        let emission = if self.defining.is_some() {
            None
        } else {
            emission
        };
        let (positions, normals, uvs, indices) = match ty {
            "sphere" => {
                let r = p.float("radius", 1.0)?;
                if r.is_nan() || r <= 0.0 {
                    return Err(pos.error(format!("sphere radius must be > 0, got {r}")));
                }
                if p.get("zmin").is_some() || p.get("zmax").is_some() || p.get("phimax").is_some() {
                    self.warn(pos, "partial sphere (zmin/zmax/phimax): rendered whole");
                }
                let lin = DMat3::from_mat4(m);
                let scales = [
                    lin.x_axis.length(),
                    lin.y_axis.length(),
                    lin.z_axis.length(),
                ];
                let (lo, hi) = scales
                    .iter()
                    .fold((f64::MAX, 0f64), |(a, b), &s| (a.min(s), b.max(s)));
                if hi - lo > 1e-6 * hi {
                    return Err(pos.error("a sphere under a non-uniform scale is not supported"));
                }
                self.emit_prims(vec![Prim::Sphere {
                    center: m.transform_point3(DVec3::ZERO),
                    radius: r * hi,
                    material,
                    emission,
                }]);
                return Ok(());
            }
            "trianglemesh" | "bilinearmesh" => self.inline_mesh(ty, p, pos)?,
            "plymesh" => {
                let (file, fpos) = p
                    .string("filename")?
                    .ok_or_else(|| pos.error("plymesh has no filename"))?;
                let (file, fpos) = (file.to_string(), fpos.clone());
                if p.get("displacement").is_some() {
                    self.warn(
                        pos,
                        "displacement is not modelled: the mesh is rendered undisplaced",
                    );
                }
                let bytes = self.open(&file, &fpos)?;
                let room = self.limits.max_triangles.saturating_sub(self.triangles);
                let mesh = super::ply::parse(&bytes, room).map_err(|e| {
                    let msg = format!("\"{file}\": {e}");
                    if e.contains("limit of") {
                        ImportError::limit(fpos.to_string(), msg)
                    } else {
                        fpos.error(msg)
                    }
                })?;
                let pos3 =
                    |v: &[f32; 3]| DVec3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
                (
                    mesh.positions.iter().map(pos3).collect(),
                    mesh.normals.map(|ns| ns.iter().map(pos3).collect()),
                    mesh.uvs,
                    mesh.indices,
                )
            }
            other => {
                return Err(pos.error(format!(
                "shape \"{other}\" is not supported (trianglemesh, bilinearmesh, plymesh, sphere)"
            )))
            }
        };
        self.count_triangles(indices.len(), pos)?;
        let normal_m = DMat3::from_mat4(m).inverse().transpose();
        let prim = Prim::Mesh {
            positions: positions.iter().map(|&q| m.transform_point3(q)).collect(),
            normals: normals.map(|ns: Vec<DVec3>| ns.iter().map(|&n| normal_m * n).collect()),
            uvs,
            indices,
            flip,
            material,
            emission,
        };
        self.emit_prims(vec![prim]);
        Ok(())
    }

    /// `trianglemesh` (`P`, `indices`, `N`, `uv`) or `bilinearmesh` (`P`, `indices` of
    /// quads p00 p10 p01 p11, split into two triangles).
    #[allow(clippy::type_complexity)]
    fn inline_mesh(
        &mut self,
        ty: &str,
        p: &Params,
        pos: &Pos,
    ) -> Result<
        (
            Vec<DVec3>,
            Option<Vec<DVec3>>,
            Option<Vec<[f32; 2]>>,
            Vec<[u32; 3]>,
        ),
        ImportError,
    > {
        let (pts, ppos) = p
            .nums("P")?
            .ok_or_else(|| pos.error(format!("{ty} has no \"point3 P\"")))?;
        if pts.len() % 3 != 0 || pts.is_empty() {
            return Err(ppos.error(format!(
                "\"P\" must hold a multiple of 3 numbers, got {}",
                pts.len()
            )));
        }
        let positions: Vec<DVec3> = pts
            .chunks_exact(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]))
            .collect();
        let n = positions.len();
        let per = if ty == "bilinearmesh" { 4 } else { 3 };
        let idx: Vec<f64> = match p.nums("indices")? {
            Some((v, _)) => v.to_vec(),
            None if n == per => (0..per).map(|i| i as f64).collect(),
            None => {
                return Err(pos.error(format!(
                "{ty} has no \"integer indices\" (required unless there are exactly {per} points)"
            )))
            }
        };
        let ipos = p.get("indices").map_or(pos, |q| &q.pos).clone();
        if !idx.len().is_multiple_of(per) {
            return Err(ipos.error(format!(
                "\"indices\" must hold a multiple of {per} numbers, got {}",
                idx.len()
            )));
        }
        if let Some(bad) = idx.iter().find(|&&i| !(i >= 0.0 && (i as usize) < n)) {
            return Err(ipos.error(format!(
                "index {bad} is out of range: the mesh has {n} points"
            )));
        }
        let indices: Vec<[u32; 3]> = if per == 3 {
            idx.chunks_exact(3)
                .map(|c| [c[0] as u32, c[1] as u32, c[2] as u32])
                .collect()
        } else {
            idx.chunks_exact(4)
                .flat_map(|c| {
                    let q = [c[0] as u32, c[1] as u32, c[2] as u32, c[3] as u32];
                    [[q[0], q[1], q[3]], [q[0], q[3], q[2]]]
                })
                .collect()
        };
        let normals = match p.nums("N")? {
            None => None,
            Some((v, npos)) => {
                if v.len() != 3 * n {
                    return Err(npos.error(format!(
                        "\"N\" must hold 3 numbers per point ({}), got {}",
                        3 * n,
                        v.len()
                    )));
                }
                Some(
                    v.chunks_exact(3)
                        .map(|c| DVec3::new(c[0], c[1], c[2]))
                        .collect(),
                )
            }
        };
        // pbrt-v4 calls them `uv` (pbrt-v3 files may still say `st`).
        let uv_param = if p.get("uv").is_some() { "uv" } else { "st" };
        let uvs = match p.nums(uv_param)? {
            None => None,
            Some((v, upos)) => {
                if v.len() != 2 * n {
                    return Err(upos.error(format!(
                        "\"{uv_param}\" must hold 2 numbers per point ({}), got {}",
                        2 * n,
                        v.len()
                    )));
                }
                Some(
                    v.chunks_exact(2)
                        .map(|c| [c[0] as f32, c[1] as f32])
                        .collect(),
                )
            }
        };
        Ok((positions, normals, uvs, indices))
    }

    /// The scene document: materials, objects (world space, mirrored when pbrt's camera
    /// is the mirror image of Glimpse's), lights, camera and settings.
    fn finish(mut self, name: &str) -> Result<Imported, ImportError> {
        let (camera, mirror) = match self.camera {
            None => (
                CameraDoc {
                    position: [0.0; 3],
                    look_at: [0.0, 0.0, -1.0],
                    up: [0.0, 1.0, 0.0],
                    fov_y: 0.0,
                },
                DMat4::IDENTITY,
            ),
            Some((cam_from_world, fov)) => {
                let world_from_cam = cam_from_world.inverse();
                let (w, h) = (self.size.0 as f64, self.size.1 as f64);
                let fov_y = if w >= h {
                    fov
                } else {
                    // fov is the shorter (horizontal) axis's.
                    2.0 * ((fov.to_radians() * 0.5).tan() * h / w).atan().to_degrees()
                };
                let lin = DMat3::from_mat4(world_from_cam);
                let mirror = if lin.determinant() > 0.0 {
                    world_from_cam * DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0)) * cam_from_world
                } else {
                    DMat4::IDENTITY
                };
                let wfc = mirror * world_from_cam;
                let eye = wfc.transform_point3(DVec3::ZERO);
                let fwd = wfc.transform_vector3(DVec3::Z).normalize();
                let up = wfc.transform_vector3(DVec3::Y).normalize();
                (
                    CameraDoc {
                        position: eye.as_vec3().to_array(),
                        look_at: (eye + fwd).as_vec3().to_array(),
                        up: up.as_vec3().to_array(),
                        fov_y: fov_y as f32,
                    },
                    mirror,
                )
            }
        };
        let mirrored = mirror != DMat4::IDENTITY;
        if mirrored {
            let m = mirror;
            for (l, (at, dir)) in self.lights.iter_mut().zip(&self.light_frames) {
                match l {
                    LightDoc::Point(pl) => {
                        pl.position = m
                            .transform_point3(at.unwrap_or_default())
                            .as_vec3()
                            .to_array()
                    }
                    LightDoc::Directional(d) => {
                        d.direction = m
                            .transform_vector3(dir.unwrap_or(DVec3::Z))
                            .as_vec3()
                            .to_array()
                    }
                    LightDoc::Spot(sl) => {
                        sl.position = m
                            .transform_point3(at.unwrap_or_default())
                            .as_vec3()
                            .to_array();
                        sl.direction = m
                            .transform_vector3(dir.unwrap_or(DVec3::Z))
                            .as_vec3()
                            .to_array();
                    }
                    LightDoc::Environment(_) => {}
                }
            }
        }
        let mut emissive: Vec<(Emission, String)> = Vec::new();
        let mut reflective_lights = false;
        let mut objects = Vec::with_capacity(self.prims.len());
        for prim in std::mem::take(&mut self.prims) {
            let (material, emission) = match &prim {
                Prim::Mesh {
                    material, emission, ..
                }
                | Prim::Sphere {
                    material, emission, ..
                } => (material.clone(), emission.clone()),
            };
            let black = matches!(
                self.materials.get(&material),
                Some(MaterialDoc::Diffuse(DiffuseDoc {
                    albedo: Some([0.0, 0.0, 0.0]),
                    ..
                }))
            );
            reflective_lights |= emission.is_some() && !black;
            let material = match emission {
                None => material,
                Some(e) => match emissive.iter().find(|(x, _)| *x == e) {
                    Some((_, n)) => n.clone(),
                    None => {
                        let n = format!("emission-{}", emissive.len() + 1);
                        self.materials.insert(
                            n.clone(),
                            MaterialDoc::Emissive(EmissiveDoc {
                                radiance: e.radiance.map(|c| c as f32),
                                two_sided: e.two_sided,
                            }),
                        );
                        emissive.push((e, n.clone()));
                        n
                    }
                },
            };
            objects.push(object_doc(prim, material, &mirror, mirrored));
        }
        if reflective_lights {
            self.warnings.push(format!("{name}: area lights' own surfaces reflect nothing in Glimpse (pbrt adds their material's reflection)"));
        }
        let doc = SceneDoc {
            materials: self.materials,
            objects,
            lights: self.lights,
            render: RenderDoc {
                samples_per_pixel: self.spp,
                max_bounces: self.max_depth,
                ..RenderDoc::default()
            },
            ..crate::import::document(name, self.size.0, self.size.1, camera)
        };
        Ok(Imported {
            doc,
            warnings: self.warnings,
        })
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

fn prim_triangles(p: &Prim) -> usize {
    match p {
        Prim::Mesh { indices, .. } => indices.len(),
        Prim::Sphere { .. } => 0,
    }
}

/// An instance's primitive placed by `m` (pbrt: instance world = CTM at
/// `ObjectInstance` × the shape's CTM at definition).
fn transform_prim(p: &Prim, m: &DMat4) -> Prim {
    match p {
        Prim::Mesh {
            positions,
            normals,
            uvs,
            indices,
            flip,
            material,
            emission,
        } => {
            let nm = DMat3::from_mat4(*m).inverse().transpose();
            Prim::Mesh {
                positions: positions.iter().map(|&q| m.transform_point3(q)).collect(),
                normals: normals
                    .as_ref()
                    .map(|ns| ns.iter().map(|&n| nm * n).collect()),
                uvs: uvs.clone(),
                indices: indices.clone(),
                flip: *flip ^ (DMat3::from_mat4(*m).determinant() < 0.0),
                material: material.clone(),
                emission: emission.clone(),
            }
        }
        Prim::Sphere {
            center,
            radius,
            material,
            emission,
        } => {
            let lin = DMat3::from_mat4(*m);
            Prim::Sphere {
                center: m.transform_point3(*center),
                radius: radius * lin.x_axis.length(),
                material: material.clone(),
                emission: emission.clone(),
            }
        }
    }
}

/// One primitive as a document object, in Glimpse's world (after `mirror`), each
/// triangle wound so that its geometric normal is pbrt's surface normal.
fn object_doc(p: Prim, material: String, mirror: &DMat4, mirrored: bool) -> ObjectDoc {
    match p {
        Prim::Sphere { center, radius, .. } => ObjectDoc::Sphere(SphereDoc {
            center: mirror.transform_point3(center).as_vec3().to_array(),
            radius: radius as f32,
            material,
            transform: None,
        }),
        Prim::Mesh {
            positions,
            normals,
            uvs,
            mut indices,
            flip,
            ..
        } => {
            for t in &mut indices {
                let [a, b, c] = t.map(|i| positions[i as usize]);
                let winding = (b - a).cross(c - a);
                // pbrt's surface normal for this triangle, in pbrt's world.
                let want = match &normals {
                    Some(ns) => t.iter().map(|&i| ns[i as usize]).sum::<DVec3>(),
                    None if flip => -winding,
                    None => winding,
                };
                // After mirroring, the winding normal reverses; the wanted normal is
                // mirrored as a vector (its side of the surface is kept).
                let agrees = winding.dot(want) >= 0.0;
                if agrees == mirrored {
                    t.swap(1, 2);
                }
            }
            let nm = DMat3::from_mat4(*mirror).inverse().transpose();
            ObjectDoc::Mesh(MeshDoc {
                positions: positions
                    .iter()
                    .map(|&q| mirror.transform_point3(q).as_vec3().to_array())
                    .collect(),
                indices: indices.iter().map(|t| t.map(u64::from)).collect(),
                // A zero normal in a file (it happens) would be refused by validation: the
                // mesh is then shaded with its geometric normals.
                normals: normals
                    .map(|ns| {
                        ns.iter()
                            .map(|&n| (nm * n).normalize_or_zero().as_vec3())
                            .collect::<Vec<_>>()
                    })
                    .filter(|ns| ns.iter().all(|n| n.length_squared() > 0.0 && n.is_finite()))
                    .map(|ns| ns.iter().map(|n| n.to_array()).collect()),
                uvs: uvs.filter(|uv| uv.iter().flatten().all(|c| c.is_finite())),
                material,
                transform: None,
            })
        }
    }
}
