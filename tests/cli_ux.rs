//! The command line as a person meets it (cli.md): every flag explained, `--output`
//! writing the format its extension names or refusing it, `compare` in words.

use std::path::Path;
use std::process::{Command, Output};

mod common;

use common::LIT_SCENE as SCENE;

fn glimpse(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_glimpse"))
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap()
}

/// The `--flag` entries of a `--help` page without words after them.
fn unexplained_flags(help: &str) -> Vec<String> {
    let lines: Vec<&str> = help.lines().collect();
    let mut bad = Vec::new();
    for (k, line) in lines.iter().enumerate() {
        let t = line.trim_start();
        if !(t.starts_with("--") || (t.starts_with('-') && t.contains(", --"))) {
            continue;
        }
        // clap puts the text on the same line after two spaces, or on the next lines
        // (indented deeper) for long help.
        let flag_end = t.find("  ").unwrap_or(t.len());
        let same_line = t[flag_end..].trim();
        let next = lines.get(k + 1).map_or("", |l| l.trim());
        let next_is_text = !next.is_empty() && !next.starts_with('-');
        if same_line.is_empty() && !next_is_text {
            bad.push(t.to_string());
        }
    }
    bad
}

#[test]
fn every_subcommand_explains_every_flag_with_modes_and_defaults() {
    let dir = tempfile::tempdir().unwrap();
    for sub in ["serve", "render", "compare", "convert", "bench", "worker"] {
        let o = glimpse(dir.path(), &[sub, "--help"]);
        if sub == "worker" && !o.status.success() {
            continue; // the cluster's subcommand is another branch's
        }
        assert!(o.status.success(), "{sub} --help");
        let help = String::from_utf8_lossy(&o.stdout);
        let bad = unexplained_flags(&help);
        assert!(bad.is_empty(), "{sub}: flags without help: {bad:?}\n{help}");
    }
    let render =
        String::from_utf8_lossy(&glimpse(dir.path(), &["render", "--help"]).stdout).into_owned();
    for words in [
        "reference",
        "progressive",
        "guo",
        "Default",
        ".png",
        ".jpg",
        ".exr",
    ] {
        assert!(
            render.contains(words),
            "render --help lacks {words}:\n{render}"
        );
    }
    let serve =
        String::from_utf8_lossy(&glimpse(dir.path(), &["serve", "--help"]).stdout).into_owned();
    for words in [
        "[default: 127.0.0.1:8080]",
        "[default: ./glimpse-data]",
        "[default: 1]",
    ] {
        assert!(
            serve.contains(words),
            "serve --help lacks {words}:\n{serve}"
        );
    }
    let compare =
        String::from_utf8_lossy(&glimpse(dir.path(), &["compare", "--help"]).stdout).into_owned();
    assert!(
        compare.contains("<A>") && compare.contains("PNG"),
        "{compare}"
    );
}

#[test]
fn output_writes_the_format_its_extension_names_or_refuses_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("scene.json"), SCENE).unwrap();
    let magic: [(&str, &[u8]); 4] = [
        ("o.png", b"\x89PNG"),
        ("o.jpg", &[0xFF, 0xD8, 0xFF]),
        ("o.JPEG", &[0xFF, 0xD8, 0xFF]),
        ("o.exr", &[0x76, 0x2F, 0x31, 0x01]),
    ];
    for (name, head) in magic {
        let o = glimpse(dir.path(), &["render", "scene.json", "--output", name]);
        assert!(
            o.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let bytes = std::fs::read(dir.path().join(name)).unwrap();
        assert_eq!(&bytes[..head.len()], head, "{name}");
    }
    // Decodable as what they claim: the JPEG by the `image` crate, same size.
    let jpg = image::load_from_memory(&std::fs::read(dir.path().join("o.jpg")).unwrap()).unwrap();
    assert_eq!((jpg.width(), jpg.height()), (40, 30));
    for bad in ["o.tiff", "o"] {
        let started = std::time::Instant::now();
        let o = glimpse(dir.path(), &["render", "scene.json", "--output", bad]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{bad}");
        assert!(err.contains(".png") && err.contains(".exr"), "{err}");
        assert_eq!(err.lines().count(), 1, "one sentence: {err}");
        assert!(!dir.path().join(bad).exists());
        assert!(started.elapsed().as_secs_f64() < 5.0);
    }
}

#[test]
fn compare_prints_a_sentence_with_units_beside_the_json() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("scene.json"), SCENE).unwrap();
    for (name, spp) in [("a.png", "4"), ("b.png", "1")] {
        let o = glimpse(
            dir.path(),
            &[
                "render",
                "scene.json",
                "--output",
                name,
                "--mode",
                "reference",
                "--spp",
                spp,
            ],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let o = glimpse(dir.path(), &["compare", "a.png", "b.png"]);
    assert!(o.status.success());
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let said = String::from_utf8_lossy(&o.stderr);
    let mean = json["mean_distance"].as_f64().unwrap();
    assert!(
        said.contains(&format!("{mean:.2} JND on average")),
        "{said}"
    );
    assert!(
        said.contains("pixels per degree") && said.contains("cd/m²"),
        "{said}"
    );
    assert!(said.contains("a person would"), "{said}");
    let same = glimpse(dir.path(), &["compare", "a.png", "a.png"]);
    let said = String::from_utf8_lossy(&same.stderr);
    assert!(said.contains("would see no difference"), "{said}");
}
