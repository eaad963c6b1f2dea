//! The progressive perceptual renderer (F&P04 §4) and its baselines.
//!
//! One entry point, [`render`], serves the command line, the service and the benches:
//! it yields a [`Frame`] per iteration through a callback and returns the final one.
//!
//! Pipeline (F&P04 §4, vision-model.md §6), see [`driver`]:
//! * [`seeding`] — §4.1: object-id map (one ray per pixel), contour map, edge-avoiding
//!   Gaussian probability map (zero ON contours, raised AROUND them), a deterministic draw
//!   with `render.seed`, plus the four image corners so the triangulation covers the image.
//! * [`mesh`] — spade Delaunay of every traced pixel (pixel centres = integer points) and
//!   Gouraud shading by bounding-box rasterisation (each pixel owned by one triangle),
//!   each pixel interpolated only from the vertices on its own object (exact id map).
//! * [`reconstruct`] — what each vertex contributes: its estimate averaged with similar
//!   neighbours on its object until the interpolated Monte Carlo noise is no more visible
//!   than the reference's grain at the declared pixels per degree (our extension).
//! * [`classify`] — mean block-map distance per triangle; final `d < T0` (strict),
//!   smooth `T0 ≤ d < T1`, complex `d ≥ T1`; T1 = `progressive.t1` or the mean of the
//!   first map, raised to `T0·(1+1e-3)` (§2.9).
//! * [`complex`] — contour walk, rupture pixels and directional interpolation; triangles
//!   with longest edge < 5 px are traced whole.
//! * [`guo`] — Guo's baseline: Mitchell's contrast test and the least-discrepancy search.
//! * [`uniform`] — the equal-time uniform baseline.
//! * [`noise`] — noise-aware classification, an EXTENSION of F&P04 for Monte Carlo
//!   oracles (F&P04 assumed exact light vectors): a noise twin of the first sample set
//!   gives a per-pixel map of the distance that noise alone produces; each triangle's
//!   distance has that noise component removed (Minkowski β = 2.4) before the T0/T1 rules,
//!   except across object contours. A noise-free oracle (bit-identical twins) keeps F&P04
//!   exactly; T0 = 0 traces no twin. Off with `RenderOptions::noise_compensation =
//!   Some(false)`. The twins are in `stats.noise_probe_pixels` and the timings, not in
//!   `pixels_traced`.
//!
//! Choices worth knowing:
//! * Frame 0 is the Gouraud image of the first sample set; frame 1 adds one sample near
//!   every triangle's centre; from frame 1 on, each frame carries the distance map between
//!   it and the previous frame and the classes that decide the next tracing step.
//! * Every traced pixel (contour pixels included) becomes a vertex, so a complex
//!   triangle is subdivided along its traced contour next iteration; its directional fill
//!   is shown in the frame that follows its contour tracing, then replaced by the finer
//!   triangulation's Gouraud shading (which the metric then judges).
//! * Pixels are traced once. Until every pixel is traced, a traced pixel shows its
//!   vertex's reconstructed value ([`reconstruct`]); once all are, the image is the traced
//!   estimates bit for bit, so T0 = 0 ends with the reference image exactly (non-finite
//!   oracle values are mapped to finite ones: NaN → 0, +∞ → 1e30, so one bad sample
//!   cannot spread through the interpolation).
//! * 1-pixel-wide images have no triangle (collinear samples): they are traced whole.
//! * Stop: every triangle final (no work), every pixel traced, `max_iterations` frames,
//!   `RenderOptions::max_pixels` (the last tracing step is truncated to the budget) or
//!   `max_time` (checked between chunks of 4096 pixels; the first sample set is always
//!   traced whole). `stats.stop_reason` says which.

pub mod adaptive;
pub mod classify;
pub mod complex;
pub mod driver;
pub mod eta;
pub mod guo;
pub mod layers;
pub mod memory;
pub mod mesh;
pub mod noise;
pub mod preview;
pub mod reconstruct;
pub mod seeding;
pub mod stats;
pub mod uniform;

pub use stats::{IterationStats, RenderStats};

use crate::cancel::{CancelToken, Cancelled};
use crate::denoise::{DenoiseError, Denoiser, Quality, Run};
use crate::raster::{Image, LinearImage};
use crate::scene::{ObjectId, RenderMode, Scene};
use crate::tracer::{self, PixelOracle};
use crate::vision::{DisplayModel, VisionModel};
use std::sync::Arc;
use std::time::Instant;

/// §4.2's three classes of triangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TriangleClass {
    /// Distance below T0: kept, Gouraud shaded, not refined.
    Final,
    /// T0 ≤ d < T1: Gouraud shaded, refined at its centre.
    Smooth,
    /// d ≥ T1: contour traced, interpolated along the least-discrepancy direction.
    Complex,
}

/// Value of a pixel in the `classes` layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum ClassCell {
    /// Not covered by any triangle (or no triangulation, e.g. reference mode).
    #[default]
    None = 0,
    Final = 1,
    Smooth = 2,
    Complex = 3,
}

impl From<TriangleClass> for ClassCell {
    fn from(c: TriangleClass) -> Self {
        match c {
            TriangleClass::Final => ClassCell::Final,
            TriangleClass::Smooth => ClassCell::Smooth,
            TriangleClass::Complex => ClassCell::Complex,
        }
    }
}

/// Value of a pixel in the `samples` layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum SampleCell {
    #[default]
    Interpolated = 0,
    /// Traced in an earlier iteration.
    Traced = 1,
    /// Traced in this iteration.
    New = 2,
}

/// One iteration's output.
#[derive(Clone, Debug)]
pub struct Frame {
    pub iteration: u32,
    /// Linear radiance (traced where traced, interpolated elsewhere).
    pub image: LinearImage,
    pub samples: Image<SampleCell>,
    /// The perceptual distance map between this frame and the previous one (JNDs).
    pub distance: Option<Image<f32>>,
    pub classes: Image<ClassCell>,
    /// The object-id map (§4.1: the object the ray through each pixel centre hits), shared
    /// by every frame of a render: the `objects` layer, for compositing and for judging
    /// whether objects kept their colour.
    pub objects: Arc<Image<ObjectId>>,
    pub stats: RenderStats,
    /// True for the last frame of a render.
    pub last: bool,
    /// A coarse picture shown before the first iteration ([`preview`]): only its `image`
    /// layer means anything, and no iteration has run.
    pub preview: bool,
}

impl Frame {
    /// The one frame of a render whose every pixel was traced in a single pass (the
    /// reference mode, or a render too cheap for the loop): `image` with its object-id
    /// map, every pixel new, no distance or classes.
    fn traced_whole(image: LinearImage, objects: Arc<Image<ObjectId>>, stats: RenderStats) -> Self {
        let (w, h) = (image.width(), image.height());
        Frame {
            iteration: 0,
            image,
            samples: Image::filled(w, h, SampleCell::New),
            distance: None,
            classes: Image::filled(w, h, ClassCell::None),
            objects,
            stats,
            last: true,
            preview: false,
        }
    }

    /// A 1×1 frame of iteration `iteration` whose mean distance is `d` (tests of what
    /// consumes frames: the time left, the service's jobs).
    #[cfg(test)]
    pub(crate) fn fixture(iteration: u32, d: f64, last: bool) -> Self {
        Frame {
            iteration,
            image: Image::filled(1, 1, crate::raster::Rgb::ZERO),
            samples: Image::filled(1, 1, SampleCell::New),
            distance: None,
            classes: Image::filled(1, 1, ClassCell::None),
            objects: Arc::new(Image::filled(1, 1, 0)),
            stats: RenderStats {
                per_iteration: vec![IterationStats {
                    iteration,
                    mean_distance: d,
                    ..Default::default()
                }],
                final_mean_distance: d,
                pixel_fraction: 0.1,
                ..Default::default()
            },
            last,
            preview: false,
        }
    }
}

/// How to run a render (beyond what the scene says).
#[derive(Clone, Debug, Default)]
pub struct RenderOptions {
    /// Overrides the scene's `render.mode` (`glimpse render --mode`).
    pub mode: Option<RenderMode>,
    /// Stop once this many pixels have been traced (Guo at equal pixel budget).
    pub max_pixels: Option<u64>,
    /// Stop after this much wall time (equal-time comparisons).
    pub max_time: Option<std::time::Duration>,
    /// Noise-aware classification ([`noise`]); `None` = on. `Some(false)` runs F&P04's
    /// classification on the raw distances (to measure the extension's effect).
    pub noise_compensation: Option<bool>,
    /// Overrides the scene's `render.denoise` (`glimpse render --denoise/--no-denoise`).
    pub denoise: Option<bool>,
    /// Adaptive mode: stop once this many paths have been traced over the image.
    pub max_samples: Option<u64>,
    /// The denoiser's scratch memory (OIDN's `maxMemoryMB`); `None` is OIDN's default,
    /// which grows with the image ([`memory`]).
    pub denoise_memory_mb: Option<u32>,
}

/// Whether a render of `scene` with `opts` denoises: the options, else the scene's
/// `render.denoise`, else on in adaptive mode only.
#[must_use]
pub fn wants_denoise(scene: &Scene, opts: &RenderOptions) -> bool {
    let mode = opts.mode.unwrap_or(scene.render.mode);
    opts.denoise
        .or(scene.render.denoise)
        .unwrap_or(mode == RenderMode::Adaptive)
}

/// The denoiser a render of `scene` with `opts` needs, `None` if it does not denoise;
/// the error names what is missing and how to add it. Callers ask before rendering, so
/// a render that was asked to denoise never silently comes back without it.
pub fn denoiser_for(
    scene: &Scene,
    opts: &RenderOptions,
) -> Result<Option<&'static Denoiser>, DenoiseError> {
    if wants_denoise(scene, opts) {
        Denoiser::shared().map(Some)
    } else {
        Ok(None)
    }
}

/// OIDN's `inputScale` for the scene's display: 1.0 means 100 cd/m², and a radiance v
/// is shown at v · exposure · peak luminance cd/m² (vision-model.md §2.1).
#[must_use]
pub fn denoise_input_scale(scene: &Scene) -> Option<f32> {
    let s = scene.display.exposure * scene.display.peak_luminance / 100.0;
    (s.is_finite() && s > 0.0).then_some(s)
}

/// Why a render returned no picture.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The render's cancel token fired (frames already sent stand).
    #[error("cancelled")]
    Cancelled,
    /// The render was asked to denoise and the denoiser failed (or is missing): a picture
    /// that is not denoised is not what was asked for.
    #[error("the picture could not be denoised: {0}")]
    Denoise(DenoiseError),
}

impl From<Cancelled> for RenderError {
    fn from(_: Cancelled) -> Self {
        RenderError::Cancelled
    }
}

impl From<DenoiseError> for RenderError {
    fn from(e: DenoiseError) -> Self {
        match e {
            DenoiseError::Cancelled => RenderError::Cancelled,
            e => RenderError::Denoise(e),
        }
    }
}

/// Renders `scene` with `oracle`, calling `on_frame` for every iteration.
/// Returns the last frame, or why there is none (frames already sent stand).
pub fn render(
    scene: &Scene,
    oracle: &impl PixelOracle,
    opts: &RenderOptions,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, RenderError> {
    render_reporting(scene, oracle, opts, on_frame, &|_, _| {}, cancel)
}

/// [`render`], also reporting `(pixels done, pixels in all)` through `on_pixels` during
/// a single pass that has no frame until its end (the reference mode's, and a
/// progressive render's traced whole because its paths are too cheap for the loop): the
/// command line's progress bar.
pub fn render_reporting(
    scene: &Scene,
    oracle: &impl PixelOracle,
    opts: &RenderOptions,
    on_frame: &mut dyn FnMut(&Frame),
    on_pixels: &(dyn Fn(usize, usize) + Sync),
    cancel: &CancelToken,
) -> Result<Frame, RenderError> {
    let mode = opts.mode.unwrap_or(scene.render.mode);
    // The command line and the service ask [`denoiser_for`] before accepting the work;
    // a library caller that did not is refused here, before anything is traced.
    let denoiser = denoiser_for(scene, opts)?;
    let run = denoise_run(scene, opts, cancel);
    if mode == RenderMode::Adaptive {
        let denoise = denoiser.map(|d| (d, run));
        return render_adaptive(scene, oracle, opts, denoise, on_frame, cancel);
    }
    let Some(denoiser) = denoiser else {
        return render_mode(scene, oracle, opts, mode, on_frame, on_pixels, cancel);
    };
    // The last frame goes through the denoiser before anyone sees it.
    let mut last: Option<Result<Frame, RenderError>> = None;
    let mut denoise_last = |f: &Frame| {
        if !f.last {
            return on_frame(f);
        }
        let denoised = denoise_frame(oracle, denoiser, &run, f);
        if let Ok(d) = &denoised {
            on_frame(d);
        }
        last = Some(denoised);
    };
    let frame = render_mode(
        scene,
        oracle,
        opts,
        mode,
        &mut denoise_last,
        on_pixels,
        cancel,
    )?;
    cancel.check()?;
    last.unwrap_or_else(|| denoise_frame(oracle, denoiser, &run, &frame))
}

/// How a render's denoises run: at the best quality, at the scene's display, stopped by
/// the render's cancel, within the scratch memory the options allow.
fn denoise_run(scene: &Scene, opts: &RenderOptions, cancel: &CancelToken) -> Run {
    Run {
        quality: Quality::High,
        input_scale: denoise_input_scale(scene),
        cancel: cancel.clone(),
        max_memory_mb: opts.denoise_memory_mb,
    }
}

/// `frame` with its picture denoised at the best quality, the auxiliary images traced
/// for it.
fn denoise_frame(
    oracle: &impl PixelOracle,
    denoiser: &Denoiser,
    run: &Run,
    frame: &Frame,
) -> Result<Frame, RenderError> {
    let t = Instant::now();
    let filter = adaptive::estimate::Filter::Denoised {
        denoiser,
        aux: tracer::aux::aux_maps(oracle, &run.cancel)?,
        run: run.clone(),
    };
    let mut out = frame.clone();
    out.image = filter.apply(&frame.image, Quality::High)?;
    out.stats.denoised = true;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    out.stats.denoise_ms += ms;
    out.stats.total_ms += ms;
    Ok(out)
}

/// The adaptive mode ([`adaptive`]), denoising every pass when `denoise` is given.
fn render_adaptive(
    scene: &Scene,
    oracle: &impl PixelOracle,
    opts: &RenderOptions,
    denoise: Option<(&Denoiser, Run)>,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, RenderError> {
    let (w, h) = oracle.size();
    let p = &scene.progressive;
    let max_spp = scene.render.samples_per_pixel.max(1);
    let settings = adaptive::Settings {
        max_spp,
        first_spp: adaptive::Settings::first_spp_for(max_spp, opts.max_samples, w, h),
        t0: p.t0,
        seed: scene.render.seed,
        max_passes: p.max_iterations,
        max_time: opts.max_time,
        max_samples: opts.max_samples,
        metric: crate::metric::MetricParams {
            homogeneity: p.homogeneity,
            epsilon: p.epsilon,
            seed: scene.render.seed,
        },
    };
    let model = VisionModel::new(display_model(scene), w, h);
    adaptive::render(oracle, &settings, model, denoise, on_frame, cancel)
}

/// The modes that do not denoise as they go: reference, the F&P04 loop, Guo.
fn render_mode(
    scene: &Scene,
    oracle: &impl PixelOracle,
    opts: &RenderOptions,
    mode: RenderMode,
    on_frame: &mut dyn FnMut(&Frame),
    on_pixels: &(dyn Fn(usize, usize) + Sync),
    cancel: &CancelToken,
) -> Result<Frame, RenderError> {
    Ok(match mode {
        RenderMode::Adaptive => render_adaptive(scene, oracle, opts, None, on_frame, cancel)?,
        RenderMode::Reference => render_reference(scene, oracle, on_frame, on_pixels, cancel)?,
        RenderMode::Progressive => {
            let settings = settings(scene, opts, driver::Oracle::Perceptual);
            // The oracle's size is authoritative (it is what gets traced).
            let (w, h) = oracle.size();
            let mut judge = driver::VisionJudge::new(
                VisionModel::new(display_model(scene), w, h),
                scene.progressive.homogeneity,
                scene.progressive.epsilon,
                scene.render.seed,
            );
            driver::run_reporting(oracle, &settings, &mut judge, on_frame, on_pixels, cancel)?
        }
        RenderMode::Guo => {
            let settings = settings(scene, opts, driver::Oracle::Guo);
            driver::run_reporting(oracle, &settings, &mut NoJudge, on_frame, on_pixels, cancel)?
        }
    })
}

/// The vision model's view of the scene's display (scene-format.md `display`): what the
/// perceptual judge, the bench's metric column and the tests calibrate the model with.
#[must_use]
pub fn display_model(scene: &Scene) -> DisplayModel {
    let d = scene.display;
    DisplayModel {
        peak_luminance: d.peak_luminance,
        black_luminance: d.black_luminance,
        exposure: d.exposure,
        pixels_per_degree: d.pixels_per_degree,
    }
}

/// Guo mode never asks for a distance.
struct NoJudge;

impl driver::Judge for NoJudge {
    fn distance(
        &mut self,
        _: &LinearImage,
        _: &LinearImage,
        _: &[crate::raster::PixelCoord],
        _: u32,
    ) -> Option<Image<f32>> {
        None
    }
}

fn settings(scene: &Scene, opts: &RenderOptions, oracle: driver::Oracle) -> driver::Settings {
    let p = &scene.progressive;
    driver::Settings {
        oracle,
        t0: p.t0,
        t1: p.t1,
        initial_rate: p.initial_rate,
        max_iterations: p.max_iterations,
        seed: scene.render.seed,
        exposure: scene.display.exposure,
        max_pixels: opts.max_pixels,
        max_time: opts.max_time,
        samples_per_pixel: scene.render.samples_per_pixel,
        noise_compensation: opts.noise_compensation.unwrap_or(true),
        force_loop: p.force_loop,
        pixels_per_degree: scene.display.pixels_per_degree,
    }
}

/// Every pixel traced: one frame at the end.
fn render_reference(
    scene: &Scene,
    oracle: &impl PixelOracle,
    on_frame: &mut dyn FnMut(&Frame),
    on_pixels: &(dyn Fn(usize, usize) + Sync),
    cancel: &CancelToken,
) -> Result<Frame, Cancelled> {
    let start = Instant::now();
    let image = tracer::render_reference(oracle, cancel, on_pixels)?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let (w, h) = (scene.width, scene.height);
    let stats = RenderStats {
        mode: RenderMode::Reference.as_str().into(),
        width: w,
        height: h,
        iterations: 1,
        pixels_traced: u64::from(w) * u64::from(h),
        pixel_fraction: 1.0,
        total_ms: ms,
        trace_ms: ms,
        ..RenderStats::default()
    };
    let objects = Arc::new(tracer::object_id_map(oracle));
    let frame = Frame::traced_whole(image, objects, stats);
    on_frame(&frame);
    Ok(frame)
}
