//! `glimpse render` end to end (cli.md): outputs, statistics, the speed/accuracy flags
//! (`--t0`, `--max-pixels`, `--max-time`) and one-line errors.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;

use common::{LIT_SCENE as SCENE, STATS_FIELDS};

const PIXELS: u64 = 40 * 30;

struct Dir {
    _tmp: tempfile::TempDir,
    path: PathBuf,
}

fn setup() -> Dir {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().to_path_buf();
    std::fs::write(path.join("scene.json"), SCENE).unwrap();
    Dir { _tmp: tmp, path }
}

fn glimpse(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .current_dir(dir)
        .arg("render")
        .arg("scene.json")
        .args(args)
        .output()
        .unwrap()
}

fn stats(dir: &Path, name: &str) -> Value {
    serde_json::from_slice(&std::fs::read(dir.join(name)).unwrap()).unwrap()
}

fn ok(o: &Output) {
    assert!(
        o.status.success(),
        "glimpse render failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn every_mode_writes_png_exr_stats_and_layers() {
    let d = setup();
    for mode in ["reference", "progressive", "guo"] {
        let (png, st) = (format!("{mode}.png"), format!("{mode}.json"));
        let o = glimpse(
            &d.path,
            &[
                "--output", &png, "--mode", mode, "--stats", &st, "--exr", "o.exr", "--layers",
                "layers",
            ],
        );
        ok(&o);
        let img = image::open(d.path.join(&png)).unwrap();
        assert_eq!((img.width(), img.height()), (40, 30));
        let s = stats(&d.path, &st);
        for key in STATS_FIELDS {
            assert!(s.get(key).is_some(), "{mode}: stats lack {key}: {s}");
        }
        assert_eq!(s["mode"], mode);
        let exr = image::open(d.path.join("o.exr")).unwrap();
        assert_eq!(exr.width(), 40);
        assert!(d.path.join("layers/samples.png").exists());
        // Each iteration before the last keeps its layers (the last is the folder's own).
        let iterations = s["iterations"].as_u64().unwrap();
        let first = d.path.join("layers/iterations/0000-image.png");
        assert_eq!(
            first.exists(),
            iterations > 1,
            "{mode}: {iterations} iterations"
        );
        let _ = std::fs::remove_dir_all(d.path.join("layers"));
    }
}

#[test]
fn t0_zero_is_the_reference_bit_for_bit() {
    let d = setup();
    ok(&glimpse(
        &d.path,
        &["--output", "r.png", "--mode", "reference", "--exr", "r.exr"],
    ));
    ok(&glimpse(
        &d.path,
        &[
            "--output", "p.png", "--t0", "0", "--exr", "p.exr", "--stats", "p.json",
        ],
    ));
    assert_eq!(
        std::fs::read(d.path.join("r.exr")).unwrap(),
        std::fs::read(d.path.join("p.exr")).unwrap(),
        "progressive with --t0 0 must trace every pixel exactly as the reference"
    );
    assert_eq!(stats(&d.path, "p.json")["pixels_traced"], PIXELS);
}

#[test]
fn a_scene_too_cheap_for_the_loop_is_traced_whole_and_says_so() {
    let d = setup();
    let free = SCENE.replace(r#""force_loop": true"#, r#""force_loop": false"#);
    assert_ne!(free, SCENE);
    std::fs::write(d.path.join("scene.json"), free).unwrap();
    ok(&glimpse(
        &d.path,
        &["--output", "r.png", "--mode", "reference", "--exr", "r.exr"],
    ));
    ok(&glimpse(
        &d.path,
        &["--output", "p.png", "--exr", "p.exr", "--stats", "p.json"],
    ));
    let s = stats(&d.path, "p.json");
    assert_eq!(s["stop_reason"], "reference_cheaper", "{s}");
    assert_eq!(
        (s["mode"].as_str(), s["iterations"].as_u64()),
        (Some("progressive"), Some(1))
    );
    assert_eq!(
        std::fs::read(d.path.join("r.exr")).unwrap(),
        std::fs::read(d.path.join("p.exr")).unwrap(),
        "traced whole, the picture is the reference's"
    );
}

#[test]
fn a_higher_t0_traces_fewer_pixels() {
    let d = setup();
    let traced = |t0: &str| {
        let st = format!("t{t0}.json");
        ok(&glimpse(
            &d.path,
            &["--output", "o.png", "--t0", t0, "--stats", &st],
        ));
        stats(&d.path, &st)["pixels_traced"].as_u64().unwrap()
    };
    let (strict, loose) = (traced("0.25"), traced("8"));
    assert!(
        loose < strict && strict <= PIXELS,
        "t0 8 traced {loose}, t0 0.25 traced {strict}"
    );
}

#[test]
fn pixel_budgets_stop_the_render_as_a_count_or_a_share() {
    let d = setup();
    for (flag, budget) in [("50", 50u64), ("10%", PIXELS.div_ceil(10))] {
        ok(&glimpse(
            &d.path,
            &[
                "--output",
                "o.png",
                "--t0",
                "0",
                "--max-pixels",
                flag,
                "--stats",
                "s.json",
            ],
        ));
        let s = stats(&d.path, "s.json");
        assert_eq!(s["pixels_traced"].as_u64(), Some(budget), "{flag}: {s}");
        assert_eq!(s["stop_reason"], "max_pixels", "{flag}");
        // The answer so far is still a whole picture.
        let img = image::open(d.path.join("o.png")).unwrap();
        assert_eq!(img.width(), 40);
    }
}

#[test]
fn a_time_budget_ends_the_render_early() {
    let d = setup();
    ok(&glimpse(
        &d.path,
        &[
            "--output",
            "o.png",
            "--t0",
            "0",
            "--max-time",
            "0.000001",
            "--stats",
            "s.json",
        ],
    ));
    let s = stats(&d.path, "s.json");
    assert_eq!(s["stop_reason"], "max_time", "{s}");
    assert!(s["pixels_traced"].as_u64().unwrap() < PIXELS);
}

#[test]
fn bad_flags_and_bad_scenes_are_one_clear_error() {
    let d = setup();
    for (args, needle) in [
        (vec!["--output", "o.png", "--t0=-1"], "t0"),
        (vec!["--output", "o.png", "--t0", "NaN"], "t0"),
        (
            vec!["--output", "o.png", "--max-pixels", "0"],
            "pixel budget",
        ),
        (
            vec!["--output", "o.png", "--max-pixels", "150%"],
            "pixel share",
        ),
        (vec!["--output", "o.png", "--max-time", "soon"], "time"),
        (vec!["--output", "o.png", "--max-time", "1e9"], "time"),
        (vec!["--output", "o.png", "--mode", "fast"], "unknown mode"),
        (vec!["--output", "o.png", "--spp", "0"], "--spp"),
        (
            vec!["--output", "o.png", "--denoise", "--no-denoise"],
            "cannot be used with",
        ),
        (
            vec![
                "--output",
                "o.png",
                "--mode",
                "adaptive",
                "--no-denoise",
                "--max-samples",
                "1",
            ],
            "fewer than one path per pixel",
        ),
        (
            vec![
                "--output",
                "o.png",
                "--mode",
                "adaptive",
                "--no-denoise",
                "--max-samples",
                "0",
            ],
            "fewer than one path per pixel",
        ),
        (
            vec!["--output", "o.png", "--size", "100000x100000"],
            "larger than the command line renders",
        ),
        (
            vec![
                "--output",
                "o.png",
                "--size",
                "8192x8192",
                "--spp",
                "100000",
            ],
            "more than the command line traces",
        ),
    ] {
        let o = glimpse(&d.path, &args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} was accepted");
        // 1: refused by Glimpse; 2: by the flag parser. Never an abort (134).
        assert!(
            matches!(o.status.code(), Some(1 | 2)),
            "{args:?}: a refusal, not an abort: {err}"
        );
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(
            err.lines().filter(|l| !l.trim().is_empty()).count() <= 4,
            "{args:?}: {err}"
        );
    }
    std::fs::write(
        d.path.join("scene.json"),
        SCENE.replace("\"fov_y\": 45", "\"fov_y\": 500"),
    )
    .unwrap();
    let o = glimpse(&d.path, &["--output", "o.png"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("camera.fov_y"),
        "the error names the field: {err}"
    );
    assert!(
        !d.path.join("o.png").exists(),
        "no output for a refused scene"
    );
}

#[test]
fn asked_to_denoise_without_the_library_it_refuses_before_any_work() {
    let d = setup();
    let empty = tempfile::tempdir().unwrap();
    for args in [
        &["--output", "o.png", "--mode", "adaptive"][..],
        &["--output", "o.png", "--mode", "reference", "--denoise"][..],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
            .current_dir(&d.path)
            .env("GLIMPSE_OIDN_DIR", empty.path())
            .arg("render")
            .arg("scene.json")
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?}: {err}");
        assert!(err.contains("bash scripts/oidn.sh"), "{args:?}: {err}");
        assert!(!d.path.join("o.png").exists(), "{args:?}: no output");
    }
    // Told not to denoise, adaptive runs without the library and says so.
    let o = Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .current_dir(&d.path)
        .env("GLIMPSE_OIDN_DIR", empty.path())
        .args([
            "render",
            "scene.json",
            "--output",
            "o.png",
            "--mode",
            "adaptive",
        ])
        .args(["--no-denoise", "--stats", "s.json"])
        .output()
        .unwrap();
    ok(&o);
    assert_eq!(stats(&d.path, "s.json")["denoised"], false);
}
