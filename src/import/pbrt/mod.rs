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
//!
//! Layout, one file per family of directives (pbrt-v4 file format): `state` the
//! transform and attribute blocks, includes; `options` camera, film, sampler,
//! integrator; `material` materials and textures; `light` lights and area lights;
//! `shape` shapes and object instancing; `document` the scene document made at the
//! end. This file holds the importer's state, the directive dispatch and the limits.

mod document;
pub mod lexer;
mod light;
mod material;
mod options;
pub mod params;
mod shape;
mod state;

use std::collections::{BTreeMap, HashMap};

use glam::{DMat4, DVec3};

use self::lexer::{Lexer, Pos, Tok};
use self::params::{Cap, Params};
use super::{FileSource, ImportError, ImportLimits, Imported};
use crate::scene::doc::{ImageTextureDoc, LightDoc, MaterialDoc};
use crate::scene::SamplerKind;

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
    /// `Sampler "independent"` keeps plain Monte Carlo and `"zsobol"` (pbrt-v4's default)
    /// its Z-ordered Sobol; pbrt's other samplers are all stratified or low-discrepancy,
    /// which Glimpse's padded Sobol sampler stands for.
    sampler: SamplerKind,
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
    /// Directives read, in every file ([`Importer::max_directives`]).
    directives: usize,
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
        sampler: SamplerKind::ZSobol,
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
        directives: 0,
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
            self.count_directive(&pos)?;
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
    /// One directive, by family: each arm reads the directive's own arguments (pbrt-v4
    /// file format) in the file of its family.
    fn directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
        depth: usize,
    ) -> Result<(), ImportError> {
        match dir {
            "Identity" | "Translate" | "Scale" | "Rotate" | "LookAt" | "Transform"
            | "ConcatTransform" | "CoordinateSystem" | "CoordSysTransform" => {
                self.transform_directive(dir, pos, lx)
            }
            "ReverseOrientation" | "AttributeBegin" | "TransformBegin" | "AttributeEnd"
            | "TransformEnd" => self.attribute_directive(dir, pos),
            "Include" | "Import" => self.include(dir, pos, lx, depth),
            "WorldBegin" => self.world_begin(),
            "WorldEnd" => Ok(()),
            "Camera" => self.camera(dir, pos, lx),
            "Film" | "Sampler" | "Integrator" | "PixelFilter" => self.render_option(dir, pos, lx),
            "ColorSpace" | "Option" | "Accelerator" => self.setting(dir, pos, lx),
            "MakeNamedMedium" | "MediumInterface" | "Attribute" => self.unmodelled(dir, pos, lx),
            "Material" | "MakeNamedMaterial" | "NamedMaterial" => {
                self.material_directive(dir, pos, lx)
            }
            "Texture" => self.texture_directive(dir, pos, lx),
            "AreaLightSource" => self.area_light(dir, pos, lx),
            "LightSource" => self.light_source(dir, pos, lx),
            "Shape" => self.shape_directive(dir, pos, lx),
            "ObjectBegin" | "ObjectEnd" | "ObjectInstance" => self.object_directive(dir, pos, lx),
            _ => Err(pos.error(format!("unknown directive `{dir}`"))),
        }
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
            .map_err(|e| e.at(pos.to_string()))?;
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

    /// The most directives a scene may hold, in all its files: 64 per object of the
    /// object limit and 65 536 more. A shape with its attribute block, transforms and
    /// material is under ten; without this bound a 64 MiB file of `Translate 0 0 0`
    /// (4 M directives, each a matrix product and an inverse) took seconds to read.
    fn max_directives(&self) -> usize {
        self.limits
            .max_objects
            .saturating_mul(64)
            .saturating_add(65_536)
    }

    fn count_directive(&mut self, pos: &Pos) -> Result<(), ImportError> {
        self.directives += 1;
        if self.directives > self.max_directives() {
            return Err(ImportError::limit(
                pos.to_string(),
                format!(
                    "the scene has more than {} directives (64 per object of the limit of {} objects, and 65536 more): refused at this one",
                    self.max_directives(),
                    self.limits.max_objects
                ),
            ));
        }
        Ok(())
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::import::{FileSource, ReadError};
    use crate::scene::doc::ObjectDoc;

    /// Files in memory, by name as the scene writes it.
    struct Files(HashMap<&'static str, Vec<u8>>);

    impl FileSource for Files {
        fn read(&self, name: &str, max: u64) -> Result<Vec<u8>, ReadError> {
            let data = self
                .0
                .get(name)
                .ok_or_else(|| ReadError::missing(format!("\"{name}\" is not in the bundle")))?;
            if data.len() as u64 > max {
                return Err(ReadError::limit(format!(
                    "\"{name}\" is larger than {max} bytes"
                )));
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
    fn directives_are_counted_in_every_file() {
        // Five objects: 64 × 5 + 65 536 = 65 856 directives, the first `WorldBegin`.
        let text = format!("WorldBegin\n{}", "Translate 0 0 0\n".repeat(70_000));
        let e = run(&text, &[], &limits()).unwrap_err();
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "s.pbrt:65857:1");
        assert!(e.message.contains("more than 65856 directives"), "{e}");
        let inc = "Translate 0 0 0\n".repeat(30_000);
        let l = ImportLimits {
            max_read_bytes: 1 << 30,
            max_file_bytes: 1 << 30,
            ..limits()
        };
        let e = run(
            "WorldBegin\nInclude \"a\"\nInclude \"a\"\nInclude \"a\"",
            &[("a", &inc)],
            &l,
        )
        .unwrap_err();
        assert_eq!(e.location, "a:5853:1");
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

    #[test]
    fn pbrts_samplers_map_to_the_nearest_of_ours() {
        let imported = |directive: &str| {
            let text = format!("{directive}{}", mesh("0 1 2", "0 0 0 1 0 0 0 1 0"));
            run(&text, &[], &limits()).unwrap()
        };
        let sampler_of = |directive: &str| imported(directive).doc.render;
        let r = sampler_of("Sampler \"independent\" \"integer pixelsamples\" [8]\n");
        assert_eq!(
            (r.sampler, r.samples_per_pixel),
            (SamplerKind::Independent, 8)
        );
        for other in ["halton", "stratified", "sobol", "paddedsobol", "pmj02bn"] {
            let im = imported(&format!("Sampler \"{other}\"\n"));
            assert_eq!(im.doc.render.sampler, SamplerKind::Sobol, "{other}");
            // A sampler Glimpse does not have is replaced, and says so.
            let said = im
                .warnings
                .iter()
                .any(|w| w.contains(other) && w.contains("Sobol"));
            assert_eq!(said, !other.contains("sobol"), "{other}: {:?}", im.warnings);
        }
        // pbrt-v4's default sampler, named or not.
        assert_eq!(
            sampler_of("Sampler \"zsobol\"\n").sampler,
            SamplerKind::ZSobol
        );
        assert_eq!(sampler_of("").sampler, SamplerKind::ZSobol);
    }
}
