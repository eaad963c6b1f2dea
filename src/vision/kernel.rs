//! The per-pixel part of the model (vision-model.md §2.3–§2.7, procedure §2.8) evaluated
//! for [`LANES`] pixels at once, structure-of-arrays: every value below is a
//! `[f32; LANES]` with one pixel per lane, so each lane loop compiles to packed SIMD code
//! (SSE2 on the baseline target, AVX2 or AVX-512 through [`VisionModel::batch`]'s runtime
//! dispatch). The `8` in names (`V8`, `distance8`, ...) is historical: LANES was once 8.
//!
//! Why: the per-pixel map was ~1.7 µs CPU per pixel, 80 % of it in the ≈ 70 powers per
//! pixel of §2.8, computed 4 lanes at a time with a quarter of the lanes idle, plus a
//! separate sqrt branch. Here each gain, transducer and Minkowski power is one vector
//! `log2` + one vector `exp2` (fastmath.rs, relative error ~1e-6) over 8 pixels, and the
//! bilinear lookup geometry is computed once and shared by the two images.
//!
//! Full 512² map ≈ 87 → 62 ms of CPU: the kernel is bound by the latency of
//! the power chains, so fastmath.rs's `log2`/`exp2` lost their division and evaluate their
//! polynomials with Estrin's scheme; the lookup geometry is computed in vector lanes and
//! the bilinear interpolation 4 receptors at a time followed by a transpose (both were
//! scalar code before).
//!
//! For the progressive renderer's block map (2 successive frames): LANES 8 → 16
//! with an AVX-512 path, and bands whose signals are bitwise unchanged between the two
//! images are skipped (`distance8`); both change no bit of any distance.
//!
//! Results are bitwise identical whatever the vector width (only IEEE +, −, ×, ÷, min,
//! max; no fused multiply-add), so the dispatch cannot change a distance.

// Lane loops index several parallel arrays by lane on purpose (that is what vectorises).
#![allow(clippy::needless_range_loop)]

use super::calib::GainParams;
use super::fastmath::{exp2, log2};
use super::pyramid::{Plane, P4};
use super::{ContrastStack, VisionModel, MAX_BANDS};
use crate::raster::PixelCoord;

/// Pixels per kernel call: 16 (was 8) so the AVX-512 path fills a 512-bit
/// register per value; on AVX2 each value is two 256-bit registers (measured no slower:
/// more independent work per power chain). Lanes are independent, so the width changes
/// no result.
pub const LANES: usize = 16;
/// One value per pixel of a kernel call.
pub type V8 = [f32; LANES];

/// A receptor gain function (§2.3) in the form the lane loops evaluate:
/// `sat(I) · 2^(−e · log2(scale · (I + offset)))`, with `sat(I) = s / (I² + s)` for rods.
#[derive(Clone, Copy, Debug)]
pub struct FastGain {
    scale: f32,
    offset: f32,
    neg_exponent: f32,
    /// Rod saturation constant s; `None` for cones.
    saturation: Option<f32>,
}

impl FastGain {
    #[must_use]
    pub fn new(p: &GainParams) -> Self {
        Self {
            scale: p.scale as f32,
            // A zero or negative offset would put I = 0 at log2(≤ 0); keep it positive.
            offset: (p.offset as f32).max(1e-9),
            neg_exponent: -(p.exponent as f32),
            saturation: p.saturation.map(|s| s as f32),
        }
    }

    /// G(I) with I clamped ≥ 0 (§2.9). Relative error ≤ ~3e-6 against
    /// [`GainParams::gain`] (tests: `tabulated_gains_match_the_exact_formulas`).
    /// Scalar entry point (the tests check it against the exact formula).
    #[cfg_attr(not(test), allow(dead_code))]
    #[inline(always)]
    #[must_use]
    pub fn gain(&self, i: f32) -> f32 {
        match self.saturation {
            Some(s) => self.gain_sat(i, s),
            None => self.gain_plain(i),
        }
    }

    /// The power part alone (cones). Branch-free so lane loops vectorise.
    #[inline(always)]
    fn gain_plain(&self, i: f32) -> f32 {
        let i = i.max(0.0);
        exp2(self.neg_exponent * log2((self.scale * (i + self.offset)).max(1e-30)))
    }

    /// With the rod saturation factor s / (I² + s); I² overflows to +inf above 1.8e19 and
    /// the factor goes to 0 smoothly.
    #[inline(always)]
    fn gain_sat(&self, i: f32, s: f32) -> f32 {
        let i = i.max(0.0);
        s / (i * i + s) * self.gain_plain(i)
    }

    /// `out[j] = G(lo[j]) · (g[j] − lo[j])` for 8 lanes (§2.3), the variant chosen outside
    /// the lane loop so it vectorises.
    #[inline(always)]
    fn apply(&self, g: &V8, lo: &V8, out: &mut V8) {
        match self.saturation {
            Some(s) => {
                for j in 0..LANES {
                    out[j] = self.gain_sat(lo[j], s) * (g[j] - lo[j]);
                }
            }
            None => {
                for j in 0..LANES {
                    out[j] = self.gain_plain(lo[j]) * (g[j] - lo[j]);
                }
            }
        }
    }
}

/// Per-band constants of the transducer (§2.6) for one channel, in the lane form: below
/// the anchor `T = 2^(p·log2 x)`, above it `T = 2^(log2 R + q·(log2 x − log2 x_s))`, i.e.
/// `R·(x/x_s)^q` with R = 22.4, q = ½ by default. One log2 and one exp2 per value.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChannelConsts {
    /// S_k(f_n) / (g_n W_k(L_ref)); 0 disables the channel (V ≡ 0).
    pub inv_thresh: f32,
    pub p: f32,
    pub xs: f32,
    pub log2_xs: f32,
}

/// Shared transducer constants (§2.6).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransducerConsts {
    /// log2 of the anchor response (22.4).
    pub log2_response: f32,
    /// Exponent above the anchor (½).
    pub q: f32,
}

/// The signed visible contrast V = sign(c)·T(x) of §2.6 for threshold-unit magnitude `x`
/// (≥ 0) of the opponent value `c`. Exactly 0 for x ≤ 1e-30 (§2.9).
#[inline(always)]
#[must_use]
pub fn visible(x: f32, c: f32, ch: &ChannelConsts, t: &TransducerConsts) -> f32 {
    let l = log2(x.max(1e-30));
    let e = if x < ch.xs {
        ch.p * l
    } else {
        t.log2_response + t.q * (l - ch.log2_xs)
    };
    let v = exp2(e);
    let v = if x <= 1e-30 { 0.0 } else { v };
    if c < 0.0 {
        -v
    } else {
        v
    }
}

/// Bilinear lookup geometry of one level for 8 pixels (§2.2): the four sample indices and
/// the two fractions, exactly as [`super::pyramid::bilinear`] computes them.
#[derive(Clone, Copy)]
pub struct Taps {
    i00: [usize; LANES],
    i01: [usize; LANES],
    i10: [usize; LANES],
    i11: [usize; LANES],
    fx: V8,
    fy: V8,
}

impl Taps {
    const ZERO: Taps = Taps {
        i00: [0; LANES],
        i01: [0; LANES],
        i10: [0; LANES],
        i11: [0; LANES],
        fx: [0.0; LANES],
        fy: [0.0; LANES],
    };

    /// Geometry for in-range pixels `(px[j], py[j])` of a plane of at least 1×1 samples.
    #[inline(always)]
    fn new(p: &Plane, px: &[u32; LANES], py: &[u32; LANES]) -> Self {
        let mut t = Self::ZERO;
        let w = p.w as usize;
        if p.decim == 1 {
            for j in 0..LANES {
                let i = py[j] as usize * w + px[j] as usize;
                (t.i00[j], t.i01[j], t.i10[j], t.i11[j]) = (i, i, i, i);
            }
            return t;
        }
        let inv = 1.0 / p.decim as f32;
        let (wm, hm) = ((p.w - 1) as f32, (p.h - 1) as f32);
        // Lane loops in f32/i32 so they vectorise (per-lane `as usize` casts of floats
        // compiled to scalar saturating conversions: ≈ 8 % of the kernel). Same values as
        // `bilinear`: pixel coordinates and plane sizes are far below 2^31, where the i32
        // and usize casts agree.
        let (mut x0, mut y0) = ([0i32; LANES], [0i32; LANES]);
        for j in 0..LANES {
            let u = ((px[j] as i32 as f32 + 0.5) * inv - 0.5).clamp(0.0, wm);
            let v = ((py[j] as i32 as f32 + 0.5) * inv - 0.5).clamp(0.0, hm);
            x0[j] = u as i32;
            y0[j] = v as i32;
            t.fx[j] = u - x0[j] as f32;
            t.fy[j] = v - y0[j] as f32;
        }
        let (xm, ym) = (p.w as i32 - 1, p.h as i32 - 1);
        for j in 0..LANES {
            let (x0, y0) = (x0[j] as usize, y0[j] as usize);
            let x1 = (x0 as i32 + 1).min(xm) as usize;
            let y1 = (y0 as i32 + 1).min(ym) as usize;
            t.i00[j] = y0 * w + x0;
            t.i01[j] = y0 * w + x1;
            t.i10[j] = y1 * w + x0;
            t.i11[j] = y1 * w + x1;
        }
        t
    }

    /// The four receptor signals of 8 pixels, SoA. Same arithmetic as
    /// [`super::pyramid::bilinear`] (which returns the sample itself when D = 1; here
    /// the fractions are 0 and `a + (b − a)·0 = a` exactly for finite data).
    #[inline(always)]
    fn fetch(&self, p: &Plane) -> [V8; 4] {
        let mut out = [[0f32; LANES]; 4];
        if p.decim == 1 {
            // Full-resolution level: the sample itself (what `bilinear` returns).
            let mut r = [[0f32; 4]; LANES];
            for j in 0..LANES {
                r[j] = p.data[self.i00[j]];
            }
            transpose(&r, &mut out);
            return out;
        }
        // Interpolate each pixel's four receptors as one 4-lane vector (the stores to `r`
        // are contiguous, so LLVM's SLP pass emits packed 4-wide code; scattering straight
        // into the SoA output made it scalar: ≈ 10 % of the kernel), then transpose.
        let mut r = [[0f32; 4]; LANES];
        for j in 0..LANES {
            let a: P4 = p.data[self.i00[j]];
            let b: P4 = p.data[self.i01[j]];
            let c: P4 = p.data[self.i10[j]];
            let d: P4 = p.data[self.i11[j]];
            let (fx, fy) = (self.fx[j], self.fy[j]);
            let rj = &mut r[j];
            for k in 0..4 {
                let top = a[k] + (b[k] - a[k]) * fx;
                let bot = c[k] + (d[k] - c[k]) * fx;
                rj[k] = top + (bot - top) * fy;
            }
        }
        transpose(&r, &mut out);
        out
    }
}

/// `[pixel][receptor]` → `[receptor][pixel]` (AoS → SoA), bit-exact moves.
#[inline(always)]
fn transpose(r: &[P4; LANES], out: &mut [V8; 4]) {
    for j in 0..LANES {
        for k in 0..4 {
            out[k][j] = r[j][k];
        }
    }
}

/// Visible contrasts of 8 pixels: `[band][channel A, RG, BY][lane]`.
pub type Contrasts8 = [[V8; 3]; MAX_BANDS];

/// Receptor signals of 8 pixels at every level: `[level][receptor][lane]`.
type Levels8 = [[V8; 4]; MAX_BANDS + 1];

/// Bitwise equality of two levels' signals (no early exit, so it vectorises).
#[inline(always)]
fn same_bits(x: &[V8; 4], y: &[V8; 4]) -> bool {
    let mut diff = 0u32;
    for (a, b) in x.as_flattened().iter().zip(y.as_flattened()) {
        diff |= a.to_bits() ^ b.to_bits();
    }
    diff == 0
}

impl VisionModel {
    /// Lookup geometry of every level for pixels `(px, py)` (all in range).
    #[inline(always)]
    pub(super) fn taps(
        &self,
        s: &ContrastStack,
        px: &[u32; LANES],
        py: &[u32; LANES],
    ) -> [Taps; MAX_BANDS + 1] {
        let mut t = [Taps::ZERO; MAX_BANDS + 1];
        for (tl, p) in t.iter_mut().zip(&s.levels) {
            *tl = Taps::new(p, px, py);
        }
        t
    }

    /// §2.3–§2.6 for 8 pixels of one image: DoG band, gain control from the coarser
    /// low-pass, opponent channels, threshold units, transducer.
    #[inline(always)]
    pub(super) fn contrasts8(
        &self,
        s: &ContrastStack,
        taps: &[Taps; MAX_BANDS + 1],
        out: &mut Contrasts8,
    ) {
        let lv = Self::fetch_levels(s, taps);
        self.band_contrasts(&lv, &[true; MAX_BANDS], out);
    }

    /// The receptor signals of every level for 8 pixels (§2.2 lookups).
    #[inline(always)]
    fn fetch_levels(s: &ContrastStack, taps: &[Taps; MAX_BANDS + 1]) -> Levels8 {
        let mut lv = [[[0f32; LANES]; 4]; MAX_BANDS + 1];
        for ((l, t), p) in lv.iter_mut().zip(taps).zip(&s.levels) {
            *l = t.fetch(p);
        }
        lv
    }

    /// §2.3–§2.6 from fetched level signals, for the bands with `live[band]` (the others'
    /// outputs are left untouched).
    #[inline(always)]
    fn band_contrasts(&self, lv: &Levels8, live: &[bool; MAX_BANDS], out: &mut Contrasts8) {
        let tc = self.transducer;
        for (bi, (band, o)) in self.bands.iter().zip(out.iter_mut()).enumerate() {
            if !live[bi] {
                continue;
            }
            let (g, lo) = (&lv[bi], &lv[bi + 1]);
            // §2.3: bt = G(low-pass one level coarser, clamped ≥ 0) · band value.
            let mut bt = [[0f32; LANES]; 4];
            for r in 0..4 {
                let gf = if r == 3 {
                    &self.rod_gain
                } else {
                    &self.cone_gain
                };
                gf.apply(&g[r], &lo[r], &mut bt[r]);
            }
            for (k, ok) in o.iter_mut().enumerate() {
                let ch = band.lanes[k];
                if ch.inv_thresh == 0.0 {
                    *ok = [0.0; LANES];
                    continue;
                }
                let w = self.opp[k];
                for j in 0..LANES {
                    // §2.4 opponent value, §2.5 threshold units, §2.6 transducer.
                    let c = w[0] * bt[0][j] + w[1] * bt[1][j] + w[2] * bt[2][j] + w[3] * bt[3][j];
                    ok[j] = visible(c.abs() * ch.inv_thresh, c, &ch, &tc);
                }
            }
        }
    }

    /// §2.7 for 8 pixels: (Σ|ΔV|^β)^(1/β), scaled by the largest difference so nothing
    /// under/overflows, summed in f64. Exactly 0 for identical vectors.
    #[inline(always)]
    fn distance8(
        &self,
        a: &ContrastStack,
        b: &ContrastStack,
        px: &[u32; LANES],
        py: &[u32; LANES],
    ) -> V8 {
        let nb = self.bands.len();
        let ta = self.taps(a, px, py);
        // Both stacks come from this model, so they share the geometry; recompute only if
        // a caller mixes stacks of different sizes.
        let same = a.levels.len() == b.levels.len()
            && a.levels
                .iter()
                .zip(&b.levels)
                .all(|(p, q)| (p.w, p.h, p.decim) == (q.w, q.h, q.decim));
        let tb_own;
        let tb = if same {
            &ta
        } else {
            tb_own = self.taps(b, px, py);
            &tb_own
        };
        let mut va = [[[0f32; LANES]; 3]; MAX_BANDS];
        let mut vb = [[[0f32; LANES]; 3]; MAX_BANDS];
        let nb = nb
            .min(a.levels.len().saturating_sub(1))
            .min(b.levels.len().saturating_sub(1));
        let lva = Self::fetch_levels(a, &ta);
        let lvb = Self::fetch_levels(b, tb);
        // Between two progressive frames most of the image is unchanged, so a
        // band often reads bitwise-identical signals (its level and the next coarser one)
        // in both images for all 8 pixels. Its visible contrasts are then identical, every
        // ΔV is 0 (or NaN from ∞ − ∞), which leaves m unchanged (`max` ignores NaN) and adds
        // exactly +0.0 to the Minkowski sum (r ≤ 1e-30 or NaN → 0): skipping the band's
        // ≈ 17 powers per pixel changes no bit of the distance (`band_skip_tests`
        // `unchanged_bands_are_skipped_bit_exactly` below).
        let mut live = [true; MAX_BANDS];
        if same {
            let eq: [bool; MAX_BANDS + 1] = std::array::from_fn(|l| same_bits(&lva[l], &lvb[l]));
            for (bi, lb) in live.iter_mut().enumerate().take(nb) {
                *lb = !(eq[bi] && eq[bi + 1]);
            }
        }
        self.band_contrasts(&lva, &live, &mut va);
        self.band_contrasts(&lvb, &live, &mut vb);
        let mut m = [0f32; LANES];
        for bi in 0..nb {
            if !live[bi] {
                continue;
            }
            for (ca, cb) in va[bi].iter().zip(&vb[bi]) {
                for j in 0..LANES {
                    m[j] = m[j].max((ca[j] - cb[j]).abs());
                }
            }
        }
        let inv: V8 = std::array::from_fn(|j| if m[j] > 0.0 { 1.0 / m[j] } else { 0.0 });
        let beta = self.calib.minkowski as f32;
        let mut s = [0f64; LANES];
        for bi in 0..nb {
            if !live[bi] {
                continue;
            }
            for (ca, cb) in va[bi].iter().zip(&vb[bi]) {
                for j in 0..LANES {
                    let r = (ca[j] - cb[j]).abs() * inv[j];
                    let pw = exp2(beta * log2(r.max(1e-30)));
                    s[j] += f64::from(if r > 1e-30 { pw } else { 0.0 });
                }
            }
        }
        let inv_beta = 1.0 / beta;
        let mut d = [0f32; LANES];
        for j in 0..LANES {
            // s ∈ [1, 3N]: the f32 power is accurate to ~1e-6 there.
            let root = exp2(inv_beta * log2((s[j] as f32).max(1.0)));
            d[j] = if m[j] == 0.0 {
                0.0
            } else if !m[j].is_finite() {
                f32::MAX
            } else {
                m[j] * root
            };
        }
        d
    }

    /// Distances of `out.len()` pixels given by `at(i)` (§2.7), 8 at a time; out-of-image
    /// pixels get 0. Portable code path (see [`Self::batch`]).
    #[inline(always)]
    fn batch_kernel(
        &self,
        a: &ContrastStack,
        b: &ContrastStack,
        at: &dyn Fn(usize) -> PixelCoord,
        out: &mut [f32],
    ) {
        let (w, h) = (a.width.min(b.width), a.height.min(b.height));
        if self.bands.is_empty() || w == 0 || h == 0 {
            out.fill(0.0);
            return;
        }
        for (ci, chunk) in out.chunks_mut(LANES).enumerate() {
            let mut px = [0u32; LANES];
            let mut py = [0u32; LANES];
            let mut inside = [false; LANES];
            for j in 0..LANES {
                // The tail is padded with the chunk's first pixel.
                let i = ci * LANES + if j < chunk.len() { j } else { 0 };
                let p = at(i);
                inside[j] = p.x < w && p.y < h;
                (px[j], py[j]) = (p.x.min(w - 1), p.y.min(h - 1));
            }
            let d = self.distance8(a, b, &px, &py);
            for (j, o) in chunk.iter_mut().enumerate() {
                *o = if inside[j] { d[j] } else { 0.0 };
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn batch_avx2(
        &self,
        a: &ContrastStack,
        b: &ContrastStack,
        at: &dyn Fn(usize) -> PixelCoord,
        out: &mut [f32],
    ) {
        self.batch_kernel(a, b, at, out);
    }

    /// The same kernel as one 16-lane AVX-512 register per value. On the dev
    /// box (AMD EPYC, AVX-512) the kernel on progressive-frame pixels went from ≈ 4.7 to
    /// ≈ 3.5 ms per 27 k pixels (benches/vision.rs, GLIMPSE_VISION_BENCH_KERNEL=1).
    /// Bitwise identical to the other paths (same IEEE operations per lane, no FMA:
    /// Rust never contracts); `band_skip_tests` compares all three.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq,avx2")]
    fn batch_avx512(
        &self,
        a: &ContrastStack,
        b: &ContrastStack,
        at: &dyn Fn(usize) -> PixelCoord,
        out: &mut [f32],
    ) {
        self.batch_kernel(a, b, at, out);
    }

    /// [`Self::batch_kernel`] with 16-wide AVX-512 or 8-wide AVX2 code when the CPU has
    /// it. All paths give bitwise-identical results (no FMA contraction), tested in
    /// tests.rs and in `band_skip_tests` below.
    pub(super) fn batch(
        &self,
        a: &ContrastStack,
        b: &ContrastStack,
        at: &dyn Fn(usize) -> PixelCoord,
        out: &mut [f32],
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("avx2")
        {
            // SAFETY: the CPU supports every feature the function enables (checked above).
            unsafe { self.batch_avx512(a, b, at, out) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above (the only requirement of a
            // `target_feature` function).
            unsafe { self.batch_avx2(a, b, at, out) };
            return;
        }
        self.batch_kernel(a, b, at, out);
    }

    /// The portable path only (tests compare it with the dispatched one).
    #[cfg(test)]
    pub(super) fn batch_portable(
        &self,
        a: &ContrastStack,
        b: &ContrastStack,
        at: &dyn Fn(usize) -> PixelCoord,
        out: &mut [f32],
    ) {
        self.batch_kernel(a, b, at, out);
    }
}

#[cfg(test)]
mod band_skip_tests {
    //! Skipping bands whose signals are bitwise identical in both images must
    //! not change a single distance bit.
    use super::*;
    use crate::raster::{Image, Rgb};
    use crate::vision::DisplayModel;

    impl VisionModel {
        /// `distance8` without band skipping: every band evaluated, whatever the images.
        fn distance8_all_bands(
            &self,
            a: &ContrastStack,
            b: &ContrastStack,
            px: &[u32; LANES],
            py: &[u32; LANES],
        ) -> V8 {
            let nb = self
                .bands
                .len()
                .min(a.levels.len().saturating_sub(1))
                .min(b.levels.len().saturating_sub(1));
            let (ta, tb) = (self.taps(a, px, py), self.taps(b, px, py));
            let mut va = [[[0f32; LANES]; 3]; MAX_BANDS];
            let mut vb = [[[0f32; LANES]; 3]; MAX_BANDS];
            self.contrasts8(a, &ta, &mut va);
            self.contrasts8(b, &tb, &mut vb);
            let (va, vb) = (&va.as_flattened()[..3 * nb], &vb.as_flattened()[..3 * nb]);
            let mut m = [0f32; LANES];
            for (ca, cb) in va.iter().zip(vb) {
                for j in 0..LANES {
                    m[j] = m[j].max((ca[j] - cb[j]).abs());
                }
            }
            let inv: V8 = std::array::from_fn(|j| if m[j] > 0.0 { 1.0 / m[j] } else { 0.0 });
            let beta = self.calib.minkowski as f32;
            let mut s = [0f64; LANES];
            for (ca, cb) in va.iter().zip(vb) {
                for j in 0..LANES {
                    let r = (ca[j] - cb[j]).abs() * inv[j];
                    let pw = exp2(beta * log2(r.max(1e-30)));
                    s[j] += f64::from(if r > 1e-30 { pw } else { 0.0 });
                }
            }
            let inv_beta = 1.0 / beta;
            std::array::from_fn(|j| {
                let root = exp2(inv_beta * log2((s[j] as f32).max(1.0)));
                if m[j] == 0.0 {
                    0.0
                } else if !m[j].is_finite() {
                    f32::MAX
                } else {
                    m[j] * root
                }
            })
        }
    }

    /// The model both bit-exactness tests below use (a typical office display).
    fn test_model(w: u32, h: u32) -> VisionModel {
        VisionModel::new(
            DisplayModel {
                peak_luminance: 100.0,
                black_luminance: 0.5,
                exposure: 1.0,
                pixels_per_degree: 28.0,
            },
            w,
            h,
        )
    }

    #[test]
    fn unchanged_bands_are_skipped_bit_exactly() {
        let (w, h) = (96u32, 64u32);
        let model = test_model(w, h);
        let a = Image::from_fn(w, h, |x, y| {
            let v = 0.2 + 0.3 * ((x as f32 * 0.7).sin() * (y as f32 * 0.3).cos()).abs();
            Rgb::new(v, v * 0.9, v * 0.7)
        });
        // A progressive-like successor: a small changed patch, one very bright pixel, the
        // rest bitwise unchanged (so fine bands far from the changes are skipped).
        let b = Image::from_fn(w, h, |x, y| {
            let p = *a.get(x, y);
            if (10..18).contains(&x) && (40..47).contains(&y) {
                p * 1.7
            } else if (x, y) == (80, 8) {
                Rgb::new(1e6, 1e6, 1e6)
            } else {
                p
            }
        });
        let (sa, sb) = (
            model.decompose(&a).expect("finite"),
            model.decompose(&b).expect("finite"),
        );
        let nb = model.bands.len().min(sa.levels.len() - 1);
        let (mut skipped, mut live, mut nonzero) = (0, 0, 0);
        for (s1, s2) in [(&sa, &sb), (&sb, &sa), (&sa, &sa)] {
            for y in 0..h {
                // Row groups and a scattered group (every 11th pixel of the row, wrapping).
                for g in 0..(w as usize / LANES + 1) {
                    let px: [u32; LANES] = if g < w as usize / LANES {
                        std::array::from_fn(|j| (g * LANES + j) as u32)
                    } else {
                        std::array::from_fn(|j| (j as u32 * 11 + y) % w)
                    };
                    let py = [y; LANES];
                    let got = model.distance8(s1, s2, &px, &py);
                    let want = model.distance8_all_bands(s1, s2, &px, &py);
                    assert_eq!(
                        got.map(f32::to_bits),
                        want.map(f32::to_bits),
                        "pixels {px:?} row {y}"
                    );
                    nonzero += want.iter().filter(|&&d| d > 0.0).count();
                    let t = model.taps(s1, &px, &py);
                    let (l1, l2) = (
                        VisionModel::fetch_levels(s1, &t),
                        VisionModel::fetch_levels(s2, &t),
                    );
                    for bi in 0..nb {
                        if same_bits(&l1[bi], &l2[bi]) && same_bits(&l1[bi + 1], &l2[bi + 1]) {
                            skipped += 1;
                        } else {
                            live += 1;
                        }
                    }
                }
            }
        }
        // The comparison must cover both paths, and real (non-zero) distances.
        assert!(
            skipped > 100 && live > 100,
            "skipped {skipped}, live {live}"
        );
        assert!(nonzero > 100, "{nonzero}");
    }

    #[test]
    fn every_dispatch_path_gives_the_same_bits() {
        // Portable, AVX2 and AVX-512 code must agree bit for bit (the renderer's
        // golden frames and the block map's determinism rely on it), including huge
        // values, a 1-pixel tail and pixels outside the image.
        let (w, h) = (45u32, 31u32);
        let model = test_model(w, h);
        let mut s = 0x2545_f491_4f6c_dd1d_u64;
        let mut rnd = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let a = Image::from_fn(w, h, |_, _| Rgb::new(rnd(), rnd(), rnd()));
        let b = Image::from_fn(w, h, |x, y| {
            let p = *a.get(x, y);
            if (x + y) % 9 == 0 {
                Rgb::new(1e7, 0.0, 3.0)
            } else {
                p * (0.8 + 0.4 * rnd())
            }
        });
        let (sa, sb) = (
            model.decompose(&a).expect("finite"),
            model.decompose(&b).expect("finite"),
        );
        let mut pixels: Vec<PixelCoord> = (0..h)
            .flat_map(|y| (0..w).map(move |x| PixelCoord::new(x, y)))
            .collect();
        pixels.push(PixelCoord::new(w, 0));
        pixels.push(PixelCoord::new(3, h + 1));
        pixels.push(PixelCoord::new(7, 7)); // odd length: a partial last group
        let n = pixels.len();
        let run = |f: &dyn Fn(&mut [f32])| {
            let mut out = vec![f32::NAN; n];
            f(&mut out);
            out.iter().map(|d| d.to_bits()).collect::<Vec<u32>>()
        };
        let portable = run(&|o| model.batch_kernel(&sa, &sb, &|i| pixels[i], o));
        let dispatched = run(&|o| model.batch(&sa, &sb, &|i| pixels[i], o));
        assert_eq!(dispatched, portable);
        assert_eq!(portable[n - 3], 0, "outside the image: exactly 0");
        assert!(
            portable
                .iter()
                .filter(|&&d| f32::from_bits(d) > 0.1)
                .count()
                > n / 2
        );
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: AVX2 checked just above.
                let avx2 = run(&|o| unsafe { model.batch_avx2(&sa, &sb, &|i| pixels[i], o) });
                assert_eq!(avx2, portable);
            }
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512vl")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512dq")
                && std::arch::is_x86_feature_detected!("avx2")
            {
                // SAFETY: every enabled feature checked just above.
                let wide = run(&|o| unsafe { model.batch_avx512(&sa, &sb, &|i| pixels[i], o) });
                assert_eq!(wide, portable);
            }
        }
    }
}
