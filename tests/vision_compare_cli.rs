//! `glimpse compare` (cli.md): statistics, map, and one-line errors.

use glimpse::raster::{encode_exr, encode_png_rgb8, Image, Rgb};
use std::process::Command;

fn glimpse() -> Command {
    Command::new(env!("CARGO_BIN_EXE_glimpse"))
}

fn png(w: u32, h: u32, f: impl Fn(u32, u32) -> u8) -> Vec<u8> {
    encode_png_rgb8(&Image::from_fn(w, h, |x, y| {
        let v = f(x, y);
        [v, v, v]
    }))
    .unwrap()
}

#[test]
fn compare_writes_stats_and_map() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.png"), dir.path().join("b.png"));
    std::fs::write(&a, png(64, 48, |x, y| ((x * 7 + y * 3) % 200) as u8)).unwrap();
    std::fs::write(
        &b,
        png(64, 48, |x, y| {
            ((x * 7 + y * 3) % 200) as u8 + ((x * 13 + y * 29) % 11) as u8
        }),
    )
    .unwrap();
    let (stats, map) = (dir.path().join("s.json"), dir.path().join("m.png"));
    for full in [false, true] {
        let mut cmd = glimpse();
        cmd.arg("compare")
            .arg(&a)
            .arg(&b)
            .arg("--stats")
            .arg(&stats)
            .arg("--map")
            .arg(&map);
        if full {
            cmd.arg("--full");
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let printed: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let written: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
        assert_eq!(printed, written);
        for k in [
            "mean_distance",
            "max_distance",
            "p95_distance",
            "pixels_evaluated",
            "ms",
        ] {
            assert!(written[k].is_number(), "{k}");
        }
        let mean = written["mean_distance"].as_f64().unwrap();
        let p95 = written["p95_distance"].as_f64().unwrap();
        let max = written["max_distance"].as_f64().unwrap();
        assert!(mean > 0.0 && mean <= max && p95 <= max, "{written}");
        if full {
            assert_eq!(written["pixels_evaluated"].as_u64(), Some(64 * 48));
        }
        let m = image_size(&std::fs::read(&map).unwrap());
        assert_eq!(m.0, 120); // at least 120 px wide for the legend
        assert!(m.1 > 48);
    }
    // Identical images: exactly 0.
    let out = glimpse().arg("compare").arg(&a).arg(&a).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["mean_distance"].as_f64(), Some(0.0));
    assert_eq!(v["max_distance"].as_f64(), Some(0.0));
}

fn image_size(png: &[u8]) -> (u32, u32) {
    let img = glimpse::raster::decode_image(png).unwrap();
    (img.width(), img.height())
}

#[test]
fn compare_errors_are_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.png");
    let small = dir.path().join("small.png");
    let nan = dir.path().join("nan.exr");
    std::fs::write(&a, png(8, 8, |x, _| x as u8 * 20)).unwrap();
    std::fs::write(&small, png(4, 8, |x, _| x as u8 * 20)).unwrap();
    let mut img = Image::filled(8, 8, Rgb::splat(0.5));
    img.set(5, 6, Rgb::new(f32::NAN, 0.5, 0.5));
    std::fs::write(&nan, encode_exr(&img).unwrap()).unwrap();
    let cases: [(std::path::PathBuf, &str); 3] = [
        (dir.path().join("missing.png"), "cannot read"),
        (small, "differ in size"),
        (nan, "(5, 6)"),
    ];
    for (b, want) in cases {
        let out = glimpse().arg("compare").arg(&a).arg(&b).output().unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        let line = err.lines().find(|l| l.starts_with("error:")).unwrap_or("");
        assert!(line.contains(want), "want {want:?} in {err:?}");
        assert!(!err.contains("panicked"));
    }
}
