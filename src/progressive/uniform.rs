//! The equal-time uniform baseline: every pixel traced, with as many samples per pixel as
//! fit in a wall-time budget.
//!
//! "Equal time" here means equal *wall* time on the same machine and thread pool: the
//! budget is normally the total_ms of the progressive run being compared, and it covers
//! everything this function does, including its own timing pilot. The first pass's spp is
//! estimated from a pilot of 1 sample per pixel on a sparse, evenly spread subset of
//! pixels; a 1-spp pilot over-estimates the per-sample cost (fixed per-pixel and
//! scheduling costs), so once that pass has run, its measured cost per spp sizes a second
//! pass (another seed) that fills the budget left. The two passes are averaged weighted by
//! their spp, which is exactly an estimator with their total spp: the image still has one
//! uniform spp everywhere (at least 1, even if the budget is smaller than one pass).

use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{LinearImage, PixelCoord};
use crate::scene::Scene;
use crate::tracer::{self, PixelOracle};
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// Pixels in the timing pilot (or all pixels of a smaller image).
pub const PILOT_PIXELS: usize = 1024;

/// Renders every pixel with the spp that fits in `budget`; returns the image and the spp.
pub fn render_equal_time(
    scene: &Scene,
    oracle: &impl PixelOracle,
    budget: Duration,
    cancel: &CancelToken,
) -> Result<(LinearImage, u32), Cancelled> {
    let start = Instant::now();
    let (w, h) = oracle.size();
    let n = w as usize * h as usize;
    let seed = scene.render.seed;
    let spp = if n == 0 {
        1
    } else {
        let step = n.div_ceil(PILOT_PIXELS).max(1);
        let pilot: Vec<PixelCoord> = (0..n)
            .step_by(step)
            .map(|i| PixelCoord::new((i % w as usize) as u32, (i / w as usize) as u32))
            .collect();
        let t = Instant::now();
        // A different seed than the final pass, so the pilot does not warm any cache the
        // final pass would then hit for free (the oracle is pure, but be safe).
        pilot.par_iter().for_each(|&p| {
            let _ = oracle.radiance_with(p, 1, seed ^ 0x9E37_79B9);
        });
        if cancel.is_cancelled() {
            return Err(Cancelled);
        }
        let per_pixel = t.elapsed().as_secs_f64() / pilot.len() as f64;
        let pass = (per_pixel * n as f64).max(1e-9);
        let left = budget.saturating_sub(start.elapsed()).as_secs_f64();
        spp_for(left, pass)
    };
    let t = Instant::now();
    let mut img = tracer::render_reference_with(oracle, Some((spp, seed)), cancel, &|_, _| {})?;
    let per_spp = t.elapsed().as_secs_f64() / f64::from(spp);
    let left = budget.saturating_sub(start.elapsed()).as_secs_f64();
    // Only when at least one more full sample per pixel fits.
    if left >= per_spp {
        let more = spp_for(left, per_spp);
        let second = tracer::render_reference_with(
            oracle,
            Some((more, seed ^ SECOND_PASS_SEED)),
            cancel,
            &|_, _| {},
        )?;
        let (a, b) = (spp as f32, more as f32);
        for (p, q) in img.pixels_mut().iter_mut().zip(second.pixels()) {
            *p = (*p * a + *q * b) / (a + b);
        }
        return Ok((img, spp + more));
    }
    Ok((img, spp))
}

/// Seed offset of the second pass (independent samples from the first).
const SECOND_PASS_SEED: u64 = 0x5851_F42D_4C95_7F2D;

/// Samples per pixel that fit `left` seconds at `pass` seconds per 1-spp pass: at least 1,
/// at most 1 << 20 (the command line's spp limit).
#[must_use]
pub fn spp_for(left: f64, pass: f64) -> u32 {
    let s = (left / pass).floor();
    if s.is_finite() {
        s.clamp(1.0, f64::from(1u32 << 20)) as u32
    } else {
        1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spp_is_budget_over_pass_time_clamped() {
        assert_eq!(spp_for(1.0, 0.1), 10);
        assert_eq!(spp_for(0.01, 0.1), 1);
        assert_eq!(spp_for(0.0, 0.1), 1);
        assert_eq!(spp_for(1e9, 1e-9), 1 << 20);
        assert_eq!(spp_for(f64::NAN, 1.0), 1);
    }
}
