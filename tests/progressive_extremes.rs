//! The progressive renderer at its numerical extremes, with analytic pixel
//! oracles so every test is fast: black and saturated scenes, tiny and 1-D images,
//! identical samples, T1 ≤ T0, NaN-free layers, T0 = 0 ≡ reference, cancellation, Guo's
//! pixel budget, and dark scenes costing less.

use glam::Vec3;
use glimpse::cancel::CancelToken;
use glimpse::progressive::{render, ClassCell, Frame, RenderError, RenderOptions};
use glimpse::raster::{PixelCoord, Rgb};
use glimpse::scene::{Camera, ObjectId, RenderMode, Scene};
use glimpse::tracer::{fixtures, render_reference, PixelOracle};

/// A pixel oracle from two closures: colour and object id of pixel (x, y).
struct Analytic<F, G> {
    w: u32,
    h: u32,
    f: F,
    g: G,
}

impl<F, G> PixelOracle for Analytic<F, G>
where
    F: Fn(u32, u32) -> Rgb + Sync,
    G: Fn(u32, u32) -> ObjectId + Sync,
{
    fn size(&self) -> (u32, u32) {
        (self.w, self.h)
    }
    fn radiance(&self, p: PixelCoord) -> Rgb {
        (self.f)(p.x, p.y)
    }
    fn radiance_with(&self, p: PixelCoord, _: u32, _: u64) -> Rgb {
        (self.f)(p.x, p.y)
    }
    fn object_id(&self, p: PixelCoord) -> ObjectId {
        (self.g)(p.x, p.y)
    }
}

fn oracle(
    w: u32,
    h: u32,
    f: impl Fn(u32, u32) -> Rgb + Sync,
) -> Analytic<impl Fn(u32, u32) -> Rgb + Sync, impl Fn(u32, u32) -> ObjectId + Sync> {
    Analytic {
        w,
        h,
        f,
        g: |_, _| 0,
    }
}

fn scene(w: u32, h: u32, mode: RenderMode) -> Scene {
    // An empty scene: the analytic oracle, not the tracer, supplies every pixel.
    let camera = Camera {
        position: Vec3::ZERO,
        look_at: Vec3::Z,
        up: Vec3::Y,
        fov_y_deg: 40.0,
    };
    let mut s = fixtures::scene(w, h, camera, Vec::new(), Vec::new(), Vec::new(), (1, 1, 7));
    s.name = "analytic".into();
    s.render.mode = mode;
    s.progressive.initial_rate = 0.05;
    // The oracle's pixels are free, but the loop weighs a pixel as the scene's samples
    // per pixel: at 1 it would find tracing every open pixel cheaper than one iteration
    // and end at once (`Plan::finish_if_cheaper`); these tests are about the iterations.
    s.render.samples_per_pixel = 1024;
    s
}

/// A step edge (object 1 right of x = 3w/5, brighter) over a smooth gradient.
fn step(w: u32) -> impl Fn(u32, u32) -> Rgb + Sync {
    move |x, y| {
        let base = 0.05 + 0.3 * x as f32 / w as f32 + 0.01 * y as f32;
        if 5 * x >= 3 * w {
            Rgb::new(base + 0.5, base + 0.4, base)
        } else {
            Rgb::new(base, base * 0.8, base * 0.5)
        }
    }
}

fn run(s: &Scene, o: &impl PixelOracle, opts: &RenderOptions) -> (Frame, Vec<Frame>) {
    let mut frames = Vec::new();
    let last = render(
        s,
        o,
        opts,
        &mut |f| frames.push(f.clone()),
        &CancelToken::new(),
    )
    .expect("not cancelled");
    (last, frames)
}

fn assert_no_nan(f: &Frame) {
    assert!(
        !f.image.has_non_finite(),
        "image has NaN/Inf at iteration {}",
        f.iteration
    );
    if let Some(d) = &f.distance {
        assert!(d.pixels().iter().all(|v| !v.is_nan()), "distance has NaN");
    }
    assert!(f.stats.pixel_fraction.is_finite() && f.stats.final_mean_distance.is_finite());
}

#[test]
fn black_scene_is_final_after_the_first_iteration() {
    let (w, h) = (48, 32);
    let s = scene(w, h, RenderMode::Progressive);
    let (last, frames) = run(
        &s,
        &oracle(w, h, |_, _| Rgb::ZERO),
        &RenderOptions::default(),
    );
    assert_eq!(
        frames.len(),
        2,
        "frame 0 (first set) and frame 1 (centres), then all final"
    );
    assert!(last.last && !frames[0].last);
    assert_eq!(last.stats.stop_reason.as_deref(), Some("all_final"));
    assert!(last.stats.triangles_final > 0);
    assert_eq!(
        last.stats.triangles_smooth + last.stats.triangles_complex,
        0
    );
    assert!(last.image.pixels().iter().all(|p| *p == Rgb::ZERO));
    assert!(last.classes.pixels().iter().all(|c| *c == ClassCell::Final));
    assert!(
        last.stats.pixel_fraction < 0.2,
        "{}",
        last.stats.pixel_fraction
    );
    frames.iter().for_each(assert_no_nan);
}

#[test]
fn saturated_scene_is_final_after_the_first_iteration() {
    let (w, h) = (40, 30);
    let s = scene(w, h, RenderMode::Progressive);
    let o = oracle(w, h, |x, y| Rgb::splat(1e6 + (x * y) as f32));
    let (last, frames) = run(&s, &o, &RenderOptions::default());
    assert_eq!(frames.len(), 2);
    assert_eq!(last.stats.stop_reason.as_deref(), Some("all_final"));
    assert_eq!(
        last.stats.triangles_smooth + last.stats.triangles_complex,
        0
    );
    assert!(last.image.pixels().iter().all(|p| p.min_element() > 0.99e6));
    frames.iter().for_each(assert_no_nan);
}

#[test]
fn identical_samples_are_final_and_exact() {
    let (w, h) = (33, 17);
    let s = scene(w, h, RenderMode::Progressive);
    let c = Rgb::new(0.3, 0.2, 0.1);
    let (last, frames) = run(&s, &oracle(w, h, move |_, _| c), &RenderOptions::default());
    assert_eq!(frames.len(), 2);
    assert_eq!(last.stats.stop_reason.as_deref(), Some("all_final"));
    for p in last.image.pixels() {
        assert!((*p - c).abs().max_element() < 1e-6, "{p:?}");
    }
}

#[test]
fn tiny_and_one_dimensional_images_never_panic() {
    for (w, h) in [(1, 1), (3, 2), (2, 3), (400, 1), (1, 50)] {
        for mode in [RenderMode::Progressive, RenderMode::Guo] {
            let s = scene(w, h, mode);
            let o = oracle(w, h, step(w));
            let (last, frames) = run(&s, &o, &RenderOptions::default());
            assert!(last.last);
            assert_eq!(last.image.width(), w);
            frames.iter().for_each(assert_no_nan);
            if w == 1 || h == 1 {
                // Collinear samples: no triangle, every pixel traced.
                let r = render_reference(&o, &CancelToken::new(), &|_, _| {}).expect("ok");
                assert_eq!(last.image, r, "{w}x{h}");
                assert_eq!(last.stats.pixels_traced, u64::from(w * h));
                assert_eq!(last.stats.stop_reason.as_deref(), Some("no_triangles"));
            }
        }
    }
}

#[test]
fn t1_below_t0_is_raised_and_classes_do_not_invert() {
    let (w, h) = (48, 32);
    let mut s = scene(w, h, RenderMode::Progressive);
    s.progressive.t1 = Some(0.25);
    let (last, frames) = run(&s, &oracle(w, h, step(w)), &RenderOptions::default());
    let t1 = last.stats.t1_used.expect("t1 used");
    assert!(t1 >= 1.0 * (1.0 + 1e-3) - 1e-9, "{t1}");
    frames.iter().for_each(assert_no_nan);
}

#[test]
fn t0_zero_gives_the_reference_bit_for_bit() {
    let (w, h) = (40, 28);
    for mode in [RenderMode::Progressive, RenderMode::Guo] {
        let mut s = scene(w, h, mode);
        s.progressive.t0 = 0.0;
        s.progressive.max_iterations = 10_000;
        let o = oracle(w, h, step(w));
        let (last, frames) = run(&s, &o, &RenderOptions::default());
        let r = render_reference(&o, &CancelToken::new(), &|_, _| {}).expect("ok");
        assert_eq!(last.image, r, "{mode:?}");
        assert_eq!(
            last.stats.pixels_traced,
            u64::from(w * h),
            "each pixel traced once"
        );
        assert_eq!(last.stats.stop_reason.as_deref(), Some("all_traced"));
        // Intermediate frames are approximations with fewer traced pixels.
        assert!(frames[0].stats.pixels_traced < u64::from(w * h) / 4);
        frames.iter().for_each(assert_no_nan);
    }
}

#[test]
fn nan_from_the_oracle_stays_out_of_every_layer() {
    let (w, h) = (32, 24);
    let s = scene(w, h, RenderMode::Progressive);
    let o = oracle(w, h, |x, y| {
        if (x + y) % 7 == 0 {
            Rgb::splat(f32::NAN)
        } else {
            Rgb::splat(0.2)
        }
    });
    let (_, frames) = run(&s, &o, &RenderOptions::default());
    frames.iter().for_each(assert_no_nan);
}

#[test]
fn cancelling_from_the_frame_callback_stops_the_render() {
    let (w, h) = (48, 32);
    let mut s = scene(w, h, RenderMode::Progressive);
    s.progressive.t0 = 0.0;
    s.progressive.max_iterations = 10_000;
    let cancel = CancelToken::new();
    let mut n = 0;
    let r = render(
        &s,
        &oracle(w, h, step(w)),
        &RenderOptions::default(),
        &mut |_| {
            n += 1;
            cancel.cancel();
        },
        &cancel,
    );
    assert!(matches!(r, Err(RenderError::Cancelled)), "{r:?}");
    assert_eq!(n, 1, "no frame after the cancel");
}

#[test]
fn guo_stops_at_the_pixel_budget() {
    let (w, h) = (64, 48);
    let s = scene(w, h, RenderMode::Guo);
    let opts = RenderOptions {
        max_pixels: Some(500),
        ..RenderOptions::default()
    };
    let (last, frames) = run(&s, &oracle(w, h, step(w)), &opts);
    assert!(
        last.stats.pixels_traced <= 500,
        "{}",
        last.stats.pixels_traced
    );
    assert!(last.stats.pixels_traced > 300);
    assert_eq!(last.stats.stop_reason.as_deref(), Some("max_pixels"));
    assert_eq!(last.stats.mode, "guo");
    frames.iter().for_each(assert_no_nan);
}

#[test]
fn guo_stops_by_itself_on_a_smooth_image() {
    let (w, h) = (64, 48);
    let s = scene(w, h, RenderMode::Guo);
    let smooth = oracle(w, h, |x: u32, y: u32| {
        Rgb::new(0.3 + x as f32 * 0.002, 0.3 + y as f32 * 0.002, 0.3)
    });
    let (last, _) = run(&s, &smooth, &RenderOptions::default());
    assert_eq!(last.stats.stop_reason.as_deref(), Some("all_final"));
    assert!(last.stats.triangles_final > 0);
    assert!(
        last.stats.pixel_fraction < 0.5,
        "{}",
        last.stats.pixel_fraction
    );
}

#[test]
fn the_step_edge_is_refined_where_it_is() {
    // Complex triangles gather on the edge: the traced fraction near x = 3w/5 is much
    // higher than far from it.
    let (w, h) = (80, 60);
    let s = scene(w, h, RenderMode::Progressive);
    let (last, _) = run(&s, &oracle(w, h, step(w)), &RenderOptions::default());
    let near = |x: u32| x.abs_diff(3 * w / 5) <= 2;
    let (mut tn, mut nn, mut tf, mut nf) = (0, 0, 0, 0);
    for y in 0..h {
        for x in 0..w {
            let traced = *last.samples.get(x, y) != glimpse::progressive::SampleCell::Interpolated;
            if near(x) {
                nn += 1;
                tn += usize::from(traced);
            } else if x.abs_diff(3 * w / 5) > 10 {
                nf += 1;
                tf += usize::from(traced);
            }
        }
    }
    let (fnear, ffar) = (tn as f64 / nn as f64, tf as f64 / nf as f64);
    assert!(fnear > 2.0 * ffar, "near {fnear} far {ffar}");
    // And the interpolated step is sharp: mean error against the truth is small.
    let truth = step(w);
    let err: f64 = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| f64::from((*last.image.get(x, y) - truth(x, y)).abs().max_element()))
        .sum::<f64>()
        / f64::from(w * h);
    assert!(err < 0.02, "mean abs error {err}");
}

#[test]
fn dark_display_traces_fewer_pixels() {
    // A textured scene (fine sinusoid, visible at exposure 1) shown 1/16 as bright: the
    // vision model sees less, so fewer pixels need tracing (F&P04 §5.3).
    let (w, h) = (64, 64);
    let tex = |x: u32, y: u32| {
        let v = 0.3
            + 0.1 * ((x as f32 * 0.9).sin() * (y as f32 * 0.7).cos())
            + 0.2 * (x / 16 % 2) as f32;
        Rgb::splat(v)
    };
    let frac = |exposure: f32| {
        let mut s = scene(w, h, RenderMode::Progressive);
        s.display.exposure = exposure;
        let (last, _) = run(&s, &oracle(w, h, tex), &RenderOptions::default());
        last.stats.pixel_fraction
    };
    let (bright, dark) = (frac(1.0), frac(1.0 / 256.0));
    assert!(dark < bright, "dark {dark} bright {bright}");
}
