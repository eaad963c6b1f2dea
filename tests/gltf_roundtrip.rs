//! The glTF round trip (scene-import.md, "How faithful"): `tests/gltf/roundtrip.json`, a
//! scene made only of what glTF says exactly (metallic-roughness materials, an emissive
//! quad, point and spot lights, transformed meshes, a perspective camera), is written as
//! `.glb` and `.gltf` by an independent writer (pygltflib, `scripts/gltf_export.py`),
//! checked by the Khronos glTF validator, and rendered by the real binary: the `.glb`
//! renders the document's picture (each channel's mean within 5 %, over the whole image
//! and over each quadrant, so a mirrored or misplaced object is caught), and the `.gltf`
//! imports to the same document as the `.glb`. `scripts/gltf_tools.sh` installs the writer
//! and the validator into `target/` when they are missing.

use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn run(cmd: &mut Command, what: &str) -> String {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot start: {e}"));
    assert!(
        out.status.success(),
        "{what} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `doc` written as `out` (`.glb` or `.gltf`) by pygltflib, then validated.
fn export(doc: &Path, out: &Path) {
    run(
        Command::new("python3")
            .arg(repo().join("scripts/gltf_export.py"))
            .arg(doc)
            .arg(out)
            .env("PYTHONPATH", repo().join("target/pydeps")),
        "scripts/gltf_export.py",
    );
    let report = run(
        Command::new("bash")
            .arg(repo().join("scripts/gltf_tools.sh"))
            .arg("validate")
            .arg(out),
        "the Khronos glTF validator",
    );
    eprintln!("{}: {}", out.display(), report.trim());
}

/// Mean linear RGB over the pixels with x in `xs` and y in `ys` (fractions of the size).
fn mean(img: &[[f32; 3]], (w, h): (u32, u32), xs: (f64, f64), ys: (f64, f64)) -> [f64; 3] {
    let at = |f: f64, n: u32| (f * f64::from(n)).round() as u32;
    let (mut s, mut n) = ([0f64; 3], 0u32);
    for y in at(ys.0, h)..at(ys.1, h) {
        for x in at(xs.0, w)..at(xs.1, w) {
            let p = img[(y * w + x) as usize];
            for c in 0..3 {
                s[c] += f64::from(p[c]);
            }
            n += 1;
        }
    }
    s.map(|v| v / f64::from(n))
}

fn converted(file: &Path, dir: &Path) -> String {
    let out = dir.join(format!(
        "{}.json",
        file.extension().unwrap().to_string_lossy()
    ));
    run(
        Command::new(env!("CARGO_BIN_EXE_glimpse"))
            .arg("convert")
            .arg(file)
            .arg("--output")
            .arg(&out),
        "glimpse convert",
    );
    std::fs::read_to_string(out).unwrap()
}

#[test]
fn a_document_written_as_gltf_by_pygltflib_renders_the_same_picture() {
    run(
        Command::new("bash")
            .arg(repo().join("scripts/gltf_tools.sh"))
            .arg("ensure"),
        "scripts/gltf_tools.sh ensure",
    );
    let tmp = tempfile::tempdir().unwrap();
    let doc = repo().join("tests/gltf/roundtrip.json");
    let (glb, gltf) = (tmp.path().join("scene.glb"), tmp.path().join("scene.gltf"));
    export(&doc, &glb);
    export(&doc, &gltf);
    assert_eq!(
        converted(&glb, tmp.path()),
        converted(&gltf, tmp.path()),
        "the .gltf (data URI) and the .glb import to different documents"
    );

    let args = ["--spp", "64", "--size", "96x72", "--seed", "1"];
    let (ours, w, h) = common::render_exr(&doc, &args);
    let (theirs, w2, h2) = common::render_exr(&glb, &args);
    assert_eq!((w, h), (w2, h2));
    let regions = [
        ("whole", (0.0, 1.0), (0.0, 1.0)),
        ("top left", (0.0, 0.5), (0.0, 0.5)),
        ("top right", (0.5, 1.0), (0.0, 0.5)),
        ("bottom left", (0.0, 0.5), (0.5, 1.0)),
        ("bottom right", (0.5, 1.0), (0.5, 1.0)),
    ];
    for (name, xs, ys) in regions {
        let a = mean(&ours, (w, h), xs, ys);
        let b = mean(&theirs, (w, h), xs, ys);
        let worst = (0..3)
            .map(|c| (a[c] - b[c]).abs() / a[c])
            .fold(0.0, f64::max);
        eprintln!(
            "{name}: document {a:.4?}, glTF {b:.4?}: worst channel {:.2} %",
            worst * 100.0
        );
        assert!(
            worst < 0.05,
            "{name}: document {a:?} vs glTF {b:?} ({:.1} %)",
            worst * 100.0
        );
    }
}
