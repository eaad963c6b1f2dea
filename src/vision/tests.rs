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
