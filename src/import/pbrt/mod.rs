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

use self::lexer::{Lexer, Pos, Tok};
use self::params::{Cap, Params, Values};
use super::texture::Encoding;
use super::{FileSource, ImportError, ImportLimits, Imported};
use crate::scene::doc::{
    CameraDoc, CoatedDiffuseDoc, ConductorDoc, DielectricDoc, DiffuseDoc, DirectionalLightDoc,
    EmissiveDoc, EnvironmentLightDoc, FalloffDoc, ImageTextureDoc, LightDoc, MaterialDoc, MeshDoc,
    ObjectDoc, PointLightDoc, RenderDoc, SceneDoc, SphereDoc, SpotLightDoc, TextureDoc, WrapDoc,
};

/// Includes may nest this deep (a file including itself is refused here).
const MAX_INCLUDE_DEPTH: usize = 16;

/// The most values one parameter may hold outside a mesh's own lists (a camera, a light, a
/// material, a spectrum's wavelength/value pairs need a few dozen).
const MAX_LIST: usize = 1 << 16;

/// The cap of a parameter outside a shape.
fn list_cap(_name: &str, _so_far: &Params) -> Cap {
    Cap {
        max: MAX_LIST,
        why: format!("a parameter outside a mesh holds at most {MAX_LIST}"),
    }
}

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
    /// Shapes read, inside object definitions too.
    shapes: usize,
    files_opened: usize,
    /// Bytes of every file read so far ([`ImportLimits::max_read_bytes`]).
    read_bytes: u64,
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
        shapes: 0,
        files_opened: 0,
        read_bytes: text.len() as u64,
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
        let mut lx = Lexer::new(file, text);
        while let Some((tok, pos)) = lx.take()? {
            let Tok::Word(dir) = tok else {
                return Err(pos.error(format!("expected a directive, got {}", tok.describe())));
            };
            self.directive(&dir, &pos, &mut lx, depth)?;
            self.check_counts(&pos)?;
        }
        Ok(())
    }

    /// `n` numbers, bare or in brackets.
    fn numbers(lx: &mut Lexer, n: usize, pos: &Pos, dir: &str) -> Result<Vec<f64>, ImportError> {
        let bracket = matches!(lx.peek()?, Some((Tok::Open, _)));
        if bracket {
            lx.take()?;
        }
        let mut out = Vec::with_capacity(n);
        while out.len() < n {
            match lx.peek()? {
                Some((Tok::Num(v), _)) => {
                    out.push(*v);
                    lx.take()?;
                }
                _ => return Err(pos.error(format!("`{dir}` takes {n} numbers, got {}", out.len()))),
            }
        }
        if bracket {
            match lx.peek()? {
                Some((Tok::Close, _)) => {
                    lx.take()?;
                }
                _ => return Err(pos.error(format!("`{dir}`: `]` expected after {n} numbers"))),
            }
        }
        Ok(out)
    }

    fn string(lx: &mut Lexer, pos: &Pos, dir: &str) -> Result<String, ImportError> {
        match lx.peek()? {
            Some((Tok::Str(_), _)) => match lx.take()? {
                Some((Tok::Str(s), _)) => Ok(s),
                _ => Err(pos.error(format!("`{dir}` needs a quoted name"))),
            },
            _ => Err(pos.error(format!("`{dir}` needs a quoted name"))),
        }
    }

    fn directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
        depth: usize,
    ) -> Result<(), ImportError> {
        match dir {
            "Identity" => self.state.ctm = DMat4::IDENTITY,
            "Translate" => {
                let v = Self::numbers(lx, 3, pos, dir)?;
                self.concat(
                    DMat4::from_translation(DVec3::new(v[0], v[1], v[2])),
                    pos,
                    dir,
                )?;
            }
            "Scale" => {
                let v = Self::numbers(lx, 3, pos, dir)?;
                let m = DMat4::from_scale(DVec3::new(v[0], v[1], v[2]));
                invertible(
                    &m,
                    pos,
                    &format!("`Scale {} {} {}`", num(v[0]), num(v[1]), num(v[2])),
                )?;
                self.concat(m, pos, dir)?;
            }
            "Rotate" => {
                let v = Self::numbers(lx, 4, pos, dir)?;
                let axis = DVec3::new(v[1], v[2], v[3]);
                let axis = axis
                    .try_normalize()
                    .ok_or_else(|| pos.error("`Rotate` needs a non-zero axis"))?;
                self.concat(DMat4::from_axis_angle(axis, v[0].to_radians()), pos, dir)?;
            }
            "LookAt" => {
                let v = Self::numbers(lx, 9, pos, dir)?;
                let m = look_at(
                    DVec3::new(v[0], v[1], v[2]),
                    DVec3::new(v[3], v[4], v[5]),
                    DVec3::new(v[6], v[7], v[8]),
                )
                .ok_or_else(|| {
                    pos.error("`LookAt`: the eye equals the target or `up` is parallel to the view")
                })?;
                self.concat(m, pos, dir)?;
            }
            "Transform" | "ConcatTransform" => {
                let v = Self::numbers(lx, 16, pos, dir)?;
                let mut a = [0.0; 16];
                a.copy_from_slice(&v);
                // The list is pbrt's matrix transposed, i.e. column-major: glam's order.
                let m = DMat4::from_cols_array(&a);
                invertible(&m, pos, &format!("the matrix of `{dir}`"))?;
                if dir == "Transform" {
                    self.state.ctm = m;
                } else {
                    self.concat(m, pos, dir)?;
                }
            }
            "CoordinateSystem" => {
                let n = Self::string(lx, pos, dir)?;
                self.named_coords.insert(n, self.state.ctm);
            }
            "CoordSysTransform" => {
                let n = Self::string(lx, pos, dir)?;
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
                let name = Self::string(lx, pos, dir)?;
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
            }
            "Film" => {
                let _ = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &list_cap)?;
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
                let _ = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &list_cap)?;
                let n = p.float("pixelsamples", 16.0)?;
                if n < 1.0 {
                    return Err(pos.error(format!("pixelsamples must be ≥ 1, got {n}")));
                }
                self.spp = n as u64;
            }
            "Integrator" => {
                let ty = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &list_cap)?;
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
                let ty = Self::string(lx, pos, dir)?;
                let _ = params::parse(lx, &list_cap)?;
                if ty != "box" {
                    self.warn(pos, format!("pixel filter \"{ty}\": Glimpse averages each pixel's samples (a box filter)"));
                }
            }
            "ColorSpace" | "Option" | "Accelerator" => {
                // Only settings that do not change the picture in RGB (ColorSpace other
                // than sRGB would, and is refused).
                if dir == "ColorSpace" {
                    let cs = Self::string(lx, pos, dir)?;
                    if cs != "srgb" {
                        return Err(
                            pos.error(format!("color space \"{cs}\" is not supported (sRGB only)"))
                        );
                    }
                } else if dir == "Option" {
                    let _ = params::parse(lx, &list_cap)?;
                } else {
                    let _ = Self::string(lx, pos, dir)?;
                    let _ = params::parse(lx, &list_cap)?;
                }
            }
            "MakeNamedMedium" | "MediumInterface" | "Attribute" => {
                // Participating media and attribute defaults are not modelled.
                // Their parameters are skipped up to the next directive (a bare word
                // other than a bool); their numbers count against the list cap too.
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
            }
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
            "NamedMaterial" => {
                let name = Self::string(lx, pos, dir)?;
                if !self.materials.contains_key(&name) {
                    return Err(pos.error(format!(
                        "unknown material \"{name}\" (not made by MakeNamedMaterial before)"
                    )));
                }
                self.state.material = name;
            }
            "Texture" => {
                let name = Self::string(lx, pos, dir)?;
                let _kind = Self::string(lx, pos, dir)?;
                let class = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &list_cap)?;
                let c = self.texture(&name, &class, &p, pos)?;
                self.textures.insert(name, c);
            }
            "AreaLightSource" => {
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
            }
            "LightSource" => {
                let ty = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &list_cap)?;
                self.light(&ty, &p, pos)?;
            }
            "Shape" => {
                self.shapes += 1;
                let ty = Self::string(lx, pos, dir)?;
                let p = params::parse(lx, &|name, so_far| self.shape_cap(&ty, name, so_far))?;
                self.shape(&ty, &p, pos)?;
            }
            "ObjectBegin" => {
                let name = Self::string(lx, pos, dir)?;
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
                let name = Self::string(lx, pos, dir)?;
                let prims = self
                    .instances
                    .get(&name)
                    .ok_or_else(|| pos.error(format!("unknown object \"{name}\"")))?;
                let count: usize = prims.iter().map(prim_triangles).sum();
                if self.prims.len() + prims.len() > self.limits.max_objects {
                    return Err(self.too_many(pos, "objects (shapes)"));
                }
                let m = self.state.ctm;
                let placed: Vec<Prim> = prims.iter().map(|p| transform_prim(p, &m)).collect();
                self.count_triangles(count, pos)?;
                self.emit_prims(placed);
            }
            _ => return Err(pos.error(format!("unknown directive `{dir}`"))),
        }
        Ok(())
    }

    /// The current transform times `m`; refused if the product has no inverse (factors
    /// each invertible can still underflow to a zero determinant).
    fn concat(&mut self, m: DMat4, pos: &Pos, dir: &str) -> Result<(), ImportError> {
        let ctm = self.state.ctm * m;
        invertible(&ctm, pos, &format!("the transform after `{dir}`"))?;
        self.state.ctm = ctm;
        Ok(())
    }

    fn open(&mut self, name: &str, pos: &Pos) -> Result<Vec<u8>, ImportError> {
        self.files_opened += 1;
        if self.files_opened > self.limits.max_files {
            return Err(ImportError::limit(
                pos.to_string(),
                format!("more than {} files named", self.limits.max_files),
            ));
        }
        let bytes = self
            .files
            .read(name, self.limits.max_file_bytes)
            .map_err(|e| pos.error(e))?;
        self.read_bytes += bytes.len() as u64;
        if self.read_bytes > self.limits.max_read_bytes {
            return Err(ImportError::limit(
                pos.to_string(),
                format!(
                    "reading \"{name}\" takes the files this scene reads (each Include counted every time) past the limit of {} bytes",
                    self.limits.max_read_bytes
                ),
            ));
        }
        Ok(bytes)
    }

    /// The cap of a shape's parameter, from the triangle limit: `indices` may hold the
    /// scene's remaining room, and a point list (`P`, `N`, `S`, `uv`) no more points than
    /// the indices read before it can use (4096 spare), or than three per triangle of that
    /// room when the points come first. Unused points are dropped later
    /// ([`drop_unused_points`]); these caps bound what reading them costs.
    fn shape_cap(&self, ty: &str, name: &str, so_far: &Params) -> Cap {
        let room = self.limits.max_triangles.saturating_sub(self.triangles);
        let limit = self.limits.max_triangles;
        // Numbers per triangle in `indices`: a bilinear patch is 4 indices, 2 triangles.
        let per_triangle = if ty == "bilinearmesh" { 2 } else { 3 };
        let width = match name {
            "indices" => {
                return Cap {
                    max: room.saturating_mul(per_triangle),
                    why: format!("the scene's limit of {limit} triangles"),
                }
            }
            "P" | "N" | "S" => 3,
            "uv" | "st" => 2,
            _ => return list_cap(name, so_far),
        };
        let (points, why) = match so_far.get("indices").map(|p| &p.values) {
            Some(Values::Nums(idx)) => (
                idx.len().saturating_add(4096),
                format!(
                    "one point per index read before it ({}), 4096 spare",
                    idx.len()
                ),
            ),
            _ => (
                room.saturating_mul(3).max(4),
                format!("three points per triangle of the scene's limit of {limit} triangles"),
            ),
        };
        Cap {
            max: points.saturating_mul(width),
            why,
        }
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

    /// What a file has made so far against the object limit, checked after each
    /// directive: shapes (inside object definitions too), placed objects and lights at
    /// most `max_objects` each, materials, textures and named coordinate systems at most
    /// 4× that (measured before: a million `Shape "sphere"` lines took 1.2 GB before the
    /// document's validation refused them).
    fn check_counts(&self, pos: &Pos) -> Result<(), ImportError> {
        let max = self.limits.max_objects;
        if self.shapes > max || self.prims.len() > max {
            return Err(self.too_many(pos, "objects (shapes)"));
        }
        if self.lights.len() > max {
            return Err(self.too_many(pos, "lights"));
        }
        let named = self.materials.len() + self.textures.len() + self.named_coords.len();
        if named > max.saturating_mul(4).max(64) {
            return Err(self.too_many(pos, "materials, textures and coordinate systems"));
        }
        Ok(())
    }

    fn too_many(&self, pos: &Pos, what: &str) -> ImportError {
        let max = self.limits.max_objects;
        let max = if what.starts_with("materials") {
            max.saturating_mul(4).max(64)
        } else {
            max
        };
        ImportError::limit(
            pos.to_string(),
            format!("the scene has more than the limit of {max} {what}"),
        )
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
        let (positions, normals, uvs, indices) =
            drop_unused_points(positions, normals, uvs, indices);
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

/// A mesh without the points no triangle uses (kept in their order, indices renumbered):
/// the document stores only what renders (measured before: 30 M unused numbers in `P`
/// became a 150 MB document). A mesh that uses every point is returned as it is.
#[allow(clippy::type_complexity)]
fn drop_unused_points(
    positions: Vec<DVec3>,
    normals: Option<Vec<DVec3>>,
    uvs: Option<Vec<[f32; 2]>>,
    mut indices: Vec<[u32; 3]>,
) -> (
    Vec<DVec3>,
    Option<Vec<DVec3>>,
    Option<Vec<[f32; 2]>>,
    Vec<[u32; 3]>,
) {
    let mut used = vec![false; positions.len()];
    for &i in indices.iter().flatten() {
        used[i as usize] = true;
    }
    if used.iter().all(|&u| u) {
        return (positions, normals, uvs, indices);
    }
    let mut new_index = vec![u32::MAX; positions.len()];
    for (next, (k, _)) in used.iter().enumerate().filter(|(_, &u)| u).enumerate() {
        new_index[k] = next as u32;
    }
    let keep = |k: &usize| used[*k];
    let pick = |v: Vec<DVec3>| -> Vec<DVec3> {
        v.into_iter()
            .enumerate()
            .filter(|(k, _)| keep(k))
            .map(|(_, p)| p)
            .collect()
    };
    let uvs = uvs.map(|v| {
        v.into_iter()
            .enumerate()
            .filter(|(k, _)| keep(k))
            .map(|(_, p)| p)
            .collect()
    });
    for i in indices.iter_mut().flatten() {
        *i = new_index[*i as usize];
    }
    (pick(positions), normals.map(pick), uvs, indices)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::import::FileSource;

    /// Files in memory, by name as the scene writes it.
    struct Files(HashMap<&'static str, Vec<u8>>);

    impl FileSource for Files {
        fn read(&self, name: &str, max: u64) -> Result<Vec<u8>, String> {
            let data = self
                .0
                .get(name)
                .ok_or_else(|| format!("\"{name}\" is not in the bundle"))?;
            if data.len() as u64 > max {
                return Err(format!("\"{name}\" is larger than {max} bytes"));
            }
            Ok(data.clone())
        }
    }

    fn limits() -> ImportLimits {
        ImportLimits {
            max_file_bytes: 1 << 20,
            max_triangles: 10,
            max_texture_pixels: 1 << 10,
            max_files: 64,
            max_read_bytes: 1 << 20,
            max_objects: 5,
        }
    }

    fn run(
        text: &str,
        files: &[(&'static str, &str)],
        l: &ImportLimits,
    ) -> Result<Imported, ImportError> {
        let files = Files(
            files
                .iter()
                .map(|(n, t)| (*n, t.as_bytes().to_vec()))
                .collect(),
        );
        import("s.pbrt", text, &files, l)
    }

    fn mesh(indices: &str, points: &str) -> String {
        format!("WorldBegin\nShape \"trianglemesh\" \"integer indices\" [{indices}]\n  \"point3 P\" [{points}]\n")
    }

    #[test]
    fn indices_past_the_triangle_limit_stop_the_reading_at_the_first_one_too_many() {
        // 11 triangles against a limit of 10, then something the tokenizer refuses: the
        // limit is met first, so nothing after it was read.
        let idx = "0 1 2 ".repeat(11);
        let e = run(
            &mesh(&format!("{idx} @"), "0 0 0 1 0 0 0 1 0"),
            &[],
            &limits(),
        )
        .unwrap_err();
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "s.pbrt:2:101", "{e}");
        assert!(e.message.contains("limit of 10 triangles"), "{e}");
    }

    #[test]
    fn points_beyond_what_the_indices_can_use_are_refused_while_read() {
        // Indices first: one point per index read, 4096 spare.
        let pts = "0 0 0 ".repeat(3 + 4097);
        let e = run(&mesh("0 1 2", &pts), &[], &limits()).unwrap_err();
        assert!(
            e.too_large && e.message.contains("one point per index"),
            "{e}"
        );
        // Points first: three per triangle of the limit (10 triangles, 30 points).
        let text = format!(
            "WorldBegin\nShape \"trianglemesh\" \"point3 P\" [{}] \"integer indices\" [0 1 2]",
            "0 0 0 ".repeat(31)
        );
        let e = run(&text, &[], &limits()).unwrap_err();
        assert!(
            e.too_large && e.message.contains("three points per triangle"),
            "{e}"
        );
        assert!(e.location.starts_with("s.pbrt:2:"), "{e}");
    }

    #[test]
    fn unused_points_are_dropped_and_indices_renumbered() {
        let im = run(
            &mesh("1 3 4", "9 9 9  0 0 0  9 9 9  1 0 0  0 1 0"),
            &[],
            &limits(),
        )
        .unwrap();
        let ObjectDoc::Mesh(m) = &im.doc.objects[0] else {
            panic!("not a mesh")
        };
        assert_eq!(m.positions.len(), 3);
        assert!(m.positions.iter().all(|p| p[0] < 2.0), "{:?}", m.positions);
        let mut idx: Vec<u64> = m.indices.iter().flatten().copied().collect();
        idx.sort_unstable();
        assert_eq!(idx, [0, 1, 2]);
    }

    #[test]
    fn shapes_and_lights_past_the_object_limit_are_refused_where_they_pass_it() {
        let text = format!("WorldBegin\n{}", "Shape \"sphere\"\n".repeat(100));
        let e = run(&text, &[], &limits()).unwrap_err();
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "s.pbrt:7:1");
        assert!(e.message.contains("limit of 5 objects"), "{e}");
        let text = format!("WorldBegin\n{}", "LightSource \"point\"\n".repeat(100));
        let e = run(&text, &[], &limits()).unwrap_err();
        assert_eq!(e.location, "s.pbrt:7:1");
        assert!(e.message.contains("limit of 5 lights"), "{e}");
        // Defining shapes in an object counts too.
        let text = format!(
            "WorldBegin\nObjectBegin \"a\"\n{}ObjectEnd",
            "Shape \"sphere\"\n".repeat(10)
        );
        assert!(run(&text, &[], &limits()).unwrap_err().too_large);
    }

    #[test]
    fn includes_are_budgeted_by_the_bytes_they_make_the_import_read() {
        let comment = format!("# {}\n", "x".repeat(300));
        let l = ImportLimits {
            max_read_bytes: 1000,
            ..limits()
        };
        let text = "Include \"c.pbrt\"\n".repeat(200);
        let e = run(&text, &[("c.pbrt", &comment)], &l).unwrap_err();
        assert!(e.too_large, "{e}");
        // The scene itself (3400 bytes) is already past 1000: the first include fails.
        assert_eq!(e.location, "s.pbrt:1:1");
        let three = "Include \"c.pbrt\"\n".repeat(3);
        let l = ImportLimits {
            max_read_bytes: three.len() as u64 + 2 * comment.len() as u64,
            ..limits()
        };
        let two = "Include \"c.pbrt\"\n".repeat(2);
        assert!(run(&two, &[("c.pbrt", &comment)], &l).is_ok());
        let e = run(&three, &[("c.pbrt", &comment)], &l).unwrap_err();
        assert_eq!(e.location, "s.pbrt:3:1");
        assert!(e.message.contains("each Include counted every time"), "{e}");
    }

    #[test]
    fn degenerate_transforms_are_refused_at_their_directive() {
        let cases = [
            ("Scale 0 0 0", "`Scale 0 0 0` is degenerate"),
            ("Scale 1 0 1", "`Scale 1 0 1` is degenerate"),
            (
                "Transform [1 0 0 0  0 1 0 0  0 0 0 0  0 0 0 1]",
                "the matrix of `Transform` is degenerate",
            ),
            (
                "ConcatTransform [0 0 0 0  0 0 0 0  0 0 0 0  0 0 0 1]",
                "the matrix of `ConcatTransform` is degenerate",
            ),
            (
                "Scale 1e-100 1e-100 1e-100 Scale 1e-100 1 1",
                "the transform after `Scale` is degenerate",
            ),
            ("LookAt 0 0 0  0 0 0  0 1 0", "the eye equals the target"),
            ("LookAt 0 0 0  0 1 0  0 1 0", "parallel"),
            ("Rotate 30 0 0 0", "non-zero axis"),
        ];
        for (directive, want) in cases {
            let text = format!("WorldBegin\n  {directive}\nShape \"sphere\"");
            let e = run(&text, &[], &limits()).unwrap_err();
            assert!(!e.too_large, "{directive}: {e}");
            assert!(e.message.contains(want), "{directive}: {e}");
            let col = if directive.contains("1e-100 Scale") {
                30
            } else {
                3
            };
            assert_eq!(e.location, format!("s.pbrt:2:{col}"), "{directive}: {e}");
        }
        assert!(run(
            "WorldBegin Scale 1 -2 3 Shape \"trianglemesh\" \"point3 P\" [0 0 0 1 0 0 0 1 0]",
            &[],
            &limits()
        )
        .is_ok());
    }

    #[test]
    fn nested_includes_resolve_from_the_main_files_folder_as_in_pbrt_v4() {
        // pbrt-v4 (parser.cpp) sets its search directory once, from the file named on the
        // command line, and resolves every Include, Import, PLY and texture name against
        // it: "geo/a.pbrt" names its own neighbour as "geo/b.pbrt".
        let files = [
            ("geo/a.pbrt", "Include \"geo/b.pbrt\"\n"),
            ("geo/b.pbrt", "Shape \"sphere\"\n"),
        ];
        let im = run("WorldBegin\nInclude \"geo/a.pbrt\"\n", &files, &limits()).unwrap();
        assert_eq!(im.doc.objects.len(), 1);
        let files = [
            ("geo/a.pbrt", "Include \"b.pbrt\"\n"),
            ("geo/b.pbrt", "Shape \"sphere\"\n"),
        ];
        let e = run("WorldBegin\nInclude \"geo/a.pbrt\"\n", &files, &limits()).unwrap_err();
        assert_eq!(e.location, "geo/a.pbrt:1:1");
        assert!(e.message.contains("\"b.pbrt\" is not in the bundle"), "{e}");
    }
}
