//! The octave Gaussian stack with explicit sigmas and decimated storage
//! (vision-model.md §2.2). Pixels hold the four receptor signals (L, M, S, R) interleaved,
//! so one bilinear lookup fetches all four and the blur loops vectorise.

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

#[inline(always)]
fn madd(acc: &mut P4, v: &P4, w: f32) {
    for c in 0..4 {
        acc[c] += v[c] * w;
    }
}

/// Builds `spec`'s level from `src` (separable: rows, then columns; mirror borders).
/// `tmp` is scratch for the horizontal pass, reused across levels and calls so the big
/// intermediate is not a fresh (page-faulting, zero-filled) allocation every time.
#[must_use]
#[inline(always)]
pub fn build_level(src: &Plane, spec: &LevelSpec, tmp: &mut Vec<P4>) -> Plane {
    let (sw, sh) = (src.w as usize, src.h as usize);
    let step = spec.step as usize;
    let dw = sw.div_ceil(step);
    let dh = sh.div_ceil(step);
    let lo = spec.kernel.first().map_or(0, |t| t.0);
    let hi = spec.kernel.last().map_or(0, |t| t.0);
    // Horizontal pass: each source row into `dw` samples.
    // Every sample is overwritten below; resize only fills new capacity.
    tmp.resize(dw * sh, [0f32; 4]);
    let tmp = &mut tmp[..dw * sh];
    tmp.par_chunks_mut(dw)
        .enumerate()
        .for_each_init(Vec::<P4>::new, |pad, (y, out)| {
            let row = &src.data[y * sw..(y + 1) * sw];
            // Mirror-padded copy so the inner loop has no index arithmetic.
            let left = (-lo).max(0) as usize;
            let right = hi.max(0) as usize + step;
            pad.clear();
            pad.extend(
                (0..left + sw + right).map(|i| row[mirror(i as i64 - left as i64, sw as i64)]),
            );
            for (j, o) in out.iter_mut().enumerate() {
                let base = (j * step + left) as i64;
                let mut acc = [0f32; 4];
                for &(off, w) in &spec.kernel {
                    madd(&mut acc, &pad[(base + i64::from(off)) as usize], w);
                }
                *o = acc;
            }
        });
    // Vertical pass: each output row is a weighted sum of whole source rows.
    let mut data = vec![[0f32; 4]; dw * dh];
    data.par_chunks_mut(dw).enumerate().for_each(|(j, out)| {
        for (t, &(off, w)) in spec.kernel.iter().enumerate() {
            let sy = mirror((j * step) as i64 + i64::from(off), sh as i64);
            let row = &tmp[sy * dw..(sy + 1) * dw];
            if t == 0 {
                // The first tap writes without reading: reading the fresh zeroed allocation
                // first maps the shared zero page, and the write that follows then costs a
                // copy-on-write fault plus a TLB shoot-down on every core (≈ 7 % of the
                // profile). Same sum: 0 + v·w = v·w.
                for (o, v) in out.iter_mut().zip(row) {
                    *o = [v[0] * w, v[1] * w, v[2] * w, v[3] * w];
                }
            } else {
                for (o, v) in out.iter_mut().zip(row) {
                    madd(o, v, w);
                }
            }
        }
    });
    Plane {
        w: dw as u32,
        h: dh as u32,
        decim: src.decim * spec.step,
        data,
    }
}

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
        let out = build_level(&src, &spec, &mut Vec::new());
        assert_eq!((out.w, out.h), (7, 4));
        for p in &out.data {
            for (a, b) in p.iter().zip([3.0, 2.0, 1.0, 0.5]) {
                assert!((a - b).abs() < 1e-5);
            }
        }
        let v = bilinear(&out, 12, 6);
        assert!((v[0] - 3.0).abs() < 1e-5);
    }
}
