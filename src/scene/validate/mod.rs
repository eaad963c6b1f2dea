//! Validation of a [`super::doc`] document into a [`super::Scene`]: collects every problem
//! with its JSON path.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use glam::{Vec2, Vec3};

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

mod lights;
mod limits;
mod materials;
mod objects;
mod settings;
mod syntax;
mod view;

use lights::check_light;
use materials::check_materials;
use objects::check_object;
use settings::{check_progressive, check_render};
use syntax::parse_doc;
use view::{check_camera, check_display};

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

/// Document → validated [`Scene`]: the size limits first (so nothing is built for a
/// document too large), then each section of scene-format.md, then every problem found
/// decides the result.
fn build(doc: &SceneDoc, origin: &SceneOrigin, limits: &Limits) -> Result<Scene, SceneError> {
    let mut cx = Ctx::default();
    if doc.version != 1 {
        cx.err("version", format!("must be 1, got {}", doc.version));
    }
    let geometry_over = limits::check_sizes(&mut cx, doc, limits);
    let camera = check_camera(&mut cx, &doc.camera);
    let display = check_display(&mut cx, &doc.display);
    let (materials, material_names) = check_materials(&mut cx, &doc.materials);
    // Geometry past its limit is refused as declared, not built first: a million
    // triangles cost many times their text to build (measured: an 8 MB mesh over the limit
    // held +221 MB before its refusal).
    let shapes = if geometry_over {
        Vec::new()
    } else {
        check_objects(&mut cx, doc, &material_names, origin, limits)
    };
    let lights = doc
        .lights
        .iter()
        .enumerate()
        .map(|(i, l)| check_light(&mut cx, &format!("lights[{i}]"), l))
        .collect();
    let mut render = check_render(&mut cx, &doc.render);
    render.max_bounces = render.max_bounces.min(limits.max_bounces);
    let progressive = check_progressive(&mut cx, &doc.progressive);
    let (images, warnings) = cx.into_result()?;
    let mut scene = Scene {
        // An unnamed scene is "untitled" rather than "": logs and the viewer show it.
        name: doc.name.clone().unwrap_or_else(|| "untitled".into()),
        width: u32::try_from(doc.image.width).unwrap_or(u32::MAX),
        height: u32::try_from(doc.image.height).unwrap_or(u32::MAX),
        camera,
        display,
        materials,
        material_names,
        shapes,
        lights,
        images,
        render,
        progressive,
        warnings,
    };
    let suspicious = super::warnings::check(&scene);
    scene.warnings.extend(suspicious);
    Ok(scene)
}

/// Every object built into world-space shapes, each within ±[`MAX_COORDINATE`], and the
/// triangles they make within the limit. Nothing is built when the document is already
/// too large: the point of the limits is that no work is spent on it.
fn check_objects(
    cx: &mut Ctx,
    doc: &SceneDoc,
    material_names: &[String],
    origin: &SceneOrigin,
    limits: &Limits,
) -> Vec<Shape> {
    let mut shapes = Vec::with_capacity(doc.objects.len());
    if cx.too_large.is_empty() {
        for (k, o) in doc.objects.iter().enumerate() {
            let shape = check_object(cx, k, o, material_names, origin);
            if let Some(Shape::Sphere { center, radius, .. }) = &shape {
                for v in [*center - *radius, *center + *radius] {
                    note_far(cx, v);
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
    shapes
}

impl Ctx {
    /// The images and warnings of a valid document, or every problem: the kind is
    /// [`SceneErrorKind::InvalidScene`] if any problem is not a limit, `TooLarge` only if
    /// every problem is one.
    fn into_result(mut self) -> Result<(Vec<Arc<TextureImage>>, Vec<Problem>), SceneError> {
        if self.unlisted_errors > 0 {
            self.errors.push(Problem {
                path: String::new(),
                message: format!("... and {} more problems not listed", self.unlisted_errors),
            });
        }
        if !self.errors.is_empty() {
            let mut problems = self.errors;
            problems.extend(self.too_large);
            return Err(SceneError {
                kind: SceneErrorKind::InvalidScene,
                problems,
            });
        }
        if !self.too_large.is_empty() {
            return Err(SceneError {
                kind: SceneErrorKind::TooLarge,
                problems: self.too_large,
            });
        }
        if self.unlisted_warnings > 0 {
            self.warnings.push(Problem {
                path: "objects".into(),
                message: format!(
                    "... and {} more degenerate triangles dropped",
                    self.unlisted_warnings
                ),
            });
        }
        Ok((self.images, self.warnings))
    }
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

#[cfg(test)]
mod tests;
