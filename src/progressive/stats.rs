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
    /// Object-id map and first sample set (§4.1), ms; not part of trace_ms.
    #[serde(default)]
    pub analysis_ms: f64,
    /// Why the loop ended: "all_final", "all_traced", "max_iterations", "max_pixels",
    /// "max_time", "no_triangles" (1-pixel-wide images are traced fully).
    #[serde(default)]
    pub stop_reason: Option<String>,
}
