//! Pattanaik, Ferwerda, Fairchild & Greenberg (1998), used as an image metric
//! (shared/spec/vision-model.md §2). Owned by issue #3.
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
//! Degenerate sizes: when the image is too small for any band to pass the size rule of
//! §2.2 (e.g. 1×1, 2×2 at 28 ppd) the model has N = 0 bands and every distance is exactly 0:
//! there is no spatial contrast to see at the scales the model knows.

pub mod calib;
mod fastmath;
mod pyramid;

pub use calib::{Calibration, GainParams};

use crate::raster::{Image, LinearImage, PixelCoord};
use calib::{DOG_PEAK_TIMES_SIGMA, RGB_TO_LMSR};
use fastmath::{pow4, F4};
use pyramid::{bilinear, build_level, LevelSpec, Plane, P4};
use rayon::prelude::*;

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
    /// S_k(f_n) / (g_n W_k(L_ref)): band value → threshold units (lanes A, RG, BY, unused;
    /// 0 for disabled channels, which makes their V exactly 0).
    inv_thresh: F4,
    /// Transducer exponent below the anchor and the anchor x_s.
    p: F4,
    xs: F4,
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
    cone_gain: GainTable,
    rod_gain: GainTable,
    /// Transducer above the anchor: response · (x/x_s)^q, q = ½ by default (sqrt fast path).
    anchor_response: f32,
    high_exponent: f32,
    opp: [[f32; 4]; 3],
}

/// A receptor gain function (§2.3) tabulated for the per-pixel path: the gains were more
/// than half of the per-pixel cost when computed with two powers each. Entries are spaced
/// 256 per octave of `u = I + offset` (indexed straight from the float's bits) and
/// interpolated linearly between exact f64 values: relative error ≤ 2.1e-5, continuous,
/// monotone like the function. Beyond 2^40 cd/m² it falls back to the exact formula.
#[derive(Clone, Debug)]
struct GainTable {
    params: GainParams,
    offset: f32,
    /// `u.to_bits() >> SHIFT` of entry 0.
    base: u32,
    /// (u₀, G(u₀ − offset), slope) per entry.
    entries: Vec<[f32; 3]>,
}

impl GainTable {
    const SHIFT: u32 = 15;
    const MAX_U: f32 = 1.099_511_6e12; // 2^40

    fn new(params: &GainParams) -> Self {
        // A zero or negative offset would put I = 0 at u ≤ 0; keep u positive.
        let offset = (params.offset as f32).max(1e-9);
        let base = offset.to_bits() >> Self::SHIFT;
        let top = Self::MAX_U.to_bits() >> Self::SHIFT;
        let g = |u: f32| params.gain(f64::from(u) - f64::from(offset));
        let entries = (base..top)
            .map(|k| {
                // Entry 0 starts exactly at I = 0 so G(0) is exact.
                let u0 = f32::from_bits(k << Self::SHIFT).max(offset);
                let u1 = f32::from_bits((k + 1) << Self::SHIFT);
                let (g0, g1) = (g(u0), g(u1));
                [
                    u0,
                    g0 as f32,
                    ((g1 - g0) / (f64::from(u1) - f64::from(u0))) as f32,
                ]
            })
            .collect();
        Self {
            params: *params,
            offset,
            base,
            entries,
        }
    }

    #[inline(always)]
    fn gain(&self, i: f32) -> f32 {
        let u = i.max(0.0) + self.offset;
        let k = (u.to_bits() >> Self::SHIFT).wrapping_sub(self.base) as usize;
        match self.entries.get(k) {
            Some(e) => e[1] + e[2] * (u - e[0]),
            None => self.params.gain(f64::from(i)) as f32,
        }
    }
}

/// One image's multiscale decomposition (receptor pyramids), ready for per-pixel lookups.
pub struct ContrastStack {
    width: u32,
    height: u32,
    levels: Vec<Plane>,
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
                let mut inv_thresh = [0f32; 4];
                let mut p = [1f32; 4];
                let mut xs = [0f32; 4];
                for k in 0..3 {
                    if enabled[k] && g > 0.0 && w_ref[k] > 0.0 {
                        inv_thresh[k] = (sensitivity[k] / (g * w_ref[k])) as f32;
                        p[k] = calib.transducer_exponent(sensitivity[k]) as f32;
                        xs[k] = (calib.transducer_anchor_contrast * sensitivity[k]) as f32;
                    }
                }
                BandInfo {
                    cpd,
                    sigma_px,
                    peak_gain: g,
                    sensitivity,
                    enabled,
                    inv_thresh,
                    p,
                    xs,
                }
            })
            .collect();
        let opp = calib.opponent.map(|r| r.map(|v| v as f32));
        Self {
            display,
            width,
            height,
            cone_gain: GainTable::new(&calib.cone_gain),
            rod_gain: GainTable::new(&calib.rod_gain),
            anchor_response: calib.transducer_anchor_response as f32,
            high_exponent: calib.transducer_high_exponent as f32,
            calib,
            levels,
            bands,
            opp,
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
        if img.is_empty() {
            return Err(VisionError::Empty);
        }
        if (img.width(), img.height()) != (self.width, self.height) {
            return Err(VisionError::SizeMismatch {
                a: (self.width, self.height),
                b: (img.width(), img.height()),
            });
        }
        if let Some(i) = img.pixels().iter().position(|p| !p.is_finite()) {
            let w = img.width() as usize;
            return Err(VisionError::NonFinite {
                x: (i % w) as u32,
                y: (i / w) as u32,
            });
        }
        if self.levels.is_empty() {
            return Ok(ContrastStack {
                width: self.width,
                height: self.height,
                levels: Vec::new(),
            });
        }
        let d = self.display;
        let (black, range, expo) = (
            d.black_luminance,
            d.peak_luminance - d.black_luminance,
            d.exposure,
        );
        // §2.1: displayed luminance per channel, then receptors, clamped ≥ 0 (a saturated
        // red has a negative rod signal).
        let mut data = vec![[0f32; 4]; img.len()];
        data.par_chunks_mut(4096)
            .zip(img.pixels().par_chunks(4096))
            .for_each(|(out, inp)| {
                for (o, p) in out.iter_mut().zip(inp) {
                    let y = [p.x, p.y, p.z].map(|v| black + range * (v * expo).clamp(0.0, 1.0));
                    for (k, row) in RGB_TO_LMSR.iter().enumerate() {
                        o[k] = (row[0] * y[0] + row[1] * y[1] + row[2] * y[2]).max(0.0);
                    }
                }
            });
        let input = Plane {
            w: self.width,
            h: self.height,
            decim: 1,
            data,
        };
        Ok(ContrastStack {
            width: self.width,
            height: self.height,
            levels: build_levels(input, &self.levels),
        })
    }

    /// The signed visible contrasts V_{n,k} (§2.6) at (x, y), band-major (A, RG, BY per
    /// band), written to `out[..3N]`; returns 3N. Disabled channels are 0.
    pub fn visible_contrasts(&self, s: &ContrastStack, x: u32, y: u32, out: &mut [f32]) -> usize {
        let n = self.bands.len();
        if n == 0 || x >= s.width || y >= s.height || out.len() < 3 * n {
            return 0;
        }
        let mut lv = [[0f32; 4]; MAX_BANDS + 1];
        for (l, p) in s.levels.iter().enumerate() {
            lv[l] = bilinear(p, x, y);
        }
        for (bi, band) in self.bands.iter().enumerate() {
            let (g, lo) = (lv[bi], lv[bi + 1]);
            // §2.3: gain from the co-located low-pass one level coarser, clamped ≥ 0 (§2.9;
            // the tables clamp).
            let bt = [
                self.cone_gain.gain(lo[0]) * (g[0] - lo[0]),
                self.cone_gain.gain(lo[1]) * (g[1] - lo[1]),
                self.cone_gain.gain(lo[2]) * (g[2] - lo[2]),
                self.rod_gain.gain(lo[3]) * (g[3] - lo[3]),
            ];
            // §2.4 opponent channels, then §2.5 threshold units.
            let mut c = [0f32; 4];
            let mut x = [0f32; 4];
            let mut xl = [1f32; 4];
            for k in 0..3 {
                let o = &self.opp[k];
                c[k] = o[0] * bt[0] + o[1] * bt[1] + o[2] * bt[2] + o[3] * bt[3];
                x[k] = c[k].abs() * band.inv_thresh[k];
                xl[k] = x[k].max(1e-30);
            }
            // §2.6 transducer, both branches computed lane-wise, then selected.
            let low = pow4(xl, band.p);
            let high = if self.high_exponent == 0.5 {
                std::array::from_fn::<f32, 4, _>(|k| (xl[k] / band.xs[k].max(1e-30)).sqrt())
            } else {
                pow4(
                    std::array::from_fn(|k| xl[k] / band.xs[k].max(1e-30)),
                    [self.high_exponent; 4],
                )
            };
            for k in 0..3 {
                let t = if x[k] <= 1e-30 {
                    0.0
                } else if x[k] < band.xs[k] {
                    low[k]
                } else {
                    self.anchor_response * high[k]
                };
                out[3 * bi + k] = if c[k] < 0.0 { -t } else { t };
            }
        }
        3 * n
    }

    /// Perceptual distance in JNDs at pixel (x, y) between two decomposed images (§2.7).
    #[must_use]
    pub fn distance_at(&self, a: &ContrastStack, b: &ContrastStack, x: u32, y: u32) -> f32 {
        let mut va = [0f32; 3 * MAX_BANDS];
        let mut vb = [0f32; 3 * MAX_BANDS];
        let n = self.visible_contrasts(a, x, y, &mut va);
        let m = self.visible_contrasts(b, x, y, &mut vb);
        minkowski(
            &va[..n.min(m)],
            &vb[..n.min(m)],
            self.calib.minkowski as f32,
        )
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
        out[..n]
            .par_iter_mut()
            .with_min_len(256)
            .zip(&pixels[..n])
            .for_each(|(o, p)| {
                *o = self.distance_at(a, b, p.x, p.y);
            });
    }

    /// Every pixel's distance (the full map, for comparison and tests).
    #[must_use]
    pub fn full_map(&self, a: &ContrastStack, b: &ContrastStack) -> Image<f32> {
        let (w, h) = (a.width.min(b.width), a.height.min(b.height));
        let mut data = vec![0f32; w as usize * h as usize];
        if w > 0 && !self.bands.is_empty() {
            data.par_chunks_mut(w as usize)
                .enumerate()
                .for_each(|(y, row)| {
                    for (x, o) in row.iter_mut().enumerate() {
                        *o = self.distance_at(a, b, x as u32, y as u32);
                    }
                });
        }
        Image::from_vec(w, h, data).unwrap_or_else(|| Image::filled(w, h, 0.0))
    }
}

/// The cascade of §2.2 from the receptor image.
fn build_levels(input: Plane, specs: &[LevelSpec]) -> Vec<Plane> {
    let mut out: Vec<Plane> = Vec::with_capacity(specs.len());
    for spec in specs {
        let next = build_level(out.last().unwrap_or(&input), spec);
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
    let planes = build_levels(
        Plane {
            w: len,
            h: 1,
            decim: 1,
            data,
        },
        &levels[..(n + 2).min(levels.len())],
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

/// (Σ |a_i − b_i|^β)^(1/β), scaled by the largest difference and summed in f64 (§2.7) so
/// neither tiny nor huge differences under/overflow. Exactly 0 for identical vectors.
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
