//! Mutation fuzzing of scene documents, end to end: the bundled scenes with 1–4 of their
//! numbers replaced by extreme values (0, ±1, ±1e30, 3.4e38, 1e-45, 1e9...), keys deleted
//! or values of the wrong type. Each document must either be refused with an explained error,
//! or be accepted and then render (BVH build, tracer, the progressive loop, Guo) without a
//! panic and without NaN in the picture. This is how the ±1e9 coordinate range
//! (`scene::MAX_COORDINATE`) was found: a sphere of radius 1e30 passed validation and
//! `obvhs` panicked building its BVH.
//!
//! Deterministic (seeded); a failure prints the seed, the scene and the mutations. CI runs
//! [`CASES`] of them; `GLIMPSE_FUZZ_CASES=20000 cargo test --release --test scene_fuzz`
//! runs more (seeds from 0, so the CI cases are among them).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;

use glimpse::cancel::CancelToken;
use glimpse::progressive::{self, RenderOptions};
use glimpse::scene::{parse_scene, Limits, RenderMode, SceneOrigin};
use glimpse::tracer::PathTracer;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde_json::{json, Value};

/// Cases in CI (~6 s in the dev profile).
const CASES: u64 = 600;

/// Values that broke, or could break, something downstream of validation.
const EXTREMES: [f64; 16] = [
    0.0,
    -0.0,
    1.0,
    -1.0,
    0.5,
    2.0,
    1e-45,
    1e-30,
    -1e-30,
    1e9,
    -1e9,
    1e30,
    -1e30,
    3.4e38,
    1e6,
    4294967296.0,
];

/// A 2×2 PNG as a `data:` URI (an image texture's `data`).
fn png_uri() -> String {
    use base64::Engine as _;
    let img = image::RgbImage::from_raw(
        2,
        2,
        vec![200, 40, 40, 40, 200, 40, 40, 40, 200, 230, 230, 230],
    )
    .unwrap();
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    )
}

/// Every type the scene format has (scene-format.md "Fields", and the import extensions:
/// image textures, mesh uvs, coated diffuse, metallic-roughness, spot lights), so that
/// fields no bundled scene uses (glass, mirror, point and directional lights, mesh
/// normals, per-axis scale, rotations, t1) are mutated too.
fn every_type() -> Value {
    let png = png_uri();
    json!({
        "version": 1,
        "name": "every-type",
        "image": { "width": 12, "height": 9 },
        "camera": { "position": [0, 1.5, 6], "look_at": [0, 1, 0], "up": [0, 1, 0], "fov_y": 45 },
        "display": { "peak_luminance": 100, "black_luminance": 0.5, "exposure": 1.0,
                     "pixels_per_degree": 28 },
        "materials": {
            "white": { "type": "diffuse", "albedo": [0.7, 0.7, 0.7] },
            "checker": { "type": "diffuse",
                         "texture": { "type": "checker", "scale": 0.5, "a": [0.9, 0.9, 0.9], "b": [0.1, 0.1, 0.1] } },
            "noise": { "type": "diffuse",
                       "texture": { "type": "noise", "scale": 0.3, "a": [0.8, 0.2, 0.2], "b": [0.2, 0.2, 0.8] } },
            "glossy": { "type": "glossy", "albedo": [0.8, 0.8, 0.8], "roughness": 0.3 },
            "mirror": { "type": "mirror", "reflectance": [0.95, 0.95, 0.95] },
            "glass": { "type": "dielectric", "ior": 1.5, "tint": [1, 0.9, 0.9] },
            "lamp": { "type": "emissive", "radiance": [8, 8, 8], "two_sided": true },
            "picture": { "type": "diffuse",
                         "texture": { "type": "image", "data": png, "encoding": "srgb", "wrap": "mirror",
                                      "uv_scale": [2, 2], "uv_offset": [0.1, 0], "factor": [1, 0.9, 0.9] } },
            "coat": { "type": "coated_diffuse", "roughness": 0.2, "ior": 1.5,
                      "texture": { "type": "image", "data": png, "encoding": "linear", "wrap": "clamp" } },
            "plastic": { "type": "metallic_roughness", "base_color": [0.5, 0.5, 0.5], "metallic": 0.3,
                         "roughness": 0.4, "texture": { "type": "image", "data": png } }
        },
        "objects": [
            { "type": "sphere", "center": [-1, 0.5, 0], "radius": 0.5, "material": "glass" },
            { "type": "sphere", "center": [1, 0.5, 0], "radius": 0.5, "material": "mirror",
              "transform": { "scale": 1.2, "rotate_x": 10 } },
            { "type": "quad", "corner": [-3, 0, -3], "edge_u": [0, 0, 6], "edge_v": [6, 0, 0],
              "material": "checker" },
            { "type": "quad", "corner": [-0.5, 2.9, -0.5], "edge_u": [1, 0, 0], "edge_v": [0, 0, 1],
              "material": "lamp" },
            { "type": "box", "min": [-0.4, 0, -0.4], "max": [0.4, 0.8, 0.4], "material": "glossy",
              "transform": { "translate": [0, 0, -1.5], "rotate_y": 30, "rotate_z": 5,
                             "scale": [1, 1.5, 1] } },
            { "type": "mesh", "positions": [[-3, 0, -3], [3, 0, -3], [0, 3, -3]],
              "normals": [[0, 0, 1], [0, 0, 1], [0, 0.1, 1]], "indices": [[0, 1, 2]],
              "material": "noise" },
            { "type": "mesh", "positions": [[-3, 0, -2], [3, 0, -2], [0, 3, -2]],
              "uvs": [[0, 1], [1, 1], [0.5, 0]], "indices": [[0, 1, 2]], "material": "picture" },
            { "type": "sphere", "center": [0, 2, 1], "radius": 0.3, "material": "coat" },
            { "type": "quad", "corner": [2, 0, -1], "edge_u": [0, 1, 0], "edge_v": [0, 0, 1],
              "material": "plastic" }
        ],
        "lights": [
            { "type": "point", "position": [2, 3, 2], "intensity": [20, 20, 20] },
            { "type": "directional", "direction": [0.3, -1, -0.2], "irradiance": [1, 1, 1] },
            { "type": "environment", "radiance": [0.1, 0.1, 0.12] },
            { "type": "spot", "position": [0, 2.8, 0], "direction": [0, -1, 0.1], "intensity": [10, 10, 10],
              "outer_angle": 40, "inner_angle": 25, "falloff": "squared_linear" }
        ],
        "render": { "mode": "progressive", "samples_per_pixel": 2, "max_bounces": 5, "seed": 3 },
        "progressive": { "t0": 1.0, "t1": 4.0, "initial_rate": 0.05, "homogeneity": 0.8,
                         "epsilon": 1.0, "max_iterations": 16 }
    })
}

/// The JSON pointer (RFC 6901) of every node of `v` but the root.
fn pointers(v: &Value, at: &str, out: &mut Vec<String>) {
    let mut visit = |key: &str, child: &Value| {
        let p = format!("{at}/{}", key.replace('~', "~0").replace('/', "~1"));
        out.push(p.clone());
        pointers(child, &p, out);
    };
    match v {
        Value::Object(m) => m.iter().for_each(|(k, c)| visit(k, c)),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, c)| visit(&i.to_string(), c)),
        _ => {}
    }
}

/// Applies one random mutation; returns what it did (for the failure message).
fn mutate(doc: &mut Value, rng: &mut Pcg64Mcg) -> String {
    let mut all = Vec::new();
    pointers(doc, "", &mut all);
    // Three mutations in four change a number: a structural change is mostly refused at
    // once, and what gets past validation is what this test is for.
    let numbers: Vec<&String> = all
        .iter()
        .filter(|p| doc.pointer(p).is_some_and(Value::is_number))
        .collect();
    let path = if !numbers.is_empty() && rng.random_bool(0.75) {
        numbers[rng.random_range(0..numbers.len())].clone()
    } else {
        all[rng.random_range(0..all.len())].clone()
    };
    let Some(target) = doc.pointer_mut(&path) else {
        return String::new();
    };
    if target.is_number() {
        let v = EXTREMES[rng.random_range(0..EXTREMES.len())];
        *target = json!(v);
        return format!("{path} = {v:e}");
    }
    let (replacement, shown) = match rng.random_range(0..4) {
        0 => {
            // Delete the key or array element.
            let (parent, last) = path.rsplit_once('/').expect("not the root");
            match doc.pointer_mut(parent) {
                Some(Value::Object(m)) => {
                    m.remove(&last.replace("~1", "/").replace("~0", "~"));
                }
                Some(Value::Array(a)) => {
                    if let Some(i) = last.parse::<usize>().ok().filter(|&i| i < a.len()) {
                        a.remove(i);
                    }
                }
                _ => {}
            }
            return format!("{path} deleted");
        }
        1 => (json!(null), "null"),
        2 => (json!([]), "[]"),
        _ => (json!("x"), "\"x\""),
    };
    *target = replacement;
    format!("{path} = {shown}")
}

#[test]
fn mutated_scenes_are_refused_with_an_explanation_or_render_without_panic_or_nan() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut bases: Vec<(String, Value)> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .map(|p| {
            let v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
            (p.file_name().unwrap().to_string_lossy().into_owned(), v)
        })
        .collect();
    bases.sort_by(|a, b| a.0.cmp(&b.0));
    assert!(bases.len() >= 3);
    bases.push(("every-type".into(), every_type()));
    // Tiny renders: the limits refuse any mutation that would make a case expensive.
    let limits = Limits {
        max_width: 64,
        max_height: 64,
        max_pixels: 1024,
        max_sample_budget: 4096,
        max_objects: 100,
        max_triangles: 100_000,
        max_samples_per_pixel: 4,
        max_bounces: 8,
    };
    // Unmutated, every base renders within those limits (else its mutations test little).
    for (name, base) in &bases {
        let mut doc = base.clone();
        doc["image"] = json!({ "width": 12, "height": 9 });
        doc["render"]["samples_per_pixel"] = json!(2);
        let origin = SceneOrigin::File { dir: dir.clone() };
        if let Err(e) = parse_scene(&doc.to_string(), &origin, &limits) {
            panic!("{name} unmutated is refused: {e}");
        }
    }
    let cases = std::env::var("GLIMPSE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(CASES);
    let (mut accepted, mut refused) = (0, 0);
    for seed in 0..cases {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let (name, base) = &bases[rng.random_range(0..bases.len())];
        let mut doc = base.clone();
        doc["image"] = json!({ "width": 12, "height": 9 });
        doc["render"]["samples_per_pixel"] = json!(2);
        let what: Vec<String> = (0..rng.random_range(1..=4))
            .map(|_| mutate(&mut doc, &mut rng))
            .collect();
        let case = format!("seed {seed}, {name}, mutations {what:?}");
        let origin = SceneOrigin::File { dir: dir.clone() };
        let parsed = catch_unwind(|| parse_scene(&doc.to_string(), &origin, &limits));
        let scene = match parsed {
            Err(_) => panic!("{case}: validation panicked"),
            Ok(Err(e)) => {
                refused += 1;
                assert!(
                    e.problems.iter().all(|p| !p.message.is_empty()),
                    "{case}: an unexplained refusal {e}"
                );
                continue;
            }
            Ok(Ok(s)) => s,
        };
        accepted += 1;
        for mode in [RenderMode::Progressive, RenderMode::Guo] {
            let r = catch_unwind(AssertUnwindSafe(|| {
                let tracer = PathTracer::new(&scene);
                let opts = RenderOptions {
                    mode: Some(mode),
                    ..RenderOptions::default()
                };
                progressive::render(&scene, &tracer, &opts, &mut |_| {}, &CancelToken::new())
            }));
            match r {
                Err(_) => panic!("{case}: {mode:?} render panicked"),
                Ok(Err(_)) => panic!("{case}: cancelled without a cancel"),
                Ok(Ok(frame)) => assert!(
                    frame.image.pixels().iter().all(|p| !p.is_nan()),
                    "{case}: NaN in the {mode:?} picture"
                ),
            }
        }
    }
    eprintln!("{cases} mutated scenes: {accepted} accepted and rendered, {refused} refused");
    // Both outcomes are exercised (a fuzzer whose every case is refused tests nothing).
    assert!(
        accepted >= cases / 5 && refused >= cases / 5,
        "{accepted} accepted, {refused} refused"
    );
}

/// Seed 809 (`GLIMPSE_FUZZ_CASES=4000`): spheres-rough with its lamp's red radiance at
/// 3.4e38 rendered NaN in the progressive picture. Now refused naming the field and the
/// limit; at the limit itself (`MAX_EMISSION`) the same scene renders in both modes
/// without NaN.
#[test]
fn a_lamp_at_the_emission_limit_renders_without_nan_and_beyond_it_is_refused() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let text = std::fs::read_to_string(dir.join("spheres-rough.json")).unwrap();
    let mut doc: Value = serde_json::from_str(&text).unwrap();
    doc["image"] = json!({ "width": 12, "height": 9 });
    doc["render"]["samples_per_pixel"] = json!(2);
    doc["objects"][2]["radius"] = json!(2.0);
    doc["objects"][3]["center"][1] = json!(1.0);
    doc["objects"][2]["center"][2] = json!(-0.0);
    let origin = SceneOrigin::File { dir: dir.clone() };
    let limits = Limits::command_line();

    doc["materials"]["lamp"]["radiance"][0] = json!(3.4e38);
    let e = parse_scene(&doc.to_string(), &origin, &limits).expect_err("3.4e38 is refused");
    assert!(
        e.problems
            .iter()
            .any(|p| p.path == "materials.lamp.radiance[0]" && p.message.contains("at most 1e12")),
        "{e}"
    );

    doc["materials"]["lamp"]["radiance"][0] = json!(glimpse::scene::MAX_EMISSION);
    let scene = parse_scene(&doc.to_string(), &origin, &limits).expect("the limit is accepted");
    for mode in [RenderMode::Progressive, RenderMode::Guo] {
        let tracer = PathTracer::new(&scene);
        let opts = RenderOptions {
            mode: Some(mode),
            ..RenderOptions::default()
        };
        let frame =
            progressive::render(&scene, &tracer, &opts, &mut |_| {}, &CancelToken::new()).unwrap();
        let px = frame.image.pixels();
        assert!(
            px.iter().all(|p| p.is_finite()),
            "{mode:?}: a non-finite pixel"
        );
        // The lamp is seen: the limit is reached, not clamped away.
        let max = px.iter().map(|p| p.x).fold(0.0f32, f32::max);
        assert!(max > 1e11, "{mode:?}: brightest red {max:e}");
    }
}
