//! F&P04 Table 1: visual masking in the distance the loop judges by. The two spheres
//! scenes differ only in their floor's texture (a fine, full-contrast noise on
//! `spheres-rough`, a faint, coarse one on `spheres-smooth`). The same Monte Carlo noise
//! (8 against 64 samples per pixel) should be *less* visible on the busy floor: the paper
//! reports a mean distance 1.52× as large on the smooth floor as on the rough one.
//!
//! Here: both scenes rendered at 8 and at 64 spp (independent seeds), the vision model's
//! full distance map between the two (vision-model.md §2, at the scene's display), its
//! mean over the floor's pixels (object-id map), median of `RUNS` seed pairs.
//!
//! Run: `cargo bench --bench masking` (a few minutes on 2 cores).

use glimpse::cancel::CancelToken;
use glimpse::progressive::display_model;
use glimpse::scene::examples::EXAMPLES;
use glimpse::scene::{parse_scene, Limits, Scene, SceneOrigin};
use glimpse::tracer::{self, PathTracer};
use glimpse::vision::VisionModel;

const RUNS: u64 = 3;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The mean distance (JND) between `LOW`- and `HIGH`-spp renders made with seeds from
/// `run`, over the floor and over its near part (the image's bottom third, where the rough
/// texture is resolved rather than averaged to grey by the pixels).
fn floor_distance(scene: &Scene, (low, high): (u32, u32), run: u64) -> (f64, f64) {
    let tracer = PathTracer::new(scene);
    let cancel = CancelToken::new();
    let render = |spp: u32, seed: u64| {
        tracer::render_reference_with(&tracer, Some((spp, seed)), &cancel, &|_, _| {})
            .expect("not cancelled")
    };
    let (low, high) = (render(low, 2 * run + 1), render(high, 2 * run + 2));
    let ids = tracer::object_id_map(&tracer);
    // The floor is what the bottom row's centre sees (both scenes: the first object).
    let floor = *ids.get(scene.width / 2, scene.height - 1);
    let model = VisionModel::new(display_model(scene), scene.width, scene.height);
    let (a, b) = (
        model.decompose(&low).expect("finite"),
        model.decompose(&high).expect("finite"),
    );
    let map = model.full_map(&a, &b);
    let mean_below = |top: u32| {
        let (sum, n) = (top..scene.height)
            .flat_map(|y| (0..scene.width).map(move |x| (x, y)))
            .filter(|&(x, y)| *ids.get(x, y) == floor)
            .fold((0.0, 0usize), |(s, n), (x, y)| {
                (s + f64::from(*map.get(x, y)), n + 1)
            });
        sum / n.max(1) as f64
    };
    (mean_below(0), mean_below(scene.height * 2 / 3))
}

fn main() {
    let scene = |name: &str| {
        let text = EXAMPLES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| *t)
            .expect("bundled");
        parse_scene(text, &SceneOrigin::Request, &Limits::command_line()).expect("valid")
    };
    let (smooth, rough) = (scene("spheres-smooth"), scene("spheres-rough"));
    for spp in [(8, 64), (64, 512)] {
        table("rough", &smooth, &rough, spp);
    }
    // The rough floor's noise cells are 0.12 m: about 1 degree at the camera's distance,
    // a band (≈ 0.5–1 cycle/degree) far below the pixel noise's (7–14 at 28 ppd), so it
    // cannot mask that noise in a band-wise model (vision-model.md §2.6). The same floor
    // with 0.01 m cells puts the texture's energy in the noise's bands.
    let fine = parse_scene(
        &EXAMPLES
            .iter()
            .find(|(n, _)| *n == "spheres-rough")
            .map(|(_, t)| t.replace("\"scale\": 0.12", "\"scale\": 0.01"))
            .expect("bundled"),
        &SceneOrigin::Request,
        &Limits::command_line(),
    )
    .expect("valid");
    table("rough, 0.01 m texture", &smooth, &fine, (8, 64));
}

/// One row pair of the table: `spp.0` against `spp.1` samples per pixel.
fn table(name: &str, smooth: &Scene, rough: &Scene, spp: (u32, u32)) {
    let ds: Vec<(f64, f64)> = (0..RUNS).map(|r| floor_distance(smooth, spp, r)).collect();
    let dr: Vec<(f64, f64)> = (0..RUNS).map(|r| floor_distance(rough, spp, r)).collect();
    let (low, high) = spp;
    println!("F&P04 Table 1 (masking), smooth against {name} floor, {low} vs {high} spp, median of {RUNS}:");
    for (what, pick) in [
        (
            "whole floor",
            (|d: &(f64, f64)| d.0) as fn(&(f64, f64)) -> f64,
        ),
        ("near floor (bottom third)", |d: &(f64, f64)| d.1),
    ] {
        let s: Vec<f64> = ds.iter().map(pick).collect();
        let r: Vec<f64> = dr.iter().map(pick).collect();
        let ratios: Vec<f64> = s.iter().zip(&r).map(|(s, r)| s / r).collect();
        println!(
            "  {what:<26} smooth {:.3} JND, rough {:.3} JND, smooth / rough {:.2} (F&P04: 1.52)",
            median(s),
            median(r),
            median(ratios)
        );
    }
}
