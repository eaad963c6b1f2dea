//! The horizontal pass of §2.2's separable filter: one source row into one level row,
//! decimating or not, with mirror borders.

#[cfg(target_arch = "x86_64")]
use super::simd;
use super::sum::weighted_sum;
use super::{mirror, Isa, LevelSpec, Source, P4};

/// Per-thread buffers of the horizontal pass.
#[derive(Default)]
pub(super) struct RowScratch {
    /// The mirror-padded source row.
    pad: Vec<P4>,
    /// Its `step` phases (pad[q + step·i]) one after the other, for decimating levels.
    phases: Vec<P4>,
}

/// Horizontal pass of one row (§2.2): `out[j] = Σ_t w_t · row[j·step + off_t]` with mirror
/// borders, computed tap-major as whole-row multiply-adds (the tap order and so every
/// rounding is the same as a per-sample loop).
#[inline(always)]
pub(super) fn h_row(
    src: &Source,
    y: usize,
    spec: &LevelSpec,
    s: &mut RowScratch,
    out: &mut [P4],
    isa: Isa,
) {
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
