//! `glimpse bench` end to end on one tiny scene: the study runs every method, writes its
//! report, raw numbers and plot, and checks the issue's targets on what it measured.

use serde_json::Value;
use std::process::Command;

const TINY: &str = r#"{
  "version": 1, "name": "tiny",
  "image": { "width": 40, "height": 30 },
  "camera": { "position": [0, 1, 4], "look_at": [0, 0.5, 0], "fov_y": 45 },
  "materials": {
    "floor": { "type": "diffuse", "texture": { "type": "checker", "scale": 0.5,
               "a": [0.8, 0.8, 0.8], "b": [0.1, 0.1, 0.1] } },
    "ball": { "type": "diffuse", "albedo": [0.7, 0.3, 0.2] },
    "lamp": { "type": "emissive", "radiance": [8, 8, 8] }
  },
  "objects": [
    { "type": "quad", "corner": [-3, 0, 3], "edge_u": [6, 0, 0], "edge_v": [0, 0, -6],
      "material": "floor" },
    { "type": "sphere", "center": [0, 0.5, 0], "radius": 0.5, "material": "ball" },
    { "type": "quad", "corner": [-0.5, 2.5, -0.5], "edge_u": [1, 0, 0], "edge_v": [0, 0, 1],
      "material": "lamp" }
  ],
  "render": { "mode": "progressive", "samples_per_pixel": 4, "max_bounces": 2, "seed": 3 }
}"#;

#[test]
fn bench_writes_report_results_and_plot_for_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    std::fs::create_dir(&scenes).unwrap();
    std::fs::write(scenes.join("tiny.json"), TINY).unwrap();
    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args(["bench", "--quick", "--scenes"])
        .arg(&scenes)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let results: Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    let scene = &results["scenes"][0];
    assert_eq!(scene["scene"], "tiny");
    let methods: Vec<&str> = scene["methods"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["method"].as_str().unwrap())
        .collect();
    for m in ["reference", "progressive", "guo", "uniform (equal time)"] {
        assert!(methods.contains(&m), "{m} missing from {methods:?}");
    }
    for m in scene["methods"].as_array().unwrap() {
        let flip = m["flip"]["mean"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&flip), "{m}");
        assert!(m["ms"].as_f64().unwrap() > 0.0, "{m}");
    }
    // Guo gets the progressive run's ray budget (noise twins included), never more.
    let px = |name: &str| {
        scene["methods"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["method"] == name)
            .unwrap()["pixels_traced"]
            .as_u64()
            .unwrap()
    };
    assert!(px("guo") <= px("progressive") + 40 * 30);
    assert_eq!(scene["sweep"].as_array().unwrap().len(), 3);
    assert!(!scene["targets"].as_array().unwrap().is_empty());

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("### tiny") && report.contains("| target | met | measured |"));
    let svg = std::fs::read_to_string(out.join("tradeoff.svg")).unwrap();
    assert!(svg.starts_with("<svg") || svg.contains("<svg"));
    for m in ["reference", "progressive", "guo", "uniform"] {
        assert!(out.join(format!("tiny-{m}.png")).exists(), "{m} image");
    }
}

#[test]
fn bench_on_a_missing_folder_is_one_clear_error() {
    let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args(["bench", "--scenes", "/nonexistent/glimpse-scenes", "--out"])
        .arg(std::env::temp_dir().join("glimpse-bench-none"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("cannot read scene folder"), "{err}");
}
