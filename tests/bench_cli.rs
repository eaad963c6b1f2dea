//! `glimpse bench` end to end on one tiny scene: the study runs every method, writes its
//! report, raw numbers and plot, and checks the study's targets on what it measured; and on
//! a two-scene generated corpus, judged against its cached truth.

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
    // Quick mode sweeps three t0 at one condition; every point has a positive, finite Q.
    let sweep = scene["sweep"].as_array().unwrap();
    assert_eq!(sweep.len(), 3);
    for p in sweep {
        assert_eq!(p["ppd"], 28.0, "{p}");
        assert!(
            positive_finite(&p["q"]) && positive_finite(&p["time_ratio"]),
            "{p}"
        );
    }
    // The judge against the truth at quick mode's two conditions.
    let conditions = scene["conditions"].as_array().unwrap();
    let ppds: Vec<f64> = conditions
        .iter()
        .map(|c| c["ppd"].as_f64().unwrap())
        .collect();
    assert_eq!(ppds, [28.0, 60.0]);
    for c in conditions {
        check_condition(c, &out);
    }
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
    // The report opens with the summary against the targets, and links the sheets.
    assert!(report.contains("## Summary against the targets"));
    // First a sentence in plain words, then the words the tables use; the exact judge last.
    assert!(
        report.contains("In short: on ")
            && report.contains("bundled scene and viewing-distance pairs")
    );
    let words = report.find("Words used below").expect("the words");
    let judge = report
        .find("## How it is judged, exactly")
        .expect("the judge");
    assert!(words < report.find("### tiny").unwrap() && judge > report.find("### tiny").unwrap());
    assert!(report.contains("bundled scenes at 60 ppd: Q ≤ 1 at ≤ 0.5× time"));
    assert!(report.contains("(sheets/tiny-60ppd.png)"));
    assert!(report.contains("| ppd | Q (FLIP vs truth"));
    let summary = results["summary"].as_array().unwrap();
    assert!(summary.iter().any(|t| t["target"]
        .as_str()
        .unwrap()
        .contains("objects keep their colour")));
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

fn positive_finite(v: &Value) -> bool {
    v.as_f64().is_some_and(|x| x.is_finite() && x > 0.0)
}

/// One scene at one condition: Q, time and FLIPs sane, objects judged with sane
/// allowances, the contact sheet a PNG of four panels.
fn check_condition(c: &Value, out: &std::path::Path) {
    for k in [
        "q",
        "time_ratio",
        "progressive_flip",
        "reference_flip",
        "floor_ratio",
    ] {
        assert!(positive_finite(&c[k]), "{k}: {c}");
    }
    let q = c["q"].as_f64().unwrap();
    let (p, r) = (
        c["progressive_flip"].as_f64().unwrap(),
        c["reference_flip"].as_f64().unwrap(),
    );
    assert!((q - p / r).abs() < 1e-9, "{c}");
    let worst = c["worst_object_ratio"].as_f64().unwrap();
    assert!(worst.is_finite() && worst >= 0.0, "{c}");
    for o in c["objects"].as_array().unwrap() {
        assert!(o["coverage"].as_f64().unwrap() >= 0.005, "{o}");
        assert!(o["allowed"].as_f64().unwrap() >= 0.06, "{o}");
        let ratio = o["progressive_error"].as_f64().unwrap() / o["allowed"].as_f64().unwrap();
        assert!(ratio <= worst + 1e-12, "{o} vs worst {worst}");
    }
    let sheet = out.join(c["sheet"].as_str().unwrap());
    let img = glimpse::raster::decode_image(&std::fs::read(&sheet).unwrap()).unwrap();
    // Four panels of the render's size (enlarged by a whole factor) and three 4-pixel gaps.
    assert!(
        img.height() > 0 && img.width() > 12 && (img.width() - 12).is_multiple_of(4),
        "{}",
        sheet.display()
    );
}

#[test]
fn bench_judges_a_generated_corpus_against_a_cached_truth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let bench = || {
        let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
            .args([
                "bench",
                "--quick",
                "--corpus",
                "2",
                "--seed",
                "11",
                "--corpus-only",
                "--out",
            ])
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    bench();
    let cache = || {
        let mut files: Vec<_> = std::fs::read_dir(out.join("cache"))
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (e.file_name(), e.metadata().unwrap().modified().unwrap())
            })
            .collect();
        files.sort();
        files
    };
    let first = cache();
    // Each truth is two halves or more (its chunks), each cached.
    assert!(first.len() >= 4 && first.len() % 2 == 0, "{first:?}");

    let results: Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    assert!(
        results["scenes"].as_array().unwrap().is_empty(),
        "--corpus-only"
    );
    let corpus = results["corpus"].as_array().unwrap();
    assert_eq!(corpus.len(), 2);
    for r in corpus {
        // The document is written where the report says, and validates as it stands.
        let doc = std::fs::read_to_string(out.join(r["file"].as_str().unwrap())).unwrap();
        let scene = glimpse::scene::parse_scene(
            &doc,
            &glimpse::scene::SceneOrigin::Request,
            &glimpse::scene::Limits::command_line(),
        )
        .unwrap();
        let ppd = r["declared_ppd"].as_f64().unwrap();
        assert_eq!(ppd, f64::from(scene.display.pixels_per_degree));
        assert!((20.0..=100.0).contains(&ppd));
        let truth_spp = r["truth"]["spp"].as_u64().unwrap();
        assert!(
            truth_spp >= 16 * u64::from(scene.render.samples_per_pixel),
            "{r}"
        );
        let conditions = r["conditions"].as_array().unwrap();
        assert_eq!(conditions.len(), 1, "the declared condition only");
        let own = conditions[0]["truth_self_flip"].as_f64().unwrap();
        assert!(own > 0.0 && own.is_finite(), "{r}");
        assert_eq!(conditions[0]["ppd"].as_f64().unwrap(), ppd);
        check_condition(&conditions[0], &out);
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("`glimpse bench --quick --corpus 2 --seed 11 --corpus-only`"));
    assert!(report.contains("## Corpus (2 generated scenes"));
    assert!(report.contains("median corpus time (declared ppd)"));
    assert!(report.contains("| truth self-error (÷ reference's) |"));
    assert!(report.contains("median adaptive ÷ uniform + OIDN"));
    assert!(
        report.contains("In short: on ")
            && report.contains("generated scenes (at their own viewing distance)")
    );

    // A second run reads both truths from the cache: no file is written again.
    bench();
    assert_eq!(cache(), first);
}

#[test]
fn bench_refuses_a_bad_ppd_and_corpus_flags_without_a_corpus() {
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
            .arg("bench")
            .args(args)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{args:?}");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = run(&["--ppd", "28,-60"]);
    assert!(e.contains("--ppd") && e.contains("-60"), "{e}");
    let e = run(&["--ppd", "NaN"]);
    assert!(e.contains("--ppd"), "{e}");
    let e = run(&["--corpus-profile", "users"]);
    assert!(e.contains("--corpus"), "{e}");
    let e = run(&["--corpus", "1", "--corpus-profile", "huge"]);
    assert!(e.contains("--corpus-profile") && e.contains("users"), "{e}");
    let e = run(&["--truth-cap", "0"]);
    assert!(e.contains("--truth-cap"), "{e}");
    let e = run(&["--corpus-only"]);
    assert!(e.contains("--corpus"), "{e}");
    let e = run(&["--corpus", "0"]);
    assert!(e.contains("--corpus"), "{e}");
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
