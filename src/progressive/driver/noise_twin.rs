//! The noise twin of the first sample set ([`crate::progressive::noise`]): the same
//! pixels traced again with another seed, shaded on the same triangulation, and the
//! judge's distance between the two pictures: the distance noise alone produces.

use super::classifier::Classifier;
use super::{Mesh, Run};
use crate::cancel::{CancelToken, Cancelled};
use crate::progressive::guo;
use crate::progressive::mesh::Triangulator;
use crate::progressive::noise::{NoiseLevel, Twin, NOISE_SCALE, TWIN_SEED};
use crate::raster::{LinearImage, PixelCoord, Rgb};
use crate::scene::ObjectId;
use crate::tracer::{self, PixelOracle};
use std::time::Instant;

impl<O: PixelOracle> Run<'_, O> {
    /// Traces the twin of `first` and hands the classifier the twin image with `cur` (the
    /// first frame, shaded on `mesh`) to measure the distance noise alone makes. Nothing
    /// is handed over when the twins equal the first estimates bit for bit (a noise-free
    /// oracle: F&P04 unchanged, no map computed). Twin traces count in
    /// `noise_probe_pixels` and the timings, not in `pixels_traced` (they are not pixels
    /// of the image).
    ///
    /// The loop calls this once the first frame is out: the first classification needs no
    /// noise (every triangle is refined), and the twin's trace, shading and map are a
    /// fifth to a third of the time to the first frame otherwise.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn noise_twin(
        &mut self,
        first: &[PixelCoord],
        mesh: &Mesh,
        tri: &Triangulator,
        ids: &[ObjectId],
        cur: &LinearImage,
        classifier: &mut dyn Classifier,
        cancel: &CancelToken,
    ) -> Result<(), Cancelled> {
        let t = Instant::now();
        let twin = Twin {
            inner: self.oracle,
            samples: self.s.samples_per_pixel,
            seed: self.s.seed ^ TWIN_SEED,
        };
        let (vals, mut twin_albedo): (Vec<Rgb>, Option<Vec<Option<Rgb>>>) =
            if self.px.albedo.is_some() {
                let (v, a) = tracer::trace_pixels_albedo(&twin, first, cancel)?
                    .into_iter()
                    .unzip();
                (v, Some(a))
            } else {
                (tracer::trace_pixels(&twin, first, cancel)?, None)
            };
        self.it.trace_ms += t.elapsed().as_secs_f64() * 1e3;
        self.stats.noise_probe_pixels += first.len() as u64;
        let idx: Vec<usize> = first.iter().map(|&p| self.px.index(p)).collect();
        let e = self.s.exposure;
        let mut same = true;
        let mut amps = Vec::with_capacity(first.len());
        let mut vals: Vec<Rgb> = idx
            .iter()
            .zip(vals)
            .map(|(&i, v)| {
                let v = super::samples::finite(v);
                let mine = self.px.rad[i];
                same &= v.to_array().map(f32::to_bits) == mine.to_array().map(f32::to_bits);
                amps.push((i, guo::displayed(mine, e) - guo::displayed(v, e)));
                v
            })
            .collect();
        if same {
            return Ok(());
        }
        let level = NoiseLevel::new(self.px.w as usize, self.px.h as usize, &amps);
        let t = Instant::now();
        // The twin image: the same triangulation over the twins' values (and their own
        // vertex albedos: other jitter than the firsts'). They are swapped into the radiance
        // and albedo buffers for the shading and swapped back, instead of copying
        // whole-image buffers.
        let swap = |run: &mut Self, vals: &mut [Rgb], albedo: &mut Option<Vec<Option<Rgb>>>| {
            for (k, &i) in idx.iter().enumerate() {
                std::mem::swap(&mut run.px.rad[i], &mut vals[k]);
                if let (Some(mine), Some(theirs)) = (run.px.albedo.as_mut(), albedo.as_mut()) {
                    std::mem::swap(&mut mine[i], &mut theirs[k]);
                }
            }
        };
        swap(self, &mut vals, &mut twin_albedo);
        let twin_img = self.shaded(mesh, tri, ids);
        swap(self, &mut vals, &mut twin_albedo);
        self.it.triangulate_ms += t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let map = classifier.learn_noise(cur, &twin_img, first, level);
        if let Some(map) = map {
            self.stats.noise_distance_mean = step_noise_mean(map);
        }
        self.it.metric_ms += t.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }
}

/// The mean noise distance, scaled to one step's worth ([`NOISE_SCALE`]), for the
/// statistics.
fn step_noise_mean(v: &[f32]) -> f64 {
    let s: f64 = v
        .iter()
        .filter(|x| x.is_finite())
        .map(|&x| f64::from(x))
        .sum();
    s / v.len().max(1) as f64 * NOISE_SCALE
}
