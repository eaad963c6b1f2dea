//! Scenes people download render unchanged over HTTP: every scene file of every public
//! scene folder (the shared copy beside the repository, `../shared/scenes-public`, when
//! present, else `tests/public-scenes/`), zipped with the files it names and posted to the
//! real server at a small size, finishes `succeeded` with no warning but what its import
//! approximated. And no public, bundled or generated scene is named by the checks for
//! scenes that are almost surely wrong (`scene::warnings`): they must never cry wolf.

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Words of the warnings `scene::warnings` and `scene::reach` give; none may appear for a
/// scene that renders as its author meant.
const MISTAKES: [&str; 5] = [
    "lights almost nothing",
    "faces away from every other object",
    "almost no light reaches the camera",
    "the camera is inside",
    "this server's cap",
];

/// The public scene folders: `GLIMPSE_PUBLIC_SCENES`, else the shared copy beside the
/// repository (every public file), else the repository's own subset.
fn public_root() -> PathBuf {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    if let Some(p) = std::env::var_os("GLIMPSE_PUBLIC_SCENES") {
        return PathBuf::from(p);
    }
    let shared = repo.join("../shared/scenes-public");
    if shared.is_dir() {
        shared
    } else {
        repo.join("tests/public-scenes")
    }
}

fn is_scene_file(p: &Path) -> bool {
    matches!(
        p.extension().and_then(|e| e.to_str()),
        Some("json" | "pbrt" | "gltf" | "glb" | "obj")
    )
}

/// A Tungsten scene (`"bsdfs"`, `"primitives"`) is not a format Glimpse reads
/// (scene-import.md): it is not posted.
fn is_foreign_json(p: &Path) -> bool {
    p.extension().is_some_and(|e| e == "json")
        && std::fs::read_to_string(p).is_ok_and(|t| t.contains("\"primitives\""))
}

/// Every (folder, scene file) to post, in a fixed order.
fn scene_files() -> Vec<(PathBuf, PathBuf)> {
    let mut out = Vec::new();
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(public_root())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for d in dirs {
        let mut files: Vec<PathBuf> = std::fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file() && is_scene_file(p) && !is_foreign_json(p))
            .collect();
        files.sort();
        out.extend(files.into_iter().map(|f| (d.clone(), f)));
    }
    out
}

/// The files a scene may name: everything in its folder but the other scene files at its
/// root and the reference renders shipped beside it (`TungstenRender.*`, not part of the
/// scene, which would put the bundle above the default 8 MiB body).
fn bundle_files(dir: &Path, scene: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            let name = p
                .strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/");
            let at_root = !name.contains('/');
            let skip = (at_root && is_scene_file(&p) && p != scene)
                || name.starts_with("TungstenRender.")
                || name.ends_with(".md")
                || name.starts_with("LICENSE");
            if !skip {
                out.push((name, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

fn assert_no_mistake(what: &str, warnings: &[String]) {
    for w in warnings {
        assert!(
            !MISTAKES.iter().any(|m| w.contains(m)),
            "{what}: a false warning: {w}"
        );
    }
}

#[tokio::test]
async fn every_public_scene_posted_as_a_zip_renders_unchanged() {
    let files = scene_files();
    assert!(files.len() >= 5, "{files:?}");
    let data = tempfile::tempdir().unwrap();
    let port = common::free_port();
    let c = reqwest::Client::new();
    let _srv = common::spawn(data.path(), port, None, &[], &[], &c).await;
    let base = format!("http://127.0.0.1:{port}");
    let started = Instant::now();
    let mut jobs = Vec::new();
    for (dir, scene) in &files {
        let what = scene
            .strip_prefix(public_root())
            .unwrap()
            .display()
            .to_string();
        let files = bundle_files(dir, scene);
        let entries: Vec<(&str, Vec<u8>, u32)> = files
            .iter()
            .map(|(n, d)| (n.as_str(), d.clone(), 0o100_644))
            .collect();
        let body = common::zip(&entries, true);
        let t = Instant::now();
        let r = c
            .post(format!("{base}/v1/jobs?spp=2&width=64&height=64"))
            .header("content-type", "application/zip")
            .body(body)
            .send()
            .await
            .unwrap();
        let status = r.status().as_u16();
        let v: serde_json::Value = r.json().await.unwrap();
        assert_eq!(status, 201, "{what}: {v}");
        let warnings: Vec<String> = v["warnings"]
            .as_array()
            .map(|a| a.iter().map(|w| w.as_str().unwrap().to_owned()).collect())
            .unwrap_or_default();
        eprintln!("{what}: 201 in {:?}, warnings {warnings:?}", t.elapsed());
        assert_no_mistake(&what, &warnings);
        jobs.push((what, v["id"].as_str().unwrap().to_owned()));
    }
    for (what, id) in &jobs {
        let deadline = Instant::now() + Duration::from_secs(300);
        loop {
            let j = common::job(&c, &base, id).await;
            match j["state"].as_str().unwrap() {
                "succeeded" => break,
                "failed" | "cancelled" => panic!("{what}: {j}"),
                _ => {}
            }
            assert!(Instant::now() < deadline, "{what}: did not finish");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        eprintln!("{what}: succeeded at {:?}", started.elapsed());
    }
}

#[test]
fn no_public_bundled_or_generated_scene_is_taken_for_a_mistake() {
    let limits = glimpse::scene::Limits::command_line();
    for (_, scene) in scene_files() {
        let t = Instant::now();
        let (s, _) = glimpse::import::load_path(&scene, &limits)
            .unwrap_or_else(|e| panic!("{}: {e}", scene.display()));
        let warnings: Vec<String> = s.warnings.iter().map(ToString::to_string).collect();
        eprintln!(
            "{}: validated with its warnings in {:?}",
            scene.display(),
            t.elapsed()
        );
        assert_no_mistake(&scene.display().to_string(), &warnings);
    }
    for (name, text) in glimpse::scene::examples::EXAMPLES {
        let s = glimpse::scene::parse_scene(text, &glimpse::scene::SceneOrigin::Request, &limits)
            .unwrap();
        let warnings: Vec<String> = s.warnings.iter().map(ToString::to_string).collect();
        assert_no_mistake(name, &warnings);
    }
    for seed in [1, 2] {
        for g in glimpse::bench::corpus::generate(40, seed) {
            let s = glimpse::scene::parse_scene(
                &g.document,
                &glimpse::scene::SceneOrigin::Request,
                &limits,
            )
            .unwrap_or_else(|e| panic!("{}: {e}", g.name));
            let warnings: Vec<String> = s.warnings.iter().map(ToString::to_string).collect();
            assert_no_mistake(&g.name, &warnings);
        }
    }
}
