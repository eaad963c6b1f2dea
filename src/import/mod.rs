//! Scene import (shared/spec/scene-import.md): files made by other programs become the
//! scene document ([`crate::scene::doc::SceneDoc`]) that Glimpse's own format is, and then
//! the validated [`crate::scene::Scene`] through the same validation. Every mode, the
//! statistics and the service therefore see an imported scene exactly like a document,
//! and `glimpse convert` writes the document an import produced.
//!
//! - [`gltf`]: glTF 2.0 (`.gltf`, `.glb`), errors at JSON pointers;
//! - [`pbrt`]: the pbrt-v4 subset (own tokenizer and parser, errors at file:line:column);
//! - [`ply`]: the PLY meshes pbrt scenes name.
//!
//! Files a scene names are read through a [`FileSource`], which confines every name to the
//! scene's folder: an import never reads a file outside it.

pub mod bundle;
pub mod gltf;
mod gltf_expansion;
pub mod json_count;
pub mod obj;
pub mod pbrt;
pub mod ply;
pub mod texture;

use std::path::{Path, PathBuf};

use crate::scene::doc::{CameraDoc, EnvironmentLightDoc, LightDoc, ObjectDoc, SceneDoc, V3};
use crate::scene::{
    parse_scene, validate_doc, Limits, Problem, Scene, SceneError, SceneErrorKind, SceneOrigin,
};

/// A problem with an imported file: where (`file:line:column`, a JSON pointer, a zip
/// entry) and what.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{location}: {message}")]
pub struct ImportError {
    pub location: String,
    pub message: String,
    /// Fine, but beyond a limit (the service answers `too_large`).
    pub too_large: bool,
}

impl ImportError {
    pub fn invalid(location: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            location: location.into(),
            message: message.into(),
            too_large: false,
        }
    }

    pub fn limit(location: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            too_large: true,
            ..Self::invalid(location, message)
        }
    }
}

impl From<ImportError> for SceneError {
    fn from(e: ImportError) -> Self {
        SceneError {
            kind: if e.too_large {
                SceneErrorKind::TooLarge
            } else {
                SceneErrorKind::InvalidScene
            },
            problems: vec![Problem {
                path: e.location,
                message: e.message,
            }],
        }
    }
}

/// The file formats Glimpse reads, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Glimpse's own scene document.
    Json,
    Pbrt,
    /// `.gltf` or `.glb` (told apart by the GLB magic).
    Gltf,
    /// Wavefront `.obj` with its `.mtl`.
    Obj,
}

impl Format {
    /// The format of `path` by its extension (case-insensitive).
    pub fn of(path: &Path) -> Result<Self, String> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        match ext.as_str() {
            "json" => Ok(Format::Json),
            "pbrt" => Ok(Format::Pbrt),
            "gltf" | "glb" => Ok(Format::Gltf),
            "obj" => Ok(Format::Obj),
            other => Err(format!(
                "unknown scene format `.{other}`; Glimpse reads .json, .pbrt, .gltf, .glb and .obj"
            )),
        }
    }
}

/// Where the files a scene names come from.
pub trait FileSource {
    /// The bytes of `name` (relative to the scene file), refused if larger than `max`
    /// bytes. The error says why, naming the file.
    fn read(&self, name: &str, max: u64) -> Result<Vec<u8>, ReadError>;
}

/// Why a named file was not read: it is missing or outside the scene's folder, or it is
/// past a limit (`too_large`, which the service answers as such).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReadError {
    pub message: String,
    pub too_large: bool,
}

impl ReadError {
    pub fn missing(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            too_large: false,
        }
    }

    pub fn limit(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            too_large: true,
        }
    }

    /// The error at `location` (where the scene names the file).
    #[must_use]
    pub fn at(self, location: impl Into<String>) -> ImportError {
        ImportError {
            location: location.into(),
            message: self.message,
            too_large: self.too_large,
        }
    }
}

impl std::fmt::Display for ReadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

/// Files in a folder on disk (the command line): names resolve inside it only.
pub struct DirSource {
    pub dir: PathBuf,
}

impl FileSource for DirSource {
    fn read(&self, name: &str, max: u64) -> Result<Vec<u8>, ReadError> {
        let path = crate::scene::obj::resolve(&self.dir, name).map_err(ReadError::missing)?;
        let len = std::fs::metadata(&path)
            .map_err(|e| ReadError::missing(format!("cannot open \"{name}\": {e}")))?
            .len();
        if len > max {
            return Err(ReadError::limit(format!(
                "\"{name}\" is {len} bytes, more than the limit of {max}"
            )));
        }
        std::fs::read(&path).map_err(|e| ReadError::missing(format!("cannot read \"{name}\": {e}")))
    }
}

/// Bounds on what an import may read and build, checked before allocating.
#[derive(Clone, Copy, Debug)]
pub struct ImportLimits {
    /// Largest single file (scene, include, mesh, texture).
    pub max_file_bytes: u64,
    pub max_triangles: usize,
    /// Largest texture, in pixels.
    pub max_texture_pixels: u64,
    /// Most files an import may open (includes, meshes, textures).
    pub max_files: usize,
    /// Most bytes an import may read, all files together, the scene file and each
    /// `Include` of the same file counted every time: a small file included many times
    /// is parsed many times.
    pub max_read_bytes: u64,
    /// Most objects (shapes) and most lights; materials and textures at most 4× as many.
    pub max_objects: usize,
}

impl ImportLimits {
    /// Derived from the scene limits of the caller.
    #[must_use]
    pub fn from_scene(l: &Limits) -> Self {
        Self {
            max_file_bytes: 1 << 30,
            max_triangles: l.max_triangles,
            max_texture_pixels: 1 << 26,
            max_files: 4096,
            max_read_bytes: 1 << 32,
            max_objects: l.max_objects,
        }
    }
}

/// A scene document made from another format, with what the import had to approximate
/// or supply (one line each).
#[derive(Clone, Debug)]
pub struct Imported {
    pub doc: SceneDoc,
    pub warnings: Vec<String>,
}

/// Imports `bytes` (the contents of the scene file `name`) in `format`.
pub fn import(
    format: Format,
    name: &str,
    bytes: &[u8],
    files: &dyn FileSource,
    limits: &ImportLimits,
) -> Result<Imported, ImportError> {
    let mut imported = match format {
        Format::Json => {
            return Err(ImportError::invalid(
                name,
                "a scene document is parsed, not imported",
            ))
        }
        Format::Pbrt => {
            let text = std::str::from_utf8(bytes)
                .map_err(|e| ImportError::invalid(name, format!("not UTF-8 text: {e}")))?;
            pbrt::import(name, text, files, limits)?
        }
        Format::Gltf => gltf::import(name, bytes, files, limits)?,
        Format::Obj => obj::import(name, bytes, files, limits)?,
    };
    supply_missing(&mut imported);
    Ok(imported)
}

/// The document an importer fills in: named after the file's stem, `width`×`height`,
/// seen by `camera`, with default display, render and progressive settings and no
/// materials, objects or lights yet.
pub(crate) fn document(file: &str, width: u64, height: u64, camera: CameraDoc) -> SceneDoc {
    SceneDoc {
        version: 1,
        name: Path::new(file)
            .file_stem()
            .and_then(|s| s.to_str())
            .map(str::to_string),
        image: crate::scene::doc::ImageDoc { width, height },
        camera,
        display: crate::scene::doc::DisplayDoc::default(),
        materials: std::collections::BTreeMap::new(),
        objects: Vec::new(),
        lights: Vec::new(),
        render: crate::scene::doc::RenderDoc::default(),
        progressive: crate::scene::doc::ProgressiveDoc::default(),
    }
}

/// What a file lacks, supplied with one warning each (scene-import.md "Command line"): a
/// camera that frames the scene's bounds from the front (the importer leaves a zero
/// `fov_y` when the file has none), and a constant white environment when nothing emits.
fn supply_missing(im: &mut Imported) {
    let doc = &mut im.doc;
    if doc.camera.fov_y == 0.0 {
        doc.camera = framing_camera(doc);
        im.warnings.push(format!(
            "no camera: using one at {:?} looking at {:?} (fov_y {}°)",
            doc.camera.position, doc.camera.look_at, doc.camera.fov_y
        ));
    }
    let emits = doc
        .materials
        .values()
        .any(|m| matches!(m, crate::scene::doc::MaterialDoc::Emissive(_)));
    if doc.lights.is_empty() && !emits {
        doc.lights.push(LightDoc::Environment(EnvironmentLightDoc {
            radiance: [1.0; 3],
        }));
        im.warnings
            .push("no light: using a constant white environment (radiance 1)".into());
    }
}

/// A camera on +z of the bounds' centre, far enough for the bounding sphere to fit a
/// 40° vertical field of view.
fn framing_camera(doc: &SceneDoc) -> CameraDoc {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    let mut grow = |p: V3, r: f32| {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] - r);
            hi[a] = hi[a].max(p[a] + r);
        }
    };
    for o in &doc.objects {
        match o {
            ObjectDoc::Mesh(m) => m.positions.iter().for_each(|&p| grow(p, 0.0)),
            ObjectDoc::Sphere(s) => grow(s.center, s.radius),
            _ => {}
        }
    }
    if !lo[0].is_finite() {
        (lo, hi) = ([-1.0; 3], [1.0; 3]);
    }
    let c = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
    let r = (0..3)
        .map(|a| (hi[a] - lo[a]) * 0.5)
        .map(|h| h * h)
        .sum::<f32>()
        .sqrt()
        .max(1e-3);
    let fov: f32 = 40.0;
    let dist = r / (fov.to_radians() * 0.5).sin() * 1.05;
    CameraDoc {
        position: [c[0], c[1], c[2] + dist],
        look_at: c,
        up: [0.0, 1.0, 0.0],
        fov_y: fov,
    }
}

/// A mesh's vertex lists without the vertices no triangle uses, kept in their order,
/// `indices` (each below the number of positions) renumbered; lists whose every vertex is
/// used are returned as they are. Every importer drops them, so that a document holds at
/// most three vertices per triangle, however many a file lists (measured before: 30 M
/// unused numbers in a pbrt `P` became a 150 MB document).
pub(crate) fn drop_unused_vertices<P, N, T>(
    positions: Vec<P>,
    normals: Option<Vec<N>>,
    uvs: Option<Vec<T>>,
    indices: &mut [u32],
) -> (Vec<P>, Option<Vec<N>>, Option<Vec<T>>) {
    let n = positions.len();
    let mut used = vec![false; n];
    for &i in indices.iter() {
        used[i as usize] = true;
    }
    if used.iter().all(|&u| u) {
        return (positions, normals, uvs);
    }
    let mut new_index = vec![u32::MAX; n];
    for (next, (k, _)) in used.iter().enumerate().filter(|(_, &u)| u).enumerate() {
        new_index[k] = next as u32;
    }
    for i in indices.iter_mut() {
        *i = new_index[*i as usize];
    }
    (
        kept(positions, &used),
        normals.map(|v| kept(v, &used)),
        uvs.map(|v| kept(v, &used)),
    )
}

/// The items of `v` that `keep` marks.
fn kept<T>(v: Vec<T>, keep: &[bool]) -> Vec<T> {
    v.into_iter()
        .zip(keep)
        .filter(|(_, &k)| k)
        .map(|(x, _)| x)
        .collect()
}

/// Reads the file at `path` without validating it: a scene document is parsed, any other
/// format imported. `None` for a scene document (it is its own document).
pub fn import_path(path: &Path, limits: &Limits) -> Result<Option<Imported>, SceneError> {
    let format = Format::of(path).map_err(|m| file_error(path, m))?;
    if format == Format::Json {
        return Ok(None);
    }
    let il = ImportLimits::from_scene(limits);
    let len = std::fs::metadata(path)
        .map_err(|e| file_error(path, format!("cannot read: {e}")))?
        .len();
    if len > il.max_file_bytes {
        return Err(file_error(
            path,
            format!("{len} bytes exceed the limit of {}", il.max_file_bytes),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| file_error(path, format!("cannot read: {e}")))?;
    let files = DirSource {
        dir: folder_of(path),
    };
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("scene");
    Ok(Some(import(format, name, &bytes, &files, &il)?))
}

/// The validated scene in the file at `path`, in any format, with the import's warnings
/// (the validation's own warnings are in [`Scene::warnings`]).
pub fn load_path(path: &Path, limits: &Limits) -> Result<(Scene, Vec<String>), SceneError> {
    let dir = folder_of(path);
    match import_path(path, limits)? {
        None => {
            let json = std::fs::read_to_string(path)
                .map_err(|e| file_error(path, format!("cannot read: {e}")))?;
            Ok((
                parse_scene(&json, &SceneOrigin::File { dir }, limits)?,
                Vec::new(),
            ))
        }
        Some(im) => {
            // Imported documents hold their meshes inline: nothing more is read.
            let scene = validate_doc(&im.doc, &SceneOrigin::Request, limits)?;
            Ok((scene, im.warnings))
        }
    }
}

/// The folder a scene file's relative paths start from: `.` for a bare file name, whose
/// `parent()` is the empty path: that cannot be canonicalised, and `glimpse render
/// scene.gltf` run beside its `.bin` could not read it.
fn folder_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn file_error(path: &Path, message: impl Into<String>) -> SceneError {
    ImportError::invalid(path.display().to_string(), message).into()
}

/// What `POST /v1/jobs` may carry besides a scene document (scene-import.md "Over HTTP").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Upload {
    /// `model/gltf-binary`: a self-contained `.glb`.
    Glb,
    /// `application/zip`: one scene file at the root and the files it names.
    Zip,
}

/// Render settings given as query parameters for an uploaded file.
#[derive(Clone, Copy, Debug, Default)]
pub struct UploadSettings {
    pub width: Option<u64>,
    pub height: Option<u64>,
    pub samples_per_pixel: Option<u64>,
    pub mode: Option<crate::scene::RenderMode>,
    pub seed: Option<u64>,
    pub denoise: Option<bool>,
    pub sampler: Option<crate::scene::SamplerKind>,
}

impl UploadSettings {
    /// The image size for a file whose own is `width`×`height`: the parameters given,
    /// and one side alone keeps the file's aspect (as the viewer's size override does for
    /// a document), rounded, at least 1.
    #[must_use]
    pub fn size_of(&self, width: u64, height: u64) -> (u64, u64) {
        let follow = |given: u64, num: u64, den: u64| {
            if num == 0 || den == 0 {
                return num;
            }
            let v = (u128::from(given) * u128::from(num) + u128::from(den) / 2) / u128::from(den);
            u64::try_from(v).unwrap_or(u64::MAX).max(1)
        };
        match (self.width, self.height) {
            (Some(w), Some(h)) => (w, h),
            (Some(w), None) => (w, follow(w, height, width)),
            (None, Some(h)) => (follow(h, width, height), h),
            (None, None) => (width, height),
        }
    }
}

/// An upload as a scene document (JSON text, what the job stores and a restart parses
/// again) and the import's warnings. A bundle whose scene file is itself a document is
/// returned unchanged: its own settings hold, and it is held to `max_document_bytes`, the
/// limit of a posted document.
pub fn import_upload(
    kind: Upload,
    bytes: &[u8],
    settings: &UploadSettings,
    limits: &Limits,
    max_document_bytes: u64,
) -> Result<(String, Vec<String>), SceneError> {
    let mut il = ImportLimits::from_scene(limits);
    il.max_file_bytes = bundle::MAX_FILE;
    let imported = match kind {
        Upload::Glb => import(
            Format::Gltf,
            "upload.glb",
            bytes,
            &bundle::Bundle::default(),
            &il,
        )?,
        Upload::Zip => {
            let b = bundle::Bundle::parse(bytes, &UPLOAD_BUNDLE).map_err(bundle_error)?;
            let name = b.scene_file().map_err(bundle_error)?.to_string();
            let format =
                Format::of(Path::new(&name)).map_err(|m| ImportError::invalid(&name, m))?;
            if format == Format::Json {
                return Ok((bundled_document(&b, &name, max_document_bytes)?, Vec::new()));
            }
            // The bundle counts every read itself; the importers' own count agrees.
            il.max_read_bytes = b.read_budget();
            let data = b.read(&name, il.max_file_bytes).map_err(|e| e.at(&name))?;
            import(format, &name, &data, &b, &il)?
        }
    };
    let Imported { mut doc, warnings } = imported;
    let (width, height) = settings.size_of(doc.image.width, doc.image.height);
    doc.image.width = width;
    doc.image.height = height;
    if let Some(s) = settings.samples_per_pixel {
        doc.render.samples_per_pixel = s;
    }
    if let Some(m) = settings.mode {
        doc.render.mode = m;
    }
    if let Some(s) = settings.seed {
        doc.render.seed = s;
    }
    if let Some(d) = settings.denoise {
        doc.render.denoise = Some(d);
    }
    if let Some(s) = settings.sampler {
        doc.render.sampler = s;
    }
    let text = serde_json::to_string(&doc).map_err(|e| {
        ImportError::invalid("", format!("cannot write the imported document: {e}"))
    })?;
    Ok((text, warnings))
}

/// What an uploaded bundle may hold.
const UPLOAD_BUNDLE: bundle::BundleLimits = bundle::BundleLimits {
    max_entries: bundle::MAX_ENTRIES,
    max_unpacked: bundle::MAX_UNPACKED,
};

fn bundle_error(e: bundle::BundleError) -> SceneError {
    let f = if e.too_large {
        ImportError::limit
    } else {
        ImportError::invalid
    };
    f("bundle", e.message).into()
}

/// The scene document `name` of a bundle, held to the limit of a posted document: from
/// the directory's declared size, before inflating (measured before: a 350 KB zip of a
/// 30 M-triangle document took the server past 4 GB, 250 MiB of whitespace around a
/// scene filled the database past 1 GB).
fn bundled_document(b: &bundle::Bundle, name: &str, max: u64) -> Result<String, SceneError> {
    let size = b.size_of(name).unwrap_or(0);
    if size > max {
        return Err(ImportError::limit(
            name,
            format!(
                "the scene document unpacks to {size} bytes, more than the limit of {max} bytes for a scene document, posted or in a bundle (refused before unpacking)"
            ),
        )
        .into());
    }
    let data = b.read(name, max).map_err(|e| e.at(name))?;
    String::from_utf8(data).map_err(|_| ImportError::invalid(name, "not UTF-8 text").into())
}

#[cfg(test)]
mod tests {
    use super::{folder_of, UploadSettings};
    use std::path::Path;

    #[test]
    fn a_bare_file_name_reads_its_siblings_from_the_working_folder() {
        assert_eq!(folder_of(Path::new("scene.gltf")), Path::new("."));
        assert_eq!(folder_of(Path::new("a/b/scene.gltf")), Path::new("a/b"));
        assert_eq!(folder_of(Path::new("/scene.gltf")), Path::new("/"));
    }

    #[test]
    fn one_side_of_an_upload_keeps_the_files_aspect() {
        let s = |width, height| UploadSettings {
            width,
            height,
            ..UploadSettings::default()
        };
        assert_eq!(s(None, None).size_of(1280, 720), (1280, 720));
        assert_eq!(s(Some(96), Some(40)).size_of(1280, 720), (96, 40));
        assert_eq!(s(Some(96), None).size_of(1280, 720), (96, 54));
        assert_eq!(s(None, Some(72)).size_of(1280, 720), (128, 72));
        // Rounded to the nearest pixel, never below one; a file's zero stays for
        // validation to name.
        assert_eq!(s(Some(100), None).size_of(3, 2), (100, 67));
        assert_eq!(s(Some(1), None).size_of(1000, 1), (1, 1));
        assert_eq!(s(Some(64), None).size_of(0, 10), (64, 10));
        assert_eq!(s(Some(64), None).size_of(10, 0), (64, 0));
        assert_eq!(s(Some(u64::MAX), None).size_of(1, 2), (u64::MAX, u64::MAX));
    }
}
