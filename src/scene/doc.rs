//! The scene document exactly as `shared/spec/scene-format.md` defines it (serde,
//! unknown fields refused).
//!
//! These types only describe the *shape* of the JSON; every range and consistency check
//! lives in [`super::validate`], which turns a [`SceneDoc`] into a [`super::Scene`].
//!
//! Why the tagged enums (`"type": ...`) are deserialized by hand: serde's derived
//! internally tagged enums buffer the object and then deserialize the variant from that
//! buffer, which (a) hides the path of a bad field inside the variant from
//! `serde_path_to_error` (an error in `objects[3].radius` would only say `objects[3]`) and
//! (b) gives poor messages for an unknown `type`. [`tagged`] instead removes `type`, picks
//! the variant struct and deserializes it with its own path tracking; the inner path is
//! carried out in the error message between two [`PATH_MARK`] characters and spliced onto
//! the outer path by `validate` (see [`split_marked`]). Nesting (a texture inside a
//! material) composes.
//!
//! Numbers: every real is `f32` (what the tracer uses). serde converts an `f64` that is
//! too large for `f32` to an infinity without complaint, so `validate` checks every real
//! for finiteness and reports the path. Counts (`width`, `samples_per_pixel`, indices,
//! ...) are `u64` so that a huge value reaches validation and is reported against the
//! server's limit (`too_large`) instead of failing as a type error.

use std::collections::BTreeMap;

use serde::de::{DeserializeOwned, Error as _};
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::Value;

use super::RenderMode;

/// A 3-vector or an RGB triple, as written in the document.
pub type V3 = [f32; 3];

/// The whole document (scene-format.md, top level).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SceneDoc {
    /// Must be 1 (checked in validation so the message can say so).
    pub version: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    pub image: ImageDoc,
    pub camera: CameraDoc,
    #[serde(default)]
    pub display: DisplayDoc,
    /// A `BTreeMap`, so iteration is sorted by name: this is the deterministic material
    /// order of [`super::Scene::materials`]. Optional: a scene lit only by an
    /// environment, with no objects, needs none.
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialDoc>,
    #[serde(default)]
    pub objects: Vec<ObjectDoc>,
    #[serde(default)]
    pub lights: Vec<LightDoc>,
    #[serde(default)]
    pub render: RenderDoc,
    #[serde(default)]
    pub progressive: ProgressiveDoc,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ImageDoc {
    pub width: u64,
    pub height: u64,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDoc {
    pub position: V3,
    pub look_at: V3,
    /// Not given a default by the spec; +y is the universal convention, so a document
    /// may omit it.
    #[serde(default = "default_up")]
    pub up: V3,
    pub fov_y: f32,
}

fn default_up() -> V3 {
    [0.0, 1.0, 0.0]
}

/// Defaults from scene-format.md `display`: 100, 0.5, 1.0, 28.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DisplayDoc {
    pub peak_luminance: f32,
    pub black_luminance: f32,
    pub exposure: f32,
    pub pixels_per_degree: f32,
}

impl Default for DisplayDoc {
    fn default() -> Self {
        let d = super::Display::default();
        Self {
            peak_luminance: d.peak_luminance,
            black_luminance: d.black_luminance,
            exposure: d.exposure,
            pixels_per_degree: d.pixels_per_degree,
        }
    }
}

/// Materials (`"type"`: diffuse, glossy, conductor, metallic_roughness, coated_diffuse,
/// mirror, dielectric, emissive).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum MaterialDoc {
    Diffuse(DiffuseDoc),
    Glossy(GlossyDoc),
    Conductor(ConductorDoc),
    #[serde(rename = "metallic_roughness")]
    MetallicRoughness(MetallicRoughnessDoc),
    #[serde(rename = "coated_diffuse")]
    CoatedDiffuse(CoatedDiffuseDoc),
    Mirror(MirrorDoc),
    Dielectric(DielectricDoc),
    Emissive(EmissiveDoc),
}

/// Exactly one of `albedo` and `texture` (checked in validation).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DiffuseDoc {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub albedo: Option<V3>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<TextureDoc>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GlossyDoc {
    pub albedo: V3,
    pub roughness: f32,
}

/// A metal (our extension for imported scenes): complex index `eta + i·k` per RGB channel
/// and GGX `roughness` in [0, 1] (alpha = roughness², as `glossy`).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ConductorDoc {
    pub eta: V3,
    pub k: V3,
    pub roughness: f32,
}

/// glTF 2.0's metallic-roughness material (our extension for imported scenes):
/// `base_color` in [0, 1], `metallic` and `roughness` in [0, 1] (alpha = roughness²);
/// an optional `texture` replaces `base_color` (glTF's `baseColorFactor` goes into an
/// image texture's `factor`).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MetallicRoughnessDoc {
    pub base_color: V3,
    pub metallic: f32,
    pub roughness: f32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<TextureDoc>,
}

/// pbrt-v4's `coateddiffuse` (our extension for imported scenes): a Lambertian base
/// (exactly one of `reflectance` in [0, 1] and `texture`) under a dielectric coat of
/// index `ior` > 0 (default 1.5) with GGX `roughness` in [0, 1] (default 0, alpha =
/// roughness²).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CoatedDiffuseDoc {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reflectance: Option<V3>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<TextureDoc>,
    #[serde(default)]
    pub roughness: f32,
    #[serde(default = "default_coat_ior")]
    pub ior: f32,
}

fn default_coat_ior() -> f32 {
    1.5
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MirrorDoc {
    pub reflectance: V3,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DielectricDoc {
    pub ior: f32,
    /// Default: clear glass, `[1, 1, 1]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tint: Option<V3>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EmissiveDoc {
    pub radiance: V3,
    /// Default false: emits only on the side of the geometric normal.
    #[serde(default)]
    pub two_sided: bool,
}

/// Textures (`"type"`: checker, noise: procedural, with the same fields; image: our
/// extension, looked up at the surface's `uvs`).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum TextureDoc {
    Checker(TextureFields),
    Noise(TextureFields),
    Image(ImageTextureDoc),
}

/// An image texture (our extension for imported scenes): the file inline as a `data:`
/// URI (PNG, JPEG or TGA), how its values encode light (default `srgb`), what lies
/// outside it (`wrap`, default `repeat`), the mapping `uv × uv_scale + uv_offset`
/// (defaults `[1, 1]`, `[0, 0]`; (0, 0) is the image's top-left corner) and a `factor`
/// in [0, 1] that multiplies every texel (default `[1, 1, 1]`).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ImageTextureDoc {
    pub data: String,
    #[serde(default = "default_encoding")]
    pub encoding: super::image::Encoding,
    #[serde(default = "default_wrap")]
    pub wrap: WrapDoc,
    #[serde(default = "default_uv_scale")]
    pub uv_scale: [f32; 2],
    #[serde(default)]
    pub uv_offset: [f32; 2],
    #[serde(default = "default_factor")]
    pub factor: V3,
}

fn default_encoding() -> super::image::Encoding {
    super::image::Encoding::Srgb
}
fn default_wrap() -> WrapDoc {
    WrapDoc::Repeat
}
fn default_uv_scale() -> [f32; 2] {
    [1.0, 1.0]
}
fn default_factor() -> V3 {
    [1.0; 3]
}

/// An image texture's `wrap`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum WrapDoc {
    Repeat,
    Clamp,
    Mirror,
    Black,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TextureFields {
    pub scale: f32,
    pub a: V3,
    pub b: V3,
}

/// `transform`: scale, then rotate x, y, z (degrees), then translate.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TransformDoc {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translate: Option<V3>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<ScaleDoc>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotate_x: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotate_y: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotate_z: Option<f32>,
}

/// `scale`: a number (uniform) or a 3-vector (per axis).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(untagged)]
pub enum ScaleDoc {
    Uniform(f32),
    Axes(V3),
}

impl<'de> Deserialize<'de> for ScaleDoc {
    /// By hand rather than `#[serde(untagged)]`, whose error ("data did not match any
    /// variant") does not tell the user what is expected.
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = Value::deserialize(d)?;
        if v.is_number() {
            return f32::deserialize(v)
                .map(ScaleDoc::Uniform)
                .map_err(D::Error::custom);
        }
        V3::deserialize(v).map(ScaleDoc::Axes).map_err(|e| {
            D::Error::custom(format!("{e}; expected a number or an array of 3 numbers"))
        })
    }
}

/// Objects (`"type"`: sphere, quad, box, mesh, obj).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum ObjectDoc {
    Sphere(SphereDoc),
    Quad(QuadDoc),
    Box(BoxDoc),
    Mesh(MeshDoc),
    Obj(ObjDoc),
}

impl ObjectDoc {
    #[must_use]
    pub fn material(&self) -> &str {
        match self {
            ObjectDoc::Sphere(o) => &o.material,
            ObjectDoc::Quad(o) => &o.material,
            ObjectDoc::Box(o) => &o.material,
            ObjectDoc::Mesh(o) => &o.material,
            ObjectDoc::Obj(o) => &o.material,
        }
    }

    #[must_use]
    pub fn transform(&self) -> Option<&TransformDoc> {
        match self {
            ObjectDoc::Sphere(o) => o.transform.as_ref(),
            ObjectDoc::Quad(o) => o.transform.as_ref(),
            ObjectDoc::Box(o) => o.transform.as_ref(),
            ObjectDoc::Mesh(o) => o.transform.as_ref(),
            ObjectDoc::Obj(o) => o.transform.as_ref(),
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SphereDoc {
    pub center: V3,
    pub radius: f32,
    pub material: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<TransformDoc>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct QuadDoc {
    pub corner: V3,
    pub edge_u: V3,
    pub edge_v: V3,
    pub material: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<TransformDoc>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BoxDoc {
    pub min: V3,
    pub max: V3,
    pub material: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<TransformDoc>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MeshDoc {
    pub positions: Vec<V3>,
    pub indices: Vec<[u64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub normals: Option<Vec<V3>>,
    /// Texture coordinates per position (our extension): `[u, v]`, (0, 0) the top-left
    /// corner of an image texture.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uvs: Option<Vec<[f32; 2]>>,
    pub material: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<TransformDoc>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObjDoc {
    pub path: String,
    pub material: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<TransformDoc>,
}

/// Explicit lights (`"type"`: point, directional, environment, spot).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum LightDoc {
    Point(PointLightDoc),
    Directional(DirectionalLightDoc),
    Environment(EnvironmentLightDoc),
    Spot(SpotLightDoc),
}

/// A spot light (our extension for imported scenes): a point light at `position`
/// pointing along `direction`, full `intensity` within `inner_angle` of its axis, none
/// beyond `outer_angle` (half-angles in degrees, 0 ≤ inner ≤ outer ≤ 180; inner
/// default 0), and between them `falloff`: `smoothstep` (pbrt-v4, the default) or
/// `squared_linear` (glTF), both over the cosine of the angle.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SpotLightDoc {
    pub position: V3,
    pub direction: V3,
    pub intensity: V3,
    pub outer_angle: f32,
    #[serde(default)]
    pub inner_angle: f32,
    #[serde(default = "default_falloff")]
    pub falloff: FalloffDoc,
}

fn default_falloff() -> FalloffDoc {
    FalloffDoc::Smoothstep
}

/// A spot light's `falloff`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FalloffDoc {
    Smoothstep,
    SquaredLinear,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PointLightDoc {
    pub position: V3,
    pub intensity: V3,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DirectionalLightDoc {
    pub direction: V3,
    pub irradiance: V3,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentLightDoc {
    pub radiance: V3,
}

/// `render`. The spec gives no defaults; ours are cheap and safe: a progressive render
/// of 16 samples per traced pixel, 5 bounces, seed 1.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderDoc {
    pub mode: RenderMode,
    pub samples_per_pixel: u64,
    pub max_bounces: u64,
    pub seed: u64,
    /// `"independent"` (the default) or `"sobol"`.
    pub sampler: crate::scene::SamplerKind,
    /// `null`/absent: on in adaptive mode, off in the others.
    pub denoise: Option<bool>,
}

impl Default for RenderDoc {
    fn default() -> Self {
        Self {
            mode: RenderMode::Progressive,
            samples_per_pixel: 16,
            max_bounces: 5,
            seed: 1,
            sampler: crate::scene::SamplerKind::Independent,
            denoise: None,
        }
    }
}

/// `progressive`. Defaults are [`super::ProgressiveSettings::default`] (the spec's example
/// values: t0 1, t1 null, initial_rate 0.01, homogeneity 0.8, epsilon 1, 64 iterations).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProgressiveDoc {
    pub t0: f32,
    pub t1: Option<f32>,
    pub initial_rate: f32,
    pub homogeneity: f32,
    pub epsilon: f32,
    pub max_iterations: u64,
    pub force_loop: bool,
}

impl Default for ProgressiveDoc {
    fn default() -> Self {
        let p = super::ProgressiveSettings::default();
        Self {
            t0: p.t0,
            t1: p.t1,
            initial_rate: p.initial_rate,
            homogeneity: p.homogeneity,
            epsilon: p.epsilon,
            max_iterations: u64::from(p.max_iterations),
            force_loop: p.force_loop,
        }
    }
}

// ---------------------------------------------------------------------------------------
// Tagged-enum plumbing (see the module doc).

/// Delimits a path carried inside an error message: `MARK path MARK message`. A control
/// character that no JSON key printed by serde can produce unescaped.
pub const PATH_MARK: char = '\u{1f}';

/// Splits a message produced by [`tagged`] into (inner path, message). A message without
/// a mark has an empty inner path.
#[must_use]
pub fn split_marked(msg: &str) -> (&str, &str) {
    if let Some(rest) = msg.strip_prefix(PATH_MARK) {
        if let Some(end) = rest.find(PATH_MARK) {
            return (&rest[..end], &rest[end + PATH_MARK.len_utf8()..]);
        }
    }
    ("", msg)
}

/// Joins two JSON paths (`objects[3]` + `radius`, `positions` + `[2]`).
#[must_use]
pub fn join_path(outer: &str, inner: &str) -> String {
    if outer.is_empty() {
        inner.to_string()
    } else if inner.is_empty() {
        outer.to_string()
    } else if inner.starts_with('[') {
        format!("{outer}{inner}")
    } else {
        format!("{outer}.{inner}")
    }
}

fn marked<E: serde::de::Error>(path: &str, msg: impl std::fmt::Display) -> E {
    E::custom(format!("{PATH_MARK}{path}{PATH_MARK}{msg}"))
}

/// Reads a JSON object, removes and checks its `type`, and returns it with the rest.
fn tagged<'de, D: Deserializer<'de>>(
    d: D,
    what: &str,
    types: &[&str],
) -> Result<(String, Value), D::Error> {
    let mut map = serde_json::Map::<String, Value>::deserialize(d)?;
    let Some(t) = map.remove("type") else {
        return Err(marked(
            "type",
            format!(
                "missing field `type` (a {what} type: one of {})",
                types.join(", ")
            ),
        ));
    };
    Ok((type_named(t, what, types)?, Value::Object(map)))
}

/// The value of a `type` field, checked to be one of `types`.
fn type_named<E: serde::de::Error>(t: Value, what: &str, types: &[&str]) -> Result<String, E> {
    let list = types.join(", ");
    match t {
        Value::String(t) if types.contains(&t.as_str()) => Ok(t),
        Value::String(t) => Err(marked(
            "type",
            format!("unknown {what} type `{t}`, expected one of {list}"),
        )),
        other => Err(marked(
            "type",
            format!("must be a string (one of {list}), got {other}"),
        )),
    }
}

/// Deserializes one variant's fields with path tracking, carrying the inner path out.
fn variant<T: DeserializeOwned, E: serde::de::Error>(v: Value) -> Result<T, E> {
    serde_path_to_error::deserialize(v).map_err(|e| {
        let outer = e.path().to_string();
        let outer = if outer == "." { String::new() } else { outer };
        let msg = e.into_inner().to_string();
        let (inner, msg) = split_marked(&msg);
        marked(&join_path(&outer, inner), msg)
    })
}

impl<'de> Deserialize<'de> for MaterialDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let types = [
            "diffuse",
            "glossy",
            "conductor",
            "metallic_roughness",
            "coated_diffuse",
            "mirror",
            "dielectric",
            "emissive",
        ];
        let (t, rest) = tagged(d, "material", &types)?;
        match t.as_str() {
            "diffuse" => variant(rest).map(MaterialDoc::Diffuse),
            "glossy" => variant(rest).map(MaterialDoc::Glossy),
            "conductor" => variant(rest).map(MaterialDoc::Conductor),
            "metallic_roughness" => variant(rest).map(MaterialDoc::MetallicRoughness),
            "coated_diffuse" => variant(rest).map(MaterialDoc::CoatedDiffuse),
            "mirror" => variant(rest).map(MaterialDoc::Mirror),
            "dielectric" => variant(rest).map(MaterialDoc::Dielectric),
            _ => variant(rest).map(MaterialDoc::Emissive),
        }
    }
}

impl<'de> Deserialize<'de> for TextureDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let (t, rest) = tagged(d, "texture", &["checker", "noise", "image"])?;
        match t.as_str() {
            "checker" => variant(rest).map(TextureDoc::Checker),
            "image" => variant(rest).map(TextureDoc::Image),
            _ => variant(rest).map(TextureDoc::Noise),
        }
    }
}

const OBJECT_TYPES: [&str; 5] = ["sphere", "quad", "box", "mesh", "obj"];

/// An object whose `type` comes first (as every bundled, imported and written document
/// has it) is read as it streams: a mesh's arrays go straight into their vectors. Read
/// whole into a `Value` first, as the other tagged types are, an 8 MB mesh held ~20× its
/// text. An object whose `type` comes later is read whole, as before.
impl<'de> Deserialize<'de> for ObjectDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_map(ObjectVisitor)
    }
}

struct ObjectVisitor;

impl<'de> serde::de::Visitor<'de> for ObjectVisitor {
    type Value = ObjectDoc;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an object with a `type`")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<ObjectDoc, A::Error> {
        let first: Option<String> = map.next_key()?;
        if first.as_deref() == Some("type") {
            let t = type_named(map.next_value()?, "object", &OBJECT_TYPES)?;
            // The caller's path tracking goes on through the same map: an error in the
            // rest is named by its whole path already.
            let rest = serde::de::value::MapAccessDeserializer::new(map);
            return match t.as_str() {
                "sphere" => SphereDoc::deserialize(rest).map(ObjectDoc::Sphere),
                "quad" => QuadDoc::deserialize(rest).map(ObjectDoc::Quad),
                "box" => BoxDoc::deserialize(rest).map(ObjectDoc::Box),
                "mesh" => MeshDoc::deserialize(rest).map(ObjectDoc::Mesh),
                _ => ObjDoc::deserialize(rest).map(ObjectDoc::Obj),
            };
        }
        let mut whole = serde_json::Map::new();
        if let Some(key) = first {
            whole.insert(key, map.next_value()?);
        }
        while let Some((key, value)) = map.next_entry::<String, Value>()? {
            whole.insert(key, value);
        }
        let (t, rest) =
            tagged(Value::Object(whole), "object", &OBJECT_TYPES).map_err(A::Error::custom)?;
        match t.as_str() {
            "sphere" => variant(rest).map(ObjectDoc::Sphere),
            "quad" => variant(rest).map(ObjectDoc::Quad),
            "box" => variant(rest).map(ObjectDoc::Box),
            "mesh" => variant(rest).map(ObjectDoc::Mesh),
            _ => variant(rest).map(ObjectDoc::Obj),
        }
    }
}

/// A data error's message without the " at line L column C" a streaming parse appends:
/// the error names its place by JSON path instead, as one from a parsed tree does.
#[must_use]
pub fn without_position(mut msg: String) -> String {
    if let Some(at) = msg.rfind(" at line ") {
        let tail = &msg[at + " at line ".len()..];
        let is_position = tail.split_once(" column ").is_some_and(|(l, c)| {
            !l.is_empty()
                && !c.is_empty()
                && l.bytes().all(|b| b.is_ascii_digit())
                && c.bytes().all(|b| b.is_ascii_digit())
        });
        if is_position {
            msg.truncate(at);
        }
    }
    msg
}

impl<'de> Deserialize<'de> for LightDoc {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let (t, rest) = tagged(d, "light", &["point", "directional", "environment", "spot"])?;
        match t.as_str() {
            "point" => variant(rest).map(LightDoc::Point),
            "spot" => variant(rest).map(LightDoc::Spot),
            "directional" => variant(rest).map(LightDoc::Directional),
            _ => variant(rest).map(LightDoc::Environment),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::without_position;

    #[test]
    fn only_a_trailing_position_is_taken_off() {
        let m = |s: &str| without_position(s.to_owned());
        assert_eq!(
            m("invalid type: string \"x\", expected f32 at line 3 column 17"),
            "invalid type: string \"x\", expected f32"
        );
        assert_eq!(m("unknown field `a`"), "unknown field `a`");
        assert_eq!(
            m("name \"at line 3 column x\""),
            "name \"at line 3 column x\""
        );
        assert_eq!(m("ends at line 4"), "ends at line 4");
    }
}
