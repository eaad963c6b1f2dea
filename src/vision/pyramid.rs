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

use super::calib::RGB_TO_LMSR;
use crate::raster::LinearImage;
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

/// `out[i] = Σ_t w_t · row(off_t)[i]` over whole rows (both passes of §2.2). Taps go in
/// groups of up to 8; within a group each 64-float chunk of `out` (16 samples: 8 AVX2
/// registers, enough independent add chains to hide their latency; 16- and 32-float
/// chunks measured slower) is summed in registers (one load per tap and element instead
/// of a load, a load and a store for a tap-by-tap row update). The sum runs in tap order, `((x₀w₀ + x₁w₁) + x₂w₂) + …`, which is the
/// rounding of the plain per-sample loop. The first tap writes without reading `out`, so
/// `out` may hold anything (a recycled buffer) and needs no zero fill.
#[inline(always)]
fn weighted_sum<'a>(
    out: &mut [P4],
    kernel: &[(i32, f32)],
    row: impl Fn(i32) -> &'a [P4],
    isa: Isa,
) {
    const GROUP: usize = 8;
    let n = out.len();
    let out = out.as_flattened_mut();
    for (g, taps) in kernel.chunks(GROUP).enumerate() {
        let mut rows: [&[f32]; GROUP] = [&[]; GROUP];
        let mut ws = [0f32; GROUP];
        for (t, &(off, w)) in taps.iter().enumerate() {
            rows[t] = row(off)[..n].as_flattened();
            ws[t] = w;
        }
        let (rows, ws, first) = (&rows[..taps.len()], &ws[..taps.len()], g == 0);
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: callers pass an `isa` clamped to `Isa::best()`: the CPU has AVX-512F.
            Isa::Avx512 => unsafe { simd::accumulate_avx512(out, rows, ws, first) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above, the CPU has AVX2.
            Isa::Avx2 => unsafe { simd::accumulate_avx2(out, rows, ws, first) },
            _ => accumulate(out, rows, ws, first),
        }
    }
}

/// One group of [`weighted_sum`]: `out (+)= Σ_t ws[t] · rows[t]`, `first` = no `out` term.
#[inline(always)]
fn accumulate(out: &mut [f32], rows: &[&[f32]], ws: &[f32], first: bool) {
    const C: usize = 64;
    let (Some(&r0), Some(&w0)) = (rows.first(), ws.first()) else {
        return;
    };
    let n = out.len();
    let body = n / C * C;
    let skip = usize::from(first);
    for (base, o) in (0..body).step_by(C).zip(out.chunks_exact_mut(C)) {
        let mut acc = [0f32; C];
        if first {
            let r = &r0[base..base + C];
            for k in 0..C {
                acc[k] = r[k] * w0;
            }
        } else {
            acc.copy_from_slice(o);
        }
        for (row, &w) in rows.iter().zip(ws).skip(skip) {
            let r = &row[base..base + C];
            for k in 0..C {
                acc[k] += r[k] * w;
            }
        }
        o.copy_from_slice(&acc);
    }
    accumulate_tail(out, rows, ws, first, body);
}

/// [`accumulate`] per float from index `from` on (the chunk loops' remainder).
#[inline(always)]
fn accumulate_tail(out: &mut [f32], rows: &[&[f32]], ws: &[f32], first: bool, from: usize) {
    accumulate_range(out, rows, ws, first, from, out.len());
}

/// [`accumulate`] per float over indices `from..to`.
#[inline(always)]
fn accumulate_range(
    out: &mut [f32],
    rows: &[&[f32]],
    ws: &[f32],
    first: bool,
    from: usize,
    to: usize,
) {
    let (Some(&r0), Some(&w0)) = (rows.first(), ws.first()) else {
        return;
    };
    let skip = usize::from(first);
    for i in from..to.min(out.len()) {
        let mut a = if first { r0[i] * w0 } else { out[i] };
        for (row, &w) in rows.iter().zip(ws).skip(skip) {
            a += row[i] * w;
        }
        out[i] = a;
    }
}

/// Explicit-intrinsic builds of [`accumulate`]. The generic loop, inlined into the
/// fused band code, had its 16 accumulators spilled to the stack (a store and reload per
/// chunk, the hottest instructions in the profile); intrinsics pin them in registers
/// whatever the surrounding code. Same operations in the same order as [`accumulate`]:
/// `acc = r₀·w₀` (or `out`), then `acc = acc + rₜ·wₜ` per tap, separate multiply and add
/// (no FMA, which would round once instead of twice), so bitwise the same results.
#[cfg(target_arch = "x86_64")]
mod simd {
    use std::arch::x86_64::*;

    /// AVX2: 64 floats (8 registers) per chunk, as the generic loop.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    pub unsafe fn accumulate_avx2(out: &mut [f32], rows: &[&[f32]], ws: &[f32], first: bool) {
        const R: usize = 8;
        const L: usize = 8;
        let n = out.len();
        let (Some(&r0), Some(&w0)) = (rows.first(), ws.first()) else {
            return;
        };
        if rows.len() != ws.len() || rows.iter().any(|r| r.len() < n) {
            // Never happens (weighted_sum slices every row to `n`); keeps the raw loads
            // below in bounds whatever the caller.
            return super::accumulate(out, rows, ws, first);
        }
        let body = n / (R * L) * (R * L);
        let skip = usize::from(first);
        let o = out.as_mut_ptr();
        let mut base = 0;
        while base < body {
            let mut acc = [_mm256_setzero_ps(); R];
            if first {
                let w = _mm256_set1_ps(w0);
                for (k, a) in acc.iter_mut().enumerate() {
                    // SAFETY: base + k·L + L ≤ body ≤ n ≤ r0.len() (checked above).
                    *a =
                        _mm256_mul_ps(unsafe { _mm256_loadu_ps(r0.as_ptr().add(base + k * L)) }, w);
                }
            } else {
                for (k, a) in acc.iter_mut().enumerate() {
                    // SAFETY: base + k·L + L ≤ body ≤ n = out.len().
                    *a = unsafe { _mm256_loadu_ps(o.add(base + k * L)) };
                }
            }
            // Index loop, not `zip(..).skip(..)`: the iterator's `next` was not inlined and
            // the call forced every accumulator through the stack.
            for t in skip..rows.len() {
                let w = _mm256_set1_ps(ws[t]);
                let p = rows[t].as_ptr();
                for (k, a) in acc.iter_mut().enumerate() {
                    // SAFETY: as above, every row holds at least n floats.
                    let x = unsafe { _mm256_loadu_ps(p.add(base + k * L)) };
                    *a = _mm256_add_ps(*a, _mm256_mul_ps(x, w));
                }
            }
            for (k, a) in acc.iter().enumerate() {
                // SAFETY: base + k·L + L ≤ n = out.len().
                unsafe { _mm256_storeu_ps(o.add(base + k * L), *a) };
            }
            base += R * L;
        }
        super::accumulate_tail(out, rows, ws, first, body);
    }

    /// AVX-512F: 128 floats (8 zmm registers, 32 samples) per chunk: 8 independent add
    /// chains cover the add latency at two adds per cycle.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f,avx2")]
    #[inline(never)]
    pub unsafe fn accumulate_avx512(out: &mut [f32], rows: &[&[f32]], ws: &[f32], first: bool) {
        const R: usize = 8;
        const L: usize = 16;
        let n = out.len();
        let (Some(&r0), Some(&w0)) = (rows.first(), ws.first()) else {
            return;
        };
        if rows.len() != ws.len() || rows.iter().any(|r| r.len() < n) {
            return super::accumulate(out, rows, ws, first);
        }
        // Peel floats until the output is 64-byte aligned, so no store of the main loop
        // splits a cache line (the level buffers come from the allocator 16-byte aligned).
        let peel = ((64 - out.as_ptr() as usize % 64) % 64 / 4).min(n);
        super::accumulate_range(out, rows, ws, first, 0, peel);
        let o = out.as_mut_ptr();
        let body = peel + (n - peel) / (R * L) * (R * L);
        let skip = usize::from(first);
        let mut base = peel;
        while base < body {
            let mut acc = [_mm512_setzero_ps(); R];
            if first {
                let w = _mm512_set1_ps(w0);
                for (k, a) in acc.iter_mut().enumerate() {
                    // SAFETY: base + k·L + L ≤ body ≤ n ≤ r0.len() (checked above).
                    *a =
                        _mm512_mul_ps(unsafe { _mm512_loadu_ps(r0.as_ptr().add(base + k * L)) }, w);
                }
            } else {
                for (k, a) in acc.iter_mut().enumerate() {
                    // SAFETY: base + k·L + L ≤ body ≤ n = out.len().
                    *a = unsafe { _mm512_loadu_ps(o.add(base + k * L)) };
                }
            }
            // Index loop, not `zip(..).skip(..)`: the iterator's `next` was not inlined and
            // the call forced every accumulator through the stack.
            for t in skip..rows.len() {
                let w = _mm512_set1_ps(ws[t]);
                let p = rows[t].as_ptr();
                for (k, a) in acc.iter_mut().enumerate() {
                    // SAFETY: as above, every row holds at least n floats.
                    let x = unsafe { _mm512_loadu_ps(p.add(base + k * L)) };
                    *a = _mm512_add_ps(*a, _mm512_mul_ps(x, w));
                }
            }
            for (k, a) in acc.iter().enumerate() {
                // SAFETY: base + k·L + L ≤ n = out.len().
                unsafe { _mm512_storeu_ps(o.add(base + k * L), *a) };
            }
            base += R * L;
        }
        // The rest (< 128 floats) 8 at a time, then per float: same order per element.
        let body8 = body + (n - body) / 8 * 8;
        while base < body8 {
            let mut a = if first {
                // SAFETY: base + 8 ≤ body8 ≤ n ≤ r0.len().
                _mm256_mul_ps(
                    unsafe { _mm256_loadu_ps(r0.as_ptr().add(base)) },
                    _mm256_set1_ps(w0),
                )
            } else {
                // SAFETY: base + 8 ≤ n = out.len().
                unsafe { _mm256_loadu_ps(o.add(base)) }
            };
            for t in skip..rows.len() {
                // SAFETY: as above.
                let x = unsafe { _mm256_loadu_ps(rows[t].as_ptr().add(base)) };
                a = _mm256_add_ps(a, _mm256_mul_ps(x, _mm256_set1_ps(ws[t])));
            }
            // SAFETY: base + 8 ≤ n = out.len().
            unsafe { _mm256_storeu_ps(o.add(base), a) };
            base += 8;
        }
        super::accumulate_tail(out, rows, ws, first, body8);
    }

    /// Vertical pass of `K` output rows at once (`out` holds them one after the other,
    /// `nf` floats each): output row `i` = Σ_t ws[t] · rows[i·step + t], tap order, first
    /// tap a plain product, exactly as [`super::accumulate`] per row. Each ring vector is
    /// loaded once for every output row it feeds.
    // The vector type's operations come in as closures so one body serves both widths.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn vblock_generic<const K: usize, const R: usize, V: Copy>(
        out: &mut [f32],
        rows: &[&[f32]],
        ws: &[f32],
        step: usize,
        lanes: usize,
        zero: V,
        load: impl Fn(*const f32) -> V,
        store: impl Fn(*mut f32, V),
        splat: impl Fn(f32) -> V,
        mul: impl Fn(V, V) -> V,
        add: impl Fn(V, V) -> V,
    ) {
        let taps = ws.len();
        let nf = out.len() / K;
        if taps == 0 || rows.len() != taps + (K - 1) * step || rows.iter().any(|r| r.len() < nf) {
            // Never happens (band builds the block); keeps the raw accesses in bounds.
            return super::vblock(out, rows, ws, step, K);
        }
        let chunk = lanes * R;
        let body = nf / chunk * chunk;
        let o = out.as_mut_ptr();
        let mut base = 0;
        while base < body {
            let mut acc = [[zero; R]; K];
            for (r, row) in rows.iter().enumerate() {
                let p = row.as_ptr();
                let mut x = [zero; R];
                for (i, v) in x.iter_mut().enumerate() {
                    // SAFETY: base + i·lanes + lanes ≤ body ≤ nf ≤ row.len() (checked).
                    *v = load(unsafe { p.add(base + i * lanes) });
                }
                for (k, a) in acc.iter_mut().enumerate() {
                    let t = r.wrapping_sub(k * step);
                    if t < taps {
                        let w = splat(ws[t]);
                        if t == 0 {
                            for i in 0..R {
                                a[i] = mul(x[i], w);
                            }
                        } else {
                            for i in 0..R {
                                a[i] = add(a[i], mul(x[i], w));
                            }
                        }
                    }
                }
            }
            for (k, a) in acc.iter().enumerate() {
                for (i, v) in a.iter().enumerate() {
                    // SAFETY: k·nf + base + i·lanes + lanes ≤ K·nf ≤ out.len().
                    store(unsafe { o.add(k * nf + base + i * lanes) }, *v);
                }
            }
            base += chunk;
        }
        for (k, ok) in out.chunks_exact_mut(nf).enumerate().take(K) {
            super::accumulate_range(ok, &rows[k * step..k * step + taps], ws, true, body, nf);
        }
    }

    /// [`vblock_generic`] with 4 output rows × 4 zmm registers.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f,avx2")]
    #[inline(never)]
    pub unsafe fn vblock_avx512(out: &mut [f32], rows: &[&[f32]], ws: &[f32], step: usize) {
        // SAFETY: the closures are the plain AVX-512F intrinsics; pointers come in bounds.
        unsafe {
            vblock_generic::<4, 4, __m512>(
                out,
                rows,
                ws,
                step,
                16,
                _mm512_setzero_ps(),
                |p| _mm512_loadu_ps(p),
                |p, v| _mm512_storeu_ps(p, v),
                |w| _mm512_set1_ps(w),
                |a, b| _mm512_mul_ps(a, b),
                |a, b| _mm512_add_ps(a, b),
            )
        }
    }

    /// [`vblock_generic`] with 2 output rows × 4 ymm registers (16 registers in all).
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    pub unsafe fn vblock_avx2(out: &mut [f32], rows: &[&[f32]], ws: &[f32], step: usize) {
        // SAFETY: the closures are the plain AVX intrinsics; pointers come in bounds.
        unsafe {
            vblock_generic::<2, 4, __m256>(
                out,
                rows,
                ws,
                step,
                8,
                _mm256_setzero_ps(),
                |p| _mm256_loadu_ps(p),
                |p, v| _mm256_storeu_ps(p, v),
                |w| _mm256_set1_ps(w),
                |a, b| _mm256_mul_ps(a, b),
                |a, b| _mm256_add_ps(a, b),
            )
        }
    }

    /// Horizontal pass of one row with AVX-512, sharing loads between neighbouring
    /// outputs: register `i` of a chunk (4 output samples) reads tap `t` at source
    /// position `t + 4·step·i`, so one load at position `P` feeds every register with
    /// `P − 4·step·i` a tap index. Positions are visited in increasing order, so each
    /// output still sums its taps in order, first tap a plain product: bitwise the same
    /// as [`super::accumulate`]. `at(P)` is the source from position `P` on (position 0 =
    /// tap 0 of output sample 0). Only the kernel shapes of the default band set are
    /// compiled (5 and 7 taps at step 1, 14 at step 2); returns false (nothing written)
    /// for any other.
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[target_feature(enable = "avx512f,avx2")]
    #[inline(never)]
    pub unsafe fn hrow_avx512<'a>(
        out: &mut [f32],
        kernel: &[(i32, f32)],
        step: usize,
        at: impl Fn(usize) -> &'a [f32],
    ) -> bool {
        // SAFETY (all arms): the caller guarantees AVX-512F.
        unsafe {
            match (kernel.len(), step) {
                (5, 1) => hrow::<5, 4, 33>(out, kernel, at),
                (7, 1) => hrow::<7, 4, 35>(out, kernel, at),
                (14, 2) => hrow::<14, 8, 70>(out, kernel, at),
                _ => false,
            }
        }
    }

    /// [`hrow_avx512`] for `T` taps, positions `S` apart per register, `NP = T + S·(K−1)`
    /// positions for a chunk of K = 8 registers (32 samples).
    #[target_feature(enable = "avx512f,avx2")]
    #[inline]
    unsafe fn hrow<'a, const T: usize, const S: usize, const NP: usize>(
        out: &mut [f32],
        kernel: &[(i32, f32)],
        at: impl Fn(usize) -> &'a [f32],
    ) -> bool {
        const K: usize = 8;
        const L: usize = 16;
        debug_assert_eq!(NP, T + S * (K - 1));
        let n = out.len();
        let chunk = K * L;
        let body = n / chunk * chunk;
        // Offsets must be consecutive (they are, by construction of the kernels).
        if kernel.len() != T || kernel.windows(2).any(|w| w[1].0 != w[0].0 + 1) {
            return false;
        }
        let mut pos: [&[f32]; NP] = [&[]; NP];
        for (p, v) in pos.iter_mut().enumerate() {
            *v = at(p);
        }
        // Every load below reads pos[P][b..b + 16] with b ≤ body − chunk; the tail reads
        // the tap rows pos[..T] up to n. Refuse (nothing written) if any is short.
        let need = if body > 0 { body - chunk + L } else { 0 };
        if pos.iter().any(|r| r.len() < need) || pos[..T].iter().any(|r| r.len() < n) {
            return false;
        }
        let mut ws = [0f32; T];
        for (w, k) in ws.iter_mut().zip(kernel) {
            *w = k.1;
        }
        let wv: [__m512; T] = std::array::from_fn(|t| _mm512_set1_ps(ws[t]));
        let o = out.as_mut_ptr();
        let mut b = 0;
        // Register m's taps 0..S come from positions S·m + r (r = tap) and its taps
        // S..T from positions S·(m+1) + r (tap S + r), so visiting m = 0..=K in order, r
        // ascending within, applies every register's taps in order while each position
        // is loaded once (T ≤ 2S for the compiled shapes). `col!` unrolls m so the
        // accumulators stay in registers (a runtime position loop with per-register
        // branches measured slower than plain loads).
        const { assert!(S < T && T <= 2 * S && NP == T + S * (K - 1)) };
        while b < body {
            let mut acc = [_mm512_setzero_ps(); K];
            macro_rules! col {
                ($m:expr) => {{
                    let pm = S * $m;
                    for r in 0..S {
                        let both = r < T - S;
                        if $m == K && !both {
                            break;
                        }
                        // SAFETY: b + 16 ≤ need ≤ pos[..].len() (checked above).
                        let x = unsafe { _mm512_loadu_ps(pos[pm + r].as_ptr().add(b)) };
                        if let Some(a) = acc.get_mut($m) {
                            *a = if r == 0 {
                                _mm512_mul_ps(x, wv[0])
                            } else {
                                _mm512_add_ps(*a, _mm512_mul_ps(x, wv[r]))
                            };
                        }
                        if both {
                            if let Some(a) = acc.get_mut(($m as usize).wrapping_sub(1)) {
                                *a = _mm512_add_ps(*a, _mm512_mul_ps(x, wv[S + r]));
                            }
                        }
                    }
                }};
            }
            col!(0);
            col!(1);
            col!(2);
            col!(3);
            col!(4);
            col!(5);
            col!(6);
            col!(7);
            col!(8);
            for (i, a) in acc.iter().enumerate() {
                // SAFETY: b + 16·i + 16 ≤ body ≤ n = out.len().
                unsafe { _mm512_storeu_ps(o.add(b + L * i), *a) };
            }
            b += chunk;
        }
        super::accumulate_range(out, &pos[..T], &ws, true, body, n);
        true
    }
}

/// Per-thread buffers of the horizontal pass.
#[derive(Default)]
struct RowScratch {
    /// The mirror-padded source row.
    pad: Vec<P4>,
    /// Its `step` phases (pad[q + step·i]) one after the other, for decimating levels.
    phases: Vec<P4>,
}

/// Horizontal pass of one row (§2.2): `out[j] = Σ_t w_t · row[j·step + off_t]` with mirror
/// borders, computed tap-major as whole-row multiply-adds (the tap order and so every
/// rounding is the same as a per-sample loop).
#[inline(always)]
fn h_row(src: &Source, y: usize, spec: &LevelSpec, s: &mut RowScratch, out: &mut [P4], isa: Isa) {
    let (sw, _, _) = src.dims();
    let step = spec.step as usize;
    let lo = spec.kernel.first().map_or(0, |t| t.0);
    let hi = spec.kernel.last().map_or(0, |t| t.0);
    let left = (-lo).max(0) as usize;
    let len = left + sw + hi.max(0) as usize + step;
    if let Source::Plane(p) = src {
        // Read a stored level's row in place instead of copying it into the pad
        // (the copy was the largest cost after the multiply-adds).
        let row = &p.data[y * sw..(y + 1) * sw];
        if step == 1 {
            h_row_direct(row, spec, out, isa);
            return;
        }
        // Decimating: fill the phases straight from the row, mirrored at the ends.
        let plen = len.div_ceil(step);
        if s.phases.len() < plen * step {
            s.phases.resize(plen * step, [0f32; 4]);
        }
        fill_phases(row, step, left, plen, &mut s.phases[..plen * step]);
        h_phases(&s.phases, plen, left, spec, out, isa);
        return;
    }
    s.pad.resize(len, [0f32; 4]);
    let pad = &mut s.pad[..len];
    src.row(y, &mut pad[left..left + sw]);
    // Mirror the borders from the row itself (only `left + right` samples).
    for i in (0..left).chain(left + sw..len) {
        pad[i] = pad[left + mirror(i as i64 - left as i64, sw as i64)];
    }
    let pad = &s.pad[..len];
    if step == 1 {
        #[cfg(target_arch = "x86_64")]
        if isa == Isa::Avx512 {
            let o0 = (left as i64 + i64::from(lo)) as usize;
            let at = |p: usize| pad.get(o0 + p..).unwrap_or(&[]).as_flattened();
            // SAFETY: `isa` was clamped to `Isa::best()`: the CPU has AVX-512F.
            if unsafe { simd::hrow_avx512(out.as_flattened_mut(), &spec.kernel, 1, at) } {
                return;
            }
        }
        weighted_sum(
            out,
            &spec.kernel,
            |off| &pad[(left as i64 + i64::from(off)) as usize..],
            isa,
        );
        return;
    }
    // Decimating: split the padded row into its `step` phases so every tap reads a
    // contiguous run (pad[j·step + o] = phase[o % step][j + o / step]).
    let plen = len.div_ceil(step);
    s.phases.resize(plen * step, [0f32; 4]);
    for q in 0..step {
        let ph = &mut s.phases[q * plen..(q + 1) * plen];
        for (d, v) in ph.iter_mut().zip(pad[q..].iter().step_by(step)) {
            *d = *v;
        }
    }
    h_phases(&s.phases, plen, left, spec, out, isa);
}

/// Splits a stored row into its `step` phases: phase `q` sample `i` is row sample
/// `q + step·i − left`, mirrored outside the row. One contiguous pass over the row's
/// whole `step`-sample groups (each group's samples go to the `step` phases), then the
/// few remaining and mirrored samples one by one. Two strided passes (one per phase) were
/// ≈ 18 % of the decomposition in a profile.
#[inline(always)]
fn fill_phases(row: &[P4], step: usize, left: usize, plen: usize, phases: &mut [P4]) {
    const MAX_STEP: usize = 8;
    let sw = row.len();
    let mut done_to = 0; // row samples [0, done_to) are placed
    if (2..=MAX_STEP).contains(&step) {
        // Row sample step·c + r goes to phase (r + left) % step, index c + (r + left) / step.
        let mut dst = [0usize; MAX_STEP];
        for (r, d) in dst.iter_mut().enumerate().take(step) {
            *d = ((r + left) % step) * plen + (r + left) / step;
        }
        let groups = sw / step;
        // Every destination index must be inside `phases` (it is: c + (r + left) / step
        // < plen for every whole group, by the choice of plen).
        if groups == 0 || dst[..step].iter().all(|&d| d + groups <= phases.len()) {
            for (c, g) in row.chunks_exact(step).enumerate() {
                for (r, v) in g.iter().enumerate() {
                    phases[dst[r] + c] = *v;
                }
            }
            done_to = groups * step;
        }
    }
    for (q, ph) in phases.chunks_exact_mut(plen.max(1)).enumerate().take(step) {
        // Indices i with 0 ≤ q + step·i − left < done_to were placed above.
        let first = left.saturating_sub(q).div_ceil(step).min(plen);
        let end = (done_to + left)
            .saturating_sub(q)
            .div_ceil(step)
            .clamp(first, plen);
        let end = if done_to == 0 { first } else { end };
        for i in (0..first).chain(end..plen) {
            ph[i] = row[mirror((q + step * i) as i64 - left as i64, sw as i64)];
        }
    }
}

/// The decimating horizontal pass from a row split into its `step` phases (`plen`
/// samples each; phase q holds padded samples q, q + step, …, the pad starting `left`
/// samples before the row).
#[inline(always)]
fn h_phases(phases: &[P4], plen: usize, left: usize, spec: &LevelSpec, out: &mut [P4], isa: Isa) {
    let step = spec.step as usize;
    let lo = spec.kernel.first().map_or(0, |t| t.0);
    #[cfg(target_arch = "x86_64")]
    if isa == Isa::Avx512 {
        let o0 = (left as i64 + i64::from(lo)) as usize;
        let at = |p: usize| {
            let o = o0 + p;
            let i = (o % step) * plen + o / step;
            phases.get(i..).unwrap_or(&[]).as_flattened()
        };
        // SAFETY: `isa` was clamped to `Isa::best()`: the CPU has AVX-512F.
        if unsafe { simd::hrow_avx512(out.as_flattened_mut(), &spec.kernel, step, at) } {
            return;
        }
    }
    weighted_sum(
        out,
        &spec.kernel,
        |off| {
            let o = (left as i64 + i64::from(off)) as usize;
            &phases[(o % step) * plen + o / step..]
        },
        isa,
    );
}

/// Step-1 horizontal pass of a stored row without a padded copy: the outputs whose taps
/// all fall inside the row read it in place; the few border outputs (`−lo` on the left,
/// `hi` on the right) sum their mirrored taps one by one, in the same tap order.
#[inline(always)]
fn h_row_direct(row: &[P4], spec: &LevelSpec, out: &mut [P4], isa: Isa) {
    let sw = row.len();
    let (Some(&(lo, _)), Some(&(hi, _))) = (spec.kernel.first(), spec.kernel.last()) else {
        return;
    };
    let j0 = (-i64::from(lo)).max(0) as usize;
    let j1 = (sw as i64 - i64::from(hi).max(0)).max(j0 as i64) as usize;
    let j1 = j1.min(out.len());
    if j1 > j0 {
        let inner = &mut out[j0..j1];
        let o0 = (j0 as i64 + i64::from(lo)) as usize;
        let mut done = false;
        #[cfg(target_arch = "x86_64")]
        if isa == Isa::Avx512 {
            let at = |p: usize| row.get(o0 + p..).unwrap_or(&[]).as_flattened();
            // SAFETY: `isa` was clamped to `Isa::best()`: the CPU has AVX-512F.
            done = unsafe { simd::hrow_avx512(inner.as_flattened_mut(), &spec.kernel, 1, at) };
        }
        if !done {
            weighted_sum(
                inner,
                &spec.kernel,
                |off| &row[(j0 as i64 + i64::from(off)) as usize..],
                isa,
            );
        }
    }
    for j in (0..j0.min(out.len())).chain(j1.max(j0)..out.len()) {
        let mut acc = [0f32; 4];
        for (t, &(off, w)) in spec.kernel.iter().enumerate() {
            let v = row[mirror(j as i64 + i64::from(off), sw as i64)];
            for c in 0..4 {
                acc[c] = if t == 0 { v[c] * w } else { acc[c] + v[c] * w };
            }
        }
        out[j] = acc;
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

/// Per-thread buffers of a fused band.
#[derive(Default)]
struct BandScratch {
    row: RowScratch,
    /// Horizontal-pass rows: virtual source row `v` (before mirroring) lives in slot
    /// `v mod cap` (cap = the rows one vertical block reads), `dw` samples per slot
    /// plus [`RING_PAD`].
    ring: Vec<P4>,
}

/// Output rows `j0 .. j0 + out.len() / dw` of a level, both passes fused (§2.2). Output row
/// `j` reads the horizontal-pass rows of virtual source rows `j·step + off_t`; those are
/// computed in increasing order into a ring of slots, so each is computed once per
/// band (plus the band's halo) and read from cache by the vertical pass. A virtual row is
/// the horizontal pass of source row `mirror(v)`, and the vertical sum runs over the rows
/// §2.2's separable filter reads, in tap order: bitwise the per-sample loop's level.
// Plain arguments (not a struct) so the `target_feature` wrappers stay one-line forwards.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn band(
    src: &Source,
    sh: usize,
    j0: usize,
    spec: &LevelSpec,
    s: &mut BandScratch,
    out: &mut [P4],
    dw: usize,
    isa: Isa,
) {
    let step = spec.step as i64;
    let (Some(&(lo, _)), Some(&(hi, _))) = (spec.kernel.first(), spec.kernel.last()) else {
        return;
    };
    let (lo, hi) = (i64::from(lo), i64::from(hi));
    let taps = (hi - lo + 1) as usize;
    // Output rows per vertical-pass block: each loaded ring vector feeds up to `kb`
    // output rows (one load per multiply-add was the kernel's limit; measured about
    // 1.5× the multiply-add rate with 2–4 rows per load).
    let kb = match isa {
        Isa::Avx512 => 4,
        Isa::Avx2 => 2,
        Isa::Portable => 1,
    };
    let n_in = taps + (kb - 1) * step as usize;
    let kb = if n_in > MAX_BLOCK_ROWS || taps != spec.kernel.len() {
        1
    } else {
        kb
    };
    let n_in = taps + (kb - 1) * step as usize;
    let cap = n_in;
    let mut ws = [0f32; MAX_BLOCK_ROWS];
    for (w, t) in ws.iter_mut().zip(&spec.kernel) {
        *w = t.1;
    }
    // Slots are padded by one cache line so the rows read together do not all map to the
    // same L1 sets (a 512-sample row is 8 KB, a multiple of the 4 KB set period).
    let stride = dw + RING_PAD;
    if s.ring.len() < cap * stride + 4 {
        s.ring.resize(cap * stride + 4, [0f32; 4]);
    }
    // Start the slots at the output rows' offset within a 64-byte line, so ring loads and
    // output stores have the same alignment.
    let (ra, oa) = (s.ring.as_ptr() as usize, out.as_ptr() as usize);
    let a0 = if ra % 16 == 0 && oa % 16 == 0 {
        (oa % 64 + 64 - ra % 64) % 64 / 16
    } else {
        0
    };
    let slot = |v: i64| a0 + v.rem_euclid(cap as i64) as usize * stride;
    let mut next = j0 as i64 * step + lo;
    let n_out = out.len() / dw.max(1);
    let mut jj = 0;
    while jj < n_out {
        let kk = kb.min(n_out - jj);
        let base = (j0 + jj) as i64 * step;
        // Horizontal pass of every row the block reads that is not in the ring yet.
        while next <= base + (kk as i64 - 1) * step + hi {
            let k = slot(next);
            let sy = mirror(next, sh as i64);
            h_row(src, sy, spec, &mut s.row, &mut s.ring[k..k + dw], isa);
            next += 1;
        }
        let ring = &s.ring;
        let block = &mut out[jj * dw..(jj + kk) * dw];
        if kk == kb && kb > 1 {
            let mut rows: [&[f32]; MAX_BLOCK_ROWS] = [&[]; MAX_BLOCK_ROWS];
            for (r, row) in rows[..n_in].iter_mut().enumerate() {
                let k = slot(base + lo + r as i64);
                *row = ring[k..k + dw].as_flattened();
            }
            let (rows, ws, st) = (&rows[..n_in], &ws[..taps], step as usize);
            let block = block.as_flattened_mut();
            match isa {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `isa` was clamped to `Isa::best()`: the CPU has AVX-512F.
                Isa::Avx512 => unsafe { simd::vblock_avx512(block, rows, ws, st) },
                #[cfg(target_arch = "x86_64")]
                // SAFETY: as above, the CPU has AVX2.
                Isa::Avx2 => unsafe { simd::vblock_avx2(block, rows, ws, st) },
                _ => vblock(block, rows, ws, st, kb),
            }
        } else {
            for (r, orow) in block.chunks_exact_mut(dw).enumerate() {
                let base = base + r as i64 * step;
                weighted_sum(
                    orow,
                    &spec.kernel,
                    |off| {
                        let k = slot(base + i64::from(off));
                        &ring[k..k + dw]
                    },
                    isa,
                );
            }
        }
        jj += kk;
    }
}

/// Most ring rows one vertical block reads (`taps + (rows − 1) · step`); longer kernels
/// fall back to one output row at a time.
const MAX_BLOCK_ROWS: usize = 32;

/// Vertical pass of `k` output rows (`out` holds them one after the other) from `rows`:
/// output row `i` is `Σ_t ws[t] · rows[i·step + t]`, in tap order, per float (the
/// intrinsic blocks' remainder and their portable equivalent).
fn vblock(out: &mut [f32], rows: &[&[f32]], ws: &[f32], step: usize, k: usize) {
    let nf = out.len() / k.max(1);
    for (i, o) in out.chunks_exact_mut(nf.max(1)).enumerate().take(k) {
        if let Some(r) = rows.get(i * step..i * step + ws.len()) {
            accumulate_range(o, r, ws, true, 0, nf);
        }
    }
}

/// Extra samples between ring slots (4 samples = one 64-byte line per slot).
const RING_PAD: usize = 4;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn band_avx2(
    src: &Source,
    sh: usize,
    j0: usize,
    spec: &LevelSpec,
    s: &mut BandScratch,
    out: &mut [P4],
    dw: usize,
) {
    band(src, sh, j0, spec, s, out, dw, Isa::Avx2);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2")]
fn band_avx512(
    src: &Source,
    sh: usize,
    j0: usize,
    spec: &LevelSpec,
    s: &mut BandScratch,
    out: &mut [P4],
    dw: usize,
) {
    band(src, sh, j0, spec, s, out, dw, Isa::Avx512);
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

    /// Per-sample separable reference (the pre-issue-#3 loop structure): acc = 0, then
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
