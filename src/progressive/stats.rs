//! Render statistics: the `stats` object of cli.md and service-api.md.

use serde::{Deserialize, Serialize};

/// Timings and counts of one iteration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct IterationStats {
    pub iteration: u32,
    pub pixels_traced: u64,
    pub trace_ms: f64,
    pub metric_ms: f64,
    pub triangulate_ms: f64,
    pub mean_distance: f64,
    pub triangles_final: u64,
    pub triangles_smooth: u64,
    pub triangles_complex: u64,
    /// Untraced pixels of the triangles this iteration left open (not final): what the loop
    /// may still trace. The render ends once tracing them all is cheaper than an iteration.
    #[serde(default)]
    pub open_pixels: u64,
    /// Pixels the next iteration traces (0 when this one ends the render).
    #[serde(default)]
    pub planned_pixels: u64,
    /// The next iteration traces every untraced pixel left open and ends the render
    /// (stop reason `traced_rest`).
    #[serde(default)]
    pub finishing: bool,
}

/// The final (or running) statistics of a render. Field names are the contract.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RenderStats {
    pub mode: String,
    pub width: u32,
    pub height: u32,
    pub iterations: u32,
    pub pixels_traced: u64,
    pub pixel_fraction: f64,
    pub total_ms: f64,
    pub trace_ms: f64,
    pub metric_ms: f64,
    /// Wall time the loop spent on triangulation, rasterisation and shading beyond what ran
    /// beside the trace (the next triangulation is built while its samples are traced when
    /// no budget can cut the trace short; that part is inside `trace_ms`).
    pub triangulate_ms: f64,
    pub final_mean_distance: f64,
    pub triangles_final: u64,
    pub triangles_smooth: u64,
    pub triangles_complex: u64,
    /// The complex threshold actually used (T1 = mean of the first map when null).
    #[serde(default)]
    pub t1_used: Option<f64>,
    #[serde(default)]
    pub per_iteration: Vec<IterationStats>,
    /// The cost probe (`driver::cost`), object-id map and first sample set (§4.1), ms;
    /// not part of trace_ms.
    #[serde(default)]
    pub analysis_ms: f64,
    /// Why the loop ended: "all_final", "traced_rest" (the open triangles were traced
    /// whole, cheaper than another iteration), "reference_cheaper" (every pixel traced
    /// from the start: the scene's paths are too cheap for the loop to pay for its own
    /// work, `driver::cost`), "all_traced", "max_iterations",
    /// "max_pixels", "max_time", "no_triangles" (1-pixel-wide images are traced fully);
    /// adaptive mode: "all_final" (nothing visible left for two passes), "all_traced"
    /// (every pixel at `samples_per_pixel`), "max_time", "max_samples", "max_iterations".
    #[serde(default)]
    pub stop_reason: Option<String>,
    /// Noise twins traced once frame 0 is out (noise-aware extension of F&P04, see
    /// `progressive::noise`): one re-estimate, with an independent seed, of every pixel of
    /// the first sample set; counted from frame 1's statistics on, and timed in iteration
    /// 1's. Their time is in `trace_ms` and `total_ms`, but they are NOT in
    /// `pixels_traced`/`pixel_fraction`, which count the pixels of the image (a twin never
    /// becomes a pixel of the image). 0 when no twin was traced (Guo, reference, T0 = 0,
    /// compensation off).
    #[serde(default)]
    pub noise_probe_pixels: u64,
    /// Mean over the image of the per-step noise distance `NOISE_SCALE`·D_noise (JND); 0 for a
    /// noise-free oracle or when no twin was traced.
    #[serde(default)]
    pub noise_distance_mean: f64,
    /// Whether this frame's picture went through the denoiser (`render.denoise`).
    #[serde(default)]
    pub denoised: bool,
    /// Wall time spent denoising, ms (inside `total_ms`).
    #[serde(default)]
    pub denoise_ms: f64,
    /// Paths traced over the image (adaptive mode; 0 in the others, whose count is
    /// `pixels_traced` × `samples_per_pixel`).
    #[serde(default)]
    pub samples_traced: u64,
}
