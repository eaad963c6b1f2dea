use super::*;
use serde_json::json;
use serde_json::Value;

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
                v["lights"] = json!([{"type":"point","position":[-5e12,0,0],"intensity":[1,1,1]}]);
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
            with(|v| v["render"]["sampler"] = json!("halton")),
            "render.sampler",
        ),
        (
            with(|v| v["render"]["sampler"] = json!(1)),
            "render.sampler",
        ),
        (
            with(|v| {
                v["objects"][0] =
                    json!({"type":"mesh","positions":[[0,0,0]],"indices":[[0,0,-1]],"material":"m"})
            }),
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

/// Long on purpose: one table row per rule of scene-format.md, read as a list.
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
                v["materials"]["m"] = json!({"type": "glossy", "albedo": [1,1,1], "roughness": 1.5})
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
                v["objects"][0] = json!({"type":"box","min":[0,0,0],"max":[1,0,1],"material":"m"})
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
                v["lights"] =
                    json!([{"type": "directional", "direction": [0,0,0], "irradiance": [1,1,1]}])
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
        v["objects"][0]["transform"] = json!({"scale": -2, "rotate_z": 90, "translate": [0, 0, 1]});
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

#[test]
fn render_sampler_is_independent_unless_sobol_is_asked_for() {
    use crate::scene::SamplerKind;
    assert_eq!(
        parse(&base()).unwrap().render.sampler,
        SamplerKind::Independent
    );
    for (name, kind) in [
        ("sobol", SamplerKind::Sobol),
        ("zsobol", SamplerKind::ZSobol),
        ("independent", SamplerKind::Independent),
    ] {
        let s = parse(&with(|v| v["render"] = json!({"sampler": name}))).unwrap();
        assert_eq!(s.render.sampler, kind);
        assert_eq!(kind.as_str(), name);
    }
    let (_, _, msg) = refused(&with(|v| v["render"]["sampler"] = json!("Sobol")).to_string());
    assert!(
        msg.contains("independent") && msg.contains("sobol") && msg.contains("zsobol"),
        "{msg}"
    );
}

/// An object whose `type` comes first is read as it streams, one whose `type` comes later
/// whole: both give the same scene, and their errors the same paths.
#[test]
fn an_objects_type_first_or_last_reads_alike() {
    let mesh = r#"{"type": "mesh", "positions": [[0,0,0],[1,0,0],[0,1,0]], "indices": [[0,1,2]], "material": "m"}"#;
    let last = r#"{"positions": [[0,0,0],[1,0,0],[0,1,0]], "indices": [[0,1,2]], "material": "m", "type": "mesh"}"#;
    let doc = |object: &str| {
        let mut v = base();
        v["objects"] = serde_json::from_str(&format!("[{object}]")).unwrap();
        v.to_string()
    };
    let first = parse_scene(&doc(mesh), &SceneOrigin::Request, &limits()).unwrap();
    let later = parse_scene(&doc(last), &SceneOrigin::Request, &limits()).unwrap();
    assert_eq!(first.triangle_count(), 1);
    assert_eq!(first.triangle_count(), later.triangle_count());
    for object in [mesh, last] {
        let bad = object.replace("[1,0,0]", "[1,\"x\",0]");
        let (k, p, m) = refused(&doc(&bad));
        assert_eq!(
            (k, p.as_str()),
            (SceneErrorKind::InvalidScene, "objects[0].positions[1][1]"),
            "{m}"
        );
        assert!(!m.contains(" at line "), "{m}");
        let unknown = object.replace("\"material\"", "\"colour\": 1, \"material\"");
        let (_, p, m) = refused(&doc(&unknown));
        assert_eq!(p, "objects[0].colour", "{m}");
    }
    let (_, p, m) = refused(&doc(&mesh.replace("\"mesh\"", "\"blob\"")));
    assert_eq!(p, "objects[0].type", "{m}");
    assert!(m.contains("unknown object type `blob`"), "{m}");
}
