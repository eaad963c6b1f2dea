//! Every pixel's paths summed so far, and tracing a pass's plan over them.

use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage, PixelCoord};
use crate::tracer::{PixelOracle, SampleSum, BATCH};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// The image's per-pixel sums ([`SampleSum`]), row-major.
pub struct Pixels {
    width: u32,
    height: u32,
    sums: Vec<SampleSum>,
}

/// How a traced pass ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Traced {
    /// Every planned sample was traced.
    All,
    /// The deadline came first: some batches were left out.
    Deadline,
}

impl Pixels {
    #[must_use]
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            sums: vec![SampleSum::default(); width as usize * height as usize],
        }
    }

    /// Adds `extra[i]` samples to pixel i (row-major), in parallel batches of [`BATCH`]
    /// pixels; a batch not yet started when `deadline` passes is left out. Each pixel's
    /// paths are its own ([`PixelOracle::sample_sum`]), whatever the order.
    pub fn trace(
        &mut self,
        oracle: &impl PixelOracle,
        extra: &[u32],
        seed: u64,
        deadline: Option<Instant>,
        cancel: &CancelToken,
    ) -> Result<Traced, Cancelled> {
        let width = self.width as usize;
        let late = AtomicBool::new(false);
        self.sums
            .par_chunks_mut(BATCH)
            .zip(extra.par_chunks(BATCH))
            .enumerate()
            .with_max_len(1)
            .try_for_each(|(c, (sums, extra))| {
                if deadline.is_some_and(|d| Instant::now() >= d) {
                    late.store(true, Ordering::Relaxed);
                    return Ok(());
                }
                for (k, (s, &n)) in sums.iter_mut().zip(extra).enumerate() {
                    if n == 0 {
                        continue;
                    }
                    if cancel.is_cancelled() {
                        return Err(Cancelled);
                    }
                    let i = c * BATCH + k;
                    let p = PixelCoord::new((i % width) as u32, (i / width) as u32);
                    *s = oracle.sample_sum(p, n, seed, *s);
                }
                Ok(())
            })?;
        Ok(if late.into_inner() {
            Traced::Deadline
        } else {
            Traced::All
        })
    }

    /// The mean of every pixel (the reference's estimator at each pixel's own count).
    #[must_use]
    pub fn mean(&self) -> LinearImage {
        self.image(SampleSum::mean)
    }

    /// The two independent half images (even and odd paths).
    #[must_use]
    pub fn halves(&self) -> (LinearImage, LinearImage) {
        (self.image(|s| s.halves().0), self.image(|s| s.halves().1))
    }

    /// Samples per pixel so far.
    #[must_use]
    pub fn counts(&self) -> Image<u32> {
        self.map(|s| s.next)
    }

    /// Rays per sample at each pixel (1 where none was traced yet).
    #[must_use]
    pub fn cost(&self) -> Image<f32> {
        self.map(|s| {
            if s.next == 0 || s.rays == 0 {
                1.0
            } else {
                s.rays as f32 / s.next as f32
            }
        })
    }

    /// Samples traced over the image.
    #[must_use]
    pub fn total(&self) -> u64 {
        self.sums.iter().map(|s| u64::from(s.next)).sum()
    }

    fn image(&self, f: impl Fn(&SampleSum) -> crate::raster::Rgb + Sync) -> LinearImage {
        let data: Vec<_> = self.sums.par_iter().map(&f).collect();
        Image::from_vec(self.width, self.height, data).expect("one sum per pixel")
    }

    fn map<T: Send>(&self, f: impl Fn(&SampleSum) -> T + Sync) -> Image<T> {
        let data: Vec<T> = self.sums.par_iter().map(&f).collect();
        Image::from_vec(self.width, self.height, data).expect("one sum per pixel")
    }
}
