//! Every uncertain constant of the vision model in one place (vision-model.md §7, §9).
//!
//! Tags follow vision-model.md §0: **[F04]** stated in Farrugia & Péroche 2004, **[SRC]** seen
//! in a named public source, **[P?]** recalled from PFFG98 but unverified, **[D]** our design
//! decision. Change a value here and the whole model follows; the tests pin behaviour
//! (threshold = 1 JND, masking, luminance dependence), not these numbers.

/// Parameters of one receptor gain function (vision-model.md §2.3):
/// `G(I) = sat(I) / (scale · (I + offset))^exponent` with `sat(I) = s / (I² + s)` when
/// `saturation` is `Some(s)` (rods) and 1 otherwise (cones).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GainParams {
    pub scale: f64,
    pub offset: f64,
    pub exponent: f64,
    pub saturation: Option<f64>,
}

impl GainParams {
    /// The gain at receptor signal `i` (≈ cd/m²), exact in f64. `i` is clamped at 0 (§2.9:
    /// gains always take the clamped low-pass).
    #[must_use]
    pub fn gain(&self, i: f64) -> f64 {
        let i = i.max(0.0);
        let base = (self.scale * (i + self.offset)).powf(-self.exponent);
        match self.saturation {
            Some(s) => s / (i * i + s) * base,
            None => base,
        }
    }
}

/// The calibration of the model. Defaults are vision-model.md §7.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    /// Nominal band centre frequencies in cycles/degree, finest first. [P?] octaves,
    /// [D] the set 16..0.5 (§2.2).
    pub band_cpd: Vec<f64>,
    /// Bands whose finer Gaussian is narrower than this (pixels) are dropped: such kernels
    /// are nearly a delta and the band would be sampling noise. [D] 0.5 px (§2.2).
    pub min_sigma_px: f64,
    /// Gaussian kernels are truncated at this many sigmas and renormalised to sum 1. [D] 3.
    pub kernel_radius_sigmas: f64,
    /// Cone gain G_cone: 0.555, 1.0, 0.85. [P?] (§2.3)
    pub cone_gain: GainParams,
    /// Rod gain G_rod: 0.908, 0.001, 0.85, saturation 10/(I²+10). [P?] (§2.3)
    pub rod_gain: GainParams,
    /// Opponent transform rows (A, RG, BY) over (L, M, S, R): Hunt's (2, 1, 1/20),
    /// (1, −12/11, 1/11), (1/9, 1/9, −2/9) [SRC Hunt]; rods added to A with weight 1 [D].
    pub opponent: [[f64; 4]; 3],
    /// Achromatic CSF `a · f^b · exp(−c f)`: (75, 0.8, 0.2). [P?] (§2.5)
    pub csf_achromatic: [f64; 3],
    /// Red–green CSF `a1 exp(−b1 f^c1) + a2 exp(−b2 f^c2)`. [SRC vmaf fits] (§2.5)
    pub csf_red_green: [f64; 6],
    /// Blue–yellow CSF, same form. [SRC vmaf fits] (§2.5)
    pub csf_blue_yellow: [f64; 6],
    /// Chromatic sensitivity is 0 above this frequency (Mullen's chromatic acuity). [D] 12.
    pub chroma_cutoff_cpd: f64,
    /// A band/channel with sensitivity below this contributes 0: the transducer exponent
    /// ln 22.4 / ln(0.536 S) blows up as 0.536 S → 1. [D] 2 (§2.6).
    pub min_sensitivity: f64,
    /// Reference adaptation luminance (D65 grey) for threshold units. [D] 100 cd/m² (§2.5).
    pub l_ref: f64,
    /// Transducer anchor contrast 0.536 giving 22.4 units, exponent ½ above. [P?] (§2.6)
    pub transducer_anchor_contrast: f64,
    pub transducer_anchor_response: f64,
    pub transducer_high_exponent: f64,
    /// Minkowski exponent of the distance ("pseudo-Euclidean"). [F04] 2.4 (§2.7).
    pub minkowski: f64,
}

impl Default for Calibration {
    fn default() -> Self {
        Self {
            band_cpd: vec![16.0, 8.0, 4.0, 2.0, 1.0, 0.5],
            min_sigma_px: 0.5,
            kernel_radius_sigmas: 3.0,
            cone_gain: GainParams {
                scale: 0.555,
                offset: 1.0,
                exponent: 0.85,
                saturation: None,
            },
            rod_gain: GainParams {
                scale: 0.908,
                offset: 0.001,
                exponent: 0.85,
                saturation: Some(10.0),
            },
            opponent: [
                [2.0, 1.0, 1.0 / 20.0, 1.0],
                [1.0, -12.0 / 11.0, 1.0 / 11.0, 0.0],
                [1.0 / 9.0, 1.0 / 9.0, -2.0 / 9.0, 0.0],
            ],
            csf_achromatic: [75.0, 0.8, 0.2],
            csf_red_green: [91.228, 0.0003, 2.803, 74.907, 0.0038, 2.601],
            csf_blue_yellow: [5.623, 0.00001, 3.4066, 41.9363, 0.083, 1.3684],
            chroma_cutoff_cpd: 12.0,
            min_sensitivity: 2.0,
            l_ref: 100.0,
            transducer_anchor_contrast: 0.536,
            transducer_anchor_response: 22.4,
            transducer_high_exponent: 0.5,
            minkowski: 2.4,
        }
    }
}

/// Linear display RGB (cd/m² per channel) → L, M, S, R, pre-multiplied
/// (Rec.709 → XYZ → Hunt–Pointer–Estevez, and PFFG98's rod row), vision-model.md §2.1.
pub const RGB_TO_LMSR: [[f32; 3]; 4] = [
    [0.30568, 0.62274, 0.04530],
    [0.15771, 0.76972, 0.08807],
    [0.01930, 0.11920, 0.95050],
    [-0.06026, 0.54367, 0.35987],
];

/// Peak of the DoG band G(σ) − G(2σ) in cycles/pixel is this over σ (§2.2).
pub const DOG_PEAK_TIMES_SIGMA: f64 = 0.153_00;

impl Calibration {
    /// Sensitivity of channel `k` (0 = A, 1 = RG, 2 = BY) at `f` cpd (§2.5), with the
    /// chromatic acuity cut-off.
    #[must_use]
    pub fn csf(&self, k: usize, f: f64) -> f64 {
        let two = |c: &[f64; 6]| {
            c[0] * (-c[1] * f.powf(c[2])).exp() + c[3] * (-c[4] * f.powf(c[5])).exp()
        };
        match k {
            0 => {
                let [a, b, c] = self.csf_achromatic;
                a * f.powf(b) * (-c * f).exp()
            }
            _ if f > self.chroma_cutoff_cpd => 0.0,
            1 => two(&self.csf_red_green),
            _ => two(&self.csf_blue_yellow),
        }
    }

    /// Receptor signals (L, M, S, R) of a uniform D65 grey of luminance `l` (§2.1 table,
    /// last column).
    #[must_use]
    pub fn grey_receptors(l: f64) -> [f64; 4] {
        let mut out = [0.0; 4];
        for (o, row) in out.iter_mut().zip(RGB_TO_LMSR.iter()) {
            *o = l * row.iter().map(|&v| f64::from(v)).sum::<f64>();
        }
        out
    }

    /// `W_k(L)` of §2.5: the gain-controlled band response per unit contrast of the
    /// channel-`k` stimulus on a D65 grey of luminance `l`. Stimulus directions: achromatic
    /// (+c on every receptor), red–green (+cL₀, −cM₀), blue–yellow (+cS₀).
    #[must_use]
    pub fn w(&self, k: usize, l: f64) -> f64 {
        const STIM: [[f64; 4]; 3] = [
            [1.0, 1.0, 1.0, 1.0],
            [1.0, -1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let r = Self::grey_receptors(l);
        let mut s = 0.0;
        for x in 0..4 {
            let g = if x == 3 {
                self.rod_gain.gain(r[x])
            } else {
                self.cone_gain.gain(r[x])
            };
            s += self.opponent[k][x] * STIM[k][x] * r[x] * g;
        }
        s.abs()
    }

    /// Transducer exponent below the anchor, `p = ln 22.4 / ln x_s` with `x_s = 0.536 S`
    /// (§2.6), so that T(1) = 1 and T is continuous at x_s.
    #[must_use]
    pub fn transducer_exponent(&self, sensitivity: f64) -> f64 {
        self.transducer_anchor_response.ln() / (self.transducer_anchor_contrast * sensitivity).ln()
    }

    /// The transducer T(x) of §2.6 in threshold units, exact in f64 (reference for tests;
    /// the model uses a fast f32 version).
    #[must_use]
    pub fn transducer(&self, x: f64, sensitivity: f64) -> f64 {
        let xs = self.transducer_anchor_contrast * sensitivity;
        if x <= 0.0 {
            0.0
        } else if x < xs {
            x.powf(self.transducer_exponent(sensitivity))
        } else {
            self.transducer_anchor_response * (x / xs).powf(self.transducer_high_exponent)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rel(a: f64, b: f64) -> f64 {
        ((a - b) / b).abs()
    }

    #[test]
    fn gain_table_matches_spec_2_3() {
        let c = Calibration::default();
        // (I, G_cone, G_rod) from vision-model.md §2.3.
        let table = [
            (0.0, 1.6495, 385.15),
            (0.001, 1.6481, 213.67),
            (0.01, 1.6356, 50.169),
            (0.1, 1.5211, 7.6124),
            (1.0, 0.91511, 0.98597),
            (10.0, 0.21487, 0.013938),
            (100.0, 0.032635, 2.1637e-5),
            (1000.0, 0.0046450, 3.0593e-8),
        ];
        for (i, gc, gr) in table {
            // The spec prints 5 significant digits, so 1e-4 relative is the check.
            assert!(
                rel(c.cone_gain.gain(i), gc) < 1e-4,
                "G_cone({i}) = {}",
                c.cone_gain.gain(i)
            );
            assert!(
                rel(c.rod_gain.gain(i), gr) < 1e-4,
                "G_rod({i}) = {}",
                c.rod_gain.gain(i)
            );
        }
    }

    #[test]
    fn csf_and_w_match_spec_2_5() {
        let c = Calibration::default();
        for (f, a, rg, by) in [
            (8.0, 79.9, 114.4, 15.6),
            (4.0, 102.2, 155.0, 29.7),
            (1.0, 61.4, 165.8, 44.2),
        ] {
            assert!(rel(c.csf(0, f), a) < 2e-3, "S_A({f})");
            assert!(rel(c.csf(1, f), rg) < 2e-3, "S_RG({f})");
            assert!(rel(c.csf(2, f), by) < 5e-3, "S_BY({f})");
        }
        assert_eq!(c.csf(1, 16.0), 0.0);
        assert_eq!(c.csf(2, 16.0), 0.0);
        for (l, w) in [
            (100.0, 9.939),
            (10.0, 6.721),
            (1.0, 3.760),
            (0.1, 1.200),
            (0.01, 0.5315),
        ] {
            assert!(rel(c.w(0, l), w) < 1e-3, "W_A({l}) = {}", c.w(0, l));
        }
        assert!(rel(c.w(1, 100.0), 6.819) < 1e-3);
        assert!(rel(c.w(2, 100.0), 0.7351) < 1e-3);
    }

    #[test]
    fn transducer_is_one_at_threshold_continuous_and_increasing() {
        let c = Calibration::default();
        for s in [2.5, 15.6, 61.4, 102.2, 165.8] {
            assert!((c.transducer(1.0, s) - 1.0).abs() < 1e-12);
            let xs = 0.536 * s;
            let below = c.transducer(xs * (1.0 - 1e-9), s);
            let above = c.transducer(xs, s);
            assert!((below - 22.4).abs() < 1e-6 && (above - 22.4).abs() < 1e-12);
            let mut prev = 0.0;
            for i in 1..200 {
                let t = c.transducer(f64::from(i) * 0.7, s);
                assert!(t > prev);
                prev = t;
            }
        }
        assert_eq!(c.transducer(0.0, 100.0), 0.0);
        // §2.6 worked values for A at 4 cpd (S = 102.2).
        let s = c.csf(0, 4.0);
        for (x, t) in [
            (0.5, 0.584),
            (2.0, 1.713),
            (10.0, 5.98),
            (100.0, 30.3),
            (1000.0, 95.7),
        ] {
            assert!(
                rel(c.transducer(x, s), t) < 5e-3,
                "T({x}) = {}",
                c.transducer(x, s)
            );
        }
    }
}
