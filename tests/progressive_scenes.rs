//! The progressive renderer on the real path tracer (issue #4), tiny so it runs in the
//! dev profile: dark displays cost less, the result is close to the reference, Guo at the
//! same pixel budget, and equal-time uniform rendering returns a usable spp.

use glimpse::cancel::CancelToken;
use glimpse::progressive::{render, uniform, RenderOptions};
use glimpse::raster::LinearImage;
use glimpse::scene::RenderMode;
use glimpse::tracer::{fixtures::cornell_box, render_reference, PathTracer};
use std::time::Duration;

fn mean_abs(a: &LinearImage, b: &LinearImage, exposure: f32) -> f64 {
    let s: f64 = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(p, q)| f64::from(((*p - *q) * exposure).abs().element_sum()) / 3.0)
        .sum();
    s / a.len() as f64
}

#[test]
fn cornell_box_dark_costs_less_and_stays_close_to_the_reference() {
    let cancel = CancelToken::new();
    let mut fractions = Vec::new();
    for exposure in [1.0f32, 1.0 / 64.0] {
        let mut s = cornell_box(96, 72, 8, 3, 1);
        s.display.exposure = exposure;
        let t = PathTracer::new(&s);
        let reference = render_reference(&t, &cancel, &|_, _| {}).expect("not cancelled");
        let opts = RenderOptions {
            mode: Some(RenderMode::Progressive),
            ..RenderOptions::default()
        };
        let p = render(&s, &t, &opts, &mut |_| {}, &cancel).expect("not cancelled");
        assert!(p.last && !p.image.has_non_finite());
        let err = mean_abs(&p.image, &reference, exposure);
        // Displayed units: 0.03 is a few sRGB steps on average (MC noise dominates).
        assert!(err < 0.03, "exposure {exposure}: mean error {err}");
        fractions.push(p.stats.pixel_fraction);
        if exposure == 1.0 {
            let g = RenderOptions {
                mode: Some(RenderMode::Guo),
                max_pixels: Some(p.stats.pixels_traced),
                ..RenderOptions::default()
            };
            let gr = render(&s, &t, &g, &mut |_| {}, &cancel).expect("not cancelled");
            assert!(gr.stats.pixels_traced <= p.stats.pixels_traced);
            let (u, spp) = uniform::render_equal_time(
                &s,
                &t,
                Duration::from_secs_f64(p.stats.total_ms / 1e3),
                &cancel,
            )
            .expect("not cancelled");
            assert!(spp >= 1 && !u.has_non_finite());
        }
    }
    assert!(
        fractions[1] < fractions[0],
        "dark {} vs bright {}",
        fractions[1],
        fractions[0]
    );
}
