//! Validation of a [`super::doc`] document into a [`super::Scene`]: collects every problem
//! with its JSON path.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use glam::{Vec2, Vec3};
use serde_json::Value;

use super::doc::{
    join_path, split_marked, CameraDoc, DisplayDoc, FalloffDoc, ImageTextureDoc, LightDoc,
    MaterialDoc, ObjectDoc, ProgressiveDoc, RenderDoc, ScaleDoc, SceneDoc, TextureDoc,
    TransformDoc, WrapDoc, V3,
};
use super::image::{ImageError, MAX_TEXTURE_PIXELS};
use super::obj;
use super::transform::Xform;
use super::{
    Camera, Display, ImageMap, Light, Material, ProgressiveSettings, RenderSettings, Scene, Shape,
    SpotFalloff, Texture, TextureImage, Triangle, Wrap,
};

/// Where a document came from: decides whether `obj` paths may be read.
#[derive(Clone, Debug)]
pub enum SceneOrigin {
    /// A file on the command line; `obj` paths resolve inside this folder only.
    File { dir: std::path::PathBuf },
    /// A network request: `obj` objects are refused (no request reads server files).
    Request,
}

/// Size limits checked before any work starts (a server sets its own).
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub max_width: u32,
    pub max_height: u32,
    pub max_pixels: u64,
    /// `samples_per_pixel × width × height` upper bound.
    pub max_sample_budget: u64,
    pub max_objects: usize,
    pub max_triangles: usize,
    pub max_samples_per_pixel: u32,
    pub max_bounces: u32,
}

impl Limits {
    /// What the command line accepts: large but still bounded.
    #[must_use]
    pub fn command_line() -> Self {
        Self {
            max_width: 16384,
            max_height: 16384,
            max_pixels: 64 << 20,
            max_sample_budget: 1 << 40,
            max_objects: 1_000_000,
            max_triangles: 20_000_000,
            max_samples_per_pixel: 1 << 20,
            max_bounces: 1024,
        }
    }
}

/// One problem in a document, named by its JSON path (`objects[3].radius`).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Problem {
    pub path: String,
    pub message: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.path.is_empty() {
            write!(f, "{}", self.message)
        } else {
            write!(f, "{}: {}", self.path, self.message)
        }
    }
}

/// Why a document was refused; decides the HTTP status in the service.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneErrorKind {
    /// Not JSON at all (HTTP 400 `invalid_json`).
    InvalidJson,
    /// JSON, but not a valid scene (HTTP 422 `invalid_scene`).
    InvalidScene,
    /// Valid, but above a limit (HTTP 422 `over_limit`); the message names the limit.
    TooLarge,
}

/// Every problem of a refused document; the first is the headline.
#[derive(Clone, Debug, thiserror::Error)]
#[error("{}", .problems.first().map(ToString::to_string).unwrap_or_default())]
pub struct SceneError {
    pub kind: SceneErrorKind,
    pub problems: Vec<Problem>,
}

/// At most this many problems (and, separately, warnings) are listed; the rest are
/// summarised in one last entry. A bad 100 000-triangle mesh must not produce a
/// 100 000-line error.
pub const MAX_LISTED: usize = 50;

/// A triangle is degenerate (collinear or coincident points) when its height is below
/// this fraction of its longest edge, i.e. `|e1 × e2| ≤ DEGENERATE_REL · ℓ_max²`. 1e-6 is
/// about ten f32 ulps: below it the geometric normal is numerical noise.
pub const DEGENERATE_REL: f32 = 1e-6;

/// Two directions count as parallel when the sine of their angle is below this
/// (≈ 0.006°): the camera basis built from them would be numerical noise.
const PARALLEL_SIN: f32 = 1e-4;

/// Largest magnitude of a world-space coordinate (camera, point lights, every object after
/// its transform). scene-format.md forbids NaN and infinities but sets no range; a finite
/// f32 as large as 1e30 still overflows where the tracer squares a distance (a sphere's
/// `|o − c|² − r²`) or the BVH builder multiplies two box extents (surface areas), and
/// `obvhs` then panicked building the BVH (an index out of bounds while ordering a node's
/// children; found by fuzzing mutated scenes, `tests/scene_fuzz.rs`). At 1e9 squares
/// (1e18) and even fourth powers (1e36) stay finite in f32; no real scene needs more (a
/// planet in metres is 6.4e6).
pub const MAX_COORDINATE: f32 = 1e9;

/// Largest emitted radiance, light intensity or irradiance (each channel). scene-format.md
/// sets no range, but a pixel that sees a lamp of f32::MAX's order (3.4e38, found by
/// `tests/scene_fuzz.rs`) is a finite estimate whose weighted sums in the progressive
/// loop's interpolation overflow to ∞, and ∞ − ∞ is NaN in the picture. At 1e12 (the
/// sun's disc is ~1.6e9 cd/m²) a pixel's square (1e24) summed over 2^26 pixels stays
/// finite in f32.
pub const MAX_EMISSION: f32 = 1e12;

/// Parses and validates a scene document.
///
/// Two steps: the text is parsed to a `serde_json::Value` first, so every syntax problem
/// (not JSON, empty, truncated, NaN/Infinity literals, nesting deeper than serde_json's
/// limit of 128) is an [`SceneErrorKind::InvalidJson`] with line and column, and the
/// recursion limit protects the stack whatever the document's shape. The `Value` is then
/// deserialized into [`super::doc::SceneDoc`] with `serde_path_to_error`, so a wrong type
/// or an unknown field names its path. (A `Value` keeps the last of duplicate keys; the
/// document is small enough that the double pass costs nothing that matters.)
///
/// Then every rule of scene-format.md is checked and *all* problems are collected.
/// Kind: [`SceneErrorKind::InvalidScene`] if any problem is not a limit; `TooLarge` only
/// if every problem is a limit, so that `too_large` promises "fine, but too big here" and
/// the headline always matches the kind.
pub fn parse_scene(json: &str, origin: &SceneOrigin, limits: &Limits) -> Result<Scene, SceneError> {
    let doc = parse_doc(json)?;
    build(&doc, origin, limits)
}

/// Validates a document built in memory (an import) by exactly the rules a parsed one
/// meets.
pub fn validate_doc(
    doc: &SceneDoc,
    origin: &SceneOrigin,
    limits: &Limits,
) -> Result<Scene, SceneError> {
    build(doc, origin, limits)
}

fn one(kind: SceneErrorKind, path: String, message: String) -> SceneError {
    SceneError {
        kind,
        problems: vec![Problem { path, message }],
    }
}

/// Text → document (shape only).
fn parse_doc(json: &str) -> Result<SceneDoc, SceneError> {
    if json.trim().is_empty() {
        return Err(one(
            SceneErrorKind::InvalidJson,
            String::new(),
            "the document is empty; expected a JSON scene object".into(),
        ));
    }
    let value: Value = serde_json::from_str(json).map_err(|e| syntax_error(json, &e))?;
    // serde's derived structs also accept a JSON array of the fields in order; the
    // contract is an object, so the root is checked explicitly.
    if !value.is_object() {
        return Err(one(
            SceneErrorKind::InvalidScene,
            String::new(),
            format!(
                "the document must be a JSON object, got {}",
                json_type(&value)
            ),
        ));
    }
    // serde_json keeps the last of duplicate keys silently (super::duplicates).
    if let Some((path, key)) = super::duplicates::first_duplicate_key(json) {
        return Err(one(
            SceneErrorKind::InvalidScene,
            path,
            format!("duplicate key `{key}`: each key may appear only once in an object"),
        ));
    }
    serde_path_to_error::deserialize::<_, SceneDoc>(value).map_err(|e| {
        let outer = e.path().to_string();
        let outer = if outer == "." { String::new() } else { outer };
        let msg = e.into_inner().to_string();
        let (inner, msg) = split_marked(&msg);
        let mut path = join_path(&outer, inner);
        // serde_path_to_error stops at the object holding an unknown field; the spec
        // wants the path *of the field* (`image.colour`, not `image`).
        if let Some(field) = msg
            .strip_prefix("unknown field `")
            .and_then(|r| r.split('`').next())
        {
            if !path.ends_with(field) {
                path = join_path(&path, field);
            }
        }
        one(SceneErrorKind::InvalidScene, path, msg.to_string())
    })
}

fn json_type(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

/// A serde_json parse error, with the path where it happened when that helps.
fn syntax_error(json: &str, e: &serde_json::Error) -> SceneError {
    let at = format!("line {} column {}", e.line(), e.column());
    let offset = byte_offset(json, e.line(), e.column());
    let text = e.to_string();
    if text.starts_with("recursion limit exceeded") {
        // The path would be 128 levels of `[0]`: useless; the root is named instead.
        return one(
            SceneErrorKind::InvalidJson,
            String::new(),
            format!("nested 128 levels deep or more at {at} (the limit is 127); a scene never needs that"),
        );
    }
    let path = path_at(json, offset);
    if text.starts_with("number out of range") {
        // Valid JSON grammar, but no finite number: a scene problem with a path.
        return one(
            SceneErrorKind::InvalidScene,
            path,
            format!("number out of range at {at}; every number must be finite"),
        );
    }
    let lo = floor_char_boundary(json, offset.saturating_sub(10));
    let hi = floor_char_boundary(json, (offset + 10).min(json.len()));
    let near = &json[lo..hi];
    if near.contains("NaN") || near.contains("Infinity") {
        return one(
            SceneErrorKind::InvalidJson,
            path,
            format!("NaN and Infinity are not JSON numbers (at {at}); every number must be finite"),
        );
    }
    if matches!(e.classify(), serde_json::error::Category::Eof) {
        return one(
            SceneErrorKind::InvalidJson,
            path,
            format!("the document ends too early ({text})"),
        );
    }
    one(
        SceneErrorKind::InvalidJson,
        path,
        format!("not valid JSON: {text}"),
    )
}

fn floor_char_boundary(s: &str, mut i: usize) -> usize {
    while i > 0 && !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// serde_json's 1-based line and column (in bytes) → a byte offset into `json`.
fn byte_offset(json: &str, line: usize, column: usize) -> usize {
    let mut start = 0;
    for _ in 1..line {
        match json[start..].find('\n') {
            Some(i) => start += i + 1,
            None => break,
        }
    }
    floor_char_boundary(json, (start + column.saturating_sub(1)).min(json.len()))
}

/// The JSON path of the value being read at byte `offset`, from a small scan of the
/// text before it (strings, brackets, `:` and `,`). Used only to name where a syntax
/// error happened, so it may be approximate on text that is not JSON.
fn path_at(json: &str, offset: usize) -> String {
    enum Frame {
        Obj { key: Option<String>, in_key: bool },
        Arr(usize),
    }
    let mut stack: Vec<Frame> = Vec::new();
    let bytes = json.as_bytes();
    let mut i = 0;
    while i < offset.min(bytes.len()) {
        match bytes[i] {
            b'"' => {
                let start = i + 1;
                let mut j = start;
                while j < bytes.len() && bytes[j] != b'"' {
                    j += if bytes[j] == b'\\' { 2 } else { 1 };
                }
                if let Some(Frame::Obj { key, in_key: true }) = stack.last_mut() {
                    *key = json.get(start..j.min(json.len())).map(str::to_string);
                }
                i = j;
            }
            b'{' => stack.push(Frame::Obj {
                key: None,
                in_key: true,
            }),
            b'[' => stack.push(Frame::Arr(0)),
            b'}' | b']' => {
                stack.pop();
            }
            b':' => {
                if let Some(Frame::Obj { in_key, .. }) = stack.last_mut() {
                    *in_key = false;
                }
            }
            b',' => match stack.last_mut() {
                Some(Frame::Obj { key, in_key }) => {
                    *key = None;
                    *in_key = true;
                }
                Some(Frame::Arr(n)) => *n += 1,
                None => {}
            },
            _ => {}
        }
        i += 1;
    }
    let mut path = String::new();
    for f in &stack {
        match f {
            Frame::Obj { key: Some(k), .. } => path = join_path(&path, k),
            Frame::Obj { key: None, .. } => {}
            Frame::Arr(n) => path.push_str(&format!("[{n}]")),
        }
    }
    path
}

/// Collects problems while walking the document.
#[derive(Default)]
struct Ctx {
    errors: Vec<Problem>,
    too_large: Vec<Problem>,
    warnings: Vec<Problem>,
    unlisted_errors: usize,
    unlisted_warnings: usize,
    /// The farthest world-space coordinate beyond ±[`MAX_COORDINATE`] of the object being
    /// checked (value, axis), if any: reported once per object by [`build`].
    far: Option<(f32, usize)>,
    /// Image textures decoded so far, each once: a document that names the same data
    /// (and encoding) twice gets one image.
    images: Vec<Arc<TextureImage>>,
    image_index: HashMap<(u64, super::image::Encoding), u32>,
    texels: u64,
}

fn push_capped(list: &mut Vec<Problem>, unlisted: &mut usize, path: &str, message: String) {
    if list.len() < MAX_LISTED {
        list.push(Problem {
            path: path.to_string(),
            message,
        });
    } else {
        *unlisted += 1;
    }
}

impl Ctx {
    fn err(&mut self, path: &str, message: impl Into<String>) {
        push_capped(
            &mut self.errors,
            &mut self.unlisted_errors,
            path,
            message.into(),
        );
    }

    fn limit(&mut self, path: &str, message: String) {
        self.too_large.push(Problem {
            path: path.to_string(),
            message,
        });
    }

    fn warn(&mut self, path: &str, message: String) {
        push_capped(
            &mut self.warnings,
            &mut self.unlisted_warnings,
            path,
            message,
        );
    }

    /// Every real must be finite. NaN cannot come from JSON; an infinity can, from a
    /// number that fits an f64 but not an f32 (`1e39`).
    fn finite(&mut self, path: &str, v: f32) -> bool {
        if v.is_finite() {
            true
        } else {
            self.err(
                path,
                "must be a finite number (this one does not fit a 32-bit float)",
            );
            false
        }
    }

    fn vec3(&mut self, path: &str, v: V3) -> Vec3 {
        for (i, c) in v.iter().enumerate() {
            self.finite(&format!("{path}[{i}]"), *c);
        }
        Vec3::from(v)
    }

    /// A reflectance: each component in [0, 1] (energy conservation, scene-format.md).
    fn colour01(&mut self, path: &str, v: V3) -> Vec3 {
        for (i, c) in v.iter().enumerate() {
            let p = format!("{path}[{i}]");
            if self.finite(&p, *c) && !(0.0..=1.0).contains(c) {
                self.err(&p, format!("must be in [0, 1], got {c}"));
            }
        }
        Vec3::from(v)
    }

    /// An emitted quantity: each component finite and ≥ 0.
    fn nonneg3(&mut self, path: &str, v: V3) -> Vec3 {
        for (i, c) in v.iter().enumerate() {
            let p = format!("{path}[{i}]");
            if self.finite(&p, *c) && *c < 0.0 {
                self.err(&p, format!("must be ≥ 0, got {c}"));
            }
        }
        Vec3::from(v)
    }

    /// [`Self::nonneg3`] for light: each channel also at most [`MAX_EMISSION`].
    fn emission3(&mut self, path: &str, v: V3) -> Vec3 {
        for (i, c) in v.iter().enumerate() {
            if c.is_finite() && *c > MAX_EMISSION {
                self.err(
                    &format!("{path}[{i}]"),
                    format!("must be at most {MAX_EMISSION:e}, got {c:e}"),
                );
            }
        }
        self.nonneg3(path, v)
    }

    fn positive(&mut self, path: &str, v: f32) {
        if self.finite(path, v) && v <= 0.0 {
            self.err(path, format!("must be > 0, got {v}"));
        }
    }

    fn in_unit(&mut self, path: &str, v: f32) {
        if self.finite(path, v) && !(0.0..=1.0).contains(&v) {
            self.err(path, format!("must be in [0, 1], got {v}"));
        }
    }

    /// (0, 1]: a fraction that must not be zero.
    fn fraction(&mut self, path: &str, v: f32) {
        if self.finite(path, v) && !(v > 0.0 && v <= 1.0) {
            self.err(path, format!("must be in (0, 1], got {v}"));
        }
    }
}

/// Document → validated [`Scene`].
fn build(doc: &SceneDoc, origin: &SceneOrigin, limits: &Limits) -> Result<Scene, SceneError> {
    let mut cx = Ctx::default();

    if doc.version != 1 {
        cx.err("version", format!("must be 1, got {}", doc.version));
    }

    // image, then every size limit (before any geometry is built).
    let (w, h) = (doc.image.width, doc.image.height);
    for (path, v, max) in [
        ("image.width", w, limits.max_width),
        ("image.height", h, limits.max_height),
    ] {
        if v < 1 {
            cx.err(path, format!("must be ≥ 1, got {v}"));
        } else if v > u64::from(max) {
            cx.limit(path, format!("{v} exceeds this server's limit of {max}"));
        }
    }
    let pixels = w.saturating_mul(h);
    if pixels > limits.max_pixels {
        cx.limit(
            "image",
            format!(
                "{w}×{h} = {pixels} pixels exceeds this server's limit of {} pixels",
                limits.max_pixels
            ),
        );
    }
    let spp = doc.render.samples_per_pixel;
    if spp < 1 {
        cx.err(
            "render.samples_per_pixel",
            format!("must be ≥ 1, got {spp}"),
        );
    } else if spp > u64::from(limits.max_samples_per_pixel) {
        cx.limit(
            "render.samples_per_pixel",
            format!(
                "{spp} exceeds this server's limit of {}",
                limits.max_samples_per_pixel
            ),
        );
    } else {
        let budget = u128::from(spp) * u128::from(pixels);
        if budget > u128::from(limits.max_sample_budget) {
            cx.limit(
                "render.samples_per_pixel",
                format!(
                    "{spp} samples × {pixels} pixels = {budget} samples exceeds this server's limit of {} samples per render",
                    limits.max_sample_budget
                ),
            );
        }
    }
    // A bounce limit above the cap is capped, not refused: scenes people download carry
    // pbrt's `maxdepth 65` or Mitsuba's `max_depth` of 64-100, and Russian roulette
    // (`tracer::integrator`, `RR_START`) already ends nearly every path long before.
    if doc.render.max_bounces > u64::from(limits.max_bounces) {
        cx.warn(
            "render.max_bounces",
            format!(
                "{} is above this server's cap of {}: paths stop after {} bounces (Russian roulette ends nearly all of them long before, so the picture barely changes)",
                doc.render.max_bounces, limits.max_bounces, limits.max_bounces
            ),
        );
    }
    if doc.objects.len() > limits.max_objects {
        cx.limit(
            "objects",
            format!(
                "{} objects exceed this server's limit of {}",
                doc.objects.len(),
                limits.max_objects
            ),
        );
    }
    // Triangle count known before building (OBJ files add theirs when loaded).
    let declared: usize = doc
        .objects
        .iter()
        .map(|o| match o {
            ObjectDoc::Quad(_) => 2,
            ObjectDoc::Box(_) => 12,
            ObjectDoc::Mesh(m) => m.indices.len(),
            ObjectDoc::Sphere(_) | ObjectDoc::Obj(_) => 0,
        })
        .sum();
    if declared > limits.max_triangles {
        cx.limit(
            "objects",
            format!(
                "{declared} triangles exceed this server's limit of {}",
                limits.max_triangles
            ),
        );
    }

    let camera = check_camera(&mut cx, &doc.camera);
    let display = check_display(&mut cx, &doc.display);
    let (materials, material_names) = check_materials(&mut cx, &doc.materials);

    let mut shapes = Vec::with_capacity(doc.objects.len());
    // Skip building geometry when the document is already too large: the point of the
    // limits is that no work is spent on it.
    if cx.too_large.is_empty() {
        for (k, o) in doc.objects.iter().enumerate() {
            let shape = check_object(&mut cx, k, o, &material_names, origin);
            if let Some(Shape::Sphere { center, radius, .. }) = &shape {
                for v in [*center - *radius, *center + *radius] {
                    note_far(&mut cx, v);
                }
            }
            if let Some((v, a)) = cx.far.take() {
                cx.err(
                    &format!("objects[{k}]"),
                    format!(
                        "reaches {v:e} on the {} axis after its transform; world coordinates \
                         must be within ±{MAX_COORDINATE:e}",
                        ["x", "y", "z"][a]
                    ),
                );
            }
            shapes.extend(shape);
        }
    }
    let triangles: usize = shapes
        .iter()
        .map(|s| match s {
            Shape::Triangles { triangles, .. } => triangles.len(),
            Shape::Sphere { .. } => 0,
        })
        .sum();
    if cx.too_large.is_empty() && triangles > limits.max_triangles {
        cx.limit(
            "objects",
            format!(
                "{triangles} triangles exceed this server's limit of {}",
                limits.max_triangles
            ),
        );
    }

    let lights = doc
        .lights
        .iter()
        .enumerate()
        .map(|(i, l)| check_light(&mut cx, &format!("lights[{i}]"), l))
        .collect();
    let mut render = check_render(&mut cx, &doc.render);
    render.max_bounces = render.max_bounces.min(limits.max_bounces);
    let progressive = check_progressive(&mut cx, &doc.progressive);

    if cx.unlisted_errors > 0 {
        cx.errors.push(Problem {
            path: String::new(),
            message: format!("... and {} more problems not listed", cx.unlisted_errors),
        });
    }
    if !cx.errors.is_empty() {
        let mut problems = cx.errors;
        problems.extend(cx.too_large);
        return Err(SceneError {
            kind: SceneErrorKind::InvalidScene,
            problems,
        });
    }
    if !cx.too_large.is_empty() {
        return Err(SceneError {
            kind: SceneErrorKind::TooLarge,
            problems: cx.too_large,
        });
    }
    if cx.unlisted_warnings > 0 {
        cx.warnings.push(Problem {
            path: "objects".into(),
            message: format!(
                "... and {} more degenerate triangles dropped",
                cx.unlisted_warnings
            ),
        });
    }
    let mut scene = Scene {
        // An unnamed scene is "untitled" rather than "": logs and the viewer show it.
        name: doc.name.clone().unwrap_or_else(|| "untitled".into()),
        width: u32::try_from(w).unwrap_or(u32::MAX),
        height: u32::try_from(h).unwrap_or(u32::MAX),
        camera,
        display,
        materials,
        material_names,
        shapes,
        lights,
        images: cx.images,
        render,
        progressive,
        warnings: cx.warnings,
    };
    let suspicious = super::warnings::check(&scene);
    scene.warnings.extend(suspicious);
    Ok(scene)
}

/// Within ±[`MAX_COORDINATE`]; false for NaN (every comparison with NaN is false).
fn in_range(v: f32) -> bool {
    v.abs() <= MAX_COORDINATE
}

/// Records in `cx.far` a world-space point's coordinate beyond ±[`MAX_COORDINATE`] (or not
/// a number: an overflowed transform), keeping the largest seen for the current object.
/// Returns whether the point is out of range.
fn note_far(cx: &mut Ctx, p: Vec3) -> bool {
    let mut far = false;
    for a in 0..3 {
        let v = p[a];
        if !in_range(v) {
            far = true;
            if !cx.far.is_some_and(|(f, _)| f.abs() >= v.abs()) {
                cx.far = Some((v, a));
            }
        }
    }
    far
}

/// [`Ctx::vec3`] for a world-space position: finite and within ±[`MAX_COORDINATE`].
fn world_position(cx: &mut Ctx, path: &str, v: V3) -> Vec3 {
    let p = cx.vec3(path, v);
    for (i, c) in v.iter().enumerate() {
        // Non-finite values were refused by `vec3` already.
        if c.is_finite() && !in_range(*c) {
            cx.err(
                &format!("{path}[{i}]"),
                format!("must be within ±{MAX_COORDINATE:e}, got {c:e}"),
            );
        }
    }
    p
}

fn check_camera(cx: &mut Ctx, c: &CameraDoc) -> Camera {
    let position = world_position(cx, "camera.position", c.position);
    let look_at = world_position(cx, "camera.look_at", c.look_at);
    let up = cx.vec3("camera.up", c.up);
    if cx.finite("camera.fov_y", c.fov_y) && !(c.fov_y > 0.0 && c.fov_y < 180.0) {
        cx.err(
            "camera.fov_y",
            format!("must be in (0, 180) degrees, got {}", c.fov_y),
        );
    }
    let view = look_at - position;
    if position.is_finite() && look_at.is_finite() && up.is_finite() {
        if view.length_squared() == 0.0 || !view.length_squared().is_finite() {
            cx.err(
                "camera.look_at",
                "must differ from camera.position (no viewing direction)",
            );
        } else if up.length_squared() == 0.0 {
            cx.err("camera.up", "must be non-zero");
        } else if view.normalize().cross(up.normalize()).length() < PARALLEL_SIN {
            cx.err(
                "camera.up",
                "must not be parallel to the viewing direction (look_at − position)",
            );
        }
    }
    Camera {
        position,
        look_at,
        up,
        fov_y_deg: c.fov_y,
    }
}

fn check_display(cx: &mut Ctx, d: &DisplayDoc) -> Display {
    if cx.finite("display.black_luminance", d.black_luminance) && d.black_luminance < 0.0 {
        cx.err(
            "display.black_luminance",
            format!("must be ≥ 0, got {}", d.black_luminance),
        );
    }
    if cx.finite("display.peak_luminance", d.peak_luminance)
        && d.black_luminance.is_finite()
        && d.peak_luminance <= d.black_luminance
    {
        cx.err(
            "display.peak_luminance",
            format!(
                "must be greater than black_luminance ({}), got {}",
                d.black_luminance, d.peak_luminance
            ),
        );
    }
    cx.positive("display.exposure", d.exposure);
    cx.positive("display.pixels_per_degree", d.pixels_per_degree);
    Display {
        peak_luminance: d.peak_luminance,
        black_luminance: d.black_luminance,
        exposure: d.exposure,
        pixels_per_degree: d.pixels_per_degree,
    }
}

/// Materials in name order (the `BTreeMap`'s), so `MaterialId`s do not depend on how the
/// document was written or serialised.
fn check_materials(
    cx: &mut Ctx,
    m: &BTreeMap<String, MaterialDoc>,
) -> (Vec<Material>, Vec<String>) {
    let mut out = Vec::with_capacity(m.len());
    let mut names = Vec::with_capacity(m.len());
    for (name, md) in m {
        let p = format!("materials.{name}");
        let mat = match md {
            MaterialDoc::Diffuse(d) => {
                let albedo = match (&d.albedo, &d.texture) {
                    (Some(a), None) => Texture::Constant(cx.colour01(&format!("{p}.albedo"), *a)),
                    (None, Some(t)) => check_texture(cx, &format!("{p}.texture"), t),
                    (Some(_), Some(_)) => {
                        cx.err(&p, "give either albedo or texture, not both");
                        Texture::Constant(Vec3::ZERO)
                    }
                    (None, None) => {
                        cx.err(
                            &format!("{p}.albedo"),
                            "missing: a diffuse material needs `albedo` or `texture`",
                        );
                        Texture::Constant(Vec3::ZERO)
                    }
                };
                Material::Diffuse { albedo }
            }
            MaterialDoc::Glossy(g) => {
                let albedo = cx.colour01(&format!("{p}.albedo"), g.albedo);
                cx.in_unit(&format!("{p}.roughness"), g.roughness);
                Material::Glossy {
                    albedo,
                    roughness: g.roughness,
                }
            }
            MaterialDoc::Conductor(c) => {
                let eta = cx.nonneg3(&format!("{p}.eta"), c.eta);
                let k = cx.nonneg3(&format!("{p}.k"), c.k);
                // η = k = 0 makes the complex Fresnel 0/0 at normal incidence.
                if eta.max_element() <= 0.0 && k.max_element() <= 0.0 {
                    cx.err(&format!("{p}.eta"), "eta and k must not both be zero");
                }
                cx.in_unit(&format!("{p}.roughness"), c.roughness);
                Material::Conductor {
                    eta,
                    k,
                    roughness: c.roughness,
                }
            }
            MaterialDoc::MetallicRoughness(m) => {
                let base = cx.colour01(&format!("{p}.base_color"), m.base_color);
                let base_color = match &m.texture {
                    Some(t) => check_texture(cx, &format!("{p}.texture"), t),
                    None => Texture::Constant(base),
                };
                cx.in_unit(&format!("{p}.metallic"), m.metallic);
                cx.in_unit(&format!("{p}.roughness"), m.roughness);
                Material::MetallicRoughness {
                    base_color,
                    metallic: m.metallic,
                    roughness: m.roughness,
                }
            }
            MaterialDoc::CoatedDiffuse(c) => {
                let reflectance = match (&c.reflectance, &c.texture) {
                    (Some(a), None) => {
                        Texture::Constant(cx.colour01(&format!("{p}.reflectance"), *a))
                    }
                    (None, Some(t)) => check_texture(cx, &format!("{p}.texture"), t),
                    (Some(_), Some(_)) => {
                        cx.err(&p, "give either reflectance or texture, not both");
                        Texture::Constant(Vec3::ZERO)
                    }
                    (None, None) => {
                        cx.err(
                            &format!("{p}.reflectance"),
                            "missing: a coated_diffuse material needs `reflectance` or `texture`",
                        );
                        Texture::Constant(Vec3::ZERO)
                    }
                };
                cx.in_unit(&format!("{p}.roughness"), c.roughness);
                cx.positive(&format!("{p}.ior"), c.ior);
                Material::CoatedDiffuse {
                    reflectance,
                    roughness: c.roughness,
                    ior: c.ior,
                }
            }
            MaterialDoc::Mirror(r) => Material::Mirror {
                reflectance: cx.colour01(&format!("{p}.reflectance"), r.reflectance),
            },
            MaterialDoc::Dielectric(d) => {
                cx.positive(&format!("{p}.ior"), d.ior);
                let tint = cx.colour01(&format!("{p}.tint"), d.tint.unwrap_or([1.0; 3]));
                Material::Dielectric { ior: d.ior, tint }
            }
            MaterialDoc::Emissive(e) => Material::Emissive {
                radiance: cx.emission3(&format!("{p}.radiance"), e.radiance),
                two_sided: e.two_sided,
            },
        };
        out.push(mat);
        names.push(name.clone());
    }
    (out, names)
}

fn check_texture(cx: &mut Ctx, p: &str, t: &TextureDoc) -> Texture {
    let (f, checker) = match t {
        TextureDoc::Checker(f) => (f, true),
        TextureDoc::Noise(f) => (f, false),
        TextureDoc::Image(i) => return check_image_texture(cx, p, i),
    };
    cx.positive(&format!("{p}.scale"), f.scale);
    let a = cx.colour01(&format!("{p}.a"), f.a);
    let b = cx.colour01(&format!("{p}.b"), f.b);
    if checker {
        Texture::Checker {
            scale: f.scale,
            a,
            b,
        }
    } else {
        Texture::Noise {
            scale: f.scale,
            a,
            b,
        }
    }
}

/// An image texture: its mapping checked, its image decoded (once per distinct data and
/// encoding) within the document's texel limit.
fn check_image_texture(cx: &mut Ctx, p: &str, t: &ImageTextureDoc) -> Texture {
    let factor = cx.colour01(&format!("{p}.factor"), t.factor);
    for (name, v) in [("uv_scale", t.uv_scale), ("uv_offset", t.uv_offset)] {
        for (i, x) in v.iter().enumerate() {
            cx.finite(&format!("{p}.{name}[{i}]"), *x);
        }
    }
    let key = {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        t.data.hash(&mut h);
        (h.finish(), t.encoding)
    };
    let image = match cx.image_index.get(&key) {
        Some(&i) => i,
        // No image is decoded for a document already too large.
        None if !cx.too_large.is_empty() => 0,
        None => {
            let budget = MAX_TEXTURE_PIXELS.saturating_sub(cx.texels);
            match super::image::decode(&t.data, t.encoding, budget) {
                Ok(img) => {
                    cx.texels += u64::from(img.width) * u64::from(img.height);
                    let i = cx.images.len() as u32;
                    cx.images.push(Arc::new(img));
                    cx.image_index.insert(key, i);
                    i
                }
                Err(ImageError::TooLarge(m)) => {
                    cx.limit(&format!("{p}.data"), m);
                    0
                }
                Err(ImageError::Invalid(m)) => {
                    cx.err(&format!("{p}.data"), m);
                    0
                }
            }
        }
    };
    Texture::Image(ImageMap {
        image,
        factor,
        wrap: match t.wrap {
            WrapDoc::Repeat => Wrap::Repeat,
            WrapDoc::Clamp => Wrap::Clamp,
            WrapDoc::Mirror => Wrap::Mirror,
            WrapDoc::Black => Wrap::Black,
        },
        scale: Vec2::from(t.uv_scale),
        offset: Vec2::from(t.uv_offset),
    })
}

/// Checks a transform; `None` if it is unusable (the object is then not built).
fn check_transform(cx: &mut Ctx, p: &str, t: Option<&TransformDoc>) -> Option<Xform> {
    let Some(td) = t else {
        return Some(Xform::IDENTITY);
    };
    let before = cx.errors.len() + cx.unlisted_errors;
    if let Some(tr) = td.translate {
        cx.vec3(&format!("{p}.translate"), tr);
    }
    for (name, r) in [
        ("rotate_x", td.rotate_x),
        ("rotate_y", td.rotate_y),
        ("rotate_z", td.rotate_z),
    ] {
        if let Some(r) = r {
            cx.finite(&format!("{p}.{name}"), r);
        }
    }
    match td.scale {
        None => {}
        Some(ScaleDoc::Uniform(s)) => {
            let sp = format!("{p}.scale");
            if cx.finite(&sp, s) && s == 0.0 {
                cx.err(&sp, "must be non-zero (a zero scale flattens the object)");
            }
        }
        Some(ScaleDoc::Axes(a)) => {
            for (i, s) in a.iter().enumerate() {
                let sp = format!("{p}.scale[{i}]");
                if cx.finite(&sp, *s) && *s == 0.0 {
                    cx.err(&sp, "must be non-zero (a zero scale flattens the object)");
                }
            }
        }
    }
    (cx.errors.len() + cx.unlisted_errors == before).then(|| Xform::from_doc(Some(td)))
}

/// Appends a world-space triangle unless it is degenerate (then a warning at `path`).
/// Mirroring transforms swap two vertices so the geometric normal `(p1−p0)×(p2−p0)` is
/// still the transformed normal.
fn push_triangle(
    cx: &mut Ctx,
    out: &mut Vec<Triangle>,
    path: &str,
    x: &Xform,
    mut p: [Vec3; 3],
    mut n: Option<[Vec3; 3]>,
    mut uv: Option<[Vec2; 3]>,
) {
    if x.mirrors {
        p.swap(1, 2);
        if let Some(n) = n.as_mut() {
            n.swap(1, 2);
        }
        if let Some(uv) = uv.as_mut() {
            uv.swap(1, 2);
        }
    }
    // A vertex out of range refuses the whole object (reported once by `build`), before the
    // degenerate test: a far-out corner can swallow its edges in f32 and look degenerate.
    let far = p.iter().fold(false, |far, &v| note_far(cx, v) | far);
    if far {
        return;
    }
    let (e1, e2, e3) = (p[1] - p[0], p[2] - p[0], p[2] - p[1]);
    let lmax2 = e1
        .length_squared()
        .max(e2.length_squared())
        .max(e3.length_squared());
    let area2 = e1.cross(e2).length();
    // Written so that NaN also counts as degenerate (every comparison with NaN is false);
    // vertices are finite and in range here, so this is only a guard.
    let sound = area2 > DEGENERATE_REL * lmax2 && lmax2.is_finite();
    if !sound {
        cx.warn(
            path,
            "degenerate triangle (collinear or coincident points): ignored".into(),
        );
        return;
    }
    out.push(Triangle { p, n, uv });
}

/// The two triangles of a quad: (c, c+u, c+u+v) and (c, c+u+v, c+v). Both have geometric
/// normal `u × v` (scene-format.md), which decides the emitting side of a one-sided light.
fn quad_corners(c: Vec3, u: Vec3, v: Vec3) -> [[Vec3; 3]; 2] {
    [[c, c + u, c + u + v], [c, c + u + v, c + v]]
}

/// A quad's texture coordinates at [`quad_corners`]: (s, t) of `corner + s·edge_u +
/// t·edge_v`, so an image texture spans the quad once.
const QUAD_UVS: [[Vec2; 3]; 2] = [
    [Vec2::ZERO, Vec2::X, Vec2::ONE],
    [Vec2::ZERO, Vec2::ONE, Vec2::Y],
];

fn check_object(
    cx: &mut Ctx,
    k: usize,
    o: &ObjectDoc,
    names: &[String],
    origin: &SceneOrigin,
) -> Option<Shape> {
    let p = format!("objects[{k}]");
    let material = match names.binary_search_by(|n| n.as_str().cmp(o.material())) {
        Ok(i) => u32::try_from(i).ok(),
        Err(_) => {
            let known = if names.is_empty() {
                "no materials are defined".to_string()
            } else {
                format!("defined: {}", names.join(", "))
            };
            cx.err(
                &format!("{p}.material"),
                format!("unknown material \"{}\"; {known}", o.material()),
            );
            None
        }
    };
    let x = check_transform(cx, &format!("{p}.transform"), o.transform());
    match o {
        ObjectDoc::Sphere(s) => {
            let center = cx.vec3(&format!("{p}.center"), s.center);
            cx.positive(&format!("{p}.radius"), s.radius);
            let x = x?;
            // A sphere stays a sphere (the tracer intersects it analytically), so only a
            // uniform scale is meaningful; an ellipsoid must be sent as a mesh. A
            // negative uniform scale is a point reflection: the radius uses |s|.
            let s_abs = x.scale.abs();
            let (lo, hi) = (s_abs.min_element(), s_abs.max_element());
            if hi - lo > 1e-6 * hi {
                cx.err(
                    &format!("{p}.transform.scale"),
                    "must be uniform on a sphere (a sphere stays a sphere; send a mesh for an ellipsoid)",
                );
                return None;
            }
            let radius = s.radius * hi;
            Some(Shape::Sphere {
                center: x.point(center),
                radius,
                material: material?,
            })
        }
        ObjectDoc::Quad(q) => {
            let c = cx.vec3(&format!("{p}.corner"), q.corner);
            let u = cx.vec3(&format!("{p}.edge_u"), q.edge_u);
            let v = cx.vec3(&format!("{p}.edge_v"), q.edge_v);
            if !(c.is_finite() && u.is_finite() && v.is_finite()) {
                return None;
            }
            // Zero area: |u × v| ≤ DEGENERATE_REL·|u||v| (zero or parallel edges). Unlike a
            // mesh triangle this is an error: a quad is written by hand, one at a time.
            if u.length_squared() == 0.0 {
                cx.err(&format!("{p}.edge_u"), "quad has zero area: edge_u is zero");
                return None;
            }
            let has_area = u.cross(v).length() > DEGENERATE_REL * u.length() * v.length();
            if !has_area {
                cx.err(
                    &format!("{p}.edge_v"),
                    "quad has zero area: edge_v is zero or parallel to edge_u",
                );
                return None;
            }
            let x = x?;
            let mut tris = Vec::with_capacity(2);
            for (t, uv) in quad_corners(c, u, v).into_iter().zip(QUAD_UVS) {
                push_triangle(cx, &mut tris, &p, &x, t.map(|q| x.point(q)), None, Some(uv));
            }
            Some(Shape::Triangles {
                triangles: tris,
                material: material?,
            })
        }
        ObjectDoc::Box(b) => {
            let lo = cx.vec3(&format!("{p}.min"), b.min);
            let hi = cx.vec3(&format!("{p}.max"), b.max);
            if !(lo.is_finite() && hi.is_finite()) {
                return None;
            }
            if let Some(axis) = (0..3).find(|&i| lo[i] >= hi[i]) {
                cx.err(
                    &format!("{p}.max"),
                    format!(
                        "must exceed min on every axis; axis {} has min {} and max {}",
                        ["x", "y", "z"][axis],
                        lo[axis],
                        hi[axis]
                    ),
                );
                return None;
            }
            let x = x?;
            let d = hi - lo;
            let (dx, dy, dz) = (Vec3::X * d.x, Vec3::Y * d.y, Vec3::Z * d.z);
            // Six faces as quads whose u × v points outwards.
            let faces = [
                (lo, dz, dy),                          // −x
                (Vec3::new(hi.x, lo.y, lo.z), dy, dz), // +x
                (lo, dx, dz),                          // −y
                (Vec3::new(lo.x, hi.y, lo.z), dz, dx), // +y
                (lo, dy, dx),                          // −z
                (Vec3::new(lo.x, lo.y, hi.z), dx, dy), // +z
            ];
            let mut tris = Vec::with_capacity(12);
            for (c, u, v) in faces {
                for (t, uv) in quad_corners(c, u, v).into_iter().zip(QUAD_UVS) {
                    push_triangle(cx, &mut tris, &p, &x, t.map(|q| x.point(q)), None, Some(uv));
                }
            }
            Some(Shape::Triangles {
                triangles: tris,
                material: material?,
            })
        }
        ObjectDoc::Mesh(m) => {
            let idx_path = format!("{p}.indices");
            let before = cx.errors.len() + cx.unlisted_errors;
            for (i, q) in m.positions.iter().enumerate() {
                cx.vec3(&format!("{p}.positions[{i}]"), *q);
            }
            if let Some(ns) = &m.normals {
                if ns.len() != m.positions.len() {
                    cx.err(
                        &format!("{p}.normals"),
                        format!(
                            "has {} entries; expected one per position ({})",
                            ns.len(),
                            m.positions.len()
                        ),
                    );
                } else {
                    for (i, n) in ns.iter().enumerate() {
                        let np = format!("{p}.normals[{i}]");
                        if cx.vec3(&np, *n).length_squared() == 0.0 {
                            cx.err(&np, "must be non-zero");
                        }
                    }
                }
            }
            if let Some(uvs) = &m.uvs {
                if uvs.len() != m.positions.len() {
                    cx.err(
                        &format!("{p}.uvs"),
                        format!(
                            "has {} entries; expected one per position ({})",
                            uvs.len(),
                            m.positions.len()
                        ),
                    );
                } else {
                    for (i, uv) in uvs.iter().enumerate() {
                        for (j, c) in uv.iter().enumerate() {
                            cx.finite(&format!("{p}.uvs[{i}][{j}]"), *c);
                        }
                    }
                }
            }
            let count = m.positions.len() as u64;
            for (i, t) in m.indices.iter().enumerate() {
                for (j, &ix) in t.iter().enumerate() {
                    if ix >= count {
                        cx.err(
                            &format!("{idx_path}[{i}][{j}]"),
                            format!("index {ix} is out of range: the mesh has {count} positions"),
                        );
                    }
                }
            }
            if cx.errors.len() + cx.unlisted_errors != before {
                return None;
            }
            let x = x?;
            let world: Vec<Vec3> = m
                .positions
                .iter()
                .map(|q| x.point(Vec3::from(*q)))
                .collect();
            let normals: Option<Vec<Vec3>> = m
                .normals
                .as_ref()
                .map(|ns| ns.iter().map(|n| x.normal(Vec3::from(*n))).collect());
            let mut tris = Vec::with_capacity(m.indices.len());
            for (i, t) in m.indices.iter().enumerate() {
                // In range (checked above), so the casts cannot truncate.
                let ix = t.map(|v| v as usize);
                push_triangle(
                    cx,
                    &mut tris,
                    &format!("{idx_path}[{i}]"),
                    &x,
                    ix.map(|v| world[v]),
                    normals.as_ref().map(|ns| ix.map(|v| ns[v])),
                    m.uvs.as_ref().map(|uvs| ix.map(|v| Vec2::from(uvs[v]))),
                );
            }
            Some(Shape::Triangles {
                triangles: tris,
                material: material?,
            })
        }
        ObjectDoc::Obj(ob) => {
            let pp = format!("{p}.path");
            let dir = match origin {
                SceneOrigin::Request => {
                    cx.err(
                        &pp,
                        "obj files are accepted by the command line only; send a mesh",
                    );
                    return None;
                }
                SceneOrigin::File { dir } => dir,
            };
            let file = match obj::resolve(dir, &ob.path) {
                Ok(f) => f,
                Err(msg) => {
                    cx.err(&pp, msg);
                    return None;
                }
            };
            let mesh = match obj::load(&file) {
                Ok(m) => m,
                Err(msg) => {
                    cx.err(&pp, format!("\"{}\": {msg}", ob.path));
                    return None;
                }
            };
            let x = x?;
            let world: Vec<Vec3> = mesh
                .positions
                .iter()
                .map(|q| x.point(Vec3::from(*q)))
                .collect();
            let normals: Option<Vec<Vec3>> = mesh
                .normals
                .as_ref()
                .map(|ns| ns.iter().map(|n| x.normal(Vec3::from(*n))).collect());
            let mut tris = Vec::with_capacity(mesh.indices.len());
            for t in &mesh.indices {
                let ix = t.map(|v| v as usize);
                // A zero normal in the file (rare) would poison shading: drop all normals
                // of that triangle rather than the triangle.
                let n = normals
                    .as_ref()
                    .map(|ns| ix.map(|v| ns[v]))
                    .filter(|n| n.iter().all(|v| v.length_squared() > 0.0));
                push_triangle(cx, &mut tris, &pp, &x, ix.map(|v| world[v]), n, None);
            }
            Some(Shape::Triangles {
                triangles: tris,
                material: material?,
            })
        }
    }
}

fn check_light(cx: &mut Ctx, p: &str, l: &LightDoc) -> Light {
    match l {
        LightDoc::Point(pl) => Light::Point {
            position: world_position(cx, &format!("{p}.position"), pl.position),
            intensity: cx.emission3(&format!("{p}.intensity"), pl.intensity),
        },
        LightDoc::Directional(d) => {
            let dp = format!("{p}.direction");
            let dir = cx.vec3(&dp, d.direction);
            // Normalised here so the tracer can rely on a unit vector.
            let direction = dir.normalize_or_zero();
            if dir.is_finite() && direction == Vec3::ZERO {
                cx.err(&dp, "must be non-zero");
            }
            Light::Directional {
                direction,
                irradiance: cx.emission3(&format!("{p}.irradiance"), d.irradiance),
            }
        }
        LightDoc::Environment(e) => Light::Environment {
            radiance: cx.emission3(&format!("{p}.radiance"), e.radiance),
        },
        LightDoc::Spot(s) => {
            let dp = format!("{p}.direction");
            let dir = cx.vec3(&dp, s.direction);
            let direction = dir.normalize_or_zero();
            if dir.is_finite() && direction == Vec3::ZERO {
                cx.err(&dp, "must be non-zero");
            }
            let (outer, inner) = (s.outer_angle, s.inner_angle);
            let op = format!("{p}.outer_angle");
            if cx.finite(&op, outer) && !(0.0..=180.0).contains(&outer) {
                cx.err(&op, format!("must be in [0, 180] degrees, got {outer}"));
            }
            let ip = format!("{p}.inner_angle");
            if cx.finite(&ip, inner) && !(0.0..=outer.max(0.0)).contains(&inner) {
                cx.err(
                    &ip,
                    format!("must be in [0, outer_angle = {outer}] degrees, got {inner}"),
                );
            }
            Light::Spot {
                position: world_position(cx, &format!("{p}.position"), s.position),
                direction,
                intensity: cx.emission3(&format!("{p}.intensity"), s.intensity),
                cos_inner: inner.to_radians().cos(),
                cos_outer: outer.to_radians().cos(),
                falloff: match s.falloff {
                    FalloffDoc::Smoothstep => SpotFalloff::Smoothstep,
                    FalloffDoc::SquaredLinear => SpotFalloff::SquaredLinear,
                },
            }
        }
    }
}

fn check_render(cx: &mut Ctx, r: &RenderDoc) -> RenderSettings {
    // The ≥ 1 and limit checks on samples_per_pixel and max_bounces happen with the other
    // limits in `build`; a value that passed them fits a u32 (the limits are u32).
    let _ = cx;
    RenderSettings {
        mode: r.mode,
        samples_per_pixel: u32::try_from(r.samples_per_pixel).unwrap_or(u32::MAX),
        max_bounces: u32::try_from(r.max_bounces).unwrap_or(u32::MAX),
        seed: r.seed,
    }
}

fn check_progressive(cx: &mut Ctx, p: &ProgressiveDoc) -> ProgressiveSettings {
    if cx.finite("progressive.t0", p.t0) && p.t0 < 0.0 {
        cx.err("progressive.t0", format!("must be ≥ 0, got {}", p.t0));
    }
    if let Some(t1) = p.t1 {
        if cx.finite("progressive.t1", t1) && t1 < 0.0 {
            cx.err("progressive.t1", format!("must be null or ≥ 0, got {t1}"));
        }
    }
    cx.fraction("progressive.initial_rate", p.initial_rate);
    cx.fraction("progressive.homogeneity", p.homogeneity);
    cx.positive("progressive.epsilon", p.epsilon);
    let max_iterations = match u32::try_from(p.max_iterations) {
        Ok(0) => {
            cx.err("progressive.max_iterations", "must be ≥ 1, got 0");
            1
        }
        Ok(n) => n,
        Err(_) => {
            cx.err(
                "progressive.max_iterations",
                format!("must be ≤ {}, got {}", u32::MAX, p.max_iterations),
            );
            u32::MAX
        }
    };
    ProgressiveSettings {
        t0: p.t0,
        t1: p.t1,
        initial_rate: p.initial_rate,
        homogeneity: p.homogeneity,
        epsilon: p.epsilon,
        max_iterations,
        force_loop: p.force_loop,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn limits() -> Limits {
        Limits {
            max_width: 4096,
            max_height: 4096,
            max_pixels: 4096 * 4096,
            max_sample_budget: 1 << 32,
            max_objects: 1000,
            max_triangles: 100_000,
            max_samples_per_pixel: 4096,
            max_bounces: 64,
        }
    }

    /// A small valid document; tests mutate it.
    fn base() -> Value {
        json!({
            "version": 1,
            "image": { "width": 8, "height": 6 },
            "camera": { "position": [0, 1, 5], "look_at": [0, 1, 0], "up": [0, 1, 0], "fov_y": 40 },
            "materials": { "m": { "type": "diffuse", "albedo": [0.5, 0.5, 0.5] },
                           "lamp": { "type": "emissive", "radiance": [4, 4, 4] } },
            "objects": [ { "type": "sphere", "center": [0, 1, 0], "radius": 1, "material": "m" } ]
        })
    }

    fn parse(v: &Value) -> Result<Scene, SceneError> {
        parse_scene(&v.to_string(), &SceneOrigin::Request, &limits())
    }

    fn with(f: impl FnOnce(&mut Value)) -> Value {
        let mut v = base();
        f(&mut v);
        v
    }

    /// The kind and the headline path of a refused document.
    fn refused(json: &str) -> (SceneErrorKind, String, String) {
        match parse_scene(json, &SceneOrigin::Request, &limits()) {
            Ok(_) => panic!("accepted: {json}"),
            Err(e) => (
                e.kind,
                e.problems[0].path.clone(),
                e.problems[0].message.clone(),
            ),
        }
    }

    const SCENE: SceneErrorKind = SceneErrorKind::InvalidScene;

    #[test]
    fn world_coordinates_beyond_the_range_are_refused_where_they_come_from() {
        let cases: Vec<(Value, &str, &str)> = vec![
            // A finite f32 whose square overflows: the sphere itself.
            (
                with(|v| v["objects"][0]["radius"] = json!(1e30)),
                "objects[0]",
                "x axis",
            ),
            // A huge translate on a box: caught after the transform, on the axis it moves.
            (
                with(|v| {
                    v["objects"][0] = json!({"type":"box","min":[-1,-1,-1],"max":[1,1,1],
                        "material":"m","transform":{"translate":[0, 3.4e38, 0]}});
                }),
                "objects[0]",
                "y axis",
            ),
            // A scale that blows a small mesh up past the range.
            (
                with(|v| {
                    v["objects"][0] = json!({"type":"mesh","positions":[[0,0,0],[1,0,0],[0,0,1]],
                        "indices":[[0,1,2]],"material":"m","transform":{"scale":1e10}});
                }),
                "objects[0]",
                "x axis",
            ),
            (
                with(|v| v["camera"]["position"] = json!([0, 1, 2e9])),
                "camera.position[2]",
                "±1e9",
            ),
            (
                with(|v| {
                    v["lights"] =
                        json!([{"type":"point","position":[-5e12,0,0],"intensity":[1,1,1]}]);
                }),
                "lights[0].position[0]",
                "-5e12",
            ),
        ];
        for (doc, path, says) in cases {
            let (kind, p, msg) = refused(&doc.to_string());
            assert_eq!((kind, p.as_str()), (SCENE, path), "{msg}");
            assert!(msg.contains(says) && msg.contains("1e9"), "{path}: {msg}");
        }
        // A far-out corner swallows a quad's edges in f32 (its triangles would look
        // degenerate): still refused as out of range, once, not warned about per triangle.
        let quad = with(|v| {
            v["objects"][0] = json!({"type":"quad","corner":[1e30,0,0],"edge_u":[1,0,0],
                "edge_v":[0,0,1],"material":"m"});
        });
        match parse(&quad) {
            Err(e) => {
                assert_eq!(e.problems.len(), 1, "{e}");
                assert_eq!(e.problems[0].path, "objects[0]");
                assert!(e.problems[0].message.contains("1e30"), "{e}");
            }
            Ok(s) => panic!("accepted, warnings {:?}", s.warnings),
        }
        // At the edge of the range: accepted.
        let edge = with(|v| {
            v["objects"][0]["center"] = json!([0, 0, -5e8]);
            v["objects"][0]["radius"] = json!(5e8);
            v["camera"]["position"] = json!([0, 1, 1e9]);
        });
        parse(&edge).unwrap();
    }

    #[test]
    fn minimal_document_parses_with_defaults() {
        let s = parse(&base()).unwrap();
        assert_eq!((s.width, s.height), (8, 6));
        assert_eq!(s.name, "untitled");
        assert_eq!(s.display, Display::default());
        assert_eq!(s.progressive, ProgressiveSettings::default());
        assert_eq!(s.render.mode, super::super::RenderMode::Progressive);
        assert_eq!(
            (
                s.render.samples_per_pixel,
                s.render.max_bounces,
                s.render.seed
            ),
            (16, 5, 1)
        );
        // Materials sorted by name: "lamp" < "m".
        assert_eq!(s.material_names, ["lamp", "m"]);
        assert_eq!(s.shapes.len(), 1);
        assert_eq!(s.shapes[0].material(), 1);
        assert!(s.warnings.is_empty());
    }

    #[test]
    fn spec_example_validates() {
        // Copied verbatim from shared/spec/scene-format.md.
        let spec = r#"{
  "version": 1,
  "name": "cornell-box",
  "image":   { "width": 512, "height": 512 },
  "camera":  { "position": [278, 273, -800], "look_at": [278, 273, 0], "up": [0, 1, 0],
               "fov_y": 39.3 },
  "display": { "peak_luminance": 100.0, "black_luminance": 0.5, "exposure": 1.0,
               "pixels_per_degree": 28.0 },
  "materials": {
    "white": { "type": "diffuse",    "albedo": [0.73, 0.73, 0.73] },
    "red":   { "type": "diffuse",    "albedo": [0.65, 0.05, 0.05] },
    "floor": { "type": "diffuse",    "texture": { "type": "checker", "scale": 50.0,
                                                  "a": [0.8, 0.8, 0.8], "b": [0.1, 0.1, 0.1] } },
    "rough": { "type": "diffuse",    "texture": { "type": "noise", "scale": 2.0,
                                                  "a": [0.2, 0.2, 0.2], "b": [0.8, 0.8, 0.8] } },
    "metal": { "type": "glossy",     "albedo": [0.9, 0.9, 0.9], "roughness": 0.2 },
    "mirror":{ "type": "mirror",     "reflectance": [0.95, 0.95, 0.95] },
    "glass": { "type": "dielectric", "ior": 1.5 },
    "lamp":  { "type": "emissive",   "radiance": [17.0, 12.0, 4.0] }
  },
  "objects": [
    { "type": "sphere", "center": [185, 82, 169], "radius": 82, "material": "glass" },
    { "type": "quad",   "corner": [213, 548.7, 227], "edge_u": [130, 0, 0],
                        "edge_v": [0, 0, 105], "material": "lamp" },
    { "type": "box",    "min": [0, 0, 0], "max": [165, 165, 165], "material": "white",
                        "transform": { "translate": [130, 0, 65], "rotate_y": -18 } },
    { "type": "mesh",   "positions": [[0,0,0],[556,0,0],[556,0,559]],
                        "indices": [[0,1,2]], "material": "white" }
  ],
  "lights": [
    { "type": "point",       "position": [278, 500, 279], "intensity": [1e4, 1e4, 1e4] },
    { "type": "directional", "direction": [0, -1, 0.2],   "irradiance": [2, 2, 2] },
    { "type": "environment", "radiance": [0.1, 0.1, 0.12] }
  ],
  "render": { "mode": "progressive", "samples_per_pixel": 64, "max_bounces": 5, "seed": 1 },
  "progressive": { "t0": 1.0, "t1": null, "initial_rate": 0.01,
                   "homogeneity": 0.8, "epsilon": 1.0, "max_iterations": 64 }
}"#;
        let s = parse_scene(spec, &SceneOrigin::Request, &Limits::command_line()).unwrap();
        assert_eq!(s.name, "cornell-box");
        assert_eq!(
            s.material_names,
            ["floor", "glass", "lamp", "metal", "mirror", "red", "rough", "white"]
        );
        assert_eq!(s.shapes.len(), 4);
        assert_eq!(s.shapes[0].material(), 1); // glass
        assert_eq!(s.triangle_count(), 2 + 12 + 1);
        assert!(matches!(
            s.materials[0],
            Material::Diffuse {
                albedo: Texture::Checker { .. }
            }
        ));
        match s.lights[1] {
            Light::Directional { direction, .. } => {
                assert!((direction.length() - 1.0).abs() < 1e-6);
                assert!((direction - Vec3::new(0.0, -1.0, 0.2).normalize()).length() < 1e-6);
            }
            ref l => panic!("{l:?}"),
        }
        assert_eq!(s.render.samples_per_pixel, 64);
    }

    #[test]
    fn shape_errors_name_their_path() {
        let cases: Vec<(Value, &str)> = vec![
            (with(|v| v["image"]["width"] = json!("wide")), "image.width"),
            (with(|v| v["colour"] = json!(1)), "colour"),
            (with(|v| v["image"]["depth"] = json!(1)), "image.depth"),
            (
                with(|v| v["objects"][0]["radiu"] = json!(1)),
                "objects[0].radiu",
            ),
            (
                with(|v| v["objects"][0]["type"] = json!("cube")),
                "objects[0].type",
            ),
            (
                with(|v| {
                    v["objects"][0]
                        .as_object_mut()
                        .unwrap()
                        .remove("type")
                        .map(drop)
                        .unwrap_or(())
                }),
                "objects[0].type",
            ),
            (
                with(|v| v["objects"][0]["center"] = json!([1, 2])),
                "objects[0].center",
            ),
            (
                with(|v| v["objects"][0]["center"] = json!([1, "x", 2])),
                "objects[0].center[1]",
            ),
            (
                with(
                    |v| v["materials"]["m"] = json!({"type": "diffuse", "texture": {"type": "noise", "scale": 1, "a": [0,0,0], "b": [1,1,1], "sclae": 2}}),
                ),
                "materials.m.texture.sclae",
            ),
            (
                with(
                    |v| v["materials"]["m"] = json!({"type": "diffuse", "texture": {"type": "noise", "scale": "big", "a": [0,0,0], "b": [1,1,1]}}),
                ),
                "materials.m.texture.scale",
            ),
            (
                with(|v| v["objects"][0]["transform"] = json!({"scale": "x"})),
                "objects[0].transform.scale",
            ),
            (
                with(|v| v["lights"] = json!([{"type": "point", "position": [0,0,0]}])),
                "lights[0]",
            ),
            (with(|v| v["render"]["mode"] = json!("fast")), "render.mode"),
            (
                with(
                    |v| v["objects"][0] = json!({"type":"mesh","positions":[[0,0,0]],"indices":[[0,0,-1]],"material":"m"}),
                ),
                "objects[0].indices[0][2]",
            ),
        ];
        for (doc, want) in cases {
            let (kind, path, msg) = refused(&doc.to_string());
            assert_eq!((kind, path.as_str()), (SCENE, want), "{doc} → {msg}");
        }
        // A missing required field is reported at its parent (the root here).
        let (k, p, m) =
            refused(&with(|v| drop(v.as_object_mut().unwrap().remove("camera"))).to_string());
        assert_eq!((k, p.as_str()), (SCENE, ""));
        assert!(m.contains("camera"), "{m}");
    }

    #[test]
    fn rule_errors_name_their_path() {
        let cases: Vec<(Value, &str, &str)> = vec![
            (
                with(
                    |v| v["materials"]["m"] = json!({"type": "diffuse", "texture": {"type": "image", "data": "textures/wood.png"}}),
                ),
                "materials.m.texture.data",
                "data: URI",
            ),
            (
                with(
                    |v| v["materials"]["m"] = json!({"type": "diffuse", "texture": {"type": "image", "data": "data:image/png;base64,AAAA", "factor": [1, 2, 1]}}),
                ),
                "materials.m.texture.factor[1]",
                "[0, 1]",
            ),
            (
                with(|v| {
                    v["materials"]["m"] =
                        json!({"type": "coated_diffuse", "reflectance": [0.5, 0.5, 0.5], "ior": 0})
                }),
                "materials.m.ior",
                "must be > 0",
            ),
            (
                with(|v| v["materials"]["m"] = json!({"type": "coated_diffuse"})),
                "materials.m.reflectance",
                "missing",
            ),
            (
                with(|v| {
                    v["objects"][0] = json!({"type": "mesh", "positions": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                        "indices": [[0, 1, 2]], "uvs": [[0, 0], [1, 0]], "material": "m"})
                }),
                "objects[0].uvs",
                "one per position",
            ),
            (
                with(|v| {
                    v["lights"] = json!([{"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0],
                        "intensity": [1, 1, 1], "outer_angle": 20, "inner_angle": 30}])
                }),
                "lights[0].inner_angle",
                "outer_angle = 20",
            ),
            (
                with(|v| {
                    v["lights"] = json!([{"type": "spot", "position": [0, 1, 0], "direction": [0, 0, 0],
                        "intensity": [1, 1, 1], "outer_angle": 200}])
                }),
                "lights[0].direction",
                "non-zero",
            ),
            (
                with(|v| v["version"] = json!(2)),
                "version",
                "must be 1, got 2",
            ),
            (
                with(|v| v["objects"][0]["radius"] = json!(-2)),
                "objects[0].radius",
                "must be > 0, got -2",
            ),
            (
                with(|v| v["objects"][0]["radius"] = json!(0)),
                "objects[0].radius",
                "must be > 0, got 0",
            ),
            (
                with(|v| v["objects"][0]["radius"] = json!(1e39)),
                "objects[0].radius",
                "finite",
            ),
            (
                with(|v| v["objects"][0]["material"] = json!("gold")),
                "objects[0].material",
                "lamp, m",
            ),
            (
                with(|v| v["camera"]["up"] = json!([0, 0, -3])),
                "camera.up",
                "parallel",
            ),
            (
                with(|v| v["camera"]["up"] = json!([0, 0, 0])),
                "camera.up",
                "non-zero",
            ),
            (
                with(|v| v["camera"]["look_at"] = json!([0, 1, 5])),
                "camera.look_at",
                "differ",
            ),
            (
                with(|v| v["camera"]["fov_y"] = json!(180)),
                "camera.fov_y",
                "(0, 180)",
            ),
            (
                with(|v| v["display"] = json!({"peak_luminance": 0.2})),
                "display.peak_luminance",
                "greater",
            ),
            (
                with(|v| v["display"] = json!({"black_luminance": -1})),
                "display.black_luminance",
                "≥ 0",
            ),
            (
                with(|v| v["display"] = json!({"exposure": 0})),
                "display.exposure",
                "> 0",
            ),
            (
                with(|v| v["display"] = json!({"pixels_per_degree": -1})),
                "display.pixels_per_degree",
                "> 0",
            ),
            (
                with(|v| v["materials"]["m"]["albedo"] = json!([1.2, 0, 0])),
                "materials.m.albedo[0]",
                "[0, 1]",
            ),
            (
                with(|v| {
                    v["materials"]["m"] =
                        json!({"type": "glossy", "albedo": [1,1,1], "roughness": 1.5})
                }),
                "materials.m.roughness",
                "[0, 1]",
            ),
            (
                with(|v| v["materials"]["m"] = json!({"type": "dielectric", "ior": 0})),
                "materials.m.ior",
                "> 0",
            ),
            (
                with(|v| v["materials"]["m"] = json!({"type": "diffuse"})),
                "materials.m.albedo",
                "texture",
            ),
            (
                with(
                    |v| v["materials"]["m"] = json!({"type": "diffuse", "texture": {"type": "checker", "scale": 0, "a": [0,0,0], "b": [1,1,1]}}),
                ),
                "materials.m.texture.scale",
                "> 0",
            ),
            (
                with(
                    |v| v["materials"]["m"] = json!({"type": "diffuse", "texture": {"type": "checker", "scale": 1, "a": [0,0,0], "b": [1,2,1]}}),
                ),
                "materials.m.texture.b[1]",
                "[0, 1]",
            ),
            (
                with(|v| v["materials"]["lamp"]["radiance"] = json!([1, -1, 1])),
                "materials.lamp.radiance[1]",
                "≥ 0",
            ),
            (
                with(|v| v["image"]["width"] = json!(0)),
                "image.width",
                "≥ 1",
            ),
            (
                with(
                    |v| v["objects"][0] = json!({"type":"quad","corner":[0,0,0],"edge_u":[1,0,0],"edge_v":[2,0,0],"material":"m"}),
                ),
                "objects[0].edge_v",
                "zero area",
            ),
            (
                with(
                    |v| v["objects"][0] = json!({"type":"quad","corner":[0,0,0],"edge_u":[0,0,0],"edge_v":[2,0,0],"material":"m"}),
                ),
                "objects[0].edge_u",
                "zero area",
            ),
            (
                with(|v| {
                    v["objects"][0] =
                        json!({"type":"box","min":[0,0,0],"max":[1,0,1],"material":"m"})
                }),
                "objects[0].max",
                "axis y",
            ),
            (
                with(
                    |v| v["objects"][0] = json!({"type":"mesh","positions":[[0,0,0],[1,0,0],[0,1,0]],"indices":[[0,1,3]],"material":"m"}),
                ),
                "objects[0].indices[0][2]",
                "out of range",
            ),
            (
                with(
                    |v| v["objects"][0] = json!({"type":"mesh","positions":[[0,0,0],[1,0,0],[0,1,0]],"normals":[[0,0,1]],"indices":[[0,1,2]],"material":"m"}),
                ),
                "objects[0].normals",
                "one per position",
            ),
            (
                with(|v| v["objects"][0]["transform"] = json!({"scale": [1, 2, 1]})),
                "objects[0].transform.scale",
                "uniform",
            ),
            (
                with(|v| v["objects"][0]["transform"] = json!({"scale": 0})),
                "objects[0].transform.scale",
                "non-zero",
            ),
            (
                with(|v| v["objects"][0]["transform"] = json!({"scale": [1, 0, 1]})),
                "objects[0].transform.scale[1]",
                "non-zero",
            ),
            (
                with(|v| {
                    v["lights"] = json!([{"type": "directional", "direction": [0,0,0], "irradiance": [1,1,1]}])
                }),
                "lights[0].direction",
                "non-zero",
            ),
            (
                with(|v| v["lights"] = json!([{"type": "environment", "radiance": [0,-0.1,0]}])),
                "lights[0].radiance[1]",
                "≥ 0",
            ),
            // A lamp near f32::MAX made NaN in the progressive picture (scene_fuzz seed 809).
            (
                with(|v| v["materials"]["lamp"]["radiance"] = json!([3.4e38, 1, 1])),
                "materials.lamp.radiance[0]",
                "at most 1e12, got 3.4e38",
            ),
            (
                with(|v| {
                    v["lights"] =
                        json!([{"type": "point", "position": [0,1,0], "intensity": [1, 2e12, 1]}])
                }),
                "lights[0].intensity[1]",
                "at most 1e12",
            ),
            (
                with(
                    |v| v["lights"] = json!([{"type": "directional", "direction": [0,-1,0], "irradiance": [1, 1, 1e13]}]),
                ),
                "lights[0].irradiance[2]",
                "at most 1e12",
            ),
            (
                with(|v| v["lights"] = json!([{"type": "environment", "radiance": [1e30, 0, 0]}])),
                "lights[0].radiance[0]",
                "at most 1e12",
            ),
            (
                with(|v| v["render"] = json!({"samples_per_pixel": 0})),
                "render.samples_per_pixel",
                "≥ 1",
            ),
            (
                with(|v| v["progressive"] = json!({"t0": -1})),
                "progressive.t0",
                "≥ 0",
            ),
            (
                with(|v| v["progressive"] = json!({"t1": -1})),
                "progressive.t1",
                "≥ 0",
            ),
            (
                with(|v| v["progressive"] = json!({"initial_rate": 0})),
                "progressive.initial_rate",
                "(0, 1]",
            ),
            (
                with(|v| v["progressive"] = json!({"homogeneity": 1.5})),
                "progressive.homogeneity",
                "(0, 1]",
            ),
            (
                with(|v| v["progressive"] = json!({"epsilon": 0})),
                "progressive.epsilon",
                "> 0",
            ),
            (
                with(|v| v["progressive"] = json!({"max_iterations": 0})),
                "progressive.max_iterations",
                "≥ 1",
            ),
            (
                with(|v| v["objects"][0] = json!({"type":"obj","path":"a.obj","material":"m"})),
                "objects[0].path",
                "command line only",
            ),
        ];
        for (doc, want, needle) in cases {
            let (kind, path, msg) = refused(&doc.to_string());
            assert_eq!((kind, path.as_str()), (SCENE, want), "{doc} → {msg}");
            assert!(msg.contains(needle), "{want}: {msg:?} lacks {needle:?}");
        }
    }

    #[test]
    fn all_problems_are_collected_in_document_order() {
        let doc = with(|v| {
            v["version"] = json!(3);
            v["objects"][0]["radius"] = json!(-1);
            v["objects"][0]["material"] = json!("nope");
        });
        let e = parse(&doc).unwrap_err();
        let paths: Vec<&str> = e.problems.iter().map(|p| p.path.as_str()).collect();
        assert_eq!(
            paths,
            ["version", "objects[0].material", "objects[0].radius"]
        );
        assert_eq!(e.to_string(), "version: must be 1, got 3");
    }

    #[test]
    fn limits_give_too_large_unless_something_else_is_wrong() {
        let (k, p, m) = refused(&with(|v| v["image"]["width"] = json!(20000)).to_string());
        assert_eq!((k, p.as_str()), (SceneErrorKind::TooLarge, "image.width"));
        assert_eq!(m, "20000 exceeds this server's limit of 4096");
        // At the limit is fine: 4096² pixels × 16 spp = 2^28 ≤ 2^32 samples.
        assert!(parse(&with(
            |v| v["image"] = json!({"width": 4096, "height": 4096})
        ))
        .is_ok());
        let (k, p, m) = refused(
            &with(|v| {
                v["image"] = json!({"width": 4096, "height": 4096});
                v["render"] = json!({"samples_per_pixel": 1024});
            })
            .to_string(),
        );
        assert_eq!(
            (k, p.as_str()),
            (SceneErrorKind::TooLarge, "render.samples_per_pixel"),
            "{m}"
        );
        // A bounce limit above the cap is capped with a warning naming both, not refused.
        let deep = parse(&with(|v| v["render"] = json!({"max_bounces": 1000}))).unwrap();
        assert_eq!(deep.render.max_bounces, 64);
        let w = deep
            .warnings
            .iter()
            .find(|w| w.path == "render.max_bounces")
            .expect("a warning on render.max_bounces");
        assert!(
            w.message
                .starts_with("1000 is above this server's cap of 64"),
            "{}",
            w.message
        );
        let (k, p, _) = refused(&with(|v| v["image"]["width"] = json!(1u64 << 40)).to_string());
        assert_eq!((k, p.as_str()), (SceneErrorKind::TooLarge, "image.width"));
        // Too large *and* wrong: the document must be fixed first.
        let (k, p, _) = refused(
            &with(|v| {
                v["image"]["width"] = json!(20000);
                v["version"] = json!(2);
            })
            .to_string(),
        );
        assert_eq!((k, p.as_str()), (SCENE, "version"));
    }

    #[test]
    fn limits_on_objects_and_triangles() {
        let mut l = limits();
        l.max_objects = 1;
        let two = with(|v| {
            let o = v["objects"][0].clone();
            v["objects"].as_array_mut().unwrap().push(o);
        });
        let e = parse_scene(&two.to_string(), &SceneOrigin::Request, &l).unwrap_err();
        assert_eq!(
            (e.kind, e.problems[0].path.as_str()),
            (SceneErrorKind::TooLarge, "objects")
        );
        let mut l = limits();
        l.max_triangles = 11;
        let b = with(|v| {
            v["objects"][0] = json!({"type":"box","min":[0,0,0],"max":[1,1,1],"material":"m"})
        });
        let e = parse_scene(&b.to_string(), &SceneOrigin::Request, &l).unwrap_err();
        assert_eq!(e.kind, SceneErrorKind::TooLarge);
        assert!(
            e.problems[0].message.contains("12 triangles"),
            "{}",
            e.problems[0].message
        );
    }

    #[test]
    fn syntax_errors_are_invalid_json_with_position() {
        let (k, p, m) = refused("");
        assert_eq!((k, p.as_str()), (SceneErrorKind::InvalidJson, ""));
        assert!(m.contains("empty"));
        let (k, _, m) = refused("hello");
        assert_eq!(k, SceneErrorKind::InvalidJson);
        assert!(m.contains("line 1 column"), "{m}");
        let (k, p, m) = refused(r#"{"version": 1, "image": {"width": 3"#);
        assert_eq!(
            (k, p.as_str()),
            (SceneErrorKind::InvalidJson, "image.width"),
            "{m}"
        );
        let (k, p, m) = refused(r#"{"version": 1, "objects": [{"radius": NaN}]}"#);
        assert_eq!(
            (k, p.as_str()),
            (SceneErrorKind::InvalidJson, "objects[0].radius")
        );
        assert!(m.contains("NaN and Infinity"), "{m}");
        let (k, p, m) = refused(r#"{"version": 1, "objects": [{"radius": -Infinity}]}"#);
        assert_eq!(
            (k, p.as_str()),
            (SceneErrorKind::InvalidJson, "objects[0].radius"),
            "{m}"
        );
        // Valid grammar, no finite value: a scene problem with its path.
        let (k, p, m) = refused("{\"version\": 1,\n \"objects\": [{}, {\"radius\": 1e999}]}");
        assert_eq!((k, p.as_str()), (SCENE, "objects[1].radius"));
        assert!(m.contains("line 2"), "{m}");
        // 10 000 nested arrays: serde_json's recursion limit (128) stops it cleanly.
        let deep = "[".repeat(10_000) + &"]".repeat(10_000);
        let (k, p, m) = refused(&deep);
        assert_eq!((k, p.as_str()), (SceneErrorKind::InvalidJson, ""));
        assert!(m.contains("128"), "{m}");
        let deep_obj = "{\"a\":".repeat(10_000);
        assert_eq!(refused(&deep_obj).0, SceneErrorKind::InvalidJson);
    }

    fn tris(s: &Scene, k: usize) -> &[Triangle] {
        match &s.shapes[k] {
            Shape::Triangles { triangles, .. } => triangles,
            Shape::Sphere { .. } => panic!("sphere"),
        }
    }

    fn normal(t: &Triangle) -> Vec3 {
        (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]).normalize()
    }

    #[test]
    fn degenerate_mesh_triangles_are_dropped_with_a_warning() {
        let doc = with(|v| {
            v["objects"][0] = json!({"type": "mesh",
                "positions": [[0,0,0],[1,0,0],[0,1,0],[2,0,0]],
                "indices": [[0,1,2],[0,1,3],[2,2,2]], "material": "m"});
        });
        let s = parse(&doc).unwrap();
        assert_eq!(tris(&s, 0).len(), 1);
        let paths: Vec<&str> = s.warnings.iter().map(|w| w.path.as_str()).collect();
        assert_eq!(paths, ["objects[0].indices[1]", "objects[0].indices[2]"]);
    }

    #[test]
    fn quad_winding_keeps_edge_u_cross_edge_v() {
        // A ceiling light facing down: u × v = x × (−z)... use u = z, v = x: z × x = +y; so
        // for a downward light u = x, v = z: x × z = −y.
        let doc = with(|v| {
            v["objects"][0] = json!({"type":"quad","corner":[0,2,0],"edge_u":[1,0,0],"edge_v":[0,0,1],"material":"lamp"});
        });
        let s = parse(&doc).unwrap();
        let t = tris(&s, 0);
        assert_eq!(t.len(), 2);
        for tri in t {
            assert!((normal(tri) - Vec3::NEG_Y).length() < 1e-6);
        }
        // Corners: c, c+u, c+u+v and c, c+u+v, c+v.
        assert_eq!(
            t[0].p,
            [
                Vec3::new(0., 2., 0.),
                Vec3::new(1., 2., 0.),
                Vec3::new(1., 2., 1.)
            ]
        );
        assert_eq!(
            t[1].p,
            [
                Vec3::new(0., 2., 0.),
                Vec3::new(1., 2., 1.),
                Vec3::new(0., 2., 1.)
            ]
        );
        // A mirroring transform keeps the normal the transformed one: scale y by −1 turns
        // the downward normal upward, and the winding follows.
        let doc = with(|v| {
            v["objects"][0] = json!({"type":"quad","corner":[0,2,0],"edge_u":[1,0,0],"edge_v":[0,0,1],"material":"lamp",
                "transform": {"scale": [1, -1, 1]}});
        });
        let s = parse(&doc).unwrap();
        for tri in tris(&s, 0) {
            assert!((normal(tri) - Vec3::Y).length() < 1e-6, "{:?}", normal(tri));
            assert!((tri.p[0].y + 2.0).abs() < 1e-6);
        }
    }

    #[test]
    fn box_triangles_face_outwards_and_are_transformed() {
        let doc = with(|v| {
            v["objects"][0] = json!({"type":"box","min":[-1,-2,-3],"max":[1,2,3],"material":"m",
                "transform": {"translate": [10, 0, 0], "rotate_y": 90}});
        });
        let s = parse(&doc).unwrap();
        let t = tris(&s, 0);
        assert_eq!(t.len(), 12);
        let centre = Vec3::new(10.0, 0.0, 0.0);
        let mut lo = Vec3::splat(f32::MAX);
        let mut hi = Vec3::splat(f32::MIN);
        for tri in t {
            let c = (tri.p[0] + tri.p[1] + tri.p[2]) / 3.0;
            assert!(normal(tri).dot(c - centre) > 0.0, "inward triangle {tri:?}");
            for p in tri.p {
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        // rotate_y 90° maps x → −z and z → x: the z half-extent 3 becomes the x one.
        assert!((lo - Vec3::new(7.0, -2.0, -1.0)).length() < 1e-5, "{lo}");
        assert!((hi - Vec3::new(13.0, 2.0, 1.0)).length() < 1e-5, "{hi}");
    }

    #[test]
    fn sphere_takes_uniform_scale_and_transformed_centre() {
        let doc = with(|v| {
            v["objects"][0]["transform"] =
                json!({"scale": -2, "rotate_z": 90, "translate": [0, 0, 1]});
        });
        let s = parse(&doc).unwrap();
        match s.shapes[0] {
            Shape::Sphere { center, radius, .. } => {
                // (0,1,0) → ×−2 → (0,−2,0) → rot z 90° → (2,0,0) → +z → (2,0,1).
                assert!(
                    (center - Vec3::new(2.0, 0.0, 1.0)).length() < 1e-5,
                    "{center}"
                );
                assert_eq!(radius, 2.0);
            }
            ref other => panic!("{other:?}"),
        }
    }

    #[test]
    fn mesh_normals_use_the_inverse_transpose() {
        let doc = with(|v| {
            v["objects"][0] = json!({"type":"mesh","positions":[[0,0,0],[1,0,0],[0,1,0]],
                "normals":[[1,1,0],[1,1,0],[0,0,1]],"indices":[[0,1,2]],"material":"m",
                "transform": {"scale": [1, 4, 1]}});
        });
        let s = parse(&doc).unwrap();
        let n = tris(&s, 0)[0].n.unwrap();
        assert!(
            (n[0] - Vec3::new(1.0, 0.25, 0.0).normalize()).length() < 1e-6,
            "{}",
            n[0]
        );
        assert!((n[2] - Vec3::Z).length() < 1e-6);
    }

    #[test]
    fn obj_files_load_inside_the_scene_folder_only() {
        let dir = tempfile::tempdir().unwrap();
        let scenes = dir.path().join("scenes");
        std::fs::create_dir(&scenes).unwrap();
        let tri = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
        std::fs::write(scenes.join("quad.obj"), tri).unwrap();
        std::fs::write(dir.path().join("outside.obj"), tri).unwrap();
        let origin = SceneOrigin::File {
            dir: scenes.clone(),
        };
        let doc = with(|v| {
            v["objects"][0] = json!({"type":"obj","path":"quad.obj","material":"m",
                "transform": {"translate": [0, 0, -1]}});
        });
        let s = parse_scene(&doc.to_string(), &origin, &limits()).unwrap();
        let t = tris(&s, 0);
        assert_eq!(t.len(), 2);
        assert!(t.iter().all(|t| t.p.iter().all(|p| p.z == -1.0)));
        assert!((normal(&t[0]) - Vec3::Z).length() < 1e-6);
        for bad in ["../outside.obj", "/etc/passwd", "missing.obj"] {
            let doc = with(|v| v["objects"][0] = json!({"type":"obj","path": bad,"material":"m"}));
            let e = parse_scene(&doc.to_string(), &origin, &limits()).unwrap_err();
            assert_eq!(
                (e.kind, e.problems[0].path.as_str()),
                (SCENE, "objects[0].path"),
                "{bad}"
            );
        }
    }

    #[test]
    fn problem_lists_are_capped() {
        let doc = with(|v| {
            v["objects"][0] = json!({"type":"mesh","positions":[[0,0,0]],
                "indices": vec![[5, 5, 5]; 100], "material":"m"});
        });
        let e = parse(&doc).unwrap_err();
        assert_eq!(e.problems.len(), MAX_LISTED + 1);
        assert!(
            e.problems[MAX_LISTED].message.contains("250 more"),
            "{}",
            e.problems[MAX_LISTED].message
        );
    }
}
