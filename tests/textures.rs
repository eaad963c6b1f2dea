//! Image textures end to end: a textured square written as glTF 2.0 (by this test, with a
//! PNG inside), as pbrt-v4 (TGA read as linear, PNG as sRGB) and as OBJ/MTL (`map_Kd`)
//! is rendered by the real binary (`glimpse render FILE --exr`), and each quadrant of the
//! picture shows the texel the file puts there:
//! - pbrt and OBJ map to Lambertian surfaces; alone under the constant white environment
//!   an import adds to a file without lights, a plane reflects exactly its albedo
//!   (radiance = ρ · L_env, nothing else in the scene to occlude or reflect), so a
//!   quadrant's mean is the texel's linear colour;
//! - glTF maps to the metallic-roughness model (a specular layer on top), so its render is
//!   compared with a Glimpse document of four squares whose constant base colours are the
//!   four texels' (decoded from sRGB by hand), same camera, same samples.

use std::path::Path;
use std::process::Command;

mod common;

use base64::Engine as _;

/// The texture: an 8×8 image whose 4×4 quadrants are one colour each (8-bit sRGB values):
/// top-left red, top-right green, bottom-left blue, bottom-right light grey.
const QUADRANTS: [[u8; 3]; 4] = [[200, 40, 40], [40, 200, 40], [40, 40, 200], [230, 230, 230]];

fn texture_image() -> image::RgbImage {
    image::RgbImage::from_fn(8, 8, |x, y| {
        image::Rgb(QUADRANTS[(usize::from(y >= 4) << 1) | usize::from(x >= 4)])
    })
}

fn encoded(format: image::ImageFormat) -> Vec<u8> {
    let mut out = Vec::new();
    texture_image()
        .write_to(&mut std::io::Cursor::new(&mut out), format)
        .unwrap();
    out
}

/// IEC 61966-2-1, written out here rather than taken from the crate under test.
fn srgb_to_linear(v: u8) -> f64 {
    let e = f64::from(v) / 255.0;
    if e <= 0.040_45 {
        e / 12.92
    } else {
        ((e + 0.055) / 1.055).powf(2.4)
    }
}

/// Renders `scene` through the command line at 64², every pixel traced.
fn render(scene: &Path, spp: u32) -> Vec<[f32; 3]> {
    let spp = spp.to_string();
    let args = ["--spp", spp.as_str(), "--size", "64x64", "--seed", "3"];
    let (img, w, h) = common::render_exr(scene, &args);
    assert_eq!((w, h), (64, 64));
    img
}

/// The square spans x, y ∈ [−1, 1] at z = 0, seen from (0, 0, 3) with a vertical field of
/// view of 2·atan(1/3)·1.25: it covers the middle 80 % of the image, pixels 6.4..57.6.
const FOV_Y_DEG: f64 = 2.0 * 0.321_750_554_396_642_2 * 57.295_779_513_082_32 * 1.25;

/// Mean linear RGB of each quadrant of the square in a 64² render (top-left, top-right,
/// bottom-left, bottom-right), over pixels at least 3 pixels away from the square's edge
/// and from the texture's middle lines (where bilinear filtering blends two texels).
fn quadrant_means(img: &[[f32; 3]]) -> [[f64; 3]; 4] {
    let mut sum = [[0f64; 3]; 4];
    let mut n = [0u32; 4];
    for y in 0..64usize {
        for x in 0..64usize {
            let inside = |c: usize| (10..=28).contains(&c) || (35..=53).contains(&c);
            if !(inside(x) && inside(y)) {
                continue;
            }
            let q = (usize::from(y >= 32) << 1) | usize::from(x >= 32);
            for c in 0..3 {
                sum[q][c] += f64::from(img[y * 64 + x][c]);
            }
            n[q] += 1;
        }
    }
    std::array::from_fn(|q| sum[q].map(|s| s / f64::from(n[q])))
}

fn assert_close(what: &str, got: [[f64; 3]; 4], want: [[f64; 3]; 4], tol: f64) {
    eprintln!("{what}: got {got:?}\n  want {want:?}");
    for q in 0..4 {
        for c in 0..3 {
            let err = (got[q][c] - want[q][c]).abs() / want[q][c].max(0.02);
            assert!(
                err < tol,
                "{what}: quadrant {q} channel {c}: {} vs {} ({:.1} % off)",
                got[q][c],
                want[q][c],
                err * 100.0
            );
        }
    }
}

fn texel_linear() -> [[f64; 3]; 4] {
    QUADRANTS.map(|t| t.map(srgb_to_linear))
}

#[test]
fn pbrt_imagemaps_show_their_texels_where_the_uvs_put_them() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("q.png"), encoded(image::ImageFormat::Png)).unwrap();
    std::fs::write(dir.path().join("q.tga"), encoded(image::ImageFormat::Tga)).unwrap();
    // pbrt reads an image at (u, 1 − v) from its top-left corner: uv (0, 0) is the image's
    // bottom-left texel. `Scale -1 1 1` before `LookAt` (as exporters write it) puts world
    // +x on the right of pbrt's picture.
    let scene = |file: &str| {
        format!(
            r#"Scale -1 1 1
LookAt 0 0 3  0 0 0  0 1 0
Camera "perspective" "float fov" [{FOV_Y_DEG}]
Film "rgb" "integer xresolution" [64] "integer yresolution" [64]
WorldBegin
Texture "t" "spectrum" "imagemap" "string filename" "{file}"
Material "diffuse" "texture reflectance" "t"
Shape "trianglemesh" "point3 P" [-1 -1 0  1 -1 0  1 1 0  -1 1 0]
  "point2 uv" [0 0  1 0  1 1  0 1] "integer indices" [0 1 2  0 2 3]
"#
        )
    };
    std::fs::write(dir.path().join("png.pbrt"), scene("q.png")).unwrap();
    std::fs::write(dir.path().join("tga.pbrt"), scene("q.tga")).unwrap();
    let png = quadrant_means(&render(&dir.path().join("png.pbrt"), 16));
    assert_close("pbrt, PNG as sRGB", png, texel_linear(), 0.02);
    // pbrt-v4 reads an 8-bit TGA as linear values: v / 255.
    let tga = quadrant_means(&render(&dir.path().join("tga.pbrt"), 16));
    let linear = QUADRANTS.map(|t| t.map(|v| f64::from(v) / 255.0));
    assert_close("pbrt, TGA as linear", tga, linear, 0.02);
}

#[test]
fn obj_map_kd_shows_its_texels_where_vt_puts_them() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("q.png"), encoded(image::ImageFormat::Png)).unwrap();
    // `vt` grows upwards (OpenGL): (0, 0) is the image's bottom-left corner. Kd multiplies
    // the map; 1 leaves it as it is.
    std::fs::write(
        dir.path().join("q.mtl"),
        "newmtl tex\nKd 1 1 1\nKs 0 0 0\nmap_Kd q.png\n",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("q.obj"),
        "mtllib q.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         usemtl tex\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n",
    )
    .unwrap();
    // Without a camera the import frames the bounds from the front (+z, +x to the right);
    // a document with that camera spelled out makes the framing this test's own.
    let out = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .arg("convert")
        .arg(dir.path().join("q.obj"))
        .arg("--output")
        .arg(dir.path().join("q.json"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut doc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("q.json")).unwrap()).unwrap();
    doc["camera"] = serde_json::json!({
        "position": [0, 0, 3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": FOV_Y_DEG
    });
    assert!(doc["materials"]["tex"]["texture"]["data"]
        .as_str()
        .unwrap()
        .starts_with("data:image/png;base64,"));
    std::fs::write(dir.path().join("q.json"), doc.to_string()).unwrap();
    let got = quadrant_means(&render(&dir.path().join("q.json"), 16));
    assert_close("OBJ map_Kd", got, texel_linear(), 0.02);
}

/// A glTF 2.0 file with one textured square (buffers and the PNG as data URIs), a camera
/// at (0, 0, 3) and no light; UV (0, 0) is the image's top-left corner in glTF.
fn gltf_square() -> String {
    let mut bin = Vec::new();
    let positions: [[f32; 3]; 4] = [[-1., 1., 0.], [1., 1., 0.], [1., -1., 0.], [-1., -1., 0.]];
    let uvs: [[f32; 2]; 4] = [[0., 0.], [1., 0.], [1., 1.], [0., 1.]];
    for p in positions {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in uvs {
        for c in t {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in [0u16, 3, 2, 0, 2, 1] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let b64 = |b: &[u8]| base64::engine::general_purpose::STANDARD.encode(b);
    let png = encoded(image::ImageFormat::Png);
    let yfov = FOV_Y_DEG.to_radians();
    format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0, 1]}}],
  "nodes": [{{"mesh": 0}}, {{"camera": 0, "translation": [0, 0, 3]}}],
  "cameras": [{{"type": "perspective", "perspective": {{"yfov": {yfov}, "aspectRatio": 1.0, "znear": 0.1}}}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "TEXCOORD_0": 1}}, "indices": 2, "material": 0}}]}}],
  "materials": [{{"pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}, "metallicFactor": 0.0, "roughnessFactor": 1.0}}}}],
  "textures": [{{"source": 0, "sampler": 0}}],
  "samplers": [{{"wrapS": 33071, "wrapT": 33071}}],
  "images": [{{"uri": "data:image/png;base64,{png}"}}],
  "buffers": [{{"byteLength": {len}, "uri": "data:application/octet-stream;base64,{bin}"}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": 48}},
    {{"buffer": 0, "byteOffset": 48, "byteLength": 32}},
    {{"buffer": 0, "byteOffset": 80, "byteLength": 12}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"}},
    {{"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}}
  ]
}}"#,
        png = b64(&png),
        len = bin.len(),
        bin = b64(&bin),
    )
}

#[test]
fn gltf_base_colour_texture_renders_like_constant_squares_of_its_texels() {
    let dir = tempfile::tempdir().unwrap();
    let gltf = dir.path().join("square.gltf");
    std::fs::write(&gltf, gltf_square()).unwrap();
    let textured = quadrant_means(&render(&gltf, 32));
    // The same picture as a Glimpse document: four squares, one per quadrant, each with
    // its texel's colour as a constant base colour, under the environment the import adds.
    let lin = texel_linear();
    let corners = [[-1.0, 0.0], [0.0, 0.0], [-1.0, -1.0], [0.0, -1.0]];
    let mut materials = serde_json::Map::new();
    let mut objects = Vec::new();
    for q in 0..4 {
        materials.insert(
            format!("q{q}"),
            serde_json::json!({"type": "metallic_roughness", "base_color": lin[q],
                               "metallic": 0.0, "roughness": 1.0}),
        );
        objects.push(
            serde_json::json!({"type": "quad", "corner": [corners[q][0], corners[q][1], 0.0],
            "edge_u": [1, 0, 0], "edge_v": [0, 1, 0], "material": format!("q{q}")}),
        );
    }
    let doc = serde_json::json!({
        "version": 1,
        "image": {"width": 64, "height": 64},
        "camera": {"position": [0, 0, 3], "look_at": [0, 0, 0], "fov_y": FOV_Y_DEG},
        "materials": materials,
        "objects": objects,
        "lights": [{"type": "environment", "radiance": [1, 1, 1]}],
    });
    let json = dir.path().join("squares.json");
    std::fs::write(&json, doc.to_string()).unwrap();
    let constant = quadrant_means(&render(&json, 32));
    assert_close("glTF texture vs constant squares", textured, constant, 0.02);
    // And the picture is the texture's: each quadrant's dominant channel is its texel's.
    for (q, c) in textured.iter().enumerate().take(3) {
        let top = (0..3).max_by(|&a, &b| c[a].total_cmp(&c[b])).unwrap();
        assert_eq!(top, q, "quadrant {q}: {c:?}");
    }
}
