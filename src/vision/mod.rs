//! Pattanaik, Ferwerda, Fairchild & Greenberg (1998), used as an image metric
//! (shared/spec/vision-model.md §2).
//!
//! The spatial decomposition runs on whole images ([`VisionModel::decompose`]); everything
//! after it is per pixel ([`VisionModel::distance_at`]), so the adaptive metric can
//! evaluate only chosen pixels.
//!
//! Pipeline per image: display model → cd/m² per channel → (L, M, S, R) receptor signals
//! clamped ≥ 0 (§2.1) → octave Gaussian stack with explicit sigmas, decimated storage (§2.2).
//! Per pixel: DoG band B_n = G_n − G_{n+1}, gain control from G_{n+1} (§2.3), Hunt opponent
//! transform with rods in A (§2.4), CSF threshold normalisation (§2.5), transducer (§2.6),
//! then the L^2.4 distance between the two images' vectors (§2.7), in JNDs.
//!
//! Speed: the per-pixel part runs in kernel.rs, 8 pixels per call in struct-of-arrays form
//! (vectorised, AVX2 when available), with fast log2/exp2 powers (fastmath.rs) checked
//! against calib.rs's exact f64 formulas in tests.rs. Decompose (pyramid/) runs fused
//! row/column passes per band of rows (AVX-512 or AVX2 kernels, run-time dispatch, all
//! bitwise identical) with the receptor conversion and the NaN/∞ check fused in, and
//! recycles the planes of dropped stacks (so a model keeps about one stack's worth of
//! buffers alive between calls).
//!
//! Degenerate sizes: when the image is too small for any band to pass the size rule of
//! §2.2 (e.g. 1×1, 2×2 at 28 ppd) the model has N = 0 bands and every distance is exactly 0:
//! there is no spatial contrast to see at the scales the model knows.

pub mod calib;
mod fastmath;
mod kernel;
mod pyramid;

pub use calib::{Calibration, GainParams};

use crate::raster::{Image, LinearImage, PixelCoord};
use calib::DOG_PEAK_TIMES_SIGMA;
#[cfg(test)]
use fastmath::pow4;
use kernel::{ChannelConsts, FastGain, TransducerConsts, LANES};
use pyramid::{bilinear, build_level, BufferPool, DisplayConv, LevelSpec, Plane, Source, P4};
pub use pyramid::{Isa, RowPath};
use rayon::prelude::*;
use std::sync::Arc;

/// Most bands the per-pixel code handles on the stack (the default set has 6).
pub const MAX_BANDS: usize = 8;

/// The display a frame is shown on (scene-format.md `display`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DisplayModel {
    pub peak_luminance: f32,
    pub black_luminance: f32,
    pub exposure: f32,
    pub pixels_per_degree: f32,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VisionError {
    #[error("image has a non-finite value (NaN or infinity) at pixel ({x}, {y})")]
    NonFinite { x: u32, y: u32 },
    #[error("images differ in size: {a:?} vs {b:?}")]
    SizeMismatch { a: (u32, u32), b: (u32, u32) },
    #[error("image is empty")]
    Empty,
}

/// One kept band and its precomputed threshold normalisation and transducer (§2.5, §2.6).
#[derive(Clone, Debug, PartialEq)]
pub struct BandInfo {
    /// Nominal centre frequency, cycles/degree.
    pub cpd: f64,
    /// σ_n of the finer Gaussian, full-resolution pixels (σ = 0.153·ppd/f).
    pub sigma_px: f64,
    /// Peak gain g_n of this band's filters, measured with a sinusoid at start-up (§2.2).
    pub peak_gain: f64,
    /// CSF value S_k(f_n) per channel (A, RG, BY).
    pub sensitivity: [f64; 3],
    /// Channel contributes (S ≥ `min_sensitivity`).
    pub enabled: [bool; 3],
    /// Per channel (A, RG, BY): S_k(f_n) / (g_n W_k(L_ref)) (band value → threshold
    /// units; 0 for disabled channels, which makes their V exactly 0), the transducer
    /// exponent below the anchor and the anchor x_s (§2.5, §2.6).
    lanes: [ChannelConsts; 3],
}

/// The model for one display and one image size (bands depend on both).
pub struct VisionModel {
    display: DisplayModel,
    width: u32,
    height: u32,
    calib: Calibration,
    /// N + 1 levels for N bands (empty when N = 0).
    levels: Vec<LevelSpec>,
    bands: Vec<BandInfo>,
    /// Receptor gains (§2.3) in the per-pixel kernel's form.
    cone_gain: FastGain,
    rod_gain: FastGain,
    /// Transducer constants shared by all bands (§2.6).
    transducer: TransducerConsts,
    opp: [[f32; 4]; 3],
    /// Reused planes of [`Self::decompose`]: the horizontal-pass scratch and the levels
    /// of dropped [`ContrastStack`]s (pyramid/mod.rs [`BufferPool`]).
    pool: Arc<BufferPool>,
}

/// One image's multiscale decomposition (receptor pyramids), ready for per-pixel lookups.
pub struct ContrastStack {
    width: u32,
    height: u32,
    levels: Vec<Plane>,
    /// Where the level buffers go back to when the stack is dropped.
    pool: Option<Arc<BufferPool>>,
}

impl Drop for ContrastStack {
    fn drop(&mut self) {
        if let Some(pool) = &self.pool {
            for l in self.levels.drain(..) {
                pool.give(l.data);
            }
        }
    }
}

impl ContrastStack {
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Whether the two stacks hold bitwise the same levels (the bench checks that every
    /// pyramid path gives the same stack).
    #[doc(hidden)]
    #[must_use]
    pub fn bitwise_eq(&self, other: &ContrastStack) -> bool {
        let same = |a: &Plane, b: &Plane| {
            (a.w, a.h, a.decim) == (b.w, b.h, b.decim)
                && a.data.len() == b.data.len()
                && a.data
                    .as_flattened()
                    .iter()
                    .zip(b.data.as_flattened())
                    .all(|(x, y)| x.to_bits() == y.to_bits())
        };
        (self.width, self.height) == (other.width, other.height)
            && self.levels.len() == other.levels.len()
            && self
                .levels
                .iter()
                .zip(&other.levels)
                .all(|(a, b)| same(a, b))
    }

    /// Bytes of pixel storage (the memory budget is ≤ 64 B per image pixel).
    #[must_use]
    pub fn bytes(&self) -> usize {
        self.levels
            .iter()
            .map(|l| l.data.len() * std::mem::size_of::<P4>())
            .sum()
    }
}

impl VisionModel {
    /// The model with the default [`Calibration`] (vision-model.md §7).
    #[must_use]
    pub fn new(display: DisplayModel, width: u32, height: u32) -> Self {
        Self::with_calibration(display, width, height, Calibration::default())
    }

    /// The model with an explicit calibration. Non-finite or non-positive display
    /// parameters are replaced by the project defaults (peak 100, black 0.5 clamped to
    /// [0, peak], exposure 1, ppd 28) so no NaN can enter; callers validate user input.
    #[must_use]
    pub fn with_calibration(
        display: DisplayModel,
        width: u32,
        height: u32,
        calib: Calibration,
    ) -> Self {
        let ok = |v: f32, d: f32| if v.is_finite() && v > 0.0 { v } else { d };
        let peak = ok(display.peak_luminance, 100.0);
        let black = if display.black_luminance.is_finite() {
            display.black_luminance.clamp(0.0, peak)
        } else {
            0.5f32.min(peak)
        };
        let display = DisplayModel {
            peak_luminance: peak,
            black_luminance: black,
            exposure: if display.exposure.is_finite() && display.exposure >= 0.0 {
                display.exposure
            } else {
                1.0
            },
            pixels_per_degree: ok(display.pixels_per_degree, 28.0),
        };
        let ppd = f64::from(display.pixels_per_degree);
        // §2.2 band set: keep f_n when σ_n ≥ 0.5 px and 2σ_n ≤ max(W, H)/2.
        let half = f64::from(width.max(height)) / 2.0;
        let mut kept: Vec<(f64, f64)> = calib
            .band_cpd
            .iter()
            .map(|&f| (f, DOG_PEAK_TIMES_SIGMA * ppd / f))
            .filter(|&(f, s)| f > 0.0 && s >= calib.min_sigma_px && 2.0 * s <= half)
            .collect();
        kept.sort_by(|a, b| a.1.total_cmp(&b.1));
        kept.truncate(MAX_BANDS);
        let mut levels = Vec::new();
        if !kept.is_empty() {
            let mut sigmas: Vec<f64> = kept.iter().map(|k| k.1).collect();
            sigmas.push(2.0 * kept[kept.len() - 1].1);
            let (mut src_s, mut src_d) = (0.0, 1);
            for s in sigmas {
                let spec = LevelSpec::new(s, src_s, src_d, calib.kernel_radius_sigmas);
                src_s = s;
                src_d = spec.decim;
                levels.push(spec);
            }
        }
        let w_ref: [f64; 3] = std::array::from_fn(|k| calib.w(k, calib.l_ref));
        let bands = kept
            .iter()
            .enumerate()
            .map(|(n, &(cpd, sigma_px))| {
                let g = measure_peak_gain(&levels, n, cpd / ppd);
                let sensitivity: [f64; 3] = std::array::from_fn(|k| calib.csf(k, cpd));
                let enabled = sensitivity.map(|s| s >= calib.min_sensitivity);
                let lanes = std::array::from_fn(|k| {
                    if enabled[k] && g > 0.0 && w_ref[k] > 0.0 {
                        let xs = calib.transducer_anchor_contrast * sensitivity[k];
                        ChannelConsts {
                            inv_thresh: (sensitivity[k] / (g * w_ref[k])) as f32,
                            p: calib.transducer_exponent(sensitivity[k]) as f32,
                            xs: xs as f32,
                            log2_xs: xs.log2() as f32,
                        }
                    } else {
                        ChannelConsts::default()
                    }
                });
                BandInfo {
                    cpd,
                    sigma_px,
                    peak_gain: g,
                    sensitivity,
                    enabled,
                    lanes,
                }
            })
            .collect();
        let opp = calib.opponent.map(|r| r.map(|v| v as f32));
        Self {
            display,
            width,
            height,
            cone_gain: FastGain::new(&calib.cone_gain),
            rod_gain: FastGain::new(&calib.rod_gain),
            transducer: TransducerConsts {
                log2_response: calib.transducer_anchor_response.log2() as f32,
                q: calib.transducer_high_exponent as f32,
            },
            calib,
            levels,
            bands,
            opp,
            pool: Arc::new(BufferPool::default()),
        }
    }

    #[must_use]
    pub fn display(&self) -> &DisplayModel {
        &self.display
    }
    #[must_use]
    pub fn calibration(&self) -> &Calibration {
        &self.calib
    }
    /// The kept bands, finest first (empty for images too small for any band).
    #[must_use]
    pub fn bands(&self) -> &[BandInfo] {
        &self.bands
    }
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Whole-image part of the model (§2.1–2.2). Refuses NaN/Inf.
    pub fn decompose(&self, img: &LinearImage) -> Result<ContrastStack, VisionError> {
        self.decompose_with(img, RowPath::best())
    }

    /// [`Self::decompose`] with an explicit pyramid path (instruction set, band height),
    /// clamped to what the CPU runs. Every path gives bitwise the same stack (tested);
    /// this exists for the bit-identity tests and the bench's per-path timings.
    #[doc(hidden)]
    pub fn decompose_with(
        &self,
        img: &LinearImage,
        path: RowPath,
    ) -> Result<ContrastStack, VisionError> {
        if img.is_empty() {
            return Err(VisionError::Empty);
        }
        if (img.width(), img.height()) != (self.width, self.height) {
            return Err(VisionError::SizeMismatch {
                a: (self.width, self.height),
                b: (img.width(), img.height()),
            });
        }
        let non_finite = || {
            first_non_finite(img.pixels()).map(|i| {
                let w = img.width() as usize;
                VisionError::NonFinite {
                    x: (i % w) as u32,
                    y: (i / w) as u32,
                }
            })
        };
        if self.levels.is_empty() {
            // No level reads the image: scan it here.
            if let Some(e) = non_finite() {
                return Err(e);
            }
            return Ok(ContrastStack {
                width: self.width,
                height: self.height,
                levels: Vec::new(),
                pool: None,
            });
        }
        let d = self.display;
        let conv = DisplayConv {
            black: d.black_luminance,
            range: d.peak_luminance - d.black_luminance,
            exposure: d.exposure,
        };
        // §2.1 (receptor signals) happens inside the first level's horizontal pass.
        let pool = &self.pool;
        // The first level flags non-finite input while converting it (pyramid/
        // `Source::Display`); the exact first pixel is then found by a scan.
        let bad = std::sync::atomic::AtomicBool::new(false);
        let levels = build_levels(
            Source::Display(img, conv, &bad),
            &self.levels,
            |n| pool.take(n),
            path,
        );
        if bad.load(std::sync::atomic::Ordering::Relaxed) {
            for l in levels {
                pool.give(l.data);
            }
            // The flag was set, so the scan finds the pixel; `Empty` is unreachable.
            return Err(non_finite().unwrap_or(VisionError::Empty));
        }
        Ok(ContrastStack {
            width: self.width,
            height: self.height,
            levels,
            pool: Some(Arc::clone(pool)),
        })
    }

    /// The signed visible contrasts V_{n,k} (§2.6) at (x, y), band-major (A, RG, BY per
    /// band), written to `out[..3N]`; returns 3N. Disabled channels are 0. Same kernel
    /// (kernel.rs) as the distances.
    pub fn visible_contrasts(&self, s: &ContrastStack, x: u32, y: u32, out: &mut [f32]) -> usize {
        let n = self.bands.len().min(s.levels.len().saturating_sub(1));
        if n == 0 || x >= s.width || y >= s.height || out.len() < 3 * n {
            return 0;
        }
        let taps = self.taps(s, &[x; LANES], &[y; LANES]);
        let mut v = [[[0f32; LANES]; 3]; MAX_BANDS];
        self.contrasts8(s, &taps, &mut v);
        for (o, c) in out[..3 * n].iter_mut().zip(v.as_flattened()) {
            *o = c[0];
        }
        3 * n
    }

    /// Perceptual distance in JNDs at pixel (x, y) between two decomposed images (§2.7).
    /// Prefer [`Self::distances_at`] for many pixels (8 per kernel call).
    #[must_use]
    pub fn distance_at(&self, a: &ContrastStack, b: &ContrastStack, x: u32, y: u32) -> f32 {
        let mut d = [0f32];
        self.batch(a, b, &|_| PixelCoord::new(x, y), &mut d);
        d[0]
    }

    /// Batched [`Self::distance_at`]: `out[i]` = distance at `pixels[i]` (parallel for
    /// large batches). Pixels outside the image get 0.
    pub fn distances_at(
        &self,
        a: &ContrastStack,
        b: &ContrastStack,
        pixels: &[PixelCoord],
        out: &mut [f32],
    ) {
        let n = pixels.len().min(out.len());
        // Below a few hundred pixels the rayon hand-off costs more than it saves.
        const CHUNK: usize = 512;
        out[..n]
            .par_chunks_mut(CHUNK)
            .zip(pixels[..n].par_chunks(CHUNK))
            .for_each(|(o, p)| self.batch(a, b, &|i| p[i], o));
    }

    /// Every pixel's distance (the full map, for comparison and tests). Parallel over rows;
    /// no allocation per pixel.
    #[must_use]
    pub fn full_map(&self, a: &ContrastStack, b: &ContrastStack) -> Image<f32> {
        let (w, h) = (a.width.min(b.width), a.height.min(b.height));
        let mut data = vec![0f32; w as usize * h as usize];
        if w > 0 && !self.bands.is_empty() {
            data.par_chunks_mut(w as usize)
                .enumerate()
                .for_each(|(y, row)| {
                    self.batch(a, b, &|x| PixelCoord::new(x as u32, y as u32), row);
                });
        }
        Image::from_vec(w, h, data).unwrap_or_else(|| Image::filled(w, h, 0.0))
    }
}

/// Index of the first pixel with a NaN or infinite channel (only run when the first level
/// flagged one, or when there is no level). Sequential on purpose:
/// rayon's `position_first` checks a shared atomic per item and measured 13× slower than a
/// scan. The scan takes the largest exponent field of each block of pixels
/// (an integer max, which vectorises, unlike a short-circuiting `is_finite` per pixel):
/// a value is non-finite exactly when its exponent bits are all ones. Only a failing block
/// is searched pixel by pixel.
fn first_non_finite(px: &[crate::raster::Rgb]) -> Option<usize> {
    const EXP: u32 = 0x7f80_0000;
    const BLOCK: usize = 1024;
    px.chunks(BLOCK).enumerate().find_map(|(b, c)| {
        let m = c.iter().fold(0u32, |m, p| {
            m.max(p.x.to_bits() & EXP)
                .max(p.y.to_bits() & EXP)
                .max(p.z.to_bits() & EXP)
        });
        if m < EXP {
            return None;
        }
        c.iter().position(|p| !p.is_finite()).map(|i| b * BLOCK + i)
    })
}

/// The cascade of §2.2 from the input (the receptor image for level 0). `path` selects the
/// row loops (all bitwise identical); `buffer(n)` supplies each level's storage.
fn build_levels(
    input: Source,
    specs: &[LevelSpec],
    buffer: impl Fn(usize) -> Vec<P4>,
    path: RowPath,
) -> Vec<Plane> {
    let mut out: Vec<Plane> = Vec::with_capacity(specs.len());
    let (mut w, mut h) = match input {
        Source::Plane(p) => (p.w as usize, p.h as usize),
        Source::Display(img, ..) => (img.width() as usize, img.height() as usize),
    };
    for spec in specs {
        let step = spec.step as usize;
        (w, h) = (w.div_ceil(step), h.div_ceil(step));
        let src = out.last().map_or(input, Source::Plane);
        let next = build_level(&src, spec, buffer(w * h), path);
        out.push(next);
    }
    out
}

/// Measures the peak gain g_n of band `n` (§2.2): a 1-row cosine of `freq` cycles/pixel goes
/// through the very level code the model uses; g_n = max |B_n| / amplitude over the
/// central half. This absorbs sampling, truncation and decimation error of our filters.
fn measure_peak_gain(levels: &[LevelSpec], n: usize, freq: f64) -> f64 {
    let coarse = levels.get(n + 1).map_or(1.0, |l| l.sigma);
    let len = ((24.0 * coarse).ceil() as u32).max(64) + 16;
    let xc = f64::from(len / 2);
    let data = (0..len)
        .map(|x| {
            let v = 1.0 + 0.5 * (2.0 * std::f64::consts::PI * freq * (f64::from(x) - xc)).cos();
            [v as f32; 4]
        })
        .collect();
    let input = Plane {
        w: len,
        h: 1,
        decim: 1,
        data,
    };
    let planes = build_levels(
        Source::Plane(&input),
        &levels[..(n + 2).min(levels.len())],
        |_| Vec::new(),
        RowPath::best(),
    );
    let (Some(g), Some(lo)) = (planes.get(n), planes.get(n + 1)) else {
        return 0.0;
    };
    let mut peak = 0f64;
    for x in len / 4..3 * len / 4 {
        let b = f64::from(bilinear(g, x, 0)[0]) - f64::from(bilinear(lo, x, 0)[0]);
        peak = peak.max(b.abs());
    }
    peak / 0.5
}

/// Scalar reference of the kernel's Minkowski sum (kernel.rs `distance8`), kept for the
/// tests: (Σ |a_i − b_i|^β)^(1/β), scaled by the largest difference and summed in f64 (§2.7) so
/// neither tiny nor huge differences under/overflow. Exactly 0 for identical vectors.
#[cfg(test)]
fn minkowski(a: &[f32], b: &[f32], beta: f32) -> f32 {
    let m = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    if m == 0.0 || !m.is_finite() {
        return if m.is_finite() { 0.0 } else { f32::MAX };
    }
    let inv = 1.0 / m;
    let mut s = 0f64;
    for (ca, cb) in a.chunks(4).zip(b.chunks(4)) {
        let mut r = [0f32; 4];
        for i in 0..ca.len() {
            r[i] = (ca[i] - cb[i]).abs() * inv;
        }
        let rl = r.map(|v| v.max(1e-30));
        let pw = pow4(rl, [beta; 4]);
        for i in 0..4 {
            if r[i] > 1e-30 {
                s += f64::from(pw[i]);
            }
        }
    }
    (f64::from(m) * s.powf(1.0 / f64::from(beta))) as f32
}

#[cfg(test)]
mod tests;
