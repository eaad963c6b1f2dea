//! The pixel oracle: a Monte Carlo path tracer that computes the colour of any single pixel.
//!
//! A pixel's value is a pure function of (scene, seed, pixel): tracing a scattered subset
//! gives bit-identical values to the same pixels of a full render, whatever the thread
//! count (the progressive renderer relies on it).

use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage, PixelCoord, Rgb};
use crate::scene::{ObjectId, Scene};
use rayon::prelude::*;

/// Anything that can compute the true colour of one pixel. The progressive loop, the
/// benches and the tests see only this trait; tests pass analytic oracles.
pub trait PixelOracle: Sync {
    /// Image size in pixels.
    fn size(&self) -> (u32, u32);
    /// The pixel's estimate with the scene's `samples_per_pixel` and `seed`.
    fn radiance(&self, p: PixelCoord) -> Rgb;
    /// The same estimator with an explicit sample count and seed (equal-time baselines,
    /// independent references).
    fn radiance_with(&self, p: PixelCoord, samples: u32, seed: u64) -> Rgb;
    /// Id of the object hit by the ray through the pixel centre ([`crate::scene::BACKGROUND_ID`]
    /// on a miss): one ray per pixel, for the contour map of §4.1.
    fn object_id(&self, p: PixelCoord) -> ObjectId;
}

/// Pixels are traced in batches of this many; cancellation is checked between batches.
pub const BATCH: usize = 256;

/// Traces `pixels` in parallel (rayon), checking `cancel` between batches.
/// The result is in the order of `pixels` and independent of the thread count.
pub fn trace_pixels(
    oracle: &impl PixelOracle,
    pixels: &[PixelCoord],
    cancel: &CancelToken,
) -> Result<Vec<Rgb>, Cancelled> {
    let mut out = vec![Rgb::ZERO; pixels.len()];
    out.par_chunks_mut(BATCH).zip(pixels.par_chunks(BATCH)).try_for_each(|(o, p)| {
        if cancel.is_cancelled() {
            return Err(Cancelled);
        }
        for (dst, &px) in o.iter_mut().zip(p) {
            *dst = oracle.radiance(px);
        }
        Ok(())
    })?;
    Ok(out)
}

/// Every pixel traced (`render.mode = "reference"`). `progress(done, total)` is called
/// after each batch from worker threads.
pub fn render_reference(
    oracle: &impl PixelOracle,
    cancel: &CancelToken,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<LinearImage, Cancelled> {
    render_reference_with(oracle, None, cancel, progress)
}

/// Like [`render_reference`], with an explicit (samples, seed) instead of the scene's.
pub fn render_reference_with(
    oracle: &impl PixelOracle,
    samples_seed: Option<(u32, u64)>,
    cancel: &CancelToken,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<LinearImage, Cancelled> {
    let (w, h) = oracle.size();
    let total = w as usize * h as usize;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let mut data = vec![Rgb::ZERO; total];
    data.par_chunks_mut(BATCH).enumerate().try_for_each(|(c, chunk)| {
        if cancel.is_cancelled() {
            return Err(Cancelled);
        }
        for (k, dst) in chunk.iter_mut().enumerate() {
            let i = c * BATCH + k;
            let p = PixelCoord::new((i % w as usize) as u32, (i / w as usize) as u32);
            *dst = match samples_seed {
                None => oracle.radiance(p),
                Some((s, seed)) => oracle.radiance_with(p, s, seed),
            };
        }
        let d = done.fetch_add(chunk.len(), std::sync::atomic::Ordering::Relaxed) + chunk.len();
        progress(d, total);
        Ok(())
    })?;
    Ok(Image::from_vec(w, h, data).expect("size matches by construction"))
}

/// The object-id map (§4.1): one primary ray per pixel.
#[must_use]
pub fn object_id_map(oracle: &impl PixelOracle) -> Image<ObjectId> {
    let (w, h) = oracle.size();
    let data: Vec<ObjectId> = (0..w as usize * h as usize)
        .into_par_iter()
        .map(|i| oracle.object_id(PixelCoord::new((i % w as usize) as u32, (i / w as usize) as u32)))
        .collect();
    Image::from_vec(w, h, data).expect("size matches by construction")
}

/// The path tracer over a prepared scene (BVH, emitter list, feature flags).
/// Owned by issue #2's tracer work.
pub struct PathTracer {
    _private: (),
}

impl PathTracer {
    /// Prepares `scene` for tracing: builds the BVH and decides which code paths it needs.
    #[must_use]
    pub fn new(scene: &Scene) -> Self {
        let _ = scene;
        todo!("issue #2: path tracer")
    }
}

impl PixelOracle for PathTracer {
    fn size(&self) -> (u32, u32) {
        todo!()
    }
    fn radiance(&self, _p: PixelCoord) -> Rgb {
        todo!()
    }
    fn radiance_with(&self, _p: PixelCoord, _samples: u32, _seed: u64) -> Rgb {
        todo!()
    }
    fn object_id(&self, _p: PixelCoord) -> ObjectId {
        todo!()
    }
}
