//! The octave Gaussian stack with explicit sigmas and decimated storage
//! (vision-model.md §2.2). Pixels hold the four receptor signals (L, M, S, R) interleaved,
//! so one bilinear lookup fetches all four and the blur loops vectorise.
//!
//! Speed (decomposing a 512² pair costs ≈ 10 ms of CPU, ≈ 26 before these choices): both
//! passes are whole-row multiply-adds, tap by tap (decimating levels read the padded row's
//! even/odd phases), run as 8-wide AVX2 code when the CPU has it; the input's receptor
//! conversion (§2.1) is fused into the first horizontal pass; level buffers are recycled
//! through [`BufferPool`]; coarse levels skip the parallel hand-off. Every sum keeps the
//! tap order of the plain per-sample loop, so the levels are bitwise those of that loop
//! (tested against it below).
//!
//! The decomposition was most of the adaptive metric's cost, hence more: the two passes are
//! fused per band of output rows (the horizontal rows live in a small ring, not a
//! whole-level intermediate), stored rows are read in place instead of being copied into a
//! padded row, and on AVX-512 explicit intrinsic kernels load each source vector once for
//! several outputs (4 output rows in the vertical pass, 8 registers of neighbouring samples
//! in the horizontal one). The finiteness check rides on the first level's conversion.
//! Every path ([`RowPath`]: instruction set, band height) is compared bit for bit with the
//! per-sample reference below and with each other in tests.rs.

// Layout: this file holds the level types, the instruction-set choice and the level
// driver; sum.rs the whole-row weighted sums, simd.rs their intrinsic builds, hpass.rs the
// horizontal pass, band.rs the fused band of both passes.
mod band;
mod hpass;
#[cfg(target_arch = "x86_64")]
mod simd;
mod sum;

use super::calib::RGB_TO_LMSR;
use crate::raster::LinearImage;
use band::{band, BandScratch};
#[cfg(target_arch = "x86_64")]
use band::{band_avx2, band_avx512};
use rayon::prelude::*;

/// Four receptor signals of one pixel.
pub type P4 = [f32; 4];

/// One stored low-pass level: `w × h` samples, each standing for a `decim × decim` block
/// of full-resolution pixels.
#[derive(Clone, Debug)]
pub struct Plane {
    pub w: u32,
    pub h: u32,
    pub decim: u32,
    pub data: Vec<P4>,
}

/// How one level is made from the previous one (or from the input for level 0).
#[derive(Clone, Debug, PartialEq)]
pub struct LevelSpec {
    /// Gaussian width of this level in full-resolution pixels (σ_n).
    pub sigma: f64,
    /// Storage decimation factor D_n (a power of two).
    pub decim: u32,
    /// Taps (offset from `j · step`, weight) of the 1-D kernel applied to the source
    /// level's own samples; weights sum to 1.
    pub kernel: Vec<(i32, f32)>,
    /// Subsampling from the source level (D_n / D_{n−1}).
    pub step: u32,
}

impl LevelSpec {
    /// A level of width `sigma` (full-res px) built from a source of width `src_sigma`
    /// stored at factor `src_decim`; `radius_sigmas` truncates the kernel.
    #[must_use]
    pub fn new(sigma: f64, src_sigma: f64, src_decim: u32, radius_sigmas: f64) -> Self {
        // §2.2: store decimated by 2^floor(log2 σ) once σ ≥ 1 px (aliasing ≤ 0.7 %).
        let decim = if sigma >= 1.0 {
            1u32 << (sigma.log2().floor() as u32).min(20)
        } else {
            1
        };
        let decim = decim.max(src_decim);
        let step = decim / src_decim;
        // Cascade: G_{n+1} = G_n * N(sqrt(σ_{n+1}² − σ_n²)), in the source's own pixels.
        let blur = (sigma * sigma - src_sigma * src_sigma).max(0.0).sqrt() / f64::from(src_decim);
        Self {
            sigma,
            decim,
            kernel: kernel(blur, step, radius_sigmas),
            step,
        }
    }
}

/// Sampled Gaussian taps for output sample `j` of a row subsampled by `step`: the output
/// stands for the centre of `step` source samples, i.e. source position
/// `j·step + (step−1)/2`; offsets are relative to `j·step`. Normalised to sum 1 so a
/// uniform image gives exactly-uniform levels (§2.2).
fn kernel(sigma: f64, step: u32, radius_sigmas: f64) -> Vec<(i32, f32)> {
    let c = f64::from(step - 1) / 2.0;
    if sigma < 1e-3 {
        // No blur: average the `step` covered samples (only reachable with step 1 here).
        return (0..step as i32).map(|o| (o, 1.0 / step as f32)).collect();
    }
    let r = (radius_sigmas * sigma).ceil().max(1.0);
    let lo = (c - r).floor() as i32;
    let hi = (c + r).ceil() as i32;
    let mut taps: Vec<(i32, f64)> = (lo..=hi)
        .map(|o| {
            let d = f64::from(o) - c;
            (o, (-d * d / (2.0 * sigma * sigma)).exp())
        })
        .collect();
    let s: f64 = taps.iter().map(|t| t.1).sum();
    for t in &mut taps {
        t.1 /= s;
    }
    taps.into_iter().map(|(o, w)| (o, w as f32)).collect()
}

/// Symmetric mirror index (edge sample repeated), valid for any offset (period 2n).
#[inline]
fn mirror(i: i64, n: i64) -> usize {
    // Almost every index is inside: skip the 64-bit division (it was a visible share of
    // the row padding in the profile).
    if (0..n).contains(&i) {
        return i as usize;
    }
    let p = 2 * n;
    let m = i.rem_euclid(p);
    (if m >= n { p - 1 - m } else { m }) as usize
}

/// Recycled sample buffers: a [`super::ContrastStack`] hands its planes back
/// here when dropped and the next decomposition refills them, so a steady stream of
/// decompositions (progressive frames, the bench) allocates nothing. Fresh multi-MB
/// buffers cost a zero fill (`vec!`), page faults and TLB shoot-downs on free: about as
/// much as the horizontal pass itself. Buffers keep their initialised length: the level
/// code overwrites every sample, so no zero fill is needed on reuse.
#[derive(Debug, Default)]
pub struct BufferPool {
    bufs: std::sync::Mutex<Vec<Vec<P4>>>,
}

impl BufferPool {
    /// At most this many buffers are kept (two stacks of the largest band set and one
    /// more); extra ones are freed. The retained memory is about one dropped stack
    /// (≈ 37 B per image pixel at 5 bands).
    const KEPT: usize = 2 * (super::MAX_BANDS + 1) + 1;

    /// A buffer of length `n` with unspecified (initialised) contents: the smallest kept
    /// one that can hold `n` samples without reallocating, else a new one.
    #[must_use]
    pub fn take(&self, n: usize) -> Vec<P4> {
        let mut v = self
            .bufs
            .lock()
            .ok()
            .and_then(|mut b| {
                let i = (0..b.len())
                    .filter(|&i| b[i].capacity() >= n)
                    .min_by_key(|&i| b[i].capacity())?;
                Some(b.swap_remove(i))
            })
            .unwrap_or_default();
        if v.len() > n {
            v.truncate(n);
        } else {
            v.resize(n, [0f32; 4]);
        }
        v
    }

    /// Returns a buffer for reuse.
    pub fn give(&self, v: Vec<P4>) {
        if v.capacity() == 0 {
            return;
        }
        if let Ok(mut b) = self.bufs.lock() {
            if b.len() < Self::KEPT {
                b.push(v);
            }
        }
    }
}

/// Display-referred conversion of §2.1 (kept here so the first level can convert input rows
/// on the fly): cd/m² per channel = black + range · clamp(v · exposure, 0, 1).
#[derive(Clone, Copy, Debug)]
pub struct DisplayConv {
    pub black: f32,
    pub range: f32,
    pub exposure: f32,
}

/// Where a level's source rows come from.
#[derive(Clone, Copy)]
pub enum Source<'a> {
    /// A stored level.
    Plane(&'a Plane),
    /// The linear input image, converted to receptor signals row by row inside the first
    /// level's horizontal pass (§2.1): the full-size receptor image is never stored
    /// (that would be a 16 B/px write + read). The flag is set when a row read has a
    /// NaN or infinite value (every row is read at least once by the first level); the
    /// caller then discards the levels and reports the first such pixel.
    Display(
        &'a LinearImage,
        DisplayConv,
        &'a std::sync::atomic::AtomicBool,
    ),
}

impl Source<'_> {
    /// (width, height, decimation) of the source samples.
    fn dims(&self) -> (usize, usize, u32) {
        match self {
            Source::Plane(p) => (p.w as usize, p.h as usize, p.decim),
            Source::Display(img, ..) => (img.width() as usize, img.height() as usize, 1),
        }
    }

    /// Source row `y` into `out` (its length is the source width).
    #[inline(always)]
    fn row(&self, y: usize, out: &mut [P4]) {
        let w = out.len();
        match self {
            Source::Plane(p) => out.copy_from_slice(&p.data[y * w..(y + 1) * w]),
            Source::Display(img, d, bad) => {
                // §2.1: displayed luminance per channel, then receptors, clamped ≥ 0 (a
                // saturated red has a negative rod signal).
                let (black, range, expo) = (d.black, d.range, d.exposure);
                // The input's finiteness is checked here, while the pixels are read
                // anyway, instead of by a separate pass over the image before (≈ 8 % of
                // the decomposition). All-ones exponent bits = NaN or infinity.
                const EXP: u32 = 0x7f80_0000;
                let mut nonfinite = false;
                for (o, p) in out.iter_mut().zip(&img.pixels()[y * w..(y + 1) * w]) {
                    nonfinite |= (p.x.to_bits() & EXP == EXP)
                        | (p.y.to_bits() & EXP == EXP)
                        | (p.z.to_bits() & EXP == EXP);
                    let y = [p.x, p.y, p.z].map(|v| black + range * (v * expo).clamp(0.0, 1.0));
                    for (k, row) in RGB_TO_LMSR.iter().enumerate() {
                        o[k] = (row[0] * y[0] + row[1] * y[1] + row[2] * y[2]).max(0.0);
                    }
                }
                if nonfinite {
                    bad.store(true, std::sync::atomic::Ordering::Relaxed);
                }
            }
        }
    }
}

/// Instruction set of the row loops. Every one runs the same IEEE operations in the same
/// order (no FMA: Rust never contracts `a * b + c`), so the levels are bitwise identical
/// whatever the choice (tested below); only the vector width differs. Ordered by width, so
/// `min` with [`Isa::best`] clamps a request to what the CPU has.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// Whatever the build target allows (SSE2 on x86-64).
    Portable,
    /// 8-wide AVX2.
    Avx2,
    /// 16-wide AVX-512F (4 pixels × 4 receptors per register).
    Avx512,
}

impl Isa {
    /// The widest instruction set this CPU runs.
    #[must_use]
    pub fn best() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx2")
            {
                return Isa::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Isa::Avx2;
            }
        }
        Isa::Portable
    }

    /// Every instruction set this CPU runs (for the bit-identity tests and the bench).
    #[must_use]
    pub fn available() -> Vec<Isa> {
        [Isa::Portable, Isa::Avx2, Isa::Avx512]
            .into_iter()
            .filter(|&i| i <= Isa::best())
            .collect()
    }
}

/// How [`build_level`] runs. Each task runs a band of output rows, keeping the
/// horizontal-pass rows it needs in a ring of `taps` rows (L1/L2-resident) instead of a
/// whole-level intermediate (a 4 MB write + read per full-resolution level at 512²).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RowPath {
    pub isa: Isa,
    /// Output rows per band; 0 = chosen from the level size and the thread count.
    /// Tests force tiny bands to exercise the halos on small images.
    pub band_rows: usize,
}

impl RowPath {
    /// The fastest path on this CPU.
    #[must_use]
    pub fn best() -> Self {
        RowPath {
            isa: Isa::best(),
            band_rows: 0,
        }
    }
}

/// Builds `spec`'s level from `src` (separable: rows, then columns; mirror borders).
/// `path` selects the row loops (clamped to what the CPU has).
/// `out` becomes the level's storage, whatever its length and contents (every sample is
/// overwritten).
#[must_use]
pub fn build_level(src: &Source, spec: &LevelSpec, out: Vec<P4>, path: RowPath) -> Plane {
    let (sw, sh, sdecim) = src.dims();
    let step = spec.step as usize;
    let dw = sw.div_ceil(step);
    let dh = sh.div_ceil(step);
    let isa = path.isa.min(Isa::best());
    // The output is written by its first tap without being read: `out` may be a recycled
    // buffer with stale contents, and reading a fresh zeroed allocation first would map
    // the shared zero page, after which the write costs a copy-on-write fault plus a TLB
    // shoot-down.
    let mut data = out;
    if data.len() > dw * dh {
        data.truncate(dw * dh);
    } else {
        data.resize(dw * dh, [0f32; 4]);
    }
    fused_level(src, spec, sh, dw, dh, &mut data, isa, path.band_rows);
    Plane {
        w: dw as u32,
        h: dh as u32,
        decim: sdecim * spec.step,
        data,
    }
}

/// Rows per parallel task: enough samples (≥ 16 K) that a split is worth a hand-off; the
/// coarse levels then run on the calling thread with no fork-join at all.
fn min_rows(w: usize) -> usize {
    (16_384 / w.max(1)).max(1)
}

/// The fused passes over bands of output rows (see [`band`]).
#[allow(clippy::too_many_arguments)]
fn fused_level(
    src: &Source,
    spec: &LevelSpec,
    sh: usize,
    dw: usize,
    dh: usize,
    data: &mut [P4],
    isa: Isa,
    band_rows: usize,
) {
    // Band height: each band recomputes `taps − step` horizontal rows of halo, so bands
    // should be tall; but a few bands per thread keep both cores busy when one is
    // preempted (shared machine) and the coarse levels (< 16 K samples per band) stay on
    // the calling thread.
    let threads = rayon::current_num_threads().max(1);
    let rows = if band_rows > 0 {
        band_rows
    } else {
        dh.div_ceil(BANDS_PER_THREAD * threads).max(min_rows(dw))
    }
    .min(dh)
    .max(1);
    let run = |s: &mut BandScratch, (b, out): (usize, &mut [P4])| {
        let j0 = b * rows;
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `isa` was clamped to `Isa::best()`, so the CPU has AVX-512F and AVX2,
            // the only requirement of the `target_feature` function.
            Isa::Avx512 => unsafe { band_avx512(src, sh, j0, spec, s, out, dw) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above, the CPU has AVX2.
            Isa::Avx2 => unsafe { band_avx2(src, sh, j0, spec, s, out, dw) },
            _ => band(src, sh, j0, spec, s, out, dw, Isa::Portable),
        }
    };
    if rows >= dh {
        run(&mut BandScratch::default(), (0, data));
        return;
    }
    data.par_chunks_mut(rows * dw)
        .enumerate()
        .for_each_init(BandScratch::default, run);
}

/// Bands per rayon thread in [`fused_level`]: 2 keeps the halo recomputation small
/// (≈ 3–10 % of a level's horizontal rows at 512²) while leaving work to steal when one
/// core is busy with something else. Not tuned beyond that (measured on a loaded machine).
const BANDS_PER_THREAD: usize = 2;

/// Bilinear lookup of a level at full-resolution pixel (x, y) (§2.2): sample position
/// ((x+½)/D − ½, (y+½)/D − ½); clamping at the border equals the mirror rule for the
/// half-sample overhang. Non-negative weights keep non-negative signals non-negative.
#[inline(always)]
#[must_use]
pub fn bilinear(p: &Plane, x: u32, y: u32) -> P4 {
    if p.decim == 1 {
        return p.data[y as usize * p.w as usize + x as usize];
    }
    let inv = 1.0 / p.decim as f32;
    let u = ((x as f32 + 0.5) * inv - 0.5).clamp(0.0, (p.w - 1) as f32);
    let v = ((y as f32 + 0.5) * inv - 0.5).clamp(0.0, (p.h - 1) as f32);
    let (x0, y0) = (u as usize, v as usize);
    let x1 = (x0 + 1).min(p.w as usize - 1);
    let y1 = (y0 + 1).min(p.h as usize - 1);
    let (fx, fy) = (u - x0 as f32, v - y0 as f32);
    let w = p.w as usize;
    let (a, b, c, d) = (
        p.data[y0 * w + x0],
        p.data[y0 * w + x1],
        p.data[y1 * w + x0],
        p.data[y1 * w + x1],
    );
    let mut out = [0f32; 4];
    for k in 0..4 {
        let top = a[k] + (b[k] - a[k]) * fx;
        let bot = c[k] + (d[k] - c[k]) * fx;
        out[k] = top + (bot - top) * fy;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_are_normalised_and_centred() {
        for (s, step) in [(0.5, 1), (1.86, 2), (3.4, 2), (0.93, 1)] {
            let k = kernel(s, step, 3.0);
            let sum: f32 = k.iter().map(|t| t.1).sum();
            assert!((sum - 1.0).abs() < 1e-6);
            let mean: f64 = k.iter().map(|t| f64::from(t.0) * f64::from(t.1)).sum();
            assert!((mean - f64::from(step - 1) / 2.0).abs() < 1e-5, "{mean}");
        }
        assert_eq!(mirror(-1, 5), 0);
        assert_eq!(mirror(-2, 5), 1);
        assert_eq!(mirror(5, 5), 4);
        assert_eq!(mirror(6, 5), 3);
        assert_eq!(mirror(-7, 2), 1);
    }

    #[test]
    fn uniform_plane_stays_uniform_with_decimation() {
        let src = Plane {
            w: 13,
            h: 7,
            decim: 1,
            data: vec![[3.0, 2.0, 1.0, 0.5]; 91],
        };
        let spec = LevelSpec::new(2.5, 1.0, 1, 3.0);
        assert_eq!(spec.decim, 2);
        let out = build_level(&Source::Plane(&src), &spec, Vec::new(), RowPath::best());
        assert_eq!((out.w, out.h), (7, 4));
        for p in &out.data {
            for (a, b) in p.iter().zip([3.0, 2.0, 1.0, 0.5]) {
                assert!((a - b).abs() < 1e-5);
            }
        }
        let v = bilinear(&out, 12, 6);
        assert!((v[0] - 3.0).abs() < 1e-5);
    }

    /// Per-sample separable reference (the loop structure before the fused kernels): acc = 0, then
    /// acc += v·w per tap, rows then columns, `mirror` for every index.
    fn naive(src: &Plane, spec: &LevelSpec) -> Plane {
        let (sw, sh, st) = (src.w as i64, src.h as i64, spec.step as i64);
        let (dw, dh) = ((sw + st - 1) / st, (sh + st - 1) / st);
        let mut tmp = vec![[0f32; 4]; (dw * sh) as usize];
        for y in 0..sh {
            for j in 0..dw {
                let mut acc = [0f32; 4];
                for &(off, w) in &spec.kernel {
                    let v = src.data[(y * sw) as usize + mirror(j * st + i64::from(off), sw)];
                    for c in 0..4 {
                        acc[c] += v[c] * w;
                    }
                }
                tmp[(y * dw + j) as usize] = acc;
            }
        }
        let mut data = vec![[0f32; 4]; (dw * dh) as usize];
        for i in 0..dh {
            for j in 0..dw {
                let mut acc = [0f32; 4];
                for &(off, w) in &spec.kernel {
                    let v = tmp[mirror(i * st + i64::from(off), sh) * dw as usize + j as usize];
                    for c in 0..4 {
                        acc[c] += v[c] * w;
                    }
                }
                data[(i * dw + j) as usize] = acc;
            }
        }
        Plane {
            w: dw as u32,
            h: dh as u32,
            decim: src.decim * spec.step,
            data,
        }
    }

    /// Every row-loop path this CPU runs: each instruction set, with automatic bands, with
    /// bands of 1, 2, 3 and 5 rows (halos and ring wrap-around on small images) and with
    /// one band for the whole level.
    fn all_paths() -> Vec<RowPath> {
        let mut v = Vec::new();
        for isa in Isa::available() {
            for band_rows in [0, 1, 2, 3, 5, usize::MAX] {
                v.push(RowPath { isa, band_rows });
            }
        }
        v
    }

    /// The tap-major row loops (phases for decimation, mirrored pads, every instruction
    /// set, every band height) give exactly the per-sample reference, including
    /// images narrower than the kernel (mirror period shorter than the pad) and odd sizes
    /// with decimation.
    #[test]
    fn row_loops_match_the_per_sample_reference_bitwise() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f") {
            // The dev box has AVX-512: make sure the widest path is among those compared.
            assert!(Isa::available().contains(&Isa::Avx512));
        }
        let mut seed = 7u32;
        for (w, h) in [
            (1, 1),
            (2, 3),
            (5, 4),
            (13, 7),
            (37, 29),
            (64, 9),
            (1, 17),
            (17, 1),
            (3, 17),
            (17, 3),
            (33, 19),
            (131, 5),
            (6, 70),
        ] {
            let data = (0..w * h)
                .map(|_| {
                    std::array::from_fn(|_| {
                        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                        (seed >> 8) as f32 / (1 << 24) as f32 * 100.0
                    })
                })
                .collect();
            let src = Plane {
                w,
                h,
                decim: 1,
                data,
            };
            // σ 0.54 from the input (5 taps), 1.07 (step 1), 2.14 (step 2, 14 taps) and a
            // step-4 jump (not produced by the default bands, but legal).
            for spec in [
                LevelSpec::new(0.5355, 0.0, 1, 3.0),
                LevelSpec::new(1.071, 0.5355, 1, 3.0),
                LevelSpec::new(2.142, 1.071, 1, 3.0),
                LevelSpec::new(4.3, 0.5, 1, 3.0),
            ] {
                let want = naive(&src, &spec);
                for path in all_paths() {
                    // A recycled buffer with stale contents as the output (as from the pool).
                    let stale = vec![[f32::NAN; 4]; 3 * (w * h) as usize];
                    let got = build_level(&Source::Plane(&src), &spec, stale, path);
                    assert_eq!((got.w, got.h, got.decim), (want.w, want.h, want.decim));
                    assert_eq!(got.data, want.data, "{w}x{h} step {} {path:?}", spec.step);
                }
            }
        }
    }

    /// Level 0 from the image (conversion fused into the first pass) equals the per-sample
    /// reference's level 0 from the separately converted receptor plane, on every path.
    #[test]
    fn fused_display_conversion_matches_a_converted_plane() {
        use crate::raster::{Image, Rgb};
        let img: LinearImage = Image::from_fn(11, 6, |x, y| {
            Rgb::new(x as f32 * 0.13, y as f32 * 0.21 - 0.2, 1.7 - x as f32 * 0.1)
        });
        let d = DisplayConv {
            black: 0.5,
            range: 99.5,
            exposure: 1.3,
        };
        let flag = std::sync::atomic::AtomicBool::new(false);
        let src = Source::Display(&img, d, &flag);
        let mut data = vec![[0f32; 4]; 66];
        for y in 0..6 {
            src.row(y, &mut data[y * 11..(y + 1) * 11]);
        }
        // Clamping: negative rods for saturated red are 0; rows of RGB_TO_LMSR sum to ≤ 1.09.
        assert!(data.iter().flatten().all(|&v| (0.0..=109.0).contains(&v)));
        let plane = Plane {
            w: 11,
            h: 6,
            decim: 1,
            data,
        };
        let spec = LevelSpec::new(0.5355, 0.0, 1, 3.0);
        let b = naive(&plane, &spec);
        for path in all_paths() {
            let a = build_level(&src, &spec, Vec::new(), path);
            assert_eq!((a.w, a.h, a.decim), (b.w, b.h, b.decim));
            assert_eq!(a.data, b.data, "{path:?}");
        }
    }
}
