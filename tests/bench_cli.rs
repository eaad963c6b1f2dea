//! `glimpse bench` end to end on one tiny scene: the study runs every method, writes its
//! report, raw numbers and plot, and checks the targets on what it measured.

use serde_json::Value;
use std::process::Command;

mod common;

use common::LIT_SCENE as TINY;

#[test]
fn bench_writes_report_results_and_plot_for_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    std::fs::create_dir(&scenes).unwrap();
    std::fs::write(scenes.join("tiny.json"), TINY).unwrap();
    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .args(["bench", "--quick", "--spp-factor", "2", "--scenes"])
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
    // The tiny scene is written at 4 spp; every render of the study used twice that.
    assert_eq!(scene["spp"], 8, "--spp-factor 2 applied");
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
    // The time split: the traced pixels alone cost a positive share of the reference, at
    // most what a pixel fraction times a sane per-pixel cost allows, and the rest is the loop.
    let split = &scene["time_split"];
    let alone = split["traced_alone_ratio"].as_f64().unwrap();
    let cost = split["pixel_cost_ratio"].as_f64().unwrap();
    let prog = scene["methods"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["method"] == "progressive")
        .unwrap();
    let frac = prog["pixel_fraction"].as_f64().unwrap();
    assert!(alone > 0.0 && cost > 0.0, "{split}");
    assert!(
        (alone - frac * cost).abs() < 1e-9,
        "{split}: ratio = fraction × cost"
    );
    let total = prog["time_ratio"].as_f64().unwrap();
    let loop_ratio = split["loop_ratio"].as_f64().unwrap();
    assert!(
        (alone + loop_ratio - total).abs() < 1e-9,
        "{split}: the parts sum to the whole"
    );
    // The run's timed parts never exceed its total: "the rest" (total − trace − analysis −
    // metric − triangulation) is not negative unless a part is counted twice.
    for part in ["analysis_ms", "metric_ms", "triangulate_ms", "other_ms"] {
        assert!(
            split["loop_parts"][part].as_f64().unwrap() >= 0.0,
            "{split}"
        );
    }

    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("### tiny") && report.contains("| target | met | measured |"));
    assert!(report.contains("`glimpse bench --quick --spp-factor 2`"));
    assert!(
        report.contains("8 spp"),
        "the scene header shows the samples used"
    );
    assert!(report.contains("Time split of the progressive run"));
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

#[test]
fn bench_refuses_an_spp_factor_out_of_range_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    std::fs::create_dir(&scenes).unwrap();
    std::fs::write(scenes.join("tiny.json"), TINY).unwrap();
    let bench = |factor: &str| {
        Command::new(env!("CARGO_BIN_EXE_glimpse"))
            .args(["bench", "--quick", "--spp-factor", factor, "--scenes"])
            .arg(&scenes)
            .arg("--out")
            .arg(dir.path().join("out"))
            .output()
            .unwrap()
    };
    // 0 is refused by the command line itself.
    let o = bench("0");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--spp-factor"), "{err}");
    // Within the flag's range, but the scaled scene is over the limits: 1000 spp × 4096 =
    // 4 096 000 samples per pixel, over the command line's 2^20.
    std::fs::write(
        scenes.join("tiny.json"),
        TINY.replace("\"samples_per_pixel\": 4", "\"samples_per_pixel\": 1000"),
    )
    .unwrap();
    let o = bench("4096");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("tiny.json") && err.contains("--spp-factor 4096") && err.contains("1000"),
        "{err}"
    );
}
