//! What the vision model must show (vision-model.md §2.10). Small images, so the
//! whole file runs in a few seconds in the dev profile.

use glimpse::metric::{self, MetricParams};
use glimpse::raster::{Image, LinearImage, PixelCoord, Rgb};
use glimpse::vision::{Calibration, DisplayModel, VisionError, VisionModel};

fn display(peak: f32, black: f32, ppd: f32) -> DisplayModel {
    DisplayModel {
        peak_luminance: peak,
        black_luminance: black,
        exposure: 1.0,
        pixels_per_degree: ppd,
    }
}

fn default_display() -> DisplayModel {
    display(100.0, 0.5, 28.0)
}

/// Deterministic pseudo-random values in [-0.5, 0.5).
fn noise_field(w: u32, h: u32, seed: u64) -> Image<f32> {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    Image::from_fn(w, h, |_, _| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    })
}

fn grey(w: u32, h: u32, v: f32) -> LinearImage {
    Image::filled(w, h, Rgb::splat(v))
}

fn textured(w: u32, h: u32) -> LinearImage {
    let n = noise_field(w, h, 7);
    Image::from_fn(w, h, |x, y| {
        let base = 0.3 + 0.15 * ((x as f32) * 0.4).sin() * ((y as f32) * 0.3).cos();
        let v = base + 0.2 * n.get(x, y);
        Rgb::new(v, v * 0.9, v * 0.7)
    })
}

fn add_noise(img: &LinearImage, amp: f32, seed: u64) -> LinearImage {
    let n = noise_field(img.width(), img.height(), seed);
    Image::from_fn(img.width(), img.height(), |x, y| {
        *img.get(x, y) + Rgb::splat(amp * n.get(x, y))
    })
}

fn mean_distance(model: &VisionModel, a: &LinearImage, b: &LinearImage) -> f64 {
    let sa = model.decompose(a).expect("finite a");
    let sb = model.decompose(b).expect("finite b");
    metric::full_map(model, &sa, &sb).mean()
}

/// Vertical-stripe grating v(x) = mean · (1 + c cos(2π f x / ppd)), grey.
fn grating(w: u32, h: u32, mean: f32, contrast: f64, cpd: f64, ppd: f64) -> LinearImage {
    Image::from_fn(w, h, |x, _| {
        let ph = 2.0 * std::f64::consts::PI * cpd * (f64::from(x) - f64::from(w / 2)) / ppd;
        Rgb::splat((f64::from(mean) * (1.0 + contrast * ph.cos())) as f32)
    })
}

#[test]
fn identical_images_give_exactly_zero_and_uniform_gives_no_contrast() {
    let m = VisionModel::new(default_display(), 48, 40);
    let a = textured(48, 40);
    let sa = m.decompose(&a).unwrap();
    let sb = m.decompose(&a.clone()).unwrap();
    let map = m.full_map(&sa, &sb);
    assert!(map.pixels().iter().all(|&d| d == 0.0));
    for lum in [0.0, 0.01, 0.5, 1.0] {
        let su = m.decompose(&grey(48, 40, lum)).unwrap();
        let mut v = [0f32; 64];
        let n = m.visible_contrasts(&su, 20, 17, &mut v);
        assert_eq!(n, 3 * m.bands().len());
        assert!(n > 0);
        assert!(
            v[..n].iter().all(|x| x.abs() < 1e-3),
            "uniform {lum}: {:?}",
            &v[..n]
        );
    }
}

#[test]
fn distance_is_symmetric_and_non_negative() {
    let m = VisionModel::new(default_display(), 40, 36);
    let a = textured(40, 36);
    let b = add_noise(&a, 0.05, 3);
    let (sa, sb) = (m.decompose(&a).unwrap(), m.decompose(&b).unwrap());
    let ab = m.full_map(&sa, &sb);
    let ba = m.full_map(&sb, &sa);
    assert_eq!(ab.pixels(), ba.pixels());
    assert!(ab.pixels().iter().all(|&d| d >= 0.0 && d.is_finite()));
    assert!(ab.pixels().iter().any(|&d| d > 0.0));
}

#[test]
fn distance_grows_with_noise_amplitude() {
    let m = VisionModel::new(default_display(), 40, 40);
    let a = textured(40, 40);
    let mut prev = 0.0;
    for amp in [0.005, 0.01, 0.02, 0.05, 0.1] {
        let d = mean_distance(&m, &a, &add_noise(&a, amp, 11));
        assert!(d > prev * 1.05, "amp {amp}: {d} not above {prev}");
        prev = d;
    }
}

#[test]
fn texture_masks_noise() {
    // The same additive noise over a flat field and over a high-contrast texture of the same
    // mean: the texture hides it (F&P04 Table 1 trend; vision-model.md §2.10.6).
    let (w, h) = (48, 48);
    let m = VisionModel::new(default_display(), w, h);
    let flat = grey(w, h, 0.3);
    let t = noise_field(w, h, 99);
    // Random 2×2-pixel blocks at ±80 % around the mean: contrast in every band.
    let tex = Image::from_fn(w, h, |x, y| {
        Rgb::splat(0.3 * (1.0 + 1.6 * t.get(x & !1, y & !1)))
    });
    let noise = |img: &LinearImage| add_noise(img, 0.03, 5);
    let d_flat = mean_distance(&m, &flat, &noise(&flat));
    let d_tex = mean_distance(&m, &tex, &noise(&tex));
    assert!(
        d_flat > 1.0,
        "noise on a flat field should be visible: {d_flat}"
    );
    assert!(
        d_tex < 0.7 * d_flat,
        "masking: texture {d_tex} vs flat {d_flat}"
    );
}

#[test]
fn dim_display_shows_differences_less() {
    let (w, h) = (40, 40);
    let a = textured(w, h);
    let b = add_noise(&a, 0.04, 21);
    let dim = mean_distance(&VisionModel::new(display(1.0, 0.005, 28.0), w, h), &a, &b);
    let bright = mean_distance(&VisionModel::new(display(100.0, 0.5, 28.0), w, h), &a, &b);
    assert!(dim < 0.8 * bright, "1 cd/m2: {dim}, 100 cd/m2: {bright}");
    assert!(dim > 0.0);
}

#[test]
fn mid_frequency_grating_more_visible_than_fine_one() {
    // ppd 60 so that 24 cpd is below Nyquist (30 cpd).
    let (w, h) = (96, 16);
    let m = VisionModel::new(display(100.0, 0.5, 60.0), w, h);
    let flat = grey(w, h, 0.4);
    let d4 = mean_distance(&m, &flat, &grating(w, h, 0.4, 0.02, 4.0, 60.0));
    let d24 = mean_distance(&m, &flat, &grating(w, h, 0.4, 0.02, 24.0, 60.0));
    assert!(d4 > 1.5 * d24, "4 cpd {d4} vs 24 cpd {d24}");
}

#[test]
fn isoluminant_red_green_change_is_detected() {
    let (w, h) = (48, 48);
    let m = VisionModel::new(default_display(), w, h);
    let a = grey(w, h, 0.3);
    // ΔY = 0.2126 Δr + 0.7152 Δg = 0: a pure chromatic patch.
    let dr = 0.08f32;
    let dg = -dr * 0.2126 / 0.7152;
    let b = Image::from_fn(w, h, |x, y| {
        let inside = (16..32).contains(&x) && (16..32).contains(&y);
        if inside {
            Rgb::new(0.3 + dr, 0.3 + dg, 0.3)
        } else {
            Rgb::splat(0.3)
        }
    });
    let (sa, sb) = (m.decompose(&a).unwrap(), m.decompose(&b).unwrap());
    let max = m
        .full_map(&sa, &sb)
        .pixels()
        .iter()
        .copied()
        .fold(0f32, f32::max);
    assert!(max > 1.0, "isoluminant change max distance {max}");
    // ... and it is carried by the chromatic channels, not A.
    let mut va = [0f32; 64];
    let mut vb = [0f32; 64];
    let n = m.visible_contrasts(&sa, 16, 24, &mut va);
    m.visible_contrasts(&sb, 16, 24, &mut vb);
    let (mut ach, mut chrom) = (0f32, 0f32);
    for i in 0..n {
        let d = (va[i] - vb[i]).abs();
        if i % 3 == 0 {
            ach = ach.max(d);
        } else {
            chrom = chrom.max(d);
        }
    }
    assert!(chrom > 2.0 * ach, "chromatic {chrom} vs achromatic {ach}");
}

/// §2.10.3: a grating at threshold contrast 1/S_A(f_n) on a 100 cd/m² D65 grey gives a
/// peak |V_{n,A}| of 1 within 10 %, for every kept band.
#[test]
fn threshold_grating_gives_one_jnd_in_its_band() {
    let (w, h, ppd) = (256, 8, 28.0);
    // Peak 200, black 0, value 0.5 → exactly 100 cd/m².
    let m = VisionModel::new(display(200.0, 0.0, ppd as f32), w, h);
    let calib = Calibration::default();
    assert_eq!(m.bands().len(), 5);
    let at10 = |lum: f32, n: usize, cpd: f64| -> f32 {
        let c = 1.0 / calib.csf(0, cpd);
        let s = m.decompose(&grating(w, h, lum, c, cpd, ppd)).unwrap();
        let mut v = [0f32; 64];
        let mut peak = 0f32;
        for x in w / 4..3 * w / 4 {
            m.visible_contrasts(&s, x, 4, &mut v);
            peak = peak.max(v[3 * n].abs());
        }
        peak
    };
    for (n, band) in m.bands().iter().enumerate() {
        let peak = at10(0.5, n, band.cpd);
        assert!(
            (peak - 1.0).abs() < 0.1,
            "band {} cpd: peak |V_A| = {peak}",
            band.cpd
        );
        // §2.10.4: at 10 cd/m² the same contrast gives ≈ (W_A(10)/W_A(100))^p of it.
        let p = calib.transducer_exponent(band.sensitivity[0]);
        let want = (calib.w(0, 10.0) / calib.w(0, 100.0)).powf(p) as f32;
        let dim = at10(0.05, n, band.cpd);
        assert!(
            (dim / peak - want).abs() < 0.1 * want,
            "band {}: ratio {} want {want}",
            band.cpd,
            dim / peak
        );
    }
}

#[test]
fn contrast_constancy_above_the_anchor() {
    // §2.10.5: well above threshold, equal contrasts at 2 and 8 cpd give similar responses.
    let (w, h, ppd) = (256, 8, 28.0);
    let m = VisionModel::new(display(200.0, 0.0, ppd as f32), w, h);
    let resp = |cpd: f64, n: usize| {
        let s = m.decompose(&grating(w, h, 0.5, 0.9, cpd, ppd)).unwrap();
        let mut v = [0f32; 64];
        let mut peak = 0f32;
        for x in w / 4..3 * w / 4 {
            m.visible_contrasts(&s, x, 4, &mut v);
            peak = peak.max(v[3 * n].abs());
        }
        peak
    };
    let n8 = m.bands().iter().position(|b| b.cpd == 8.0).unwrap();
    let n2 = m.bands().iter().position(|b| b.cpd == 2.0).unwrap();
    let (r8, r2) = (resp(8.0, n8), resp(2.0, n2));
    assert!((r8 / r2 - 1.0).abs() < 0.1, "8 cpd {r8} vs 2 cpd {r2}");
}

#[test]
fn black_frames_and_extreme_luminance() {
    let (w, h) = (24, 24);
    // Pitch black display and images (and negative values, clamped by the display): d ≡ 0.
    let m = VisionModel::new(display(100.0, 0.0, 28.0), w, h);
    let neg = Image::from_fn(w, h, |x, y| Rgb::splat(-0.1 * (x + y) as f32));
    assert_eq!(mean_distance(&m, &grey(w, h, 0.0), &neg), 0.0);
    // 10^6 cd/m²: finite, non-negative, and the pair is still told apart.
    let m = VisionModel::new(display(1e6, 0.5, 28.0), w, h);
    let a = textured(w, h);
    let b = add_noise(&a, 0.05, 8);
    let (sa, sb) = (m.decompose(&a).unwrap(), m.decompose(&b).unwrap());
    let map = m.full_map(&sa, &sb);
    assert!(map.pixels().iter().all(|d| d.is_finite() && *d >= 0.0));
    assert!(map.pixels().iter().any(|&d| d > 0.0));
}

#[test]
fn non_finite_input_is_refused_with_the_pixel() {
    let m = VisionModel::new(default_display(), 8, 6);
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut img = grey(8, 6, 0.5);
        img.set(3, 2, Rgb::new(0.5, bad, 0.5));
        assert_eq!(
            m.decompose(&img).err(),
            Some(VisionError::NonFinite { x: 3, y: 2 })
        );
    }
    assert!(matches!(
        m.decompose(&grey(7, 6, 0.5)),
        Err(VisionError::SizeMismatch { .. })
    ));
}

#[test]
fn tiny_and_odd_sizes_work() {
    for (w, h) in [(1, 1), (2, 2), (3, 5), (7, 9), (17, 13), (1, 40), (33, 2)] {
        let m = VisionModel::new(default_display(), w, h);
        let a = textured(w, h);
        let b = add_noise(&a, 0.2, 4);
        let (sa, sb) = (m.decompose(&a).unwrap(), m.decompose(&b).unwrap());
        let map = m.full_map(&sa, &sb);
        assert_eq!((map.width(), map.height()), (w, h));
        assert!(
            map.pixels().iter().all(|d| d.is_finite() && *d >= 0.0),
            "{w}x{h}"
        );
        let bm = metric::block_map(
            &m,
            &sa,
            &sb,
            &[PixelCoord::new(0, 0)],
            &MetricParams::default(),
        );
        assert_eq!((bm.map.width(), bm.map.height()), (w, h));
        let area: u32 = bm.leaves.iter().map(|l| l.width * l.height).sum();
        assert_eq!(area, w * h);
    }
    // Smaller than the coarsest level: N = 0 bands and every distance is 0 (documented).
    let m = VisionModel::new(default_display(), 2, 2);
    assert!(m.bands().is_empty());
    let a = m.decompose(&grey(2, 2, 0.0)).unwrap();
    let b = m.decompose(&grey(2, 2, 1.0)).unwrap();
    assert_eq!(m.distance_at(&a, &b, 1, 1), 0.0);
    // 7×9 at 28 ppd keeps the bands with 2σ_n ≤ 4.5 px: σ = 0.536, 1.071, 2.142 (8, 4, 2 cpd).
    let cpd: Vec<f64> = VisionModel::new(default_display(), 7, 9)
        .bands()
        .iter()
        .map(|b| b.cpd)
        .collect();
    assert_eq!(cpd, vec![8.0, 4.0, 2.0]);
}

#[test]
fn stack_memory_is_within_budget() {
    for ppd in [28.0, 60.0, 10.0] {
        let m = VisionModel::new(display(100.0, 0.5, ppd), 128, 96);
        let s = m.decompose(&textured(128, 96)).unwrap();
        let bpp = s.bytes() as f64 / (128.0 * 96.0);
        assert!(bpp <= 64.0, "ppd {ppd}: {bpp} B/px");
        assert!(bpp >= 16.0);
    }
}
