//! Unit tests of the model's internals (vision-model.md §2.2, §2.7); behaviour tests are in
//! tests/vision_behaviour.rs.
use super::*;

fn display(ppd: f32) -> DisplayModel {
    DisplayModel {
        peak_luminance: 100.0,
        black_luminance: 0.5,
        exposure: 1.0,
        pixels_per_degree: ppd,
    }
}

#[test]
fn band_set_follows_the_sigma_and_size_rules() {
    // ppd 28, 512²: 16 cpd dropped (σ = 0.268 < 0.5), five bands, σ = 0.153·28/f.
    let m = VisionModel::new(display(28.0), 512, 512);
    let cpd: Vec<f64> = m.bands().iter().map(|b| b.cpd).collect();
    assert_eq!(cpd, vec![8.0, 4.0, 2.0, 1.0, 0.5]);
    assert!((m.bands()[0].sigma_px - 0.5355).abs() < 1e-3);
    assert_eq!(m.levels.len(), 6);
    assert_eq!(
        m.levels.iter().map(|l| l.decim).collect::<Vec<_>>(),
        vec![1, 1, 2, 4, 8, 16]
    );
    // ppd 60 keeps all six.
    assert_eq!(VisionModel::new(display(60.0), 512, 512).bands().len(), 6);
    // 1×1: nothing.
    assert!(VisionModel::new(display(28.0), 1, 1).bands().is_empty());
}

#[test]
fn measured_peak_gain_is_close_to_the_analytic_dog_peak() {
    // §2.2: H(f_peak) = 0.47247 for continuous Gaussians; our sampled, truncated, decimated
    // filters are within a few per cent (the finest band differs most).
    for ppd in [28.0, 60.0] {
        let m = VisionModel::new(display(ppd), 512, 512);
        for b in m.bands() {
            assert!(
                (b.peak_gain - 0.47247).abs() < 0.05,
                "ppd {ppd} {} cpd: g = {}",
                b.cpd,
                b.peak_gain
            );
        }
    }
}

#[test]
fn tabulated_gains_match_the_exact_formulas() {
    let m = VisionModel::new(display(28.0), 64, 64);
    let c = Calibration::default();
    let mut i = 0f32;
    while i < 1e13 {
        let (ec, er) = (
            c.cone_gain.gain(f64::from(i)),
            c.rod_gain.gain(f64::from(i)),
        );
        let (gc, gr) = (
            f64::from(m.cone_gain.gain(i)),
            f64::from(m.rod_gain.gain(i)),
        );
        assert!((gc - ec).abs() <= 3e-5 * ec, "cone {i}: {gc} vs {ec}");
        assert!(
            // Rod gains below 1e-30 (I > 1e10 cd/m²) are f32 noise and irrelevant.
            (gr - er).abs() <= 3e-5 * er + 1e-30,
            "rod {i}: {gr} vs {er}"
        );
        i = i * 1.173 + 1e-4;
    }
    // Negative signals are clamped to 0 (§2.9).
    assert_eq!(m.cone_gain.gain(-5.0), m.cone_gain.gain(0.0));
    assert!(m.rod_gain.gain(f32::MAX).is_finite());
}

#[test]
fn minkowski_is_robust_and_exact_at_zero() {
    assert_eq!(minkowski(&[1.0, 2.0], &[1.0, 2.0], 2.4), 0.0);
    assert_eq!(minkowski(&[], &[], 2.4), 0.0);
    // One non-zero component: the distance is that difference.
    assert!((minkowski(&[0.0, 3.0, 0.0], &[0.0, 0.0, 0.0], 2.4) - 3.0).abs() < 1e-5);
    // Two equal components: 2^(1/2.4) times.
    let d = minkowski(&[1.0, 1.0], &[0.0, 0.0], 2.4);
    assert!((d - 2f32.powf(1.0 / 2.4)).abs() < 1e-5);
    // Huge and tiny values neither overflow nor vanish.
    let d = minkowski(&[1e30, 1e30], &[0.0, 0.0], 2.4);
    assert!(d.is_finite() && (d / 1e30 - 2f32.powf(1.0 / 2.4)).abs() < 1e-4);
    let d = minkowski(&[1e-20, 1e-20], &[0.0, 0.0], 2.4);
    assert!(d > 0.0 && (d / 1e-20 - 2f32.powf(1.0 / 2.4)).abs() < 1e-4);
}

#[test]
fn bad_display_parameters_are_sanitised() {
    let d = DisplayModel {
        peak_luminance: f32::NAN,
        black_luminance: 1e9,
        exposure: -1.0,
        pixels_per_degree: 0.0,
    };
    let m = VisionModel::new(d, 32, 32);
    assert_eq!(m.display().peak_luminance, 100.0);
    assert_eq!(m.display().black_luminance, 100.0);
    assert_eq!(m.display().exposure, 1.0);
    assert_eq!(m.display().pixels_per_degree, 28.0);
}

/// Exact f64 reference of §2.3–§2.7 at one pixel, from the decomposed levels (the pyramid
/// is shared code; everything after the bilinear lookup uses calib.rs's exact formulas).
fn exact_contrasts(m: &VisionModel, s: &ContrastStack, x: u32, y: u32) -> Vec<f64> {
    let c = m.calibration();
    let lv: Vec<[f64; 4]> = s
        .levels
        .iter()
        .map(|p| bilinear(p, x, y).map(f64::from))
        .collect();
    let mut out = Vec::new();
    for (bi, band) in m.bands().iter().enumerate() {
        let (g, lo) = (lv[bi], lv[bi + 1]);
        let bt: [f64; 4] = std::array::from_fn(|r| {
            let gp = if r == 3 { &c.rod_gain } else { &c.cone_gain };
            gp.gain(lo[r]) * (g[r] - lo[r])
        });
        for k in 0..3 {
            if band.lanes[k].inv_thresh == 0.0 {
                out.push(0.0);
                continue;
            }
            let cv: f64 = (0..4).map(|r| c.opponent[k][r] * bt[r]).sum();
            let w_ref = c.w(k, c.l_ref);
            let xv = cv.abs() * band.sensitivity[k] / (band.peak_gain * w_ref);
            out.push(cv.signum() * c.transducer(xv, band.sensitivity[k]));
        }
    }
    out
}

/// Tiny deterministic xorshift so the test needs no RNG crate state.
fn rng(seed: &mut u64) -> f32 {
    *seed ^= *seed << 13;
    *seed ^= *seed >> 7;
    *seed ^= *seed << 17;
    (*seed >> 40) as f32 / (1u64 << 24) as f32
}

fn random_image(w: u32, h: u32, seed: u64) -> LinearImage {
    let mut s = seed;
    Image::from_fn(w, h, |_, _| {
        let base = rng(&mut s);
        // Mostly mid-grey texture, some dark and some clipped pixels.
        crate::raster::Rgb::new(
            base * 1.2,
            base * (0.6 + 0.6 * rng(&mut s)),
            base * rng(&mut s),
        )
    })
}

#[test]
fn fast_transducer_matches_the_exact_formula() {
    // kernel::visible against Calibration::transducer for every band/channel of two
    // displays, x log-uniform over 1e-8 .. 1e8 threshold units (both branches).
    let c = Calibration::default();
    let mut seed = 99u64;
    for ppd in [28.0, 60.0] {
        let m = VisionModel::new(display(ppd), 512, 512);
        for band in m.bands() {
            for k in 0..3 {
                let ch = band.lanes[k];
                if ch.inv_thresh == 0.0 {
                    continue;
                }
                for i in 0..2000 {
                    let x = 10f64.powf(-8.0 + 16.0 * f64::from(rng(&mut seed)));
                    let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                    let got = f64::from(kernel::visible(x as f32, sign as f32, &ch, &m.transducer));
                    let want = sign * c.transducer(x, band.sensitivity[k]);
                    assert!(
                        (got - want).abs() <= 1e-5 * want.abs(),
                        "band {} ch {k} x {x}: {got} vs {want}",
                        band.cpd
                    );
                }
                // Exactly 0 at 0, and T(1) = 1 (threshold is one JND).
                assert_eq!(kernel::visible(0.0, 0.0, &ch, &m.transducer), 0.0);
                let t1 = kernel::visible(1.0, 1.0, &ch, &m.transducer);
                assert!((t1 - 1.0).abs() < 1e-5, "T(1) = {t1}");
            }
        }
    }
}

#[test]
fn fast_kernel_matches_the_exact_reference_on_random_images() {
    let (w, h) = (40, 36);
    let m = VisionModel::new(display(28.0), w, h);
    assert!(m.bands().len() >= 2);
    let c = Calibration::default();
    let (a, b) = (random_image(w, h, 1), random_image(w, h, 2));
    let (sa, sb) = (m.decompose(&a).unwrap(), m.decompose(&b).unwrap());
    let full = m.full_map(&sa, &sb);
    let mut va = [0f32; 3 * MAX_BANDS];
    let mut vb = [0f32; 3 * MAX_BANDS];
    let mut worst = 0f64;
    for y in 0..h {
        for x in 0..w {
            let ea = exact_contrasts(&m, &sa, x, y);
            let eb = exact_contrasts(&m, &sb, x, y);
            let n = m.visible_contrasts(&sa, x, y, &mut va);
            assert_eq!(n, ea.len());
            m.visible_contrasts(&sb, x, y, &mut vb);
            for i in 0..n {
                for (got, want) in [(va[i], ea[i]), (vb[i], eb[i])] {
                    let err = (f64::from(got) - want).abs();
                    // 1e-4 JND absolute: tiny chromatic values come from f32 cancellation
                    // in the opponent sums (e.g. L − 12/11·M), not from the fast powers.
                    assert!(
                        err <= 2e-4 * want.abs() + 1e-4,
                        "({x}, {y}) component {i}: {got} vs {want}"
                    );
                }
            }
            // §2.7 exact: f64 Minkowski of the exact vectors.
            let beta = c.minkowski;
            let s: f64 = ea
                .iter()
                .zip(&eb)
                .map(|(p, q)| (p - q).abs().powf(beta))
                .sum();
            let want = s.powf(1.0 / beta);
            let got = f64::from(*full.get(x, y));
            let rel = (got - want).abs() / want.max(1e-6);
            worst = worst.max(rel);
            assert!(rel <= 5e-4, "d({x}, {y}) = {got} vs exact {want}");
            // The single-pixel entry point is the same kernel.
            assert_eq!(m.distance_at(&sa, &sb, x, y), *full.get(x, y));
        }
    }
    assert!(worst > 0.0, "the comparison ran");
}

#[test]
fn simd_dispatch_is_bitwise_identical_to_the_portable_path() {
    let (w, h) = (37, 29);
    let m = VisionModel::new(display(28.0), w, h);
    let (sa, sb) = (
        m.decompose(&random_image(w, h, 5)).unwrap(),
        m.decompose(&random_image(w, h, 6)).unwrap(),
    );
    // Includes out-of-image pixels, which give 0.
    let pixels: Vec<PixelCoord> = (0..h + 2)
        .flat_map(|y| (0..w + 1).map(move |x| PixelCoord::new(x, y)))
        .collect();
    let mut fast = vec![0f32; pixels.len()];
    let mut portable = vec![1f32; pixels.len()];
    m.distances_at(&sa, &sb, &pixels, &mut fast);
    m.batch_portable(&sa, &sb, &|i| pixels[i], &mut portable);
    assert_eq!(fast, portable);
    for (p, d) in pixels.iter().zip(&fast) {
        if p.x >= w || p.y >= h {
            assert_eq!(*d, 0.0);
        }
    }
    assert!(fast.iter().any(|&d| d > 0.1));
}

#[test]
fn recycled_level_buffers_give_identical_stacks() {
    // Dropped stacks hand their planes back to the model, and the next
    // decomposition overwrites them; stale contents must never leak into a level.
    let (w, h) = (37, 29);
    let m = VisionModel::new(display(28.0), w, h);
    let (a, b) = (random_image(w, h, 11), random_image(w, h, 12));
    let first = m.decompose(&a).unwrap();
    let want: Vec<Vec<P4>> = first.levels.iter().map(|l| l.data.clone()).collect();
    let bytes = first.bytes();
    drop(first);
    let other = m.decompose(&b).unwrap();
    let reused: Vec<*const P4> = other.levels.iter().map(|l| l.data.as_ptr()).collect();
    drop(other);
    let again = m.decompose(&a).unwrap();
    // The buffers did come back from the pool (not fresh allocations)...
    assert!(again
        .levels
        .iter()
        .any(|l| reused.contains(&l.data.as_ptr())));
    // ...and the levels are bitwise those of the first decomposition, same sizes.
    let got: Vec<Vec<P4>> = again.levels.iter().map(|l| l.data.clone()).collect();
    assert_eq!(got, want);
    assert_eq!(again.bytes(), bytes);
}

/// Every pyramid path (instruction set × band height) gives bitwise the stack of the
/// plainest one (portable loops, one band per level: no halo, no parallel split), through
/// the whole model (receptor conversion, every level), for odd sizes and pixel densities
/// that change the kernels. Each level of each path is checked against the per-sample
/// reference in pyramid/mod.rs.
#[test]
fn every_pyramid_path_gives_the_same_stack() {
    let mut paths = Vec::new();
    for isa in Isa::available() {
        for band_rows in [0, 1, 3, 5] {
            paths.push(RowPath { isa, band_rows });
        }
    }
    let plainest = RowPath {
        isa: Isa::Portable,
        band_rows: usize::MAX,
    };
    for (w, h) in [
        (64, 48),
        (64, 36),
        (48, 64),
        (37, 29),
        (17, 3),
        (3, 17),
        (1, 1),
        (131, 9),
    ] {
        for ppd in [28.0, 14.0, 45.0, 60.0] {
            let m = VisionModel::new(display(ppd), w, h);
            let img = random_image(w, h, u64::from(w * 31 + h) + ppd as u64);
            let want = m.decompose_with(&img, plainest).unwrap();
            for &path in &paths {
                let got = m.decompose_with(&img, path).unwrap();
                assert!(got.bitwise_eq(&want), "{w}x{h} ppd {ppd} {path:?}");
            }
        }
    }
}

/// The finiteness check rides on the first level's conversion. Every path
/// refuses NaN and ±∞ with the first offending pixel (row-major), including one in the last
/// row and the first column, and the model decomposes a finite image normally afterwards
/// (the discarded levels went back to the pool).
#[test]
fn non_finite_input_is_refused_with_its_first_pixel_on_every_path() {
    let (w, h) = (40, 33);
    let m = VisionModel::new(display(28.0), w, h);
    let good = random_image(w, h, 3);
    let want = m.decompose(&good).unwrap();
    let paths = Isa::available()
        .into_iter()
        .flat_map(|isa| [0, 1, usize::MAX].map(|band_rows| RowPath { isa, band_rows }));
    for path in paths {
        for (bad, (x, y)) in [
            (f32::NAN, (17, 5)),
            (f32::INFINITY, (0, 32)),
            (f32::NEG_INFINITY, (39, 0)),
        ] {
            let mut img = good.clone();
            let mut p = *img.get(x, y);
            p.y = bad;
            img.set(x, y, p);
            // A later non-finite pixel must not win over the first.
            let mut q = *img.get(w - 1, h - 1);
            q.z = f32::NAN;
            img.set(w - 1, h - 1, q);
            let err = m.decompose_with(&img, path).err();
            assert_eq!(err, Some(VisionError::NonFinite { x, y }), "{path:?}");
        }
        assert!(m.decompose_with(&good, path).unwrap().bitwise_eq(&want));
    }
}
