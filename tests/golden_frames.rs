//! Golden frames: every bundled scene, rendered small in reference and progressive mode,
//! compared with a stored PNG within a tolerance in perceptual units (Glimpse's own vision
//! model, JND) and FLIP. Renders are deterministic, so on one platform the difference is
//! zero; the tolerance absorbs floating-point differences between machines, and the test
//! proves it still catches a real regression (a 10 % brighter image must fail it).
//!
//! Regenerate after an intended change: `REGENERATE=1 cargo test --test golden_frames`,
//! then look at the PNGs in tests/golden/ before committing them.

use glimpse::bench::{display_model, flip::flip};
use glimpse::cancel::CancelToken;
use glimpse::progressive::{render, RenderOptions};
use glimpse::raster::{decode_image, encode_png_display, LinearImage};
use glimpse::scene::{parse_scene, Limits, RenderMode, Scene, SceneOrigin};
use glimpse::tracer::PathTracer;
use glimpse::vision::VisionModel;
use std::path::{Path, PathBuf};

/// Mean JND allowed between a render and its golden frame.
const MAX_MEAN_JND: f64 = 0.3;
/// Mean FLIP allowed (8-bit quantisation of the golden PNG alone gives ~0.002).
const MAX_FLIP: f64 = 0.01;

fn scenes() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir("scenes")
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    v.sort();
    assert!(!v.is_empty());
    v
}

fn small(path: &Path) -> Scene {
    let json = std::fs::read_to_string(path).unwrap();
    let origin = SceneOrigin::File {
        dir: PathBuf::from("scenes"),
    };
    let mut s = parse_scene(&json, &origin, &Limits::command_line()).unwrap();
    let k = 64.0 / s.width.max(s.height) as f32;
    s.width = ((s.width as f32 * k).round() as u32).max(1);
    s.height = ((s.height as f32 * k).round() as u32).max(1);
    s.render.samples_per_pixel = 8;
    // The goldens pin the loop's frames; at 8 spp some scenes' paths are cheap enough that
    // a render would trace them whole instead.
    s.progressive.force_loop = true;
    s
}

/// (mean JND, mean FLIP) of `img` against `golden`, as the scene's display shows them.
fn difference(s: &Scene, golden: &LinearImage, img: &LinearImage) -> (f64, f64) {
    let model = VisionModel::new(display_model(s), s.width, s.height);
    let a = model.decompose(golden).unwrap();
    let b = model.decompose(img).unwrap();
    let map = model.full_map(&a, &b);
    let jnd = map.pixels().iter().map(|&d| f64::from(d)).sum::<f64>() / map.len() as f64;
    let f = flip(golden, img, s.display.exposure, s.display.pixels_per_degree).mean;
    (jnd, f)
}

#[test]
fn bundled_scenes_match_their_golden_frames() {
    let regenerate = std::env::var_os("REGENERATE").is_some();
    let cancel = CancelToken::new();
    for path in scenes() {
        let s = small(&path);
        let tracer = PathTracer::new(&s);
        for mode in [RenderMode::Reference, RenderMode::Progressive] {
            let opts = RenderOptions {
                mode: Some(mode),
                ..RenderOptions::default()
            };
            let frame = render(&s, &tracer, &opts, &mut |_| {}, &cancel).unwrap();
            let png = encode_png_display(&frame.image, s.display.exposure).unwrap();
            let name = format!("{}-{}.png", s.name, mode.as_str());
            let golden_path = Path::new("tests/golden").join(&name);
            if regenerate {
                std::fs::write(&golden_path, &png).unwrap();
                continue;
            }
            let golden = decode_image(&std::fs::read(&golden_path).unwrap_or_else(|e| {
                panic!("{}: {e} (REGENERATE=1 creates it)", golden_path.display())
            }))
            .unwrap();
            // Compare what a person sees: the golden PNG against this render's own PNG.
            let now = decode_image(&png).unwrap();
            let (jnd, f) = difference(&s, &golden, &now);
            if jnd > MAX_MEAN_JND || f > MAX_FLIP {
                let out = Path::new("target").join(format!("golden-actual-{name}"));
                let _ = std::fs::write(&out, &png);
                panic!(
                    "{name}: {jnd:.3} JND, FLIP {f:.4} from the golden frame (limits \
                     {MAX_MEAN_JND}, {MAX_FLIP}); actual written to {}",
                    out.display()
                );
            }
        }
    }
}

/// The tolerance is not vacuous: a 10 % exposure change (a real regression, e.g. a light
/// off by 10 %) exceeds it on every scene.
#[test]
fn the_tolerance_catches_a_ten_percent_change() {
    for path in scenes() {
        let s = small(&path);
        let golden = decode_image(
            &std::fs::read(Path::new("tests/golden").join(format!("{}-reference.png", s.name)))
                .unwrap(),
        )
        .unwrap();
        let brighter = golden.map(|p| *p * 1.1);
        let (jnd, f) = difference(&s, &golden, &brighter);
        assert!(
            jnd > MAX_MEAN_JND || f > MAX_FLIP,
            "{}: a 10% change gives only {jnd:.3} JND and FLIP {f:.4}",
            s.name
        );
    }
}
