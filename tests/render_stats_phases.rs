//! `glimpse render --stats` reports the command's phases (load, build, render, samples
//! per second) and the process's memory beside the render's own statistics, on a small
//! generated glTF file read from the working folder by its bare name.

use base64::Engine as _;
use serde_json::Value;
use std::process::Command;

/// A glTF 2.0 grid of `n`×`n` quads (2n² triangles) in the plane z = 0, facing a camera
/// at z = 3, lit by a directional light, its buffer inline as a data URI.
fn grid_gltf(n: u32) -> String {
    let mut bin = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            let p = [x as f32 / n as f32 - 0.5, y as f32 / n as f32 - 0.5, 0.0f32];
            p.iter().for_each(|c| bin.extend(c.to_le_bytes()));
        }
    }
    let vertices = (n + 1) * (n + 1);
    let positions_len = bin.len();
    for y in 0..n {
        for x in 0..n {
            let a = y * (n + 1) + x;
            for i in [a, a + 1, a + n + 2, a, a + n + 2, a + n + 1] {
                bin.extend(i.to_le_bytes());
            }
        }
    }
    let data = base64::engine::general_purpose::STANDARD.encode(&bin);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1,2]}}],
  "extensionsUsed":["KHR_lights_punctual"],
  "extensions":{{"KHR_lights_punctual":{{"lights":[{{"type":"directional","intensity":2}}]}}}},
  "nodes":[{{"mesh":0}},{{"camera":0,"translation":[0,0,3]}},
           {{"extensions":{{"KHR_lights_punctual":{{"light":0}}}}}}],
  "cameras":[{{"type":"perspective","perspective":{{"yfov":0.6,"aspectRatio":1.333,"znear":0.1}}}}],
  "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}}]}}],
  "materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[0.8,0.8,0.8,1],"metallicFactor":0}}}}],
  "accessors":[
    {{"bufferView":0,"componentType":5126,"count":{vertices},"type":"VEC3","min":[-0.5,-0.5,0],"max":[0.5,0.5,0]}},
    {{"bufferView":1,"componentType":5125,"count":{indices},"type":"SCALAR"}}],
  "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{positions_len}}},
                 {{"buffer":0,"byteOffset":{positions_len},"byteLength":{index_len}}}],
  "buffers":[{{"byteLength":{total},"uri":"data:application/octet-stream;base64,{data}"}}]}}"#,
        indices = 6 * n * n,
        index_len = bin.len() - positions_len,
        total = bin.len(),
    )
}

#[test]
fn render_stats_report_each_phase_and_the_memory() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("grid.gltf"), grid_gltf(40)).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .current_dir(dir.path())
        .args([
            "render",
            "grid.gltf",
            "--output",
            "out.png",
            "--stats",
            "stats.json",
        ])
        .args([
            "--mode",
            "reference",
            "--spp",
            "3",
            "--size",
            "32x24",
            "--no-denoise",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.path().join("stats.json")).unwrap();
    let v: Value = serde_json::from_str(&text).unwrap();
    // The render's own fields stay where they were.
    assert_eq!(v["width"], 32);
    assert_eq!(v["pixels_traced"], 32 * 24);
    let p = &v["phases"];
    for k in ["load_ms", "build_ms", "render_ms", "samples_per_second"] {
        let x = p[k].as_f64().unwrap_or(-1.0);
        assert!(x > 0.0 && x.is_finite(), "{k} = {}", p[k]);
    }
    assert_eq!(p["samples"], 32 * 24 * 3);
    assert_eq!(p["primitives"], 2 * 40 * 40);
    let rate = p["samples"].as_f64().unwrap() / (p["render_ms"].as_f64().unwrap() / 1e3);
    assert!((p["samples_per_second"].as_f64().unwrap() / rate - 1.0).abs() < 1e-9);
    let m = &p["memory"];
    let bytes = |k: &str| m[k].as_u64().unwrap_or_else(|| panic!("{k} = {}", m[k]));
    for k in ["loaded_bytes", "built_bytes", "final_bytes"] {
        // More than a megabyte (the binary alone maps more), at most the peak.
        assert!(bytes(k) > 1 << 20 && bytes(k) <= bytes("peak_bytes"), "{m}");
    }
    assert!(bytes("load_peak_bytes") <= bytes("peak_bytes"), "{m}");
}
