//! Whole-row weighted sums, the portable kernel both passes of §2.2 run on (and the
//! dispatch to its intrinsic builds in simd.rs).

#[cfg(target_arch = "x86_64")]
use super::simd;
use super::{Isa, P4};

/// `out[i] = Σ_t w_t · row(off_t)[i]` over whole rows (both passes of §2.2). Taps go in
/// groups of up to 8; within a group each 64-float chunk of `out` (16 samples: 8 AVX2
/// registers, enough independent add chains to hide their latency; 16- and 32-float
/// chunks measured slower) is summed in registers (one load per tap and element instead
/// of a load, a load and a store for a tap-by-tap row update). The sum runs in tap order, `((x₀w₀ + x₁w₁) + x₂w₂) + …`, which is the
/// rounding of the plain per-sample loop. The first tap writes without reading `out`, so
/// `out` may hold anything (a recycled buffer) and needs no zero fill.
#[inline(always)]
pub(super) fn weighted_sum<'a>(
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
pub(super) fn accumulate(out: &mut [f32], rows: &[&[f32]], ws: &[f32], first: bool) {
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
pub(super) fn accumulate_tail(
    out: &mut [f32],
    rows: &[&[f32]],
    ws: &[f32],
    first: bool,
    from: usize,
) {
    accumulate_range(out, rows, ws, first, from, out.len());
}

/// [`accumulate`] per float over indices `from..to`.
#[inline(always)]
pub(super) fn accumulate_range(
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
