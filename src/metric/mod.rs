//! The adaptive perceptual metric of Albin et al. (2002) as used by F&P04 §3.2: a quad-tree
//! that evaluates the vision-model distance on a random fraction of the pixels.
//! Owned by issue #3.

use crate::raster::{Image, PixelCoord};
use crate::vision::{ContrastStack, VisionModel};

/// The subdivision test's parameters (scene `progressive.homogeneity`, `epsilon`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetricParams {
    /// H: a cell is homogeneous (a leaf) when at least this fraction of its samples lies
    /// within `epsilon` of the cell mean.
    pub homogeneity: f32,
    /// ε, in JNDs.
    pub epsilon: f32,
    /// Seeds the random sample positions; derive it from (job seed, frame index).
    pub seed: u64,
}

/// One leaf of the quad-tree.
#[derive(Clone, Debug, PartialEq)]
pub struct Leaf {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
    pub samples: u32,
    pub mean: f32,
    pub homogeneity: f32,
}

/// A distance map: per pixel, the distance in JNDs (block means for adaptive maps).
#[derive(Clone, Debug)]
pub struct DistanceMap {
    pub map: Image<f32>,
    pub leaves: Vec<Leaf>,
    /// Pixels at which the vision model was evaluated.
    pub pixels_evaluated: usize,
}

impl DistanceMap {
    /// Mean over the image (f64 accumulation).
    #[must_use]
    pub fn mean(&self) -> f64 {
        let n = self.map.len().max(1) as f64;
        self.map.pixels().iter().map(|&d| f64::from(d)).sum::<f64>() / n
    }
}

/// The adaptive block map between two decomposed images, seeded with `seeds` (the
/// renderer's traced pixels), deterministic for a given `params.seed`.
#[must_use]
pub fn block_map(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    seeds: &[PixelCoord],
    params: &MetricParams,
) -> DistanceMap {
    let _ = (model, a, b, seeds, params);
    todo!("issue #3")
}

/// The per-pixel map (every pixel evaluated) in the same form.
#[must_use]
pub fn full_map(model: &VisionModel, a: &ContrastStack, b: &ContrastStack) -> DistanceMap {
    let map = model.full_map(a, b);
    let pixels_evaluated = map.len();
    DistanceMap { map, leaves: Vec::new(), pixels_evaluated }
}
