//! A measurement, not a regression test (ignored by default; run it in release):
//! `cargo test --release --test progressive_bench -- --ignored --nocapture`.
//! The Cornell box fixture rendered as reference, progressive (at three display
//! exposures: dark scenes should cost less), Guo at the progressive pixel budget and the
//! uniform renderer at the progressive wall time; prints time, pixels and error.

use glimpse::cancel::CancelToken;
use glimpse::progressive::{render, uniform, RenderOptions};
use glimpse::raster::{srgb_encode, LinearImage};
use glimpse::scene::{RenderMode, Scene};
use glimpse::tracer::{fixtures::cornell_box, render_reference, PathTracer};
use std::time::{Duration, Instant};

/// Mean |ΔsRGB| of the displayed images (× exposure, clamped), ×255.
fn displayed_error(a: &LinearImage, b: &LinearImage, exposure: f32) -> f64 {
    let mut s = 0.0;
    for (p, q) in a.pixels().iter().zip(b.pixels()) {
        for k in 0..3 {
            s += f64::from((srgb_encode(p[k] * exposure) - srgb_encode(q[k] * exposure)).abs());
        }
    }
    255.0 * s / (3.0 * a.len() as f64)
}

fn scene_at(exposure: f32) -> Scene {
    let size: u32 = std::env::var("GLIMPSE_BENCH_SIZE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(128);
    let spp: u32 = std::env::var("GLIMPSE_BENCH_SPP")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(16);
    let mut s = cornell_box(size, size, spp, 5, 1);
    s.display.exposure = exposure;
    s
}

#[test]
#[ignore = "measurement; run in release with --ignored --nocapture"]
fn cornell_progressive_guo_uniform() {
    let cancel = CancelToken::new();
    let base = scene_at(1.0);
    let tracer = PathTracer::new(&base);
    let t = Instant::now();
    let reference = render_reference(&tracer, &cancel, &|_, _| {}).expect("not cancelled");
    let ref_ms = t.elapsed().as_secs_f64() * 1e3;
    println!(
        "reference {}x{} spp {}: {ref_ms:.0} ms",
        base.width, base.height, base.render.samples_per_pixel
    );
    for exposure in [1.0f32, 1.0 / 16.0, 1.0 / 256.0] {
        let s = scene_at(exposure);
        let mut opts = RenderOptions {
            mode: Some(RenderMode::Progressive),
            ..RenderOptions::default()
        };
        let p = render(&s, &tracer, &opts, &mut |_| {}, &cancel).expect("not cancelled");
        let st = &p.stats;
        if let Ok(dir) = std::env::var("GLIMPSE_BENCH_LAYERS") {
            for (name, png) in glimpse::progressive::layers::encode_all(&p).expect("encode") {
                std::fs::write(format!("{dir}/cornell-{exposure}-{name}.png"), png).expect("write");
            }
            for it in &st.per_iteration {
                println!("  {it:?}");
            }
        }
        println!(
            "progressive exposure {exposure}: {} iterations, {:.1} % pixels, total {:.0} ms (trace {:.0}, metric {:.0}, triangulate {:.0}, analysis {:.0}), mean d {:.3}, t1 {:?}, stop {:?}, |ΔsRGB| {:.2}",
            st.iterations,
            100.0 * st.pixel_fraction,
            st.total_ms,
            st.trace_ms,
            st.metric_ms,
            st.triangulate_ms,
            st.analysis_ms,
            st.final_mean_distance,
            st.t1_used,
            st.stop_reason,
            displayed_error(&p.image, &reference, exposure)
        );
        if exposure == 1.0 {
            opts.mode = Some(RenderMode::Guo);
            opts.max_pixels = Some(st.pixels_traced);
            let g = render(&s, &tracer, &opts, &mut |_| {}, &cancel).expect("not cancelled");
            println!(
                "guo at equal pixels: {} iterations, {:.1} % pixels, total {:.0} ms, |ΔsRGB| {:.2}",
                g.stats.iterations,
                100.0 * g.stats.pixel_fraction,
                g.stats.total_ms,
                displayed_error(&g.image, &reference, exposure)
            );
            let budget = Duration::from_secs_f64(st.total_ms / 1e3);
            let t = Instant::now();
            let (u, spp) =
                uniform::render_equal_time(&s, &tracer, budget, &cancel).expect("not cancelled");
            println!(
                "uniform at equal time: spp {spp}, {:.0} ms (budget {:.0}), |ΔsRGB| {:.2}",
                t.elapsed().as_secs_f64() * 1e3,
                st.total_ms,
                displayed_error(&u, &reference, exposure)
            );
        }
    }
}
