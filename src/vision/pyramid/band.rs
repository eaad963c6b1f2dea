//! Both passes of §2.2 fused over a band of output rows: horizontal rows into a ring,
//! vertical sums out of it.

use super::hpass::{h_row, RowScratch};
#[cfg(target_arch = "x86_64")]
use super::simd;
use super::sum::{accumulate_range, weighted_sum};
use super::{mirror, Isa, LevelSpec, Source, P4};

/// Per-thread buffers of a fused band.
#[derive(Default)]
pub(super) struct BandScratch {
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
pub(super) fn band(
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
    let kb = block_rows(isa, taps, step as usize, spec.kernel.len());
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
    let a0 = ring_start(&s.ring, out);
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
            vertical_block(block.as_flattened_mut(), rows, ws, st, kb, isa);
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

/// Output rows per vertical-pass block: each loaded ring vector feeds up to that many
/// output rows (one load per multiply-add was the kernel's limit; measured about 1.5× the
/// multiply-add rate with 2–4 rows per load). One row where the block would read more
/// than [`MAX_BLOCK_ROWS`] ring rows, or the kernel's offsets have gaps.
#[inline(always)]
fn block_rows(isa: Isa, taps: usize, step: usize, kernel_len: usize) -> usize {
    let kb = match isa {
        Isa::Avx512 => 4,
        Isa::Avx2 => 2,
        Isa::Portable => 1,
    };
    let n_in = taps + (kb - 1) * step;
    if n_in > MAX_BLOCK_ROWS || taps != kernel_len {
        1
    } else {
        kb
    }
}

/// The first ring sample of slot 0: the output rows' offset within a 64-byte line, so
/// ring loads and output stores have the same alignment (0 if either is not 16-byte
/// aligned).
#[inline(always)]
fn ring_start(ring: &[P4], out: &[P4]) -> usize {
    let (ra, oa) = (ring.as_ptr() as usize, out.as_ptr() as usize);
    if ra % 16 == 0 && oa % 16 == 0 {
        (oa % 64 + 64 - ra % 64) % 64 / 16
    } else {
        0
    }
}

/// Vertical pass of a block of `kb` output rows from the ring rows `rows`, on the widest
/// kernel `isa` allows ([`vblock`] otherwise).
#[inline(always)]
fn vertical_block(block: &mut [f32], rows: &[&[f32]], ws: &[f32], st: usize, kb: usize, isa: Isa) {
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` was clamped to `Isa::best()`: the CPU has AVX-512F.
        Isa::Avx512 => unsafe { simd::vblock_avx512(block, rows, ws, st) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above, the CPU has AVX2.
        Isa::Avx2 => unsafe { simd::vblock_avx2(block, rows, ws, st) },
        _ => vblock(block, rows, ws, st, kb),
    }
}

/// Most ring rows one vertical block reads (`taps + (rows − 1) · step`); longer kernels
/// fall back to one output row at a time.
const MAX_BLOCK_ROWS: usize = 32;

/// Vertical pass of `k` output rows (`out` holds them one after the other) from `rows`:
/// output row `i` is `Σ_t ws[t] · rows[i·step + t]`, in tap order, per float (the
/// intrinsic blocks' remainder and their portable equivalent).
pub(super) fn vblock(out: &mut [f32], rows: &[&[f32]], ws: &[f32], step: usize, k: usize) {
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
pub(super) fn band_avx2(
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
pub(super) fn band_avx512(
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
