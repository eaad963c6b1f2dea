//! The adaptive perceptual metric of Albin et al. (2002) as used by F&P04 §3.2: a quad-tree
//! that evaluates the vision-model distance on a random fraction of the pixels.
//! Algorithm: vision-model.md §3.2.
//!
//! Two corrections to F&P04's wording, argued in vision-model.md §3.2: a cell is a leaf when
//! its homogeneity h ≥ H (F&P04's text reads the other way round), and h's denominator is
//! the number of samples, not of pixels.

use crate::raster::{Image, PixelCoord};
use crate::vision::{ContrastStack, VisionModel};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

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

impl Default for MetricParams {
    /// H = 0.8, ε = 1 JND [F04].
    fn default() -> Self {
        Self {
            homogeneity: 0.8,
            epsilon: 1.0,
            seed: 0,
        }
    }
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

/// Samples per cell of `area` pixels (vision-model.md §3.2, [F04]): 2000 above 10 000 px,
/// 500 from 1000 to 10 000, a third (rounded up, [D]) below 1000.
#[must_use]
pub fn samples_for_area(area: u64) -> usize {
    if area > 10_000 {
        2000
    } else if area >= 1000 {
        500
    } else {
        area.div_ceil(3) as usize
    }
}

/// A cell waiting for its decision.
struct Cell {
    x: u32,
    y: u32,
    w: u32,
    h: u32,
    depth: u32,
    /// Evaluated samples inside the cell (inherited from the parent or drawn here).
    samples: Vec<(PixelCoord, f32)>,
    /// The renderer's traced pixels inside the cell not yet evaluated.
    seeds: Vec<PixelCoord>,
}

impl Cell {
    fn area(&self) -> u64 {
        u64::from(self.w) * u64::from(self.h)
    }
    /// Per-cell RNG stream: (params.seed, cell rectangle) → reproducible and independent of
    /// the order cells are visited in (§3.2 "seed from the cell id").
    fn rng(&self, seed: u64) -> Pcg64Mcg {
        let mut h = seed ^ 0x9e37_79b9_7f4a_7c15;
        for v in [self.x, self.y, self.w, self.h] {
            h = splitmix(h ^ u64::from(v));
        }
        Pcg64Mcg::seed_from_u64(h)
    }
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Cells smaller than this in both directions are never split (vision-model.md §3.2, [D]).
const MIN_SPLIT: u32 = 8;

/// The adaptive block map between two decomposed images, seeded with `seeds` (the
/// renderer's traced pixels), deterministic for a given `params.seed`.
///
/// Breadth-first: each tree level draws its cells' samples (seeds first, then uniform
/// random pixels without replacement), evaluates all new pixels of the level in one
/// parallel batch, then decides leaf or split per cell.
///
/// The quad-tree (without the dense fallback) is bit-identical to the plain transcription of
/// §3.2 (`reference.rs`, a test-only oracle; the unit tests compare them on noisy pairs)
/// but cheaper on progressive frames, where every traced pixel is a seed and the tree goes
/// deep. What changed, all without touching the sampling order
/// or the order samples are summed in:
/// - a split distributes the parent's samples and unused seeds to its children in one pass
///   (the old code filtered the whole parent list once per child) and reads the unused
///   seeds in place (no `split_off` copy); sample/seed vectors are recycled between cells;
/// - the unused-seed re-filter is gone (an unused seed is never taken: a cell draws random
///   pixels only after using all its seeds), as is the second n-sized dedup mask;
/// - each level's batch is ordered by one `u64` sort of (pixel index, batch index) keys
///   instead of a comparison sort with indirect (y, x) lookups.
#[must_use]
pub fn block_map(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    seeds: &[PixelCoord],
    params: &MetricParams,
) -> DistanceMap {
    quad_tree(model, a, b, seeds, params, DENSE_SHARE)
}

/// The per-pixel map (every pixel evaluated) in the same form.
#[must_use]
pub fn full_map(model: &VisionModel, a: &ContrastStack, b: &ContrastStack) -> DistanceMap {
    let map = model.full_map(a, b);
    let pixels_evaluated = map.len();
    DistanceMap {
        map,
        leaves: Vec::new(),
        pixels_evaluated,
    }
}

mod quad_tree;

use quad_tree::quad_tree;
pub use quad_tree::DENSE_SHARE;

/// §3.2 transcribed plainly, the bit-exact oracle of [`block_map`] in the tests.
#[cfg(test)]
mod reference;

#[cfg(test)]
mod tests;
