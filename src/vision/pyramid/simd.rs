//! Explicit-intrinsic builds of [`super::sum::accumulate`]. The generic loop, inlined into the
//! fused band code, had its 16 accumulators spilled to the stack (a store and reload per
//! chunk, the hottest instructions in the profile); intrinsics pin them in registers
//! whatever the surrounding code. Same operations in the same order as [`super::sum::accumulate`]:
//! `acc = r₀·w₀` (or `out`), then `acc = acc + rₜ·wₜ` per tap, separate multiply and add
//! (no FMA, which would round once instead of twice), so bitwise the same results.

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
        return super::sum::accumulate(out, rows, ws, first);
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
                *a = _mm256_mul_ps(unsafe { _mm256_loadu_ps(r0.as_ptr().add(base + k * L)) }, w);
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
    super::sum::accumulate_tail(out, rows, ws, first, body);
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
        return super::sum::accumulate(out, rows, ws, first);
    }
    // Peel floats until the output is 64-byte aligned, so no store of the main loop
    // splits a cache line (the level buffers come from the allocator 16-byte aligned).
    let peel = ((64 - out.as_ptr() as usize % 64) % 64 / 4).min(n);
    super::sum::accumulate_range(out, rows, ws, first, 0, peel);
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
                *a = _mm512_mul_ps(unsafe { _mm512_loadu_ps(r0.as_ptr().add(base + k * L)) }, w);
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
    super::sum::accumulate_tail(out, rows, ws, first, body8);
}

/// Vertical pass of `K` output rows at once (`out` holds them one after the other,
/// `nf` floats each): output row `i` = Σ_t ws[t] · rows[i·step + t], tap order, first
/// tap a plain product, exactly as [`super::sum::accumulate`] per row. Each ring vector is
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
        return super::band::vblock(out, rows, ws, step, K);
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
        super::sum::accumulate_range(ok, &rows[k * step..k * step + taps], ws, true, body, nf);
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
/// as [`super::sum::accumulate`]. `at(P)` is the source from position `P` on (position 0 =
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
    // Every load below reads pos[P][b..b + 16] with b ≤ body − chunk.
    let need = if body > 0 { body - chunk + L } else { 0 };
    let Some((pos, ws)) = hrow_inputs::<T, NP>(kernel, at, need, n) else {
        return false;
    };
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
    super::sum::accumulate_range(out, &pos[..T], &ws, true, body, n);
    true
}

/// The inputs of [`hrow`]: the source rows from each of the `NP` positions on and the `T`
/// weights; `None` (nothing may be written) if the kernel is not `T` consecutive offsets,
/// a position's row is shorter than `need` floats or a tap row (the tail's) shorter than
/// `n`.
#[inline(always)]
fn hrow_inputs<'a, const T: usize, const NP: usize>(
    kernel: &[(i32, f32)],
    at: impl Fn(usize) -> &'a [f32],
    need: usize,
    n: usize,
) -> Option<([&'a [f32]; NP], [f32; T])> {
    // Offsets must be consecutive (they are, by construction of the kernels).
    if kernel.len() != T || kernel.windows(2).any(|w| w[1].0 != w[0].0 + 1) {
        return None;
    }
    let mut pos: [&[f32]; NP] = [&[]; NP];
    for (p, v) in pos.iter_mut().enumerate() {
        *v = at(p);
    }
    if pos.iter().any(|r| r.len() < need) || pos[..T].iter().any(|r| r.len() < n) {
        return None;
    }
    let mut ws = [0f32; T];
    for (w, k) in ws.iter_mut().zip(kernel) {
        *w = k.1;
    }
    Some((pos, ws))
}
