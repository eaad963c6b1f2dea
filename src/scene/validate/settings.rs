//! The `render` and `progressive` sections of scene-format.md.

use super::*;

pub(super) fn check_render(cx: &mut Ctx, r: &RenderDoc) -> RenderSettings {
    // The ≥ 1 and limit checks on samples_per_pixel and max_bounces happen with the other
    // limits in `build`; a value that passed them fits a u32 (the limits are u32).
    let _ = cx;
    RenderSettings {
        mode: r.mode,
        samples_per_pixel: u32::try_from(r.samples_per_pixel).unwrap_or(u32::MAX),
        max_bounces: u32::try_from(r.max_bounces).unwrap_or(u32::MAX),
        seed: r.seed,
        sampler: r.sampler,
        denoise: r.denoise,
    }
}

pub(super) fn check_progressive(cx: &mut Ctx, p: &ProgressiveDoc) -> ProgressiveSettings {
    if cx.finite("progressive.t0", p.t0) && p.t0 < 0.0 {
        cx.err("progressive.t0", format!("must be ≥ 0, got {}", p.t0));
    }
    if let Some(t1) = p.t1 {
        if cx.finite("progressive.t1", t1) && t1 < 0.0 {
            cx.err("progressive.t1", format!("must be null or ≥ 0, got {t1}"));
        }
    }
    cx.fraction("progressive.initial_rate", p.initial_rate);
    cx.fraction("progressive.homogeneity", p.homogeneity);
    cx.positive("progressive.epsilon", p.epsilon);
    let max_iterations = match u32::try_from(p.max_iterations) {
        Ok(0) => {
            cx.err("progressive.max_iterations", "must be ≥ 1, got 0");
            1
        }
        Ok(n) => n,
        Err(_) => {
            cx.err(
                "progressive.max_iterations",
                format!("must be ≤ {}, got {}", u32::MAX, p.max_iterations),
            );
            u32::MAX
        }
    };
    ProgressiveSettings {
        t0: p.t0,
        t1: p.t1,
        initial_rate: p.initial_rate,
        homogeneity: p.homogeneity,
        epsilon: p.epsilon,
        max_iterations,
        force_loop: p.force_loop,
    }
}
