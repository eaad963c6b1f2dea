//! Fast `log2`/`exp2` for the per-pixel hot path (≈ 70 powers per pixel and image,
//! vision-model.md §2.8). Relative error below 1e-6 over the ranges the model uses, which is
//! far below the model's own uncertainty; the exact f64 formulas live in `calib.rs` and the
//! tests compare the two.

/// log2 of a positive, normal, finite `x`. Callers guarantee `x ≥ 1e-30`. Branch-free and
/// division-free so the lane loops vectorise and the dependency chain stays short (the
/// per-pixel kernel is latency-bound).
///
/// Range reduction in integers: subtracting the bits of √½ makes the exponent field round
/// to the nearest power of two, so `x = 2^e · m` with `m ∈ [√½, √2)` without a compare.
/// Then `log2 m = f · P(f)`, `f = m − 1 ∈ [−0.293, 0.414]`, P a degree-8 near-minimax
/// fit (relative error of `f · P(f)` 2.6e-8 in exact arithmetic, below f32 rounding),
/// evaluated with Estrin's scheme (depth 4 multiplies instead of Horner's 8).
///
/// Outside the contract the result stays finite: 0 and denormals give ≈ −127, +∞ 128,
/// NaN ≈ 128.6 (as the previous atanh version did); callers never pass those.
#[inline(always)]
pub fn log2(x: f32) -> f32 {
    // Bits of √½ (0x3f3504f3).
    const SQRT_HALF_BITS: u32 = 0x3f35_04f3;
    let bits = x.to_bits();
    let e = (bits.wrapping_sub(SQRT_HALF_BITS) as i32) >> 23;
    let m = f32::from_bits(bits.wrapping_sub((e as u32) << 23));
    let f = m - 1.0;
    // log2(1 + f) / f, coefficients of f^0 .. f^8: iteratively reweighted least squares
    // on 4000 Chebyshev nodes of the interval, in relative error (≈ minimax).
    const C: [f32; 9] = [
        std::f32::consts::LOG2_E,
        -0.721_347_33,
        0.480_910_66,
        -0.360_703_62,
        0.287_916_12,
        -0.238_946_17,
        0.215_718_24,
        -0.207_261_5,
        0.125_819_67,
    ];
    let f2 = f * f;
    let f4 = f2 * f2;
    let q0 = C[0] + C[1] * f;
    let q1 = C[2] + C[3] * f;
    let q2 = C[4] + C[5] * f;
    let q3 = C[6] + C[7] * f;
    let r0 = q0 + q1 * f2;
    let r1 = q2 + q3 * f2;
    let p = (r0 + r1 * f4) + C[8] * (f4 * f4);
    e as f32 + f * p
}

/// 2^y, flushing to 0 below 2^-126 and saturating at 2^127. Branch-free (no `floorf`
/// call: the baseline x86-64 target has no rounding instruction). NaN gives NaN.
#[inline(always)]
pub fn exp2(y: f32) -> f32 {
    let yc = y.clamp(-126.0, 127.0);
    // Round to the nearest integer without float→int conversion (whose saturating
    // semantics block SSE code): adding 1.5·2^23 rounds, subtracting it back is exact.
    // Nearest (not floor) keeps |f| ≤ ½ with no correction step and no √2 factor.
    const ROUND: f32 = 12_582_912.0;
    let r = (yc + ROUND) - ROUND;
    let f = yc - r;
    // 2^f on [−½, ½]: degree-6 near-minimax fit (same method) directly in f (relative error 2e-9 in
    // exact arithmetic; the old Taylor series in f·ln 2 had 1.2e-7), Estrin's scheme so
    // the chain is 3 multiplies deep instead of 6.
    const C: [f32; 7] = [
        1.0,
        std::f32::consts::LN_2,
        0.240_226_48,
        0.055_503_324,
        0.009_618_438,
        0.001_339_888,
        0.000_153_533_68,
    ];
    let f2 = f * f;
    let f4 = f2 * f2;
    let a = C[0] + C[1] * f;
    let b = C[2] + C[3] * f;
    let c = (C[4] + C[5] * f) + C[6] * f2;
    let p = (a + b * f2) + c * f4;
    // 2^r from bits: r + 2^23 + 127 holds the biased exponent r + 127 ∈ [1, 254] in its low
    // mantissa bits; shifting by 23 moves it into the exponent field.
    let scale = f32::from_bits((r + (8_388_608.0 + 127.0)).to_bits() << 23);
    let r = p * scale;
    if y < -126.0 {
        0.0
    } else {
        r
    }
}

/// x^p for x > 0 (callers guard tiny/zero x). Scalar reference for the tests.
#[allow(dead_code)]
#[inline(always)]
pub fn pow(x: f32, p: f32) -> f32 {
    exp2(p * log2(x))
}

/// Four lanes at once (the receptor or opponent channels of one band); written as a lane
/// loop so LLVM emits SSE code.
#[allow(dead_code)]
pub type F4 = [f32; 4];

/// Lane-wise `x^p`.
#[inline(always)]
#[allow(dead_code)]
pub fn pow4(x: F4, p: F4) -> F4 {
    let mut o = [0f32; 4];
    for i in 0..4 {
        o[i] = exp2(p[i] * log2(x[i]));
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_std_to_1e6() {
        let mut x = 1e-30f32;
        while x < 1e30 {
            let r = (f64::from(log2(x)) - f64::from(x).log2()).abs();
            assert!(r < 2e-6 * f64::from(x).log2().abs().max(1.0), "log2({x})");
            for p in [-0.85f32, 0.4, 0.777, 1.46, 2.4] {
                let want = f64::from(x).powf(f64::from(p));
                if want > 1e-36 && want < 1e36 {
                    let got = f64::from(pow(x, p));
                    assert!(
                        ((got - want) / want).abs()
                            < 2e-5 * (1.0 + f64::from(x).log2().abs() / 20.0),
                        "{x}^{p}"
                    );
                }
            }
            x *= 1.37;
        }
        assert_eq!(exp2(-200.0), 0.0);
        assert!(exp2(200.0).is_finite());
        assert_eq!(exp2(0.0), 1.0f32.max(exp2(0.0)));
        assert!((exp2(3.0) - 8.0).abs() < 1e-5);
    }

    /// Worst errors over the interval the range reduction maps to, on a dense grid (every
    /// 1/4096 of the mantissa range for 40 octaves), plus exact powers of two.
    #[test]
    fn polynomial_errors_are_at_f32_rounding_level() {
        let mut worst_log = 0f64;
        let mut worst_exp = 0f64;
        for oct in -20..20 {
            for k in 0..4096 {
                let x = (1.0 + f64::from(k) / 4096.0) * 2f64.powi(oct);
                let xf = x as f32;
                let want = f64::from(xf).log2();
                // Relative to max(1, |log2 x|): the final `e + f·P` rounds to half an ulp
                // of the result, 1e-6 near ±20, whatever the polynomial.
                let err = (f64::from(log2(xf)) - want).abs() / want.abs().max(1.0);
                worst_log = worst_log.max(err);
            }
        }
        for k in -4096..=4096 {
            let y = f64::from(k) / 4096.0 * 3.0;
            let yf = y as f32;
            let want = 2f64.powf(f64::from(yf));
            worst_exp = worst_exp.max(((f64::from(exp2(yf)) - want) / want).abs());
        }
        // Measured 9.5e-8 and 1.5e-7 (atanh/Taylor versions of the same functions:
        // 1.05e-7 and 2.2e-7): a coefficient typo or a lost Estrin term is far above these.
        assert!(worst_log < 1.5e-7, "log2 worst error {worst_log}");
        assert!(worst_exp < 2e-7, "exp2 worst rel error {worst_exp}");
        for e in -126..=127 {
            assert_eq!(log2(2f32.powi(e)), e as f32, "log2(2^{e})");
            assert_eq!(exp2(e as f32), 2f32.powi(e), "exp2({e})");
        }
    }

    /// Outside the callers' contract (they clamp to ≥ 1e-30 first) the functions stay
    /// finite and never panic.
    #[test]
    fn extremes_stay_finite() {
        // 0 and denormals: ≈ −127 (the exponent field is 0).
        assert_eq!(log2(0.0), -127.0);
        for d in [f32::from_bits(1), 1e-40, f32::MIN_POSITIVE * 0.5] {
            let l = log2(d);
            assert!(
                l.is_finite() && (-128.5..=-126.0).contains(&l),
                "log2({d}) = {l}"
            );
        }
        // Smallest normal and the callers' floor are exact to f32 rounding.
        assert!((log2(f32::MIN_POSITIVE) + 126.0).abs() < 1e-5);
        assert!((f64::from(log2(1e-30)) - 1e-30f64.log2()).abs() < 1e-5);
        assert!((f64::from(log2(1e6)) - 1e6f64.log2()).abs() < 5e-6);
        assert!((f64::from(log2(f32::MAX)) - f64::from(f32::MAX).log2()).abs() < 1e-4);
        for v in [f32::INFINITY, f32::NAN, -1.0] {
            assert!(log2(v).is_finite(), "log2({v})");
        }
        assert_eq!(exp2(-126.5), 0.0);
        assert_eq!(exp2(f32::NEG_INFINITY), 0.0);
        assert!(exp2(127.99).is_finite() && exp2(f32::INFINITY).is_finite());
        assert!(exp2(f32::NAN).is_nan());
        // pow of the callers' floor: 1e-30^2.4 underflows to 0, not to garbage.
        assert_eq!(pow(1e-30, 2.4), 0.0);
        assert!((pow(1e6, 0.5) - 1000.0).abs() < 1e-3);
    }
}
