//! Embeds the bundled example scenes (`scenes/*.json`) for `GET /v1/examples`
//! (service-api.md): writes `$OUT_DIR/examples.rs`, a sorted `&[(name, document)]` of
//! `include_str!`s, so the binary serves them without any file at run time.

use std::fmt::Write as _;
use std::path::Path;

fn main() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    // A directory path makes cargo rescan it: adding a scene re-runs this script.
    println!("cargo:rerun-if-changed=scenes");
    println!("cargo:rerun-if-changed=build.rs");
    let mut scenes: Vec<_> = std::fs::read_dir(&dir)
        .map(|rd| {
            rd.filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| p.extension().is_some_and(|x| x == "json") && p.is_file())
                .collect()
        })
        .unwrap_or_default();
    scenes.sort();
    let mut out = String::from("&[\n");
    for p in &scenes {
        let name = p.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
        let _ = writeln!(
            out,
            "    ({name:?}, include_str!({:?})),",
            p.display().to_string()
        );
    }
    out.push(']');
    let dest =
        Path::new(&std::env::var("OUT_DIR").expect("cargo sets OUT_DIR")).join("examples.rs");
    std::fs::write(dest, out).expect("OUT_DIR is writable");
}
