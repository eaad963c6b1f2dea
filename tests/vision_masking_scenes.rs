//! F&P04 §3.2 / Table 1 with Glimpse's own scenes: the noise of an 8-spp render against a
//! 64-spp render of the four-spheres-on-a-floor scene is less visible on the rough floor
//! than on the smooth one (paper: mean distance 3.5 vs 5.32). Small images so it runs in
//! seconds; the ranking, not the numbers, is the claim.

use glimpse::cancel::CancelToken;
use glimpse::metric;
use glimpse::scene::{parse_scene, Limits, SceneOrigin};
use glimpse::tracer::{render_reference_with, PathTracer};
use glimpse::vision::VisionModel;

fn mean_distance_8_vs_64(file: &str, w: u32, h: u32) -> f64 {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(file);
    let text = std::fs::read_to_string(&path).unwrap();
    let mut doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    doc["image"]["width"] = w.into();
    doc["image"]["height"] = h.into();
    let origin = SceneOrigin::File {
        dir: path.parent().unwrap().to_path_buf(),
    };
    let scene = parse_scene(&doc.to_string(), &origin, &Limits::command_line()).unwrap();
    let tracer = PathTracer::new(&scene);
    let cancel = CancelToken::new();
    let hi = render_reference_with(&tracer, Some((64, 1)), &cancel, &|_, _| {}).unwrap();
    let lo = render_reference_with(&tracer, Some((8, 2)), &cancel, &|_, _| {}).unwrap();
    let model = VisionModel::new(glimpse::progressive::display_model(&scene), w, h);
    let (a, b) = (model.decompose(&hi).unwrap(), model.decompose(&lo).unwrap());
    metric::full_map(&model, &a, &b).mean()
}

#[test]
fn rough_floor_masks_noise_better_than_smooth_floor() {
    let rough = mean_distance_8_vs_64("spheres-rough.json", 160, 120);
    let smooth = mean_distance_8_vs_64("spheres-smooth.json", 160, 120);
    eprintln!(
        "mean distance 8 vs 64 spp: rough {rough:.3}, smooth {smooth:.3} (F&P04: 3.5 vs 5.32)"
    );
    assert!(rough > 0.0);
    assert!(
        rough < smooth,
        "rough {rough} should be below smooth {smooth}"
    );
}
