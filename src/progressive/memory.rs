//! What a render will need in memory, known before it starts: the service refuses a job
//! that would not fit the operator's per-job budget and bounds the denoiser's scratch
//! memory by what is left of it; the command line refuses a render the machine cannot
//! hold, with one sentence instead of an allocation failure.
//!
//! The per-pixel costs are measured peaks of `glimpse render --stats` (its
//! `phases.memory.peak_bytes`) at 1024² and 2048², rounded up; docs/measurements.md
//! ("Memory of one job") has the table and the command. The denoiser's own scratch
//! memory (OIDN's `maxMemoryMB`) is apart: left alone it grows with the image, about
//! 0.8 KB a pixel, which is what made a 4096² denoise need ~16 GB.

use super::RenderOptions;
use crate::scene::{RenderMode, Scene};

/// What the process holds before any render: code, the runtime, the vision model's
/// tables, the scene's small parts.
const BASE_BYTES: u64 = 64 << 20;

/// The tracer's geometry and BVH per triangle (the scene's own copy is released once the
/// tracer is built).
const BYTES_PER_TRIANGLE: u64 = 320;

/// The smallest scratch the denoiser is given. Measured at 2048² (High, with guides):
/// 256 MB peaks as high as 512 MB (OIDN's own floor) and takes 1.4× its time; 512 MB
/// 2.4× the untiled time, 1 GB 1.7×, 2 GB 1.5×.
pub const MIN_DENOISE_SCRATCH_MB: u32 = 512;

/// The most scratch the denoiser is given: what it takes untiled at 2048² (2.7 GB),
/// the size where tiling would start to cost (see [`MIN_DENOISE_SCRATCH_MB`]).
pub const MAX_DENOISE_SCRATCH_MB: u32 = 4096;

/// A render's memory, estimated from its scene and options.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryEstimate {
    /// Everything but the denoiser's scratch: the tracer, the mode's per-pixel state,
    /// the frames, and the denoiser's images (inputs, guides, output) when it denoises.
    pub render_bytes: u64,
    /// Whether the render denoises (and so needs scratch memory besides).
    pub denoises: bool,
}

/// Bytes a pixel costs in `mode`, the frames handed to the caller included.
fn bytes_per_pixel(mode: RenderMode) -> u64 {
    match mode {
        // The image, its per-pixel sums and the frame (measured 18 B at 2048²).
        RenderMode::Reference => 48,
        // Per-pixel loop state (estimates, variances, vertex values), the triangulation,
        // the vision model's maps, the frame's five layers (measured 313 B at 1024²,
        // 345 B at 2048², 376 B at 4096²: the triangulation grows a little faster than
        // the pixels).
        RenderMode::Progressive => 400,
        // The same loop without the vision model, refining further (measured 300 B at
        // 1024², 328 B at 2048², 480 B at 4096²).
        RenderMode::Guo => 500,
        // Per-pixel sums of two halves, the passes' pictures and error maps (measured
        // 203 B at 1024², 238 B at 2048²).
        RenderMode::Adaptive => 280,
    }
}

/// The denoiser's images per pixel beside the mode's own: colour, albedo and normal,
/// their sanitised copies, the output and the frame it goes into. A reference or adaptive
/// render holds them beside everything else (a reference render with the denoiser held
/// 840 B a pixel more than without at 1024²; OIDN's untiled scratch at 2048², 2.7 GB,
/// is ~650 B of it, so ~190 B is the images, estimated, not measured apart); the loops
/// denoise their last frame only, when most of their state is gone (measured 35 B at
/// 4096², the scratch included).
fn denoise_bytes_per_pixel(mode: RenderMode) -> u64 {
    match mode {
        RenderMode::Reference | RenderMode::Adaptive => 192,
        RenderMode::Progressive | RenderMode::Guo => 48,
    }
}

impl MemoryEstimate {
    /// The estimate for `scene` rendered with `opts`, at the scene's size.
    #[must_use]
    pub fn of(scene: &Scene, opts: &RenderOptions) -> Self {
        let mode = opts.mode.unwrap_or(scene.render.mode);
        let denoises = super::wants_denoise(scene, opts);
        let pixels = u64::from(scene.width) * u64::from(scene.height);
        let per_pixel = bytes_per_pixel(mode)
            + if denoises {
                denoise_bytes_per_pixel(mode)
            } else {
                0
            };
        let triangles = scene.triangle_count() as u64;
        Self {
            render_bytes: BASE_BYTES
                .saturating_add(per_pixel.saturating_mul(pixels))
                .saturating_add(BYTES_PER_TRIANGLE.saturating_mul(triangles)),
            denoises,
        }
    }

    /// The least the render needs: its own memory and, when it denoises, the smallest
    /// scratch the denoiser is given.
    #[must_use]
    pub fn least_bytes(&self) -> u64 {
        let scratch = if self.denoises {
            u64::from(MIN_DENOISE_SCRATCH_MB) << 20
        } else {
            0
        };
        self.render_bytes.saturating_add(scratch)
    }

    /// The denoiser's scratch (OIDN's `maxMemoryMB`) within `budget` bytes for the whole
    /// render: what the render leaves, between [`MIN_DENOISE_SCRATCH_MB`] and
    /// [`MAX_DENOISE_SCRATCH_MB`]; `None` when the render does not denoise.
    #[must_use]
    pub fn denoise_scratch_mb(&self, budget: u64) -> Option<u32> {
        self.denoises.then(|| {
            let left_mb = budget.saturating_sub(self.render_bytes) >> 20;
            u32::try_from(left_mb)
                .unwrap_or(u32::MAX)
                .clamp(MIN_DENOISE_SCRATCH_MB, MAX_DENOISE_SCRATCH_MB)
        })
    }
}

/// `bytes` for a person: "1.4 GB", "830 MB".
#[must_use]
pub fn human_bytes(bytes: u64) -> String {
    let gb = bytes as f64 / 1e9;
    if gb >= 1.0 {
        format!("{gb:.1} GB")
    } else {
        format!("{:.0} MB", bytes as f64 / 1e6)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(w: u32, h: u32, mode: RenderMode, denoise: Option<bool>) -> Scene {
        let mut s = crate::tracer::fixtures::cornell_box(w, h, 4, 4, 1);
        s.render.mode = mode;
        s.render.denoise = denoise;
        s
    }

    #[test]
    fn memory_grows_with_pixels_and_the_denoiser_adds_its_images() {
        let opts = RenderOptions::default();
        let small = MemoryEstimate::of(&scene(512, 512, RenderMode::Progressive, None), &opts);
        let large = MemoryEstimate::of(&scene(2048, 2048, RenderMode::Progressive, None), &opts);
        let per_pixel = (large.render_bytes - small.render_bytes) / (2048 * 2048 - 512 * 512);
        assert_eq!(per_pixel, bytes_per_pixel(RenderMode::Progressive));
        let denoised = MemoryEstimate::of(
            &scene(2048, 2048, RenderMode::Progressive, Some(true)),
            &opts,
        );
        assert!(denoised.denoises && !large.denoises);
        assert_eq!(
            denoised.render_bytes - large.render_bytes,
            denoise_bytes_per_pixel(RenderMode::Progressive) * 2048 * 2048
        );
        // Adaptive denoises unless told not to.
        let adaptive = MemoryEstimate::of(&scene(64, 64, RenderMode::Adaptive, None), &opts);
        assert!(adaptive.denoises);
    }

    #[test]
    fn the_denoisers_scratch_is_what_the_budget_leaves_within_its_bounds() {
        let e = MemoryEstimate {
            render_bytes: 3 << 30,
            denoises: true,
        };
        assert_eq!(e.denoise_scratch_mb(4 << 30), Some(1024));
        assert_eq!(e.denoise_scratch_mb((3 << 30) + (600 << 20)), Some(600));
        assert_eq!(e.denoise_scratch_mb(64 << 30), Some(MAX_DENOISE_SCRATCH_MB));
        assert_eq!(e.denoise_scratch_mb(1 << 30), Some(MIN_DENOISE_SCRATCH_MB));
        assert_eq!(e.least_bytes(), (3 << 30) + (512 << 20));
        let raw = MemoryEstimate {
            denoises: false,
            ..e
        };
        assert_eq!(raw.denoise_scratch_mb(4 << 30), None);
        assert_eq!(raw.least_bytes(), 3 << 30);
    }

    /// The largest image the server's default limits accept fits the default budget in
    /// every mode, with and without the denoiser (their peaks measured in
    /// docs/measurements.md "Memory of one job").
    #[test]
    fn the_largest_default_image_fits_the_default_budget_in_every_mode() {
        let budget = crate::service::jobs::DEFAULT_JOB_MEMORY;
        for mode in [
            RenderMode::Reference,
            RenderMode::Progressive,
            RenderMode::Guo,
            RenderMode::Adaptive,
        ] {
            for denoise in [false, true] {
                let e = MemoryEstimate::of(
                    &scene(4096, 4096, mode, Some(denoise)),
                    &RenderOptions::default(),
                );
                assert!(e.least_bytes() <= budget, "{mode:?} {denoise}: {e:?}");
            }
        }
    }

    #[test]
    fn extreme_sizes_saturate_instead_of_overflowing() {
        let e = MemoryEstimate::of(
            &scene(u32::MAX, u32::MAX, RenderMode::Progressive, Some(true)),
            &RenderOptions::default(),
        );
        assert_eq!(e.render_bytes, u64::MAX);
        assert_eq!(e.least_bytes(), u64::MAX);
        assert_eq!(e.denoise_scratch_mb(u64::MAX), Some(MIN_DENOISE_SCRATCH_MB));
        assert_eq!(human_bytes(1_400_000_000), "1.4 GB");
        assert_eq!(human_bytes(830_000_000), "830 MB");
    }
}
