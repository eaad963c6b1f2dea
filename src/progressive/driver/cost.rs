//! Whether the loop can pay for itself on a scene at all, asked before any of its work.
//!
//! The loop saves the pixels it does not trace and spends, over a render, an analysis of
//! every pixel and several passes of triangulation, reconstruction, shading and the
//! vision model over the whole image. Where paths are cheap (an open scene at a few
//! samples per pixel) that work costs more than the pixels it saves: the loop ends later
//! than the reference, on a picture no closer to the truth. Such a render is traced whole
//! from the start, as the reference mode traces it, and says so in its stop reason. Where
//! the loop runs, the probe (1 % of the pixels, traced once more if the loop picks them)
//! is all this costs it.

use super::budget::Stop;
use super::Settings;
use crate::cancel::{CancelToken, Cancelled};
use crate::progressive::{Frame, IterationStats, RenderStats};
use crate::raster::PixelCoord;
use crate::tracer::{self, PixelOracle};
use std::sync::Arc;
use std::time::Instant;

/// What the probe found, and what it cost (ms).
pub(super) enum Verdict {
    Loop { probe_ms: f64 },
    Reference { probe_ms: f64 },
}

/// Traces [`grid`] and weighs its rays per pixel ([`loop_pays`]). A render with a pixel
/// or time budget, or `force_loop`, always runs the loop, untouched by the probe.
pub(super) fn probe<O: PixelOracle>(
    oracle: &O,
    s: &Settings,
    cancel: &CancelToken,
) -> Result<Verdict, Cancelled> {
    if s.force_loop || s.max_pixels.is_some() || s.max_time.is_some() {
        return Ok(Verdict::Loop { probe_ms: 0.0 });
    }
    let t = Instant::now();
    let (w, h) = oracle.size();
    let pixels = grid(w, h);
    let rays = tracer::trace_estimates(oracle, &pixels, cancel)?
        .iter()
        .map(|e| u64::from(e.rays))
        .sum();
    let probe_ms = t.elapsed().as_secs_f64() * 1e3;
    Ok(if loop_pays(rays, pixels.len()) {
        Verdict::Loop { probe_ms }
    } else {
        Verdict::Reference { probe_ms }
    })
}

/// The render traced whole, as the reference mode does (the same image, bit for bit,
/// reporting its pixels through `on_pixels`), with the object ids as its `objects` layer.
/// `before_ms` is the preview's and the probe's time.
pub(super) fn reference<O: PixelOracle>(
    oracle: &O,
    s: &Settings,
    start: Instant,
    before_ms: f64,
    on_pixels: &(dyn Fn(usize, usize) + Sync),
    cancel: &CancelToken,
) -> Result<Frame, Cancelled> {
    let t = Instant::now();
    let image = tracer::render_reference(oracle, cancel, on_pixels)?;
    let trace_ms = t.elapsed().as_secs_f64() * 1e3;
    let objects = Arc::new(tracer::object_id_map(oracle));
    let (w, h) = oracle.size();
    let pixels = u64::from(w) * u64::from(h);
    let stats = RenderStats {
        mode: s.oracle.mode().into(),
        width: w,
        height: h,
        iterations: 1,
        pixels_traced: pixels,
        pixel_fraction: 1.0,
        total_ms: start.elapsed().as_secs_f64() * 1e3,
        trace_ms,
        analysis_ms: before_ms,
        per_iteration: vec![IterationStats {
            pixels_traced: pixels,
            trace_ms,
            ..IterationStats::default()
        }],
        stop_reason: Some(Stop::ReferenceCheaper.as_str().to_string()),
        ..RenderStats::default()
    };
    Ok(Frame::traced_whole(image, objects, stats))
}

/// The pixels whose rays [`loop_pays`] counts: every [`GRID_STEP`]th pixel of every
/// [`GRID_STEP`]th row, centred in its cell (1 % of the image).
fn grid(w: u32, h: u32) -> Vec<PixelCoord> {
    let half = GRID_STEP / 2;
    (half..h)
        .step_by(GRID_STEP as usize)
        .flat_map(|y| {
            (half..w)
                .step_by(GRID_STEP as usize)
                .map(move |x| PixelCoord::new(x, y))
        })
        .collect()
}

const GRID_STEP: u32 = 10;

/// Whether the loop can be expected to cost less than tracing every pixel, `probed`
/// pixels having cast `rays` ([`crate::tracer::Estimate::rays`]).
///
/// Over a whole render the loop analyses every pixel (a camera ray and up to four
/// footprint taps), traces a share of them ([`TYPICAL_TRACED`]), and several times
/// re-triangulates, reconstructs, shades and judges the image: about
/// [`LOOP_RAYS_PER_PIXEL`] rays' worth of work per image pixel. Where a pixel's paths
/// cast so few rays that the pixels the loop saves cost less than that, the loop cannot
/// save time. Rays, not seconds, so a render is the same on any machine at any load. An
/// oracle that does not count rays (0) is assumed to be worth the loop.
pub(super) fn loop_pays(rays: u64, probed: usize) -> bool {
    if rays == 0 || probed == 0 {
        return true;
    }
    let per_pixel = rays as f64 / probed as f64;
    per_pixel * (1.0 - TYPICAL_TRACED) > LOOP_RAYS_PER_PIXEL
}

/// The share of pixels a render typically traces ([`loop_pays`]): the median over a
/// 40-scene corpus is 22-25 %.
const TYPICAL_TRACED: f64 = 0.25;

/// The loop's own work over a render, in rays per image pixel ([`loop_pays`]). Measured
/// on 65 scenes (two generated corpora and the bundled examples; the loop forced, medians
/// of 3 runs): (loop time ÷ reference time − 0.25) × rays per pixel has a median of 30
/// and runs from about 0 to 186, growing with the iterations a render needs, which the
/// probe cannot know. 18 sends to the reference only scenes under 24 rays a pixel, where
/// the loop took 1.06-1.94× the reference's time on five of seven (0.70× and 0.85× on
/// the other two).
const LOOP_RAYS_PER_PIXEL: f64 = 18.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_samples_one_pixel_in_a_hundred_centred_in_its_cell() {
        let g = grid(100, 50);
        assert_eq!(g.len(), 50);
        assert_eq!((g[0].x, g[0].y), (5, 5));
        assert_eq!((g[49].x, g[49].y), (95, 45));
        assert!(grid(4, 4).is_empty(), "no cell centre inside a 4×4 image");
    }

    #[test]
    fn the_loop_pays_where_paths_are_long_enough_or_their_cost_unknown() {
        // 24 rays a pixel is the break-even point: 24 × (1 − 0.25) = 18.
        assert!(!loop_pays(2300, 100));
        assert!(loop_pays(2500, 100));
        assert!(loop_pays(0, 100), "an oracle that does not count");
        assert!(loop_pays(100, 0), "an image too small for the grid");
    }
}
