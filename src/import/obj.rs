//! Wavefront OBJ with its MTL (tobj reads both from memory: the MTL through the
//! [`FileSource`], so a `mtllib ../../x` is confined like every other name). MTL
//! parameters map to Glimpse's materials:
//! - `Ke` > 0 → `emissive` (radiance Ke);
//! - `illum 5` → `mirror` (reflectance Ks);
//! - `illum 4, 6, 7` or a dissolve below 1 → `dielectric` (ior `Ni`, default 1.5);
//! - `Ks` brighter than `Kd` → `glossy` (albedo Ks, roughness from the Phong exponent `Ns`
//!   by the usual Beckmann match α = √(2 / (Ns + 2)), roughness = √α);
//! - otherwise `diffuse` (albedo Kd, or the `map_Kd` image times Kd, with the mesh's `vt`
//!   texture coordinates; a weaker specular part is dropped with a warning).

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::io::BufReader;

use super::{FileSource, ImportError, ImportLimits, Imported};
use crate::scene::doc::{
    CameraDoc, DielectricDoc, DiffuseDoc, EmissiveDoc, GlossyDoc, MaterialDoc, MeshDoc, MirrorDoc,
    ObjectDoc, SceneDoc, TextureDoc,
};

/// Imports the OBJ `bytes` (the contents of `name`), its MTL read through `files`.
pub fn import(
    name: &str,
    bytes: &[u8],
    files: &dyn FileSource,
    limits: &ImportLimits,
) -> Result<Imported, ImportError> {
    check_counts(name, bytes, limits)?;
    let (models, mats, mut warnings) = load(name, bytes, files, limits)?;
    let (mut materials, names) = materials(name, &mats, files, limits, &mut warnings)?;
    let mut objects = Vec::new();
    let mut triangles = 0usize;
    for model in &models {
        let mesh = &model.mesh;
        triangles += mesh.indices.len() / 3;
        if triangles > limits.max_triangles {
            return Err(ImportError::limit(
                name,
                format!("more than the limit of {} triangles", limits.max_triangles),
            ));
        }
        let material = match mesh.material_id.and_then(|i| names.get(i)) {
            Some(n) => n.clone(),
            None => {
                materials
                    .entry("default".into())
                    .or_insert(MaterialDoc::Diffuse(DiffuseDoc {
                        albedo: Some([0.5; 3]),
                        texture: None,
                    }));
                "default".into()
            }
        };
        objects.push(mesh_object(mesh, material));
    }
    let camera = CameraDoc {
        position: [0.0; 3],
        look_at: [0.0, 0.0, -1.0],
        up: [0.0, 1.0, 0.0],
        fov_y: 0.0,
    };
    let doc = SceneDoc {
        materials,
        objects,
        ..super::document(name, 512, 512, camera)
    };
    Ok(Imported { doc, warnings })
}

/// What an OBJ's lines ask for, counted line by line before tobj reads it (tobj holds
/// every `v`, `vt`, `vn` and face it reads, used or not): each vertex list at most three
/// entries per triangle of the limit (more cannot all be used), faces at most the
/// triangle limit (a polygon of k corners is k − 2 triangles; a line or a point counts
/// one), meshes at most the object limit (tobj starts one at each `o`, `g` or `usemtl`
/// after faces). Measured before: 30 M unused `v` lines were accepted at +572 MB.
fn check_counts(name: &str, bytes: &[u8], limits: &ImportLimits) -> Result<(), ImportError> {
    let mut counts = Counts {
        limits,
        lists: [0; 3],
        triangles: 0,
        meshes: 1,
        faces: false,
    };
    for (k, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let mut words = line
            .split(u8::is_ascii_whitespace)
            .filter(|w| !w.is_empty());
        let Some(key) = words.next() else {
            continue;
        };
        if let Some(why) = counts.line(key, words.count()) {
            return Err(ImportError::limit(format!("{name}:{}", k + 1), why));
        }
    }
    Ok(())
}

/// What an OBJ's lines have asked for so far ([`check_counts`]).
struct Counts<'l> {
    limits: &'l ImportLimits,
    /// `v`, `vt` and `vn` lines.
    lists: [usize; 3],
    triangles: usize,
    meshes: usize,
    /// Whether the current mesh has faces (the next `o`, `g` or `usemtl` starts another).
    faces: bool,
}

impl Counts<'_> {
    /// Counts a line of `key` with `args` arguments: why it passes a limit, if it does.
    fn line(&mut self, key: &[u8], args: usize) -> Option<String> {
        let l = self.limits;
        let (list, what) = match key {
            b"v" => (0, "vertex positions (`v`)"),
            b"vt" => (1, "texture coordinates (`vt`)"),
            b"vn" => (2, "normals (`vn`)"),
            b"f" | b"l" | b"p" => {
                self.triangles += args.saturating_sub(2).max(1);
                self.faces = true;
                return (self.triangles > l.max_triangles).then(|| {
                    format!(
                        "the faces read so far pass the limit of {} triangles",
                        l.max_triangles
                    )
                });
            }
            b"o" | b"g" | b"usemtl" if self.faces => {
                (self.meshes, self.faces) = (self.meshes + 1, false);
                return (self.meshes > l.max_objects).then(|| {
                    format!(
                        "more than the limit of {} objects (a mesh starts at each `o`, `g` or `usemtl` after faces)",
                        l.max_objects
                    )
                });
            }
            _ => return None,
        };
        let most = l.max_triangles.saturating_mul(3);
        self.lists[list] += 1;
        (self.lists[list] > most).then(|| {
            format!(
                "more than {most} {what}, three per triangle of the limit of {} triangles: refused at this one",
                l.max_triangles
            )
        })
    }
}

/// The OBJ's models (triangulated, one index per vertex) and its MTL's materials, with a
/// warning for each `mtllib` that cannot be read (grey diffuse materials instead).
#[allow(clippy::type_complexity)]
fn load(
    name: &str,
    bytes: &[u8],
    files: &dyn FileSource,
    limits: &ImportLimits,
) -> Result<(Vec<tobj::Model>, Vec<tobj::Material>, Vec<String>), ImportError> {
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let mtl_errors: RefCell<Vec<super::ReadError>> = RefCell::new(Vec::new());
    let (models, mats) = tobj::load_obj_buf(&mut BufReader::new(bytes), &opts, |p| {
        let n = p.to_string_lossy();
        match files.read(&n, limits.max_file_bytes) {
            Ok(b) => tobj::load_mtl_buf(&mut BufReader::new(&b[..])),
            Err(e) => {
                mtl_errors.borrow_mut().push(e);
                Err(tobj::LoadError::OpenFileFailed)
            }
        }
    })
    .map_err(|e| ImportError::invalid(name, format!("cannot read the OBJ: {e}")))?;
    let mtl_errors = mtl_errors.into_inner();
    if let Some(e) = mtl_errors.iter().find(|e| e.too_large) {
        return Err(e.clone().at(format!("{name}: mtllib")));
    }
    let mut warnings: Vec<String> = mtl_errors
        .into_iter()
        .map(|e| format!("{name}: mtllib {e}: grey diffuse materials instead"))
        .collect();
    let mats = mats.unwrap_or_else(|e| {
        warnings.push(format!(
            "{name}: the MTL cannot be read ({e}): grey diffuse materials"
        ));
        Vec::new()
    });
    Ok((models, mats, warnings))
}

/// The MTL's materials as document materials by key (the MTL name, or `material-i`
/// when it has none), and the keys in the MTL's order (a mesh's `material_id` indexes it).
fn materials(
    name: &str,
    mats: &[tobj::Material],
    files: &dyn FileSource,
    limits: &ImportLimits,
    warnings: &mut Vec<String>,
) -> Result<(BTreeMap<String, MaterialDoc>, Vec<String>), ImportError> {
    let mut materials = BTreeMap::new();
    let mut names = Vec::with_capacity(mats.len());
    for (i, m) in mats.iter().enumerate() {
        let key = if m.name.is_empty() {
            format!("material-{i}")
        } else {
            m.name.clone()
        };
        let mut doc = material(name, m, warnings);
        if let Some(map) = &m.diffuse_texture {
            diffuse_map(name, &mut doc, m, map, files, limits, warnings)?;
        }
        materials.insert(key.clone(), doc);
        names.push(key);
    }
    Ok((materials, names))
}

/// One OBJ mesh as a document mesh: its normals only when every vertex has a usable one,
/// its `vt` only when every vertex has one.
fn mesh_object(mesh: &tobj::Mesh, material: String) -> ObjectDoc {
    let positions: Vec<[f32; 3]> = mesh
        .positions
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let normals = (mesh.normals.len() == mesh.positions.len() && !mesh.normals.is_empty())
        .then(|| {
            mesh.normals
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect::<Vec<_>>()
        })
        .filter(|ns| {
            ns.iter()
                .all(|n| n.iter().any(|c| *c != 0.0) && n.iter().all(|c| c.is_finite()))
        });
    // OBJ's `vt` has v growing upwards; the document's image t grows downwards.
    let uvs = (mesh.texcoords.len() / 2 == positions.len() && !mesh.texcoords.is_empty())
        .then(|| {
            mesh.texcoords
                .chunks_exact(2)
                .map(|c| [c[0], 1.0 - c[1]])
                .collect::<Vec<_>>()
        })
        .filter(|uv| uv.iter().flatten().all(|c| c.is_finite()));
    ObjectDoc::Mesh(MeshDoc {
        positions,
        uvs,
        indices: mesh
            .indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]].map(u64::from))
            .collect(),
        normals,
        material,
        transform: None,
    })
}

/// A diffuse material's `map_Kd` (an sRGB image, multiplied by Kd as the MTL format says),
/// read through the confined source; a missing file keeps Kd with a warning (as pbrt
/// textures do), a map on any other material is dropped with one.
fn diffuse_map(
    file: &str,
    doc: &mut MaterialDoc,
    m: &tobj::Material,
    map: &str,
    files: &dyn FileSource,
    limits: &ImportLimits,
    warnings: &mut Vec<String>,
) -> Result<(), ImportError> {
    let MaterialDoc::Diffuse(d) = doc else {
        warnings.push(format!(
            "{file}: material \"{}\": map_Kd is modelled on diffuse materials only: dropped",
            m.name
        ));
        return Ok(());
    };
    let bytes = match files.read(map, limits.max_file_bytes) {
        Ok(b) => b,
        Err(e) if e.too_large => return Err(e.at(format!("{file}: map_Kd \"{map}\""))),
        Err(e) => {
            warnings.push(format!(
                "{file}: material \"{}\": map_Kd {e}: rendered with Kd",
                m.name
            ));
            return Ok(());
        }
    };
    let mut t = super::texture::image_texture(
        map,
        None,
        &bytes,
        super::texture::Encoding::Srgb,
        limits.max_texture_pixels,
    )
    .map_err(|e| ImportError::invalid(format!("{file}: map_Kd \"{map}\""), e))?;
    t.factor = d.albedo.unwrap_or([1.0; 3]);
    d.albedo = None;
    d.texture = Some(TextureDoc::Image(t));
    Ok(())
}

fn clamp01(v: [f32; 3]) -> [f32; 3] {
    v.map(|c| {
        if c.is_finite() {
            c.clamp(0.0, 1.0)
        } else {
            0.0
        }
    })
}

fn material(file: &str, m: &tobj::Material, warnings: &mut Vec<String>) -> MaterialDoc {
    let kd = m.diffuse.unwrap_or([0.5; 3]);
    let ks = m.specular.unwrap_or([0.0; 3]);
    let ke = m.emissive.unwrap_or([0.0; 3]);
    let illum = m.illumination_model.unwrap_or(2);
    let max = |v: [f32; 3]| v.iter().fold(0f32, |a, &c| a.max(c));
    if max(ke) > 0.0 && ke.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return MaterialDoc::Emissive(EmissiveDoc {
            radiance: ke,
            two_sided: false,
        });
    }
    if illum == 5 {
        return MaterialDoc::Mirror(MirrorDoc {
            reflectance: clamp01(ks),
        });
    }
    if matches!(illum, 4 | 6 | 7) || m.dissolve.is_some_and(|d| d < 1.0) {
        let ior = m
            .optical_density
            .filter(|n| n.is_finite() && *n > 0.0)
            .unwrap_or(1.5);
        return MaterialDoc::Dielectric(DielectricDoc { ior, tint: None });
    }
    if max(ks) > max(kd) {
        let ns = m
            .shininess
            .filter(|n| n.is_finite() && *n >= 0.0)
            .unwrap_or(10.0);
        let alpha = (2.0 / (ns + 2.0)).sqrt();
        return MaterialDoc::Glossy(GlossyDoc {
            albedo: clamp01(ks),
            roughness: alpha.sqrt().clamp(0.0, 1.0),
        });
    }
    if max(ks) > 0.0 {
        warnings.push(format!(
            "{file}: material \"{}\": its specular part (Ks) is dropped (diffuse Kd only)",
            m.name
        ));
    }
    MaterialDoc::Diffuse(DiffuseDoc {
        albedo: Some(clamp01(kd)),
        texture: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::import::DirSource;

    fn limits() -> ImportLimits {
        ImportLimits::from_scene(&crate::scene::Limits::command_line())
    }

    #[test]
    fn mcguire_boxes_map_their_mtl() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/public-scenes/cornell-box-mcguire");
        let src = DirSource { dir: dir.clone() };
        let read = |f: &str| std::fs::read(dir.join(f)).unwrap();
        let im = import(
            "CornellBox-Original.obj",
            &read("CornellBox-Original.obj"),
            &src,
            &limits(),
        )
        .unwrap();
        assert!(matches!(
            &im.doc.materials["light"],
            MaterialDoc::Emissive(e) if e.radiance == [17.0, 12.0, 4.0]
        ));
        assert!(matches!(
            &im.doc.materials["leftWall"],
            MaterialDoc::Diffuse(d) if d.albedo == Some([0.63, 0.065, 0.05])
        ));
        let tris: usize = im
            .doc
            .objects
            .iter()
            .map(|o| match o {
                ObjectDoc::Mesh(m) => m.indices.len(),
                _ => 0,
            })
            .sum();
        assert_eq!(tris, 36);
        let mirror = import(
            "CornellBox-Mirror.obj",
            &read("CornellBox-Mirror.obj"),
            &src,
            &limits(),
        )
        .unwrap();
        assert!(mirror
            .doc
            .materials
            .values()
            .any(|m| matches!(m, MaterialDoc::Mirror(_))));
        let sphere = import(
            "CornellBox-Sphere.obj",
            &read("CornellBox-Sphere.obj"),
            &src,
            &limits(),
        )
        .unwrap();
        assert!(sphere
            .doc
            .materials
            .values()
            .any(|m| matches!(m, MaterialDoc::Dielectric(d) if d.ior == 2.5)));
    }

    #[test]
    fn vertices_faces_and_meshes_are_counted_as_read() {
        let l = ImportLimits {
            max_triangles: 2,
            max_objects: 2,
            ..limits()
        };
        let none = DirSource {
            dir: std::env::temp_dir(),
        };
        let err = |obj: &str| import("t.obj", obj.as_bytes(), &none, &l).unwrap_err();
        // Three per triangle of the limit: the seventh `v` is refused at its line.
        let e = err(&"v 0 0 0\n".repeat(7));
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "t.obj:7");
        assert!(e.message.contains("more than 6 vertex positions"), "{e}");
        let e = err(&format!("# normals\n{}", "vn 0 0 1\r\n".repeat(7)));
        assert_eq!(e.location, "t.obj:8");
        // A pentagon is three triangles.
        let e = err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 1 2\n");
        assert!(e.message.contains("limit of 2 triangles"), "{e}");
        assert_eq!(e.location, "t.obj:4");
        // A new mesh at each group after faces: the third is past two objects.
        let tri = "f 1 2 3\n";
        let e = err(&format!(
            "v 0 0 0\nv 1 0 0\nv 0 1 0\ng a\ng b\n{tri}g c\n{tri}g d\n"
        ));
        assert!(e.message.contains("limit of 2 objects"), "{e}");
        assert_eq!(e.location, "t.obj:9");
        let ok = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\ng a\n{tri}g b\n{tri}");
        assert!(import("t.obj", ok.as_bytes(), &none, &l).is_ok());
    }

    #[test]
    fn an_mtl_outside_the_folder_is_not_read() {
        let src = DirSource {
            dir: std::env::temp_dir(),
        };
        let obj = b"mtllib ../../etc/passwd\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl x\nf 1 2 3\n";
        let im = import("t.obj", obj, &src, &limits()).unwrap();
        assert!(
            im.warnings.iter().any(|w| w.contains("climbs out")),
            "{:?}",
            im.warnings
        );
        assert!(matches!(im.doc.objects[0], ObjectDoc::Mesh(_)));
    }
}
