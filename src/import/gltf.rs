//! The glTF 2.0 importer (`.gltf` with embedded or sibling buffers, `.glb`): the node
//! tree with its transforms, triangle meshes (indices, normals, texture coordinates),
//! `pbrMetallicRoughness` materials with their base-colour texture, emission with `KHR_materials_emissive_strength`, `KHR_lights_punctual`
//! and perspective cameras. Errors name the JSON pointer of what is wrong.
//!
//! The `gltf` crate parses and validates the JSON only (its path import would read
//! `file:` URIs and `../` paths without confinement): the GLB container is split here,
//! buffers are decoded here (data URIs, or sibling files through the [`FileSource`]),
//! and every accessor is checked to lie inside its buffer view before it is read, so a
//! header claiming 2^31 elements allocates nothing.

use std::collections::BTreeMap;

use base64::Engine as _;
use glam::{Mat3, Mat4, Vec3};

use super::json_count::JsonBudget;
use super::texture::Encoding;
use super::{FileSource, ImportError, ImportLimits, Imported};
use crate::scene::doc::{
    CameraDoc, DirectionalLightDoc, EmissiveDoc, FalloffDoc, ImageTextureDoc, LightDoc,
    MaterialDoc, MeshDoc, MetallicRoughnessDoc, ObjectDoc, PointLightDoc, SceneDoc, SpotLightDoc,
    TextureDoc, WrapDoc,
};

/// Node trees deeper than this are refused (glTF forbids cycles; this also bounds them).
const MAX_DEPTH: usize = 64;

/// Imports a `.gltf` or `.glb` file (`bytes`, named `name`).
pub fn import(
    name: &str,
    bytes: &[u8],
    files: &dyn FileSource,
    limits: &ImportLimits,
) -> Result<Imported, ImportError> {
    let (json, bin) = if bytes.starts_with(b"glTF") {
        split_glb(name, bytes)?
    } else {
        (bytes, None)
    };
    check_size(name, json, limits)?;
    check_attribute_indices(name, json)?;
    // The crate's validation indexes some arrays before checking the index (a POSITION
    // accessor index out of range panicked in gltf-json 1.4.1's validation hook, found by
    // tests/import_fuzz.rs); the check above refuses that case with its pointer, and any
    // other panic inside the crate becomes an error here instead of reaching the caller.
    let parsed = std::panic::catch_unwind(|| gltf::Gltf::from_slice(json)).map_err(|_| {
        ImportError::invalid(name, "not valid glTF (the glTF parser gave up on it)")
    })?;
    let gltf = parsed.map_err(|e| json_error(name, &e))?;
    let mut im = Gltf {
        name,
        files,
        limits,
        doc: &gltf.document,
        buffers: Vec::new(),
        materials: BTreeMap::new(),
        objects: Vec::new(),
        lights: Vec::new(),
        camera: None,
        triangles: 0,
        vertices: 0,
        warnings: Vec::new(),
    };
    let scene = gltf
        .document
        .default_scene()
        .or_else(|| gltf.document.scenes().next());
    if let Some(scene) = &scene {
        super::gltf_expansion::check(name, &gltf.document, scene, limits, MAX_DEPTH)?;
    }
    im.load_buffers(bin)?;
    im.check_extensions()?;
    if let Some(scene) = scene {
        for node in scene.nodes() {
            im.node(&node, Mat4::IDENTITY, 0)?;
        }
    }
    im.finish()
}

/// The JSON and BIN chunks of a GLB, checked against the file's length.
fn split_glb<'a>(name: &str, b: &'a [u8]) -> Result<(&'a [u8], Option<&'a [u8]>), ImportError> {
    let err = |m: String| ImportError::invalid(name, m);
    let u32_at = |i: usize| {
        b.get(i..i + 4)
            .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize)
    };
    let version =
        u32_at(4).ok_or_else(|| err("truncated GLB header (12 bytes expected)".into()))?;
    let length = u32_at(8).ok_or_else(|| err("truncated GLB header (12 bytes expected)".into()))?;
    if version != 2 {
        return Err(err(format!("GLB version {version}; glTF 2.0 is version 2")));
    }
    if length != b.len() {
        return Err(err(format!(
            "the GLB header says {length} bytes, the file has {} (truncated?)",
            b.len()
        )));
    }
    let mut at = 12;
    let mut chunks = Vec::new();
    while at < b.len() {
        let (Some(len), Some(kind)) = (u32_at(at), u32_at(at + 4)) else {
            return Err(err(format!("truncated chunk header at byte {at}")));
        };
        let data = b.get(at + 8..at + 8 + len).ok_or_else(|| {
            err(format!(
                "the chunk at byte {at} claims {len} bytes past the end of the file"
            ))
        })?;
        chunks.push((kind, data));
        at += 8 + len;
    }
    const JSON: usize = 0x4E4F_534A;
    const BIN: usize = 0x004E_4942;
    match chunks.as_slice() {
        [(JSON, j), rest @ ..] => Ok((j, rest.iter().find(|c| c.0 == BIN).map(|c| c.1))),
        _ => Err(err("the first GLB chunk must be JSON".into())),
    }
}

/// What a glTF's JSON may hold, from the object limit: 128 values and 32 arrays or
/// objects per object (a mesh instance's node, mesh, primitive, accessors, buffer views and
/// material are ~100 values in ~20 containers), and a margin for small scenes. At the
/// default limits each bound costs the crate's parse ~60 MB at most (measured: 320 000
/// empty nodes +63 MiB, 1.3 M numbers in an accessor's `min` +43 MiB).
fn json_budget(limits: &ImportLimits) -> JsonBudget {
    let objects = limits.max_objects as u64;
    JsonBudget {
        max_values: objects.saturating_mul(128).saturating_add(65_536),
        max_containers: objects.saturating_mul(32).saturating_add(4_096),
    }
}

/// The arrays and objects a glTF's JSON may hold under `limits`.
pub(super) fn max_containers(limits: &ImportLimits) -> u64 {
    json_budget(limits).max_containers
}

/// The JSON's values counted before it is parsed (see [`super::json_count`]).
fn check_size(name: &str, json: &[u8], limits: &ImportLimits) -> Result<(), ImportError> {
    let budget = json_budget(limits);
    let Err(over) = super::json_count::check(json, &budget) else {
        return Ok(());
    };
    let (max, what, per) = if over.containers {
        (budget.max_containers, "arrays and objects", 32)
    } else {
        (budget.max_values, "JSON values", 128)
    };
    Err(ImportError::limit(
        format!("{name}: byte {}", over.offset),
        format!(
            "more than {max} {what} ({per} per object of the limit of {} objects, and a margin): refused at this one, before parsing",
            limits.max_objects
        ),
    ))
}

/// The part of a glTF that [`check_attribute_indices`] reads; the rest is skipped
/// without being held.
#[derive(serde::Deserialize)]
struct AttributeShape {
    #[serde(default)]
    accessors: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    meshes: Vec<MeshShape>,
}

#[derive(serde::Deserialize)]
struct MeshShape {
    #[serde(default)]
    primitives: Vec<PrimitiveShape>,
}

#[derive(serde::Deserialize)]
struct PrimitiveShape {
    #[serde(default)]
    attributes: BTreeMap<String, u64>,
}

/// Every mesh attribute's accessor index is in range (what gltf-json's validation assumes).
fn check_attribute_indices(name: &str, json: &[u8]) -> Result<(), ImportError> {
    let Ok(shape) = serde_json::from_slice::<AttributeShape>(json) else {
        // The crate reports the syntax error, or the value that is not an index, with its
        // position.
        return Ok(());
    };
    let accessors = shape.accessors.len() as u64;
    for (m, mesh) in shape.meshes.iter().enumerate() {
        for (k, prim) in mesh.primitives.iter().enumerate() {
            for (attr, idx) in &prim.attributes {
                if *idx >= accessors {
                    return Err(ImportError::invalid(
                        format!("{name}: /meshes/{m}/primitives/{k}/attributes/{attr}"),
                        format!("accessor {idx} does not exist ({accessors} accessors)"),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// A `gltf` crate error as an [`ImportError`] at its JSON pointer.
fn json_error(name: &str, e: &gltf::Error) -> ImportError {
    match e {
        gltf::Error::Validation(v) if !v.is_empty() => {
            let (path, err) = &v[0];
            ImportError::invalid(
                format!("{name}: {}", pointer(&path.to_string())),
                err.to_string(),
            )
        }
        other => ImportError::invalid(name, format!("not valid glTF: {other}")),
    }
}

/// `meshes[0].primitives[1].indices` → `/meshes/0/primitives/1/indices`.
fn pointer(path: &str) -> String {
    // The crate's path may end in ` = "value"`: the pointer stops before it.
    let path = path.split(' ').next().unwrap_or("");
    let mut out = String::from("/");
    for c in path.chars() {
        match c {
            '.' | '[' => out.push('/'),
            ']' => {}
            c => out.push(c),
        }
    }
    out.replace("//", "/")
}

struct Gltf<'a> {
    name: &'a str,
    files: &'a dyn FileSource,
    limits: &'a ImportLimits,
    doc: &'a gltf::Document,
    buffers: Vec<Vec<u8>>,
    materials: BTreeMap<String, MaterialDoc>,
    objects: Vec<ObjectDoc>,
    lights: Vec<LightDoc>,
    camera: Option<(CameraDoc, Option<f32>)>,
    triangles: usize,
    /// Vertices read, every instance of a mesh counted ([`Gltf::count_vertices`]).
    vertices: usize,
    warnings: Vec<String>,
}

impl Gltf<'_> {
    fn at(&self, pointer: &str, msg: impl Into<String>) -> ImportError {
        ImportError::invalid(format!("{}: {pointer}", self.name), msg)
    }

    fn check_extensions(&mut self) -> Result<(), ImportError> {
        const KNOWN: [&str; 2] = ["KHR_lights_punctual", "KHR_materials_emissive_strength"];
        for (i, e) in self.doc.extensions_required().enumerate() {
            if !KNOWN.contains(&e) {
                return Err(self.at(
                    &format!("/extensionsRequired/{i}"),
                    format!("required extension {e} is not supported"),
                ));
            }
        }
        for e in self.doc.extensions_used() {
            if !KNOWN.contains(&e) {
                self.warnings.push(format!(
                    "{}: extension {e} is not modelled: ignored",
                    self.name
                ));
            }
        }
        Ok(())
    }

    fn load_buffers(&mut self, bin: Option<&[u8]>) -> Result<(), ImportError> {
        // Every buffer is held at once, and many may name the same file (or the GLB's
        // binary chunk): together they may be as large as one file, what a .glb holding
        // them could be (else four 64 MiB files of an upload would be held together).
        let mut total = 0u64;
        for b in self.doc.buffers() {
            let p = format!("/buffers/{}", b.index());
            total = total.saturating_add(b.length() as u64);
            if total > self.limits.max_file_bytes {
                return Err(ImportError::limit(
                    format!("{}: {p}/byteLength", self.name),
                    format!(
                        "the buffers add up to more than the limit of {} bytes for one file",
                        self.limits.max_file_bytes
                    ),
                ));
            }
            let data = match b.source() {
                gltf::buffer::Source::Bin => bin
                    .ok_or_else(|| self.at(&p, "refers to the GLB binary chunk, which is missing"))?
                    .to_vec(),
                gltf::buffer::Source::Uri(uri) => self.uri(&p, uri)?,
            };
            if data.len() < b.length() {
                return Err(self.at(
                    &format!("{p}/byteLength"),
                    format!("is {} but the data has {} bytes", b.length(), data.len()),
                ));
            }
            self.buffers.push(data);
        }
        Ok(())
    }

    /// A buffer's bytes: a base64 data URI, or a relative file through the source.
    fn uri(&self, p: &str, uri: &str) -> Result<Vec<u8>, ImportError> {
        if let Some(rest) = uri.strip_prefix("data:") {
            let (_, data) = rest.split_once(";base64,").ok_or_else(|| {
                self.at(&format!("{p}/uri"), "only base64 data URIs are supported")
            })?;
            if data.len() as u64 > self.limits.max_file_bytes * 4 / 3 + 4 {
                return Err(ImportError::limit(
                    format!("{}: {p}/uri", self.name),
                    "the data URI exceeds the file size limit",
                ));
            }
            return base64::engine::general_purpose::STANDARD
                .decode(data)
                .map_err(|e| self.at(&format!("{p}/uri"), format!("bad base64: {e}")));
        }
        if uri.contains(':') {
            return Err(self.at(
                &format!("{p}/uri"),
                format!("\"{uri}\": only relative file names and data URIs are read"),
            ));
        }
        let name = percent_decode(uri);
        self.files
            .read(&name, self.limits.max_file_bytes)
            .map_err(|e| e.at(format!("{}: {p}/uri", self.name)))
    }

    fn node(&mut self, node: &gltf::Node, parent: Mat4, depth: usize) -> Result<(), ImportError> {
        let p = format!("/nodes/{}", node.index());
        if depth > MAX_DEPTH {
            return Err(self.at(
                &p,
                format!("the node tree is deeper than {MAX_DEPTH} (a cycle?)"),
            ));
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        let world = parent * local;
        if !world.is_finite() {
            return Err(self.at(&p, "its transform is not finite"));
        }
        if let Some(mesh) = node.mesh() {
            self.mesh(&mesh, &world)?;
        }
        if let Some(cam) = node.camera() {
            self.camera_at(&cam, &world, &p);
        }
        if let Some(light) = node.light() {
            self.light(&light, &world);
        }
        for child in node.children() {
            self.node(&child, world, depth + 1)?;
        }
        Ok(())
    }

    fn camera_at(&mut self, cam: &gltf::Camera, world: &Mat4, p: &str) {
        if self.camera.is_some() {
            return;
        }
        match cam.projection() {
            gltf::camera::Projection::Perspective(pp) => {
                let eye = world.transform_point3(Vec3::ZERO);
                let fwd = world
                    .transform_vector3(Vec3::NEG_Z)
                    .normalize_or(Vec3::NEG_Z);
                let up = world.transform_vector3(Vec3::Y).normalize_or(Vec3::Y);
                self.camera = Some((
                    CameraDoc {
                        position: eye.to_array(),
                        look_at: (eye + fwd).to_array(),
                        up: up.to_array(),
                        fov_y: pp.yfov().to_degrees(),
                    },
                    pp.aspect_ratio(),
                ));
            }
            gltf::camera::Projection::Orthographic(_) => self.warnings.push(format!(
                "{}: {p}: orthographic camera is not supported: ignored",
                self.name
            )),
        }
    }

    fn light(&mut self, light: &gltf::khr_lights_punctual::Light, world: &Mat4) {
        // Photometric units (cd, lx) are taken as Glimpse's radiometric ones, 1:1.
        let c = Vec3::from(light.color()) * light.intensity();
        let pos = world.transform_point3(Vec3::ZERO);
        let dir = world
            .transform_vector3(Vec3::NEG_Z)
            .normalize_or(Vec3::NEG_Z);
        match light.kind() {
            gltf::khr_lights_punctual::Kind::Directional => {
                self.lights.push(LightDoc::Directional(DirectionalLightDoc {
                    direction: dir.to_array(),
                    irradiance: c.to_array(),
                }));
            }
            gltf::khr_lights_punctual::Kind::Spot {
                inner_cone_angle,
                outer_cone_angle,
            } => {
                // KHR_lights_punctual: angles from the axis (−z of the node), in radians,
                // 0 ≤ inner < outer ≤ π/2, with the squared linear ramp in cos θ.
                let outer = outer_cone_angle.clamp(0.0, std::f32::consts::FRAC_PI_2);
                let inner = inner_cone_angle.clamp(0.0, outer);
                self.lights.push(LightDoc::Spot(SpotLightDoc {
                    position: pos.to_array(),
                    direction: dir.to_array(),
                    intensity: c.to_array(),
                    outer_angle: outer.to_degrees(),
                    inner_angle: inner.to_degrees(),
                    falloff: FalloffDoc::SquaredLinear,
                }));
            }
            gltf::khr_lights_punctual::Kind::Point => {
                self.lights.push(LightDoc::Point(PointLightDoc {
                    position: pos.to_array(),
                    intensity: c.to_array(),
                }));
            }
        }
    }

    /// Each triangle primitive of `mesh` placed by `world` (other modes are skipped with
    /// a warning).
    fn mesh(&mut self, mesh: &gltf::Mesh, world: &Mat4) -> Result<(), ImportError> {
        for prim in mesh.primitives() {
            let p = format!("/meshes/{}/primitives/{}", mesh.index(), prim.index());
            if prim.mode() != gltf::mesh::Mode::Triangles {
                self.warnings.push(format!(
                    "{}: {p}: mode {:?} is not triangles: ignored",
                    self.name,
                    prim.mode()
                ));
                continue;
            }
            self.primitive(&prim, &p, world)?;
        }
        Ok(())
    }

    /// One triangle primitive (JSON pointer `p`) as a document mesh in world space, its
    /// winding kept front-facing when `world` mirrors.
    fn primitive(
        &mut self,
        prim: &gltf::Primitive,
        p: &str,
        world: &Mat4,
    ) -> Result<(), ImportError> {
        let normal_m = Mat3::from_mat4(*world).inverse().transpose();
        let mirrors = Mat3::from_mat4(*world).determinant() < 0.0;
        let pos_acc = prim
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| self.at(&format!("{p}/attributes"), "has no POSITION"))?;
        let positions = self.vec3s(&pos_acc, &format!("{p}/attributes/POSITION"))?;
        self.count_vertices(positions.len(), p)?;
        let normals = match prim.get(&gltf::Semantic::Normals) {
            Some(a) => Some(self.vec3s(&a, &format!("{p}/attributes/NORMAL"))?),
            None => None,
        };
        if normals.as_ref().is_some_and(|n| n.len() != positions.len()) {
            return Err(self.at(
                &format!("{p}/attributes/NORMAL"),
                "count differs from POSITION's",
            ));
        }
        let n = positions.len();
        let mut indices = self.triangles_of(prim, p, n)?;
        if mirrors {
            // Keep the winding's normal the transformed normal (front faces stay front).
            for t in indices.chunks_exact_mut(3) {
                t.swap(1, 2);
            }
        }
        let uvs = self.primitive_uvs(prim, p, n)?;
        let (positions, normals, uvs) =
            super::drop_unused_vertices(positions, normals, uvs, &mut indices);
        let material = self.material(prim.material())?;
        let normals = normals.map(|ns| {
            ns.iter()
                .map(|&n| (normal_m * Vec3::from(n)).normalize_or_zero())
                .collect::<Vec<_>>()
        });
        self.objects.push(ObjectDoc::Mesh(MeshDoc {
            positions: positions
                .iter()
                .map(|&q| world.transform_point3(Vec3::from(q)).to_array())
                .collect(),
            indices: indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]].map(u64::from))
                .collect(),
            normals: normals
                .filter(|ns| ns.iter().all(|n| n.length_squared() > 0.0))
                .map(|ns| ns.iter().map(|n| n.to_array()).collect()),
            uvs,
            material,
            transform: None,
        }));
        Ok(())
    }

    /// Counts `n` vertices of the primitive at `p` against three per triangle of the
    /// limit, every instance of a mesh counted: each instance reads its accessors again
    /// (each read is bounded by [`Gltf::span`]), and its unused vertices are dropped only
    /// once read.
    fn count_vertices(&mut self, n: usize, p: &str) -> Result<(), ImportError> {
        self.vertices = self.vertices.saturating_add(n);
        let max = self.limits.max_triangles.saturating_mul(3);
        if self.vertices > max {
            return Err(ImportError::limit(
                format!("{}: {p}/attributes/POSITION", self.name),
                format!(
                    "the meshes read so far have more than {max} vertices, three per triangle of the limit of {} triangles",
                    self.limits.max_triangles
                ),
            ));
        }
        Ok(())
    }

    /// A primitive's indices (0..n without an accessor), checked against its `n`
    /// vertices and counted against the triangle limit.
    fn triangles_of(
        &mut self,
        prim: &gltf::Primitive,
        p: &str,
        n: usize,
    ) -> Result<Vec<u32>, ImportError> {
        let indices = match prim.indices() {
            Some(a) => self.indices(&a, &format!("{p}/indices"))?,
            None => (0..n as u32).collect(),
        };
        if indices.len() % 3 != 0 {
            return Err(self.at(
                &format!("{p}/indices"),
                format!("{} indices is not a multiple of 3", indices.len()),
            ));
        }
        if let Some(bad) = indices.iter().find(|&&i| i as usize >= n) {
            return Err(self.at(
                &format!("{p}/indices"),
                format!("index {bad} is out of range: {n} vertices"),
            ));
        }
        self.triangles += indices.len() / 3;
        if self.triangles > self.limits.max_triangles {
            return Err(ImportError::limit(
                format!("{}: {p}", self.name),
                format!(
                    "more than the limit of {} triangles",
                    self.limits.max_triangles
                ),
            ));
        }
        Ok(indices)
    }

    /// Texture coordinates only where the material maps an image with them; a missing
    /// set is a warning (the texture's corner texel everywhere).
    fn primitive_uvs(
        &mut self,
        prim: &gltf::Primitive,
        p: &str,
        n: usize,
    ) -> Result<Option<Vec<[f32; 2]>>, ImportError> {
        let uv_set = prim
            .material()
            .pbr_metallic_roughness()
            .base_color_texture()
            .filter(|_| prim.material().emissive_factor() == [0.0; 3])
            .map(|t| t.tex_coord());
        match uv_set.and_then(|set| prim.get(&gltf::Semantic::TexCoords(set)).map(|a| (set, a))) {
            Some((set, a)) => {
                let uvs = self.vec2s(&a, &format!("{p}/attributes/TEXCOORD_{set}"))?;
                if uvs.len() != n {
                    return Err(self.at(
                        &format!("{p}/attributes/TEXCOORD_{set}"),
                        "count differs from POSITION's",
                    ));
                }
                Ok(Some(uvs))
            }
            None => {
                if let Some(set) = uv_set {
                    self.warnings.push(format!(
                        "{}: {p}/attributes: no TEXCOORD_{set} for the material's base colour texture: its corner texel everywhere",
                        self.name
                    ));
                }
                Ok(None)
            }
        }
    }

    /// The bytes of accessor `a` as (data, offset, stride, count), every element checked to
    /// lie inside its buffer view and buffer before anything is read.
    fn span(&self, a: &gltf::Accessor) -> Result<(&[u8], usize, usize, usize), ImportError> {
        let p = &format!("/accessors/{}", a.index());
        if a.sparse().is_some() {
            return Err(self.at(&format!("{p}/sparse"), "sparse accessors are not supported"));
        }
        let view = a
            .view()
            .ok_or_else(|| self.at(p, "an accessor without a bufferView is not supported"))?;
        let buf = &self.buffers[view.buffer().index()];
        let size = a.size() as u64;
        let stride = view.stride().unwrap_or(a.size()) as u64;
        let count = a.count() as u64;
        let view_end = (view.offset() as u64).saturating_add(view.length() as u64);
        let start = (view.offset() as u64).saturating_add(a.offset() as u64);
        let end = match count {
            0 => start,
            _ => start
                .saturating_add(stride.saturating_mul(count - 1))
                .saturating_add(size),
        };
        if end > view_end || view_end > buf.len() as u64 || stride < size {
            return Err(self.at(
                &format!("{p}/count"),
                format!(
                    "{count} elements of {size} bytes (stride {stride}) do not fit in bufferView {} ({} bytes at offset {}) of a {}-byte buffer",
                    view.index(),
                    view.length(),
                    view.offset(),
                    buf.len()
                ),
            ));
        }
        let most = self.limits.max_triangles.saturating_mul(3) as u64;
        if count > most {
            return Err(ImportError::limit(
                format!("{}: {p}/count", self.name),
                format!(
                    "{count} elements, more than three per triangle of the limit of {} triangles",
                    self.limits.max_triangles
                ),
            ));
        }
        Ok((buf, start as usize, stride as usize, count as usize))
    }

    fn vec3s(&self, a: &gltf::Accessor, p: &str) -> Result<Vec<[f32; 3]>, ImportError> {
        if a.data_type() != gltf::accessor::DataType::F32
            || a.dimensions() != gltf::accessor::Dimensions::Vec3
        {
            return Err(self.at(p, "must be VEC3 of FLOAT"));
        }
        let (buf, start, stride, count) = self.span(a)?;
        let out: Vec<[f32; 3]> = (0..count)
            .map(|i| {
                let o = start + i * stride;
                [0, 1, 2].map(|k| {
                    let b = &buf[o + 4 * k..o + 4 * k + 4];
                    f32::from_le_bytes([b[0], b[1], b[2], b[3]])
                })
            })
            .collect();
        if let Some(i) = out.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(self.at(p, format!("element {i} is not finite")));
        }
        Ok(out)
    }

    /// Texture coordinates: VEC2 of FLOAT, or of normalised UNSIGNED_BYTE / UNSIGNED_SHORT
    /// (glTF 2.0 §3.7.2.1).
    fn vec2s(&self, a: &gltf::Accessor, p: &str) -> Result<Vec<[f32; 2]>, ImportError> {
        use gltf::accessor::DataType;
        let ty = a.data_type();
        let ok_type =
            ty == DataType::F32 || (a.normalized() && matches!(ty, DataType::U8 | DataType::U16));
        if a.dimensions() != gltf::accessor::Dimensions::Vec2 || !ok_type {
            return Err(self.at(
                p,
                "must be VEC2 of FLOAT or of normalized UNSIGNED_BYTE/UNSIGNED_SHORT",
            ));
        }
        let (buf, start, stride, count) = self.span(a)?;
        let out: Vec<[f32; 2]> = (0..count)
            .map(|i| {
                let o = start + i * stride;
                [0, 1].map(|k| match ty {
                    DataType::U8 => f32::from(buf[o + k]) / 255.0,
                    DataType::U16 => {
                        f32::from(u16::from_le_bytes([buf[o + 2 * k], buf[o + 2 * k + 1]]))
                            / 65535.0
                    }
                    _ => {
                        let b = &buf[o + 4 * k..o + 4 * k + 4];
                        f32::from_le_bytes([b[0], b[1], b[2], b[3]])
                    }
                })
            })
            .collect();
        if let Some(i) = out.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(self.at(p, format!("element {i} is not finite")));
        }
        Ok(out)
    }

    fn indices(&self, a: &gltf::Accessor, p: &str) -> Result<Vec<u32>, ImportError> {
        use gltf::accessor::DataType;
        if a.dimensions() != gltf::accessor::Dimensions::Scalar {
            return Err(self.at(p, "indices must be SCALAR"));
        }
        let (buf, start, stride, count) = self.span(a)?;
        let read = |o: usize| -> Option<u32> {
            Some(match a.data_type() {
                DataType::U8 => u32::from(buf[o]),
                DataType::U16 => u32::from(u16::from_le_bytes([buf[o], buf[o + 1]])),
                DataType::U32 => u32::from_le_bytes([buf[o], buf[o + 1], buf[o + 2], buf[o + 3]]),
                _ => return None,
            })
        };
        (0..count)
            .map(|i| {
                read(start + i * stride)
                    .ok_or_else(|| self.at(p, "indices must be unsigned integers"))
            })
            .collect()
    }

    /// The document material of a glTF material (created on first use); an emissive
    /// material becomes Glimpse's `emissive` (glTF's base layer under it is dropped).
    fn material(&mut self, m: gltf::Material) -> Result<String, ImportError> {
        let name = m
            .index()
            .map_or("default".to_string(), |i| format!("material-{i}"));
        if self.materials.contains_key(&name) {
            return Ok(name);
        }
        let p = m
            .index()
            .map_or(String::new(), |i| format!("/materials/{i}"));
        let e = Vec3::from(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
        let doc = if e.max_element() > 0.0 {
            if m.emissive_texture().is_some() {
                self.warnings.push(format!(
                    "{}: {p}/emissiveTexture: rendered as the emissive factor",
                    self.name
                ));
            }
            MaterialDoc::Emissive(EmissiveDoc {
                radiance: e.to_array(),
                two_sided: m.double_sided(),
            })
        } else {
            let pbr = m.pbr_metallic_roughness();
            let f = pbr.base_color_factor();
            let base = Vec3::new(f[0], f[1], f[2]).clamp(Vec3::ZERO, Vec3::ONE);
            let texture = match pbr.base_color_texture() {
                Some(t) => {
                    let mut doc = self.image_texture(
                        &t.texture(),
                        &format!("{p}/pbrMetallicRoughness/baseColorTexture"),
                    )?;
                    // glTF: base colour = baseColorFactor × the texture's (sRGB) colour.
                    doc.factor = base.to_array();
                    Some(TextureDoc::Image(doc))
                }
                None => None,
            };
            if pbr.metallic_roughness_texture().is_some() {
                self.warnings.push(format!("{}: {p}/pbrMetallicRoughness/metallicRoughnessTexture: not modelled, the factors are used", self.name));
            }
            MaterialDoc::MetallicRoughness(MetallicRoughnessDoc {
                base_color: base.to_array(),
                metallic: pbr.metallic_factor().clamp(0.0, 1.0),
                roughness: pbr.roughness_factor().clamp(0.0, 1.0),
                texture,
            })
        };
        self.materials.insert(name.clone(), doc);
        Ok(name)
    }

    /// A base-colour texture (glTF base colour is always sRGB) with its sampler's wrap.
    fn image_texture(
        &mut self,
        t: &gltf::Texture,
        p: &str,
    ) -> Result<ImageTextureDoc, ImportError> {
        let img = t.source();
        let ip = format!("/images/{}", img.index());
        let (name, mime, bytes) = match img.source() {
            gltf::image::Source::View { view, mime_type } => {
                let buf = &self.buffers[view.buffer().index()];
                let end = view.offset().saturating_add(view.length());
                let bytes = buf.get(view.offset()..end).ok_or_else(|| {
                    self.at(&ip, "the image's bufferView lies outside its buffer")
                })?;
                (ip.clone(), Some(mime_type), bytes.to_vec())
            }
            gltf::image::Source::Uri { uri, mime_type } => {
                (percent_decode(uri), mime_type, self.uri(&ip, uri)?)
            }
        };
        let mut doc = super::texture::image_texture(
            &name,
            mime,
            &bytes,
            Encoding::Srgb,
            self.limits.max_texture_pixels,
        )
        .map_err(|e| self.at(&ip, e))?;
        use gltf::texture::WrappingMode;
        let sampler = t.sampler();
        let wrap = |w: WrappingMode| match w {
            WrappingMode::ClampToEdge => WrapDoc::Clamp,
            WrappingMode::MirroredRepeat => WrapDoc::Mirror,
            WrappingMode::Repeat => WrapDoc::Repeat,
        };
        doc.wrap = wrap(sampler.wrap_s());
        if wrap(sampler.wrap_t()) != doc.wrap {
            self.warnings.push(format!(
                "{}: {p}: the sampler wraps s and t differently: both as wrapS",
                self.name
            ));
        }
        Ok(doc)
    }

    fn finish(self) -> Result<Imported, ImportError> {
        let (camera, aspect) = self.camera.unwrap_or((
            CameraDoc {
                position: [0.0; 3],
                look_at: [0.0, 0.0, -1.0],
                up: [0.0, 1.0, 0.0],
                fov_y: 0.0,
            },
            None,
        ));
        let height = 600u64;
        let width = aspect.map_or(800, |a| {
            ((a * height as f32).round() as u64).clamp(1, 16384)
        });
        let doc = SceneDoc {
            materials: self.materials,
            objects: self.objects,
            lights: self.lights,
            ..super::document(self.name, width, height, camera)
        };
        Ok(Imported {
            doc,
            warnings: self.warnings,
        })
    }
}

/// `%20` and friends in a relative URI.
fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            let hex = std::str::from_utf8(&b[i + 1..i + 3]).unwrap_or("");
            if let Ok(v) = u8::from_str_radix(hex, 16) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::import::DirSource;

    fn limits() -> ImportLimits {
        ImportLimits::from_scene(&crate::scene::Limits::command_line())
    }

    fn none() -> DirSource {
        DirSource {
            dir: std::env::temp_dir().join("glimpse-no-such-dir"),
        }
    }

    /// One triangle: 3 positions (36 bytes) and 3 u16 indices (6 bytes) in one buffer.
    fn triangle_json(count: u64, extra: &str) -> String {
        with_uri(count, None, extra)
    }

    fn with_uri(count: u64, uri: Option<&str>, extra: &str) -> String {
        let mut bytes = Vec::new();
        for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
            for c in v {
                bytes.extend(c.to_le_bytes());
            }
        }
        for i in [0u16, 1, 2] {
            bytes.extend(i.to_le_bytes());
        }
        let b64 = base64::engine::general_purpose::STANDARD.encode(&bytes);
        let uri = uri.map_or(
            format!("data:application/octet-stream;base64,{b64}"),
            str::to_string,
        );
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
            "nodes":[{{"mesh":0,"translation":[0,0,-3]}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
            "accessors":[
              {{"bufferView":0,"componentType":5126,"count":{count},"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
              {{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}}],
            "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":6}}],
            "buffers":[{{"byteLength":42,"uri":"{uri}"}}]{extra}}}"#
        )
    }

    fn glb(json: &str) -> Vec<u8> {
        let mut j = json.as_bytes().to_vec();
        while !j.len().is_multiple_of(4) {
            j.push(b' ');
        }
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend(((12 + 8 + j.len()) as u32).to_le_bytes());
        out.extend((j.len() as u32).to_le_bytes());
        out.extend(0x4E4F_534Au32.to_le_bytes());
        out.extend(j);
        out
    }

    /// The triangle scene with `nodes` for its nodes and `roots` for its scene's.
    fn with_nodes(nodes: &str, roots: &str) -> String {
        triangle_json(3, "")
            .replace(
                r#""nodes":[{"mesh":0,"translation":[0,0,-3]}]"#,
                &format!(r#""nodes":[{nodes}]"#),
            )
            .replace(r#""nodes":[0]"#, &format!(r#""nodes":[{roots}]"#))
    }

    /// `levels` levels of two nodes, each the parent of both nodes of the level below,
    /// the last level's holding the triangle: 2^levels instances of it.
    fn dag(levels: usize) -> String {
        let nodes: Vec<String> = (0..2 * levels)
            .map(|i| match i / 2 + 1 {
                next if next < levels => {
                    format!(r#"{{"children":[{},{}]}}"#, 2 * next, 2 * next + 1)
                }
                _ => r#"{"mesh":0}"#.to_string(),
            })
            .collect();
        with_nodes(&nodes.join(","), "0,1")
    }

    /// The server's default limits (the command line's allow a million objects).
    fn server_limits() -> ImportLimits {
        ImportLimits {
            max_objects: 10_000,
            ..limits()
        }
    }

    fn refused_fast(json: &str) -> ImportError {
        let t = std::time::Instant::now();
        let e = match import("t.glb", &glb(json), &none(), &server_limits()) {
            Ok(im) => panic!("imported {} objects", im.doc.objects.len()),
            Err(e) => e,
        };
        assert!(
            t.elapsed() < std::time::Duration::from_secs(1),
            "{:?}",
            t.elapsed()
        );
        assert!(e.too_large, "{e}");
        e
    }

    #[test]
    fn instanced_scenes_are_counted_before_they_are_expanded() {
        let max = server_limits().max_objects;
        let e = refused_fast(&dag(40));
        assert_eq!(e.location, "t.glb: /scenes/0/nodes/0");
        let objects = format!("{} objects exceed this server's limit of {max}", 1u64 << 39);
        assert!(e.message.contains(&objects), "{e}");
        let roots = vec!["0"; 100_000].join(",");
        let e = refused_fast(&with_nodes(r#"{"mesh":0}"#, &roots));
        assert_eq!(e.location, format!("t.glb: /scenes/0/nodes/{max}"));
        let objects = format!("{} objects exceed this server's limit of {max}", max + 1);
        assert!(e.message.contains(&objects), "{e}");
        // A small instanced scene is placed once per path to each node.
        let im = import("t.glb", &glb(&dag(3)), &none(), &limits()).unwrap();
        assert_eq!(im.doc.objects.len(), 8);
        let im = import(
            "t.gltf",
            with_nodes(r#"{"mesh":0}"#, "0,0,0").as_bytes(),
            &none(),
            &limits(),
        )
        .unwrap();
        assert_eq!(im.doc.objects.len(), 3);
    }

    #[test]
    fn cycles_and_deep_trees_are_refused_before_the_walk() {
        let cycle = with_nodes(r#"{"children":[1]},{"children":[0],"mesh":0}"#, "0");
        let e = import("t.gltf", cycle.as_bytes(), &none(), &limits()).unwrap_err();
        assert!(
            !e.too_large && e.message.contains("its own ancestor"),
            "{e}"
        );
        let chain: Vec<String> = (0..100)
            .map(|i| format!(r#"{{"children":[{}]}}"#, i + 1))
            .collect();
        let deep = with_nodes(&format!(r#"{},{{"mesh":0}}"#, chain.join(",")), "0");
        let e = import("t.gltf", deep.as_bytes(), &none(), &limits()).unwrap_err();
        assert!(e.message.contains("deeper than 64"), "{e}");
    }

    #[test]
    fn buffers_naming_one_file_many_times_are_bounded_together() {
        let j = with_uri(3, None, "");
        let one = r#"{"byteLength":42,"uri":"b.bin"}"#;
        let many = vec![one; 20].join(",");
        let j = j.replace(r#""buffers":[{"#, &format!(r#""buffers":[{many},{{"#));
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("b.bin"), [0u8; 42]).unwrap();
        let src = DirSource {
            dir: dir.path().to_path_buf(),
        };
        let l = ImportLimits {
            max_file_bytes: 42 * 10,
            ..limits()
        };
        let e = import("t.gltf", j.as_bytes(), &src, &l).unwrap_err();
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "t.gltf: /buffers/10/byteLength");
        assert!(import("t.gltf", j.as_bytes(), &src, &limits()).is_ok());
    }

    #[test]
    fn json_past_its_budget_is_refused_before_parsing() {
        let l = ImportLimits {
            max_objects: 1,
            ..limits()
        };
        // One object's budget: 128 + 65 536 values, 32 + 4096 containers.
        let numbers = |n: usize| format!(r#","extras":{{"a":[{}0]}}"#, "0,".repeat(n - 1));
        assert!(import(
            "t.gltf",
            triangle_json(3, &numbers(60_000)).as_bytes(),
            &none(),
            &l
        )
        .is_ok());
        let e = import(
            "t.gltf",
            triangle_json(3, &numbers(70_000)).as_bytes(),
            &none(),
            &l,
        )
        .unwrap_err();
        assert!(e.too_large, "{e}");
        assert!(e.location.starts_with("t.gltf: byte "), "{e}");
        assert!(e.message.contains("more than 65664 JSON values"), "{e}");
        let empties = format!(r#","extras":{{"a":[{}{{}}]}}"#, "{},".repeat(5_000));
        let e = import("t.gltf", triangle_json(3, &empties).as_bytes(), &none(), &l).unwrap_err();
        assert!(
            e.message.contains("more than 4128 arrays and objects"),
            "{e}"
        );
    }

    /// Four positions, one triangle on the last three: the first is dropped.
    fn unused_vertex_json() -> String {
        let mut bytes = Vec::new();
        for v in [
            [9f32, 9.0, 9.0],
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        ] {
            for c in v {
                bytes.extend(c.to_le_bytes());
            }
        }
        for i in [1u16, 2, 3] {
            bytes.extend(i.to_le_bytes());
        }
        let b64 = base64::engine::general_purpose::STANDARD.encode(&bytes);
        triangle_json(4, "")
            .replace(r#""byteLength":36}"#, r#""byteLength":48}"#)
            .replace(r#""byteOffset":36"#, r#""byteOffset":48"#)
            .replace(r#""byteLength":42"#, r#""byteLength":54"#)
            .replace(
                r#""nodes":[{"mesh":0,"translation":[0,0,-3]}]"#,
                r#""nodes":[{"mesh":0},{"mesh":0}]"#,
            )
            .replace(r#""nodes":[0]"#, r#""nodes":[0,1]"#)
            .replace(
                &format!("base64,{}", triangle_b64()),
                &format!("base64,{b64}"),
            )
    }

    fn triangle_b64() -> String {
        let j = triangle_json(3, "");
        let at = j.find("base64,").unwrap() + 7;
        j[at..at + j[at..].find('"').unwrap()].to_string()
    }

    #[test]
    fn unused_vertices_are_dropped_and_every_instance_counts_its_reads() {
        let j = unused_vertex_json();
        let im = import("t.gltf", j.as_bytes(), &none(), &limits()).unwrap();
        let ObjectDoc::Mesh(m) = &im.doc.objects[1] else {
            panic!("{:?}", im.doc.objects)
        };
        assert_eq!(
            m.positions,
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
        );
        assert_eq!(m.indices, [[0, 1, 2]]);
        // Two instances of four vertices read: past three per triangle of a limit of two.
        let l = ImportLimits {
            max_triangles: 2,
            ..limits()
        };
        let e = import("t.gltf", j.as_bytes(), &none(), &l).unwrap_err();
        // Counted from the accessors' declared counts before any is read: refused at
        // the second root.
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "t.gltf: /scenes/0/nodes/1");
        assert!(e.message.contains("8 vertices, more than 6"), "{e}");
        let l = ImportLimits {
            max_triangles: 1,
            ..limits()
        };
        let e = import("t.gltf", j.as_bytes(), &none(), &l).unwrap_err();
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "t.gltf: /scenes/0/nodes/0");
        assert!(e.message.contains("4 vertices, more than 3"), "{e}");
    }

    #[test]
    fn khronos_box_keeps_the_spec_defaults() {
        let dir =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/public-scenes/gltf-box");
        let bytes = std::fs::read(dir.join("Box.gltf")).unwrap();
        let im = import("Box.gltf", &bytes, &DirSource { dir }, &limits()).unwrap();
        // No metallicFactor or roughnessFactor in the file: both default to 1 (glTF 2.0
        // §5.19); the base colour factor is the file's.
        match &im.doc.materials["material-0"] {
            MaterialDoc::MetallicRoughness(m) => {
                assert_eq!(m.base_color, [0.8, 0.0, 0.0]);
                assert_eq!((m.metallic, m.roughness), (1.0, 1.0));
            }
            other => panic!("{other:?}"),
        }
        let ObjectDoc::Mesh(mesh) = &im.doc.objects[0] else {
            panic!()
        };
        assert_eq!(mesh.indices.len(), 12);
        // The root node turns the Z-up model by −90° about x: z extents become y.
        let ys: Vec<f32> = mesh.positions.iter().map(|p| p[1]).collect();
        assert!(ys.iter().all(|y| (y.abs() - 0.5).abs() < 1e-6), "{ys:?}");
        // No camera and no light: both supplied by the caller (fov_y 0 marks it).
        assert_eq!(im.doc.camera.fov_y, 0.0);
        assert!(im.doc.lights.is_empty());
    }

    #[test]
    fn spot_lights_keep_their_cones_and_gltf_falloff() {
        // A spot at (0, 2, 0) turned to point down (−z rotated by −90° about x is −y).
        let j = triangle_json(
            3,
            r#","extensionsUsed":["KHR_lights_punctual"],
            "extensions":{"KHR_lights_punctual":{"lights":[{"type":"spot","color":[1,0.5,0.25],
              "intensity":8,"spot":{"innerConeAngle":0.2,"outerConeAngle":0.6}}]}}"#,
        )
        .replace(
            r#""scenes":[{"nodes":[0]}]"#,
            r#""scenes":[{"nodes":[0,1]}]"#,
        )
        .replace(
            r#""nodes":[{"mesh":0,"translation":[0,0,-3]}]"#,
            r#""nodes":[{"mesh":0,"translation":[0,0,-3]},
              {"translation":[0,2,0],"rotation":[-0.70710678,0,0,0.70710678],
               "extensions":{"KHR_lights_punctual":{"light":0}}}]"#,
        );
        let im = import("t.gltf", j.as_bytes(), &none(), &limits()).unwrap();
        let [LightDoc::Spot(s)] = &im.doc.lights[..] else {
            panic!("{:?}", im.doc.lights)
        };
        assert_eq!(s.position, [0.0, 2.0, 0.0]);
        assert!(
            (Vec3::from(s.direction) - Vec3::NEG_Y).length() < 1e-5,
            "{:?}",
            s.direction
        );
        assert_eq!(s.intensity, [8.0, 4.0, 2.0]);
        assert!((s.inner_angle - 0.2f32.to_degrees()).abs() < 1e-4);
        assert!((s.outer_angle - 0.6f32.to_degrees()).abs() < 1e-4);
        assert_eq!(s.falloff, FalloffDoc::SquaredLinear);
    }

    #[test]
    fn a_triangle_imports_from_gltf_and_glb() {
        let j = triangle_json(3, "");
        for bytes in [j.as_bytes().to_vec(), glb(&j)] {
            let im = import("t.glb", &bytes, &none(), &limits()).unwrap();
            let ObjectDoc::Mesh(m) = &im.doc.objects[0] else {
                panic!()
            };
            assert_eq!(m.positions[1], [1.0, 0.0, -3.0]);
            assert_eq!(m.indices, vec![[0, 1, 2]]);
            assert!(matches!(
                im.doc.materials["default"],
                MaterialDoc::MetallicRoughness(_)
            ));
        }
    }

    #[test]
    fn bad_files_get_one_clear_error_with_the_pointer() {
        // A 2^31 accessor count over a 36-byte view: refused before any allocation.
        let e = import(
            "t.gltf",
            triangle_json(1 << 31, "").as_bytes(),
            &none(),
            &limits(),
        )
        .unwrap_err();
        assert_eq!(e.location, "t.gltf: /accessors/0/count");
        assert!(e.message.contains("do not fit"), "{e}");
        // Truncated GLB.
        let g = glb(&triangle_json(3, ""));
        let e = import("t.glb", &g[..g.len() - 10], &none(), &limits()).unwrap_err();
        assert!(e.message.contains("truncated"), "{e}");
        let e = import("t.glb", &g[..7], &none(), &limits()).unwrap_err();
        assert!(e.message.contains("truncated"), "{e}");
        // A required extension Glimpse lacks.
        let j = triangle_json(
            3,
            r#","extensionsRequired":["KHR_draco_mesh_compression"],"extensionsUsed":["KHR_draco_mesh_compression"]"#,
        );
        let e = import("t.gltf", j.as_bytes(), &none(), &limits()).unwrap_err();
        assert_eq!(e.location, "t.gltf: /extensionsRequired/0");
        // Files outside the scene's folder, and absolute URIs.
        for uri in ["../secret.bin", "/etc/passwd", "file:///etc/passwd"] {
            let j = with_uri(3, Some(uri), "");
            let e = import("t.gltf", j.as_bytes(), &none(), &limits()).unwrap_err();
            assert_eq!(e.location, "t.gltf: /buffers/0/uri", "{uri}: {e}");
        }
        // Not JSON at all.
        assert!(import("t.gltf", b"{", &none(), &limits()).is_err());
    }
}
