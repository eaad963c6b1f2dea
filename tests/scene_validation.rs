//! Scene validation against the fixture folders: every `tests/scenes-bad/NAME.json` is
//! refused with the kind and path of `NAME.expect` (format in tests/scenes-bad/README.md),
//! and every bundled `scenes/*.json` validates.

use std::path::{Path, PathBuf};

use glimpse::scene::{parse_scene, Limits, SceneErrorKind, SceneOrigin};

/// The limits the bad-scene fixtures assume (see tests/scenes-bad/README.md).
fn test_limits() -> Limits {
    Limits {
        max_width: 4096,
        max_height: 4096,
        max_pixels: 4096 * 4096,
        max_sample_budget: 1 << 32,
        max_objects: 1000,
        max_triangles: 100_000,
        max_samples_per_pixel: 4096,
        max_bounces: 64,
    }
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn json_files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .collect();
    v.sort();
    v
}

fn kind_name(k: SceneErrorKind) -> &'static str {
    match k {
        SceneErrorKind::InvalidJson => "invalid_json",
        SceneErrorKind::InvalidScene => "invalid_scene",
        SceneErrorKind::TooLarge => "over_limit",
    }
}

#[test]
fn every_bad_scene_is_refused_as_expected() {
    let files = json_files(&root().join("tests/scenes-bad"));
    assert!(files.len() >= 20, "only {} bad scenes", files.len());
    let mut failures = Vec::new();
    for f in &files {
        let body = std::fs::read_to_string(f).unwrap();
        let expect = std::fs::read_to_string(f.with_extension("expect"))
            .unwrap_or_else(|e| panic!("{}: missing .expect: {e}", f.display()));
        let mut lines = expect.lines();
        let kind = lines.next().unwrap_or("").trim().to_string();
        let path = lines.next().unwrap_or("").trim().to_string();
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        match parse_scene(&body, &SceneOrigin::Request, &test_limits()) {
            Ok(_) => failures.push(format!("{name}: accepted")),
            Err(e) => {
                let got = (kind_name(e.kind), e.problems[0].path.as_str());
                if got != (kind.as_str(), path.as_str()) {
                    failures.push(format!(
                        "{name}: expected {kind} at {path:?}, got {got:?}: {e}"
                    ));
                }
                // Every refusal carries a readable message.
                if e.problems[0].message.trim().is_empty() {
                    failures.push(format!("{name}: empty message"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn command_line_refuses_an_obj_path_that_escapes() {
    let dir = root().join("tests/scenes-bad");
    let body = std::fs::read_to_string(dir.join("obj-dotdot-path.json")).unwrap();
    let e = parse_scene(&body, &SceneOrigin::File { dir }, &Limits::command_line()).unwrap_err();
    assert_eq!(e.kind, SceneErrorKind::InvalidScene);
    assert_eq!(e.problems[0].path, "objects[0].path");
    assert!(e.problems[0].message.contains(".."), "{e}");
}

/// The bundled scenes (JSON has no comments, so they are described here):
///
/// - `cornell-box`: Bitterli's Tungsten Cornell box (shared/scenes-public/cornell-box-bitterli):
///   walls and both boxes are `mesh` objects with the exact points and indices of
///   `scene-v4.pbrt`; the light is the same rectangle as a `quad` whose `edge_u × edge_v`
///   points down (one-sided, radiance [17, 12, 4]); camera and albedos from `scene.json`.
///   Reference mean RGB of TungstenRender.exr: (0.1963, 0.1275, 0.0361) (64 bounces there,
///   5 here, so expect a slightly darker mean).
/// - `spheres-rough` / `spheres-smooth` (F&P04 §3.4, Table 1): four spheres on a floor
///   under a quad light and a weak environment; identical except the floor texture: noise of
///   feature size 0.12 between black and white (rough) vs noise of size 4 between 0.5 and
///   0.58 (smooth).
/// - `cellar` (F&P04 Figure 1): a low stone room with two rows of box columns, a sword
///   (glossy blade, brass guard and pommel, leather grip) on a pedestal, lit only by a small
///   dim warm ceiling panel in front of it; the columns are barely lit.
/// - `door` (F&P04 §5.3): two rooms separated by a 10 cm partition with a 1.2 × 2.1 m
///   opening and a dark door leaf swung 55° into the far room. The lamp is on the far
///   room's ceiling; seen from the camera the lintel hides that ceiling entirely, so the lamp
///   is never directly visible and the near room is lit by light bounced in through the
///   opening (plus a sliver of direct light on the floor by the door).
#[test]
fn every_bundled_scene_validates() {
    let dir = root().join("scenes");
    let files = json_files(&dir);
    assert!(files.len() >= 5, "only {} bundled scenes", files.len());
    for f in &files {
        let body = std::fs::read_to_string(f).unwrap();
        let origin = SceneOrigin::File { dir: dir.clone() };
        let s = parse_scene(&body, &origin, &Limits::command_line())
            .unwrap_or_else(|e| panic!("{}: {e:?}", f.display()));
        // Bundled scenes are served by the service too: they must pass a server's
        // stricter limits and not rely on the command line.
        let s2 = parse_scene(&body, &SceneOrigin::Request, &test_limits())
            .unwrap_or_else(|e| panic!("{} as a request: {e:?}", f.display()));
        assert_eq!(s.triangle_count(), s2.triangle_count());
        assert!(s.warnings.is_empty(), "{}: {:?}", f.display(), s.warnings);
        // `glimpse bench` renders every bundled scene: keep them cheap.
        assert!(
            u64::from(s.width) * u64::from(s.height) <= 320 * 240,
            "{}",
            f.display()
        );
        assert!(
            (16..=32).contains(&s.render.samples_per_pixel),
            "{}",
            f.display()
        );
        assert!(s.render.max_bounces <= 5);
    }
}
