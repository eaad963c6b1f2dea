//! `adaptive` mode: F&P04's principle applied to samples instead of pixels.
//!
//! Every pixel is traced, in passes. After each pass the picture is reconstructed (through
//! the denoiser when the render denoises), its remaining error is estimated from two
//! independent half images ([`estimate`]), and the vision model turns that error into
//! what a person would see at the scene's display and viewing distance. The next pass
//! spends samples where that visible error per unit of cost is largest ([`allocate`]);
//! the render stops when no tile shows more than t0 JND (or, where the reference itself
//! would show more, t0 × [`REFERENCE_SHARE`] of the reference's) for two passes in a row, when
//! every pixel has the scene's `samples_per_pixel`, or at the time or sample budget.
//!
//! With t0 = 0 every pixel gets `samples_per_pixel` paths, summed in the reference's own
//! arithmetic and order ([`crate::tracer::SampleSum`]): without the denoiser the last
//! frame is the reference image bit for bit.

pub mod allocate;
pub mod estimate;
pub mod pixels;

use super::{ClassCell, Frame, IterationStats, RenderError, RenderStats, SampleCell};
use crate::cancel::{CancelToken, Cancelled};
use crate::denoise::{Denoiser, Quality, Run};
use crate::metric::MetricParams;
use crate::raster::{Image, LinearImage};
use crate::scene::ObjectId;
use crate::tracer::{self, PixelOracle};
use crate::vision::VisionModel;
use allocate::{PassLimits, Tile};
use estimate::{Filter, Picture};
use pixels::{Pixels, Traced};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Side of the square tiles the visible error is pooled over before samples are placed:
/// one pixel's estimate is itself noise (a few samples per half), a tile's mean is not.
pub const TILE: u32 = 8;

/// A tile may keep this share of the visible error the reference would leave there
/// ([`estimate::reference_visible`]), when that is more than 1 JND: asking a denoised
/// picture for less error than the full render has is what made the door trace every
/// sample. The half images measure the noise the denoiser leaves, not the detail it blurs
/// away, so the loop keeps a margin below the reference rather than aiming at it.
pub const REFERENCE_SHARE: f32 = 0.5;

/// What an adaptive render is asked for.
#[derive(Clone, Debug)]
pub struct Settings {
    /// The most samples a pixel gets (the scene's `samples_per_pixel`).
    pub max_spp: u32,
    /// Samples of the first pass, every pixel.
    pub first_spp: u32,
    /// Visible error (JND) at which a tile is done.
    pub t0: f32,
    pub seed: u64,
    pub max_passes: u32,
    pub max_time: Option<Duration>,
    pub max_samples: Option<u64>,
    pub metric: MetricParams,
}

impl Settings {
    /// The first pass: an eighth of the samples, at least 8 (4 per half: fewer make the
    /// error estimate itself noise), at most all of them or what the sample budget
    /// allows a `width`×`height` image (at least 1), even (two equal halves).
    #[must_use]
    pub fn first_spp_for(max_spp: u32, max_samples: Option<u64>, width: u32, height: u32) -> u32 {
        let pixels = (u64::from(width) * u64::from(height)).max(1);
        let budget =
            max_samples.map_or(u32::MAX, |m| u32::try_from(m / pixels).unwrap_or(u32::MAX));
        let n = (max_spp / 8).max(8).min(max_spp.max(1)).min(budget.max(1));
        if n > 1 && n % 2 == 1 {
            n - 1
        } else {
            n
        }
    }
}

/// Why a pass was the last.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stop {
    NothingVisible,
    AllAtMax,
    MaxTime,
    MaxSamples,
    MaxPasses,
    TracedRest,
}

impl Stop {
    fn as_str(self) -> &'static str {
        match self {
            Stop::NothingVisible => "all_final",
            Stop::AllAtMax => "all_traced",
            Stop::MaxTime => "max_time",
            Stop::MaxSamples => "max_samples",
            Stop::MaxPasses => "max_iterations",
            Stop::TracedRest => "traced_rest",
        }
    }
}

/// What a pass's judgement found.
struct Judged {
    pic: Picture,
    /// The picture's visible error (JND per pixel); `None` if the model could not judge.
    visible: Option<Image<f32>>,
    /// The reference's predicted visible error, when the picture is denoised.
    reference: Option<Image<f32>>,
}

/// The loop's state between passes.
struct Loop<'a> {
    settings: &'a Settings,
    model: VisionModel,
    filter: Filter<'a>,
    pixels: Pixels,
    objects: Arc<Image<ObjectId>>,
    stats: RenderStats,
    start: Instant,
    /// Passes in a row that showed nothing above t0.
    calm: u32,
    /// What the last pass's reconstruction took: the final one is reserved from the time.
    last_filter: Duration,
    /// The current pass's tracing and judging times, for its [`IterationStats`].
    pass_trace_ms: f64,
    pass_metric_ms: f64,
}

/// Renders in passes, calling `on_frame` for each; returns the last frame. `denoise`:
/// the denoiser and how it runs (its quality is chosen per pass), `None` to keep passes
/// raw. A denoiser that fails ends the render with its error: a render asked to denoise
/// never comes back noisy.
pub fn render(
    oracle: &impl PixelOracle,
    settings: &Settings,
    model: VisionModel,
    denoise: Option<(&Denoiser, Run)>,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, RenderError> {
    let start = Instant::now();
    let (w, h) = oracle.size();
    let objects = Arc::new(tracer::object_id_map(oracle));
    let filter = match denoise {
        Some((denoiser, run)) => Filter::Denoised {
            denoiser,
            aux: tracer::aux::aux_maps(oracle, cancel)?,
            run,
        },
        None => Filter::Raw,
    };
    let mut lp = Loop {
        settings,
        model,
        pixels: Pixels::new(w, h),
        objects,
        stats: RenderStats {
            mode: "adaptive".into(),
            width: w,
            height: h,
            denoised: filter.denoises(),
            ..RenderStats::default()
        },
        filter,
        start,
        calm: 0,
        last_filter: Duration::ZERO,
        pass_trace_ms: 0.0,
        pass_metric_ms: 0.0,
    };
    lp.stats.analysis_ms = ms(start.elapsed());
    let mut extra = vec![settings.first_spp.min(settings.max_spp); (w * h) as usize];
    for pass in 0.. {
        let traced = lp.trace(oracle, &extra, cancel)?;
        let Judged {
            pic,
            visible,
            reference,
        } = lp.judge(pass, cancel)?;
        let tiles = lp.tiles(visible.as_ref(), reference.as_ref());
        if let Some(stop) = lp.stop(pass, traced, &tiles) {
            return lp.last_frame(pass, visible, &extra, stop, on_frame);
        }
        let (next, finishing) = lp.plan(&tiles);
        if finishing {
            // The rest costs less than another pass: trace it and end (`traced_rest`).
            on_frame(&lp.frame(pass, pic.image, visible.clone(), &extra, false));
            lp.trace(oracle, &next, cancel)?;
            return lp.last_frame(pass + 1, visible, &next, Stop::TracedRest, on_frame);
        }
        if next.iter().all(|&n| n == 0) {
            // Nothing above t0 that is not at max_spp already: nothing left to spend on.
            let stop = if lp.calm > 0 {
                Stop::NothingVisible
            } else {
                Stop::AllAtMax
            };
            return lp.last_frame(pass, visible, &extra, stop, on_frame);
        }
        // A streamed pass shows the mean of its two reconstructed halves (already made
        // for the error estimate); only the last frame reconstructs all the samples at once.
        on_frame(&lp.frame(pass, pic.image, visible, &extra, false));
        extra = next;
    }
    unreachable!("the pass loop only returns")
}

impl Loop<'_> {
    /// Traces the pass's samples, stopping at the deadline (less the final
    /// reconstruction's time) if there is one.
    fn trace(
        &mut self,
        oracle: &impl PixelOracle,
        extra: &[u32],
        cancel: &CancelToken,
    ) -> Result<Traced, Cancelled> {
        let t = Instant::now();
        let deadline = self
            .settings
            .max_time
            .map(|m| self.start + m.saturating_sub(self.last_filter * 2));
        let traced = self
            .pixels
            .trace(oracle, extra, self.settings.seed, deadline, cancel)?;
        let took = ms(t.elapsed());
        self.pass_trace_ms += took;
        self.stats.trace_ms += took;
        Ok(traced)
    }

    /// The pass's picture (the mean of its halves reconstructed at the streamed quality),
    /// the visible error left in it and, when it is denoised, the visible error the
    /// reference would leave ([`estimate::reference_visible`]).
    fn judge(&mut self, pass: u32, cancel: &CancelToken) -> Result<Judged, RenderError> {
        let t = Instant::now();
        let (a, b) = self.pixels.halves();
        let pic = estimate::picture((&a, &b), &self.filter, Quality::Fast)?;
        // Two reconstructions: about what the last frame's one at the best quality costs.
        self.last_filter = t.elapsed();
        if self.filter.denoises() {
            self.stats.denoise_ms += ms(self.last_filter);
        }
        let t = Instant::now();
        let params = MetricParams {
            seed: self.settings.metric.seed
                ^ u64::from(pass + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            ..self.settings.metric
        };
        // The vision model's maps take a few hundred ms at 2048² and do not look at the
        // token: a cancel is seen between them.
        cancel.check()?;
        let visible = estimate::visible_error(&self.model, &pic, &params);
        cancel.check()?;
        // Raw, the picture is the reference's estimator: its error can only reach the
        // reference's at max_spp, so there is nothing to compare.
        let reference = if self.filter.denoises() {
            let counts = self.pixels.counts();
            let max = self.settings.max_spp;
            estimate::reference_visible(&self.model, (&a, &b), &counts, max, &params)
        } else {
            None
        };
        self.pass_metric_ms = ms(t.elapsed());
        self.stats.metric_ms += self.pass_metric_ms;
        Ok(Judged {
            pic,
            visible,
            reference,
        })
    }

    /// The picture of all the samples so far, reconstructed at `quality`.
    fn reconstruct(&mut self, quality: Quality) -> Result<LinearImage, RenderError> {
        let t = Instant::now();
        let image = self.filter.apply(&self.pixels.mean(), quality)?;
        if self.filter.denoises() {
            self.stats.denoise_ms += ms(t.elapsed());
        }
        Ok(image)
    }

    /// Each tile's samples, visible error and cost. The error is counted in what the tile
    /// may keep: 1 JND, or [`REFERENCE_SHARE`] of the reference's own visible error where
    /// that is larger.
    fn tiles(&self, visible: Option<&Image<f32>>, reference: Option<&Image<f32>>) -> Vec<Tile> {
        let counts = self.pixels.counts();
        let cost = self.pixels.cost();
        let (w, h) = (counts.width(), counts.height());
        let pooled = visible.map(|v| estimate::pool_mean(v, TILE));
        let allowed = reference.map(|r| estimate::pool_mean(r, TILE));
        let (tw, th) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let mut tiles = Vec::with_capacity((tw * th) as usize);
        for ty in 0..th {
            for tx in 0..tw {
                let (x0, y0) = (tx * TILE, ty * TILE);
                let (x1, y1) = ((x0 + TILE).min(w), (y0 + TILE).min(h));
                let mut samples = u32::MAX;
                let mut c = 0f32;
                for y in y0..y1 {
                    for x in x0..x1 {
                        samples = samples.min(*counts.get(x, y));
                        c += cost.get(x, y);
                    }
                }
                let pixels = (x1 - x0) * (y1 - y0);
                let i = (ty * tw + tx) as usize;
                tiles.push(Tile {
                    pixels,
                    samples,
                    // Unjudged: unfinished, as visible as the worst the metric reports.
                    visible: pooled.as_ref().map_or(f32::INFINITY, |p| {
                        let reference = allowed.as_ref().map_or(0.0, |a| a[i] * REFERENCE_SHARE);
                        p[i] / reference.max(1.0)
                    }),
                    cost: c / pixels as f32,
                });
            }
        }
        tiles
    }

    /// Whether this pass is the last, and why.
    fn stop(&mut self, pass: u32, traced: Traced, tiles: &[Tile]) -> Option<Stop> {
        let s = self.settings;
        let open = tiles
            .iter()
            .filter(|t| t.samples < s.max_spp && !(t.visible <= s.t0 && s.t0 > 0.0))
            .count();
        self.calm = if open == 0 { self.calm + 1 } else { 0 };
        if tiles.iter().all(|t| t.samples >= s.max_spp) {
            Some(Stop::AllAtMax)
        } else if traced == Traced::Deadline
            || s.max_time
                .is_some_and(|m| self.start.elapsed() + self.last_filter * 2 >= m)
        {
            Some(Stop::MaxTime)
        } else if s.max_samples.is_some_and(|m| self.pixels.total() >= m) {
            Some(Stop::MaxSamples)
        } else if self.calm >= 2 {
            Some(Stop::NothingVisible)
        } else if pass + 1 >= s.max_passes {
            Some(Stop::MaxPasses)
        } else {
            None
        }
    }

    /// The next pass's samples per pixel: the tiles' plan spread over their pixels,
    /// within the sample budget; and whether it finishes the render (the rest traced
    /// whole, [`allocate::finish_if_cheaper`]).
    fn plan(&self, tiles: &[Tile]) -> (Vec<u32>, bool) {
        let s = self.settings;
        let total = self.pixels.total();
        let mut budget = total.max(1);
        if let Some(m) = s.max_samples {
            budget = budget.min(m.saturating_sub(total));
        }
        let limits = PassLimits {
            // A pass that was not calm may have been lucky: once calm, keep sampling
            // until a second calm pass confirms it (two passes in a row).
            t0: if self.calm == 1 { s.t0 * 0.75 } else { s.t0 },
            max_spp: s.max_spp,
            budget,
        };
        let mut per_tile = allocate::plan(tiles, &limits);
        let pixels = tiles.iter().map(|t| u64::from(t.pixels)).sum::<u64>();
        let finishing = allocate::finish_if_cheaper(
            tiles,
            &mut per_tile,
            s.max_spp,
            pixels * allocate::PASS_COST_SPP,
            budget,
        );
        let counts = self.pixels.counts();
        let (w, h) = (counts.width(), counts.height());
        let tw = w.div_ceil(TILE);
        let mut extra = vec![0u32; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let t = per_tile[((y / TILE) * tw + x / TILE) as usize];
                // The tile's fewest-sampled pixel sets its count; the others catch up to
                // the same total (a pass truncated by the deadline leaves them uneven).
                let n = *counts.get(x, y);
                let tile_min = tiles[((y / TILE) * tw + x / TILE) as usize].samples;
                let target = (tile_min + t).min(s.max_spp);
                extra[(y * w + x) as usize] = if t == 0 { 0 } else { target.saturating_sub(n) };
            }
        }
        (extra, finishing)
    }

    /// A frame of the render so far.
    fn frame(
        &mut self,
        pass: u32,
        image: LinearImage,
        visible: Option<Image<f32>>,
        extra: &[u32],
        last: bool,
    ) -> Frame {
        let (w, h) = (image.width(), image.height());
        let mean_distance = visible.as_ref().map_or(0.0, |v| {
            v.pixels().iter().map(|&d| f64::from(d)).sum::<f64>() / v.len().max(1) as f64
        });
        let samples = Image::from_vec(
            w,
            h,
            extra
                .iter()
                .map(|&n| {
                    if n > 0 {
                        SampleCell::New
                    } else {
                        SampleCell::Traced
                    }
                })
                .collect(),
        )
        .expect("one count per pixel");
        let s = &mut self.stats;
        s.iterations = pass + 1;
        s.samples_traced = self.pixels.total();
        s.pixels_traced = u64::from(w) * u64::from(h);
        s.pixel_fraction = 1.0;
        s.final_mean_distance = mean_distance;
        s.total_ms = ms(self.start.elapsed());
        s.per_iteration.push(IterationStats {
            iteration: pass,
            pixels_traced: extra.iter().filter(|&&n| n > 0).count() as u64,
            trace_ms: std::mem::take(&mut self.pass_trace_ms),
            metric_ms: std::mem::take(&mut self.pass_metric_ms),
            mean_distance,
            ..IterationStats::default()
        });
        Frame {
            iteration: pass,
            image,
            samples,
            distance: visible,
            classes: Image::filled(w, h, ClassCell::None),
            objects: Arc::clone(&self.objects),
            stats: self.stats.clone(),
            last,
            preview: false,
        }
    }

    /// The last frame: the picture at the denoiser's best quality.
    fn last_frame(
        &mut self,
        pass: u32,
        visible: Option<Image<f32>>,
        extra: &[u32],
        stop: Stop,
        on_frame: &mut dyn FnMut(&Frame),
    ) -> Result<Frame, RenderError> {
        let image = self.reconstruct(Quality::High)?;
        self.stats.stop_reason = Some(stop.as_str().into());
        let frame = self.frame(pass, image, visible, extra, true);
        on_frame(&frame);
        Ok(frame)
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}
