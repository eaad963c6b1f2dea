//! The perceptual oracle of F&P04 §4.2: the distance between two successive frames, as
//! the vision model (§2) and the adaptive metric (§3) measure it.

use crate::metric::{block_map, MetricParams};
use crate::raster::{Image, LinearImage, PixelCoord, Rgb};
use crate::vision::{ContrastStack, VisionModel};
use std::borrow::Cow;

/// The distance between two successive frames (the perceptual oracle). Implemented over
/// the vision model + adaptive metric; tests pass analytic judges.
pub trait Judge {
    /// Distance map (JNDs) between `prev` and `cur`, or `None` if it cannot be computed
    /// (then every triangle is treated as smooth this iteration: refined, never final).
    fn distance(
        &mut self,
        prev: &LinearImage,
        cur: &LinearImage,
        seeds: &[PixelCoord],
        iteration: u32,
    ) -> Option<Image<f32>>;

    /// The distance map between the first frame (`first`, the Gouraud image of the first
    /// estimates) and its noise twin (same triangulation, independent estimates): the
    /// distance noise alone produces ([`crate::progressive::noise`]). `None`: no compensation. Called
    /// at most once, before the first `distance` call, whose `prev` is `first`.
    fn noise_distance(
        &mut self,
        _first: &LinearImage,
        _twin: &LinearImage,
        _seeds: &[PixelCoord],
    ) -> Option<Image<f32>> {
        None
    }
}

/// F&P04 §4.2's judge: the adaptive block map (metric §3) over the vision model (§2),
/// seeded with the traced pixels. Keeps the current frame's decomposition for the next
/// iteration, so each frame is decomposed once.
pub struct VisionJudge {
    model: VisionModel,
    cached: Option<ContrastStack>,
    homogeneity: f32,
    epsilon: f32,
    seed: u64,
}

impl VisionJudge {
    #[must_use]
    pub fn new(model: VisionModel, homogeneity: f32, epsilon: f32, seed: u64) -> Self {
        Self {
            model,
            cached: None,
            homogeneity,
            epsilon,
            seed,
        }
    }
}

/// The vision model refuses NaN/Inf (vision-model.md §2.9 says map NaN → 0, +Inf → white
/// before the display clamp); the renderer keeps raw values in its image (so T0 = 0 is
/// bit-identical to the reference) and sanitises only the copy it judges.
fn judged(img: &LinearImage) -> Cow<'_, LinearImage> {
    if !img.has_non_finite() {
        return Cow::Borrowed(img);
    }
    Cow::Owned(img.map(|c| {
        let f = |v: f32| {
            if v.is_nan() || v == f32::NEG_INFINITY {
                0.0
            } else {
                v.min(1e8)
            }
        };
        Rgb::new(f(c.x), f(c.y), f(c.z))
    }))
}

impl Judge for VisionJudge {
    fn distance(
        &mut self,
        prev: &LinearImage,
        cur: &LinearImage,
        seeds: &[PixelCoord],
        iteration: u32,
    ) -> Option<Image<f32>> {
        let a = match self.cached.take() {
            Some(s) => s,
            None => self.model.decompose(&judged(prev)).ok()?,
        };
        let b = self.model.decompose(&judged(cur)).ok()?;
        // Metric seed from (job seed, iteration) (vision-model.md §3.2, §3.4).
        let seed =
            self.seed ^ (u64::from(iteration).wrapping_add(1)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let params = MetricParams {
            homogeneity: self.homogeneity,
            epsilon: self.epsilon,
            seed,
        };
        let map = block_map(&self.model, &a, &b, seeds, &params).map;
        self.cached = Some(b);
        Some(map)
    }

    fn noise_distance(
        &mut self,
        first: &LinearImage,
        twin: &LinearImage,
        seeds: &[PixelCoord],
    ) -> Option<Image<f32>> {
        let a = self.model.decompose(&judged(first)).ok()?;
        let b = self.model.decompose(&judged(twin)).ok()?;
        // Its own metric seed (the frames use (seed, iteration ≥ 1)).
        let params = MetricParams {
            homogeneity: self.homogeneity,
            epsilon: self.epsilon,
            seed: self.seed ^ crate::progressive::noise::TWIN_SEED,
        };
        let map = block_map(&self.model, &a, &b, seeds, &params).map;
        // `first` is the next `distance` call's `prev`: decomposed once.
        self.cached = Some(a);
        Some(map)
    }
}
