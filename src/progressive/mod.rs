//! The progressive perceptual renderer (F&P04 §4) and its baselines.
//!
//! One entry point, [`render`], serves the command line, the service and the benches:
//! it yields a [`Frame`] per iteration through a callback and returns the final one.
//! Owned by issue #4 (the reference mode below is the shared skeleton).

pub mod layers;
pub mod stats;

pub use stats::{IterationStats, RenderStats};

use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage};
use crate::scene::{RenderMode, Scene};
use crate::tracer::{self, PixelOracle};
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
    pub stats: RenderStats,
    /// True for the last frame of a render.
    pub last: bool,
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
}

/// Renders `scene` with `oracle`, calling `on_frame` for every iteration.
/// Returns the last frame, or `Cancelled` if `cancel` fired (frames already sent stand).
pub fn render(
    scene: &Scene,
    oracle: &impl PixelOracle,
    opts: &RenderOptions,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, Cancelled> {
    match opts.mode.unwrap_or(scene.render.mode) {
        RenderMode::Reference => render_reference(scene, oracle, on_frame, cancel),
        RenderMode::Progressive | RenderMode::Guo => {
            todo!("issue #4: progressive loop")
        }
    }
}

/// Every pixel traced: one frame at the end.
fn render_reference(
    scene: &Scene,
    oracle: &impl PixelOracle,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, Cancelled> {
    let start = Instant::now();
    let image = tracer::render_reference(oracle, cancel, &|_, _| {})?;
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
    let frame = Frame {
        iteration: 0,
        image,
        samples: Image::filled(w, h, SampleCell::New),
        distance: None,
        classes: Image::filled(w, h, ClassCell::None),
        stats,
        last: true,
    };
    on_frame(&frame);
    Ok(frame)
}
