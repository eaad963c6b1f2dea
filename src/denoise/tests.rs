//! Tests against the real library (installed by `bash scripts/oidn.sh`, which
//! scripts/test.sh runs first): a missing library fails them with the install hint.

use super::library::SearchPlan;
use super::*;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

fn denoiser() -> &'static Denoiser {
    Denoiser::shared().unwrap_or_else(|e| panic!("{e}"))
}

/// `value` plus uniform noise in ±`amplitude` per channel, seeded.
fn noisy(truth: &LinearImage, amplitude: f32, seed: u64) -> LinearImage {
    let mut rng = Pcg32::seed_from_u64(seed);
    truth.map(|&c| {
        c + Rgb::new(
            rng.random_range(-amplitude..amplitude),
            rng.random_range(-amplitude..amplitude),
            rng.random_range(-amplitude..amplitude),
        )
    })
}

fn rmse(a: &LinearImage, b: &LinearImage) -> f32 {
    let sum: f32 = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(x, y)| (*x - *y).length_squared())
        .sum();
    (sum / (3 * a.len()) as f32).sqrt()
}

fn flat(w: u32, h: u32, v: Rgb) -> LinearImage {
    LinearImage::filled(w, h, v)
}

#[test]
fn rgb_is_three_packed_floats() {
    assert_eq!(std::mem::size_of::<Rgb>(), 12);
    assert_eq!(std::mem::align_of::<Rgb>(), 4);
}

#[test]
fn loads_version_2() {
    let d = denoiser();
    assert!(d.version().starts_with("2."), "version {}", d.version());
}

#[test]
fn noisy_constant_image_comes_back_near_the_constant() {
    let truth = flat(64, 64, Rgb::splat(0.5));
    let input = noisy(&truth, 0.3, 7);
    let out = denoiser()
        .denoise(&input, None, &Run::new(Quality::High))
        .unwrap();
    let (before, after) = (rmse(&input, &truth), rmse(&out, &truth));
    assert!(
        after * 3.0 <= before,
        "RMSE {before} before, {after} after: not 3x lower"
    );
}

#[test]
fn nan_inf_and_huge_input_give_finite_output() {
    let mut input = noisy(&flat(32, 32, Rgb::splat(0.5)), 0.1, 3);
    let bad = [
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        1e30,
        -5.0,
        f32::MAX,
    ];
    for (i, v) in bad.iter().enumerate() {
        input.set(4 + i as u32 * 4, 4, Rgb::splat(*v));
        input.set(4, 8 + i as u32 * 3, Rgb::new(*v, 0.5, 0.5));
    }
    let albedo = input.map(|_| Rgb::splat(f32::NAN));
    let normal = input.map(|_| Rgb::new(0.0, f32::INFINITY, 0.0));
    let aux = Aux {
        albedo: &albedo,
        normal: &normal,
        clean: false,
    };
    for aux in [None, Some(&aux)] {
        for q in [Quality::Fast, Quality::Balanced, Quality::High] {
            let out = denoiser().denoise(&input, aux, &Run::new(q)).unwrap();
            let bad = out
                .pixels()
                .iter()
                .filter(|p| !p.is_finite() || p.min_element() < 0.0)
                .count();
            assert_eq!(bad, 0, "{q:?}, aux {}: non-finite pixels", aux.is_some());
        }
    }
}

/// One infinite pixel is clamped to `MAX_RADIANCE`, which leaves the rest of the picture
/// alone (an uncapped 1e10 brightened all of it ~5x: the blotches of RenderKit/oidn#210).
#[test]
fn one_infinite_pixel_does_not_blotch_the_picture() {
    let mut input = noisy(&flat(32, 32, Rgb::splat(0.5)), 0.1, 3);
    input.set(4, 4, Rgb::splat(f32::INFINITY));
    for q in [Quality::Fast, Quality::Balanced, Quality::High] {
        let out = denoiser().denoise(&input, None, &Run::new(q)).unwrap();
        let far = out.get(28, 28);
        assert!(
            (far - Rgb::splat(0.5)).abs().max_element() < 0.1,
            "{q:?}: far pixel {far}"
        );
    }
}

#[test]
fn aux_of_another_size_is_an_error_naming_both_sizes() {
    let color = flat(8, 6, Rgb::splat(0.5));
    let good = flat(8, 6, Rgb::splat(0.5));
    let small = flat(4, 6, Rgb::splat(0.5));
    for (albedo, normal, what) in [(&small, &good, "albedo"), (&good, &small, "normal")] {
        let aux = Aux {
            albedo,
            normal,
            clean: true,
        };
        let e = denoiser()
            .denoise(&color, Some(&aux), &Run::new(Quality::Fast))
            .unwrap_err();
        assert!(matches!(e, DenoiseError::SizeMismatch { .. }), "{e:?}");
        let text = e.to_string();
        assert!(
            text.contains(what) && text.contains("4x6") && text.contains("8x6"),
            "{text}"
        );
    }
}

#[test]
fn input_scale_must_be_positive_and_finite() {
    let color = flat(4, 4, Rgb::splat(0.5));
    for s in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let e = denoiser()
            .denoise(
                &color,
                None,
                &Run {
                    input_scale: Some(s),
                    ..Run::new(Quality::Fast)
                },
            )
            .unwrap_err();
        assert!(matches!(e, DenoiseError::InputScale(_)), "{s}: {e:?}");
    }
    let out = denoiser()
        .denoise(
            &color,
            None,
            &Run {
                input_scale: Some(0.01),
                ..Run::new(Quality::Fast)
            },
        )
        .unwrap();
    assert!((out.get(2, 2).x - 0.5).abs() < 0.1, "{}", out.get(2, 2));
}

#[test]
fn missing_library_names_every_place_searched_and_how_to_install() {
    let empty = tempfile::tempdir().unwrap();
    let exe = empty.path().join("bin/glimpse");
    let mut plan = SearchPlan::new(None, &empty.path().join("checkout"), Some(&exe));
    plan.system = Some("libOpenImageDenoise_not_here.so.2".into());
    let e = match Denoiser::open(&plan) {
        Err(e) => e,
        Ok(_) => panic!("found a library in an empty folder"),
    };
    let text = e.to_string();
    assert!(matches!(e, DenoiseError::Missing { .. }), "{text}");
    for needle in [
        "bash scripts/oidn.sh",
        "GLIMPSE_OIDN_DIR",
        "pyoidn",
        "libOpenImageDenoise.so.2",
        "checkout/target/oidn/lib",
        "bin/../oidn/lib",
        "bin/../../oidn/lib",
        "libOpenImageDenoise_not_here.so.2 (system loader)",
    ] {
        assert!(text.contains(needle), "no {needle:?} in:\n{text}");
    }
    // GLIMPSE_OIDN_DIR, when set, is the only place searched.
    let plan = SearchPlan::new(
        Some(empty.path().to_path_buf()),
        &empty.path().join("checkout"),
        Some(&exe),
    );
    let text = Denoiser::open(&plan)
        .err()
        .expect("nothing there")
        .to_string();
    let env_dir = format!("{}/libOpenImageDenoise.so.2", empty.path().display());
    assert!(text.contains(&env_dir), "{text}");
    assert!(!text.contains("checkout/target/oidn/lib"), "{text}");
}

#[test]
fn search_order_is_env_alone_or_checkout_executable_then_system() {
    let plan = SearchPlan::new(
        Some("/o".into()),
        Path::new("/c"),
        Some(Path::new("/t/release/glimpse")),
    );
    let folders: Vec<_> = plan.folders.iter().map(|(f, _)| f.clone()).collect();
    assert_eq!(folders, ["/o", "/o/lib"].map(std::path::PathBuf::from));
    assert_eq!(plan.system, None);
    let plan = SearchPlan::new(None, Path::new("/c"), Some(Path::new("/t/release/glimpse")));
    let folders: Vec<_> = plan.folders.iter().map(|(f, _)| f.clone()).collect();
    let expect = [
        "/c/target/oidn/lib",
        "/t/release",
        "/t/release/../oidn/lib",
        "/t/release/../../oidn/lib",
    ];
    assert_eq!(folders, expect.map(std::path::PathBuf::from));
    assert_eq!(plan.system.as_deref(), Some("libOpenImageDenoise.so.2"));
    // An empty GLIMPSE_OIDN_DIR is no folder.
    let plan = SearchPlan::new(Some("".into()), Path::new("/c"), None);
    assert_eq!(plan.folders.len(), 1);
}

#[test]
fn every_quality_runs_with_and_without_aux() {
    let truth = flat(48, 40, Rgb::splat(0.25));
    let input = noisy(&truth, 0.1, 11);
    let albedo = flat(48, 40, Rgb::splat(0.5));
    let normal = flat(48, 40, Rgb::Z);
    for clean in [false, true] {
        let aux = Aux {
            albedo: &albedo,
            normal: &normal,
            clean,
        };
        for aux in [None, Some(&aux)] {
            for q in [Quality::Fast, Quality::Balanced, Quality::High] {
                let out = denoiser().denoise(&input, aux, &Run::new(q)).unwrap();
                assert_eq!((out.width(), out.height()), (48, 40));
                assert!(
                    rmse(&out, &truth) < rmse(&input, &truth),
                    "{q:?} clean {clean}"
                );
            }
        }
    }
}

#[test]
fn tiny_and_thin_images_work() {
    for (w, h) in [(1, 1), (3, 2), (400, 1), (1, 300), (0, 0), (0, 5)] {
        let color = flat(w, h, Rgb::splat(0.5));
        let albedo = flat(w, h, Rgb::splat(0.5));
        let normal = flat(w, h, Rgb::Z);
        let aux = Aux {
            albedo: &albedo,
            normal: &normal,
            clean: true,
        };
        for aux in [None, Some(&aux)] {
            let out = denoiser()
                .denoise(&color, aux, &Run::new(Quality::High))
                .unwrap_or_else(|e| panic!("{w}x{h}: {e}"));
            assert_eq!((out.width(), out.height()), (w, h));
            for p in out.pixels() {
                assert!((p.x - 0.5).abs() < 0.1, "{w}x{h}: {p}");
            }
        }
    }
}

/// A checkerboard of two albedos under constant light: the clean albedo tells the
/// filter where the edges are, so it keeps them sharp where colour alone cannot.
#[test]
fn clean_aux_beats_no_aux_on_edges() {
    let (w, h) = (96, 96);
    let albedo = LinearImage::from_fn(w, h, |x, y| {
        if (x / 6 + y / 6) % 2 == 0 {
            Rgb::splat(0.8)
        } else {
            Rgb::new(0.1, 0.2, 0.15)
        }
    });
    let truth = albedo.map(|&a| a * 0.5);
    let input = noisy(&truth, 0.25, 5);
    let normal = flat(w, h, Rgb::Z);
    let aux = Aux {
        albedo: &albedo,
        normal: &normal,
        clean: true,
    };
    let with = denoiser()
        .denoise(&input, Some(&aux), &Run::new(Quality::High))
        .unwrap();
    let without = denoiser()
        .denoise(&input, None, &Run::new(Quality::High))
        .unwrap();
    let (e_with, e_without) = (rmse(&with, &truth), rmse(&without, &truth));
    assert!(
        e_with * 1.5 < e_without,
        "RMSE {e_with} with clean aux, {e_without} without"
    );
}

#[test]
fn prefiltered_noisy_aux_stays_in_range_and_loses_its_noise() {
    let albedo_truth = flat(40, 40, Rgb::splat(0.5));
    let albedo = noisy(&albedo_truth, 0.2, 9);
    let normal = noisy(&flat(40, 40, Rgb::Z), 0.3, 10);
    let (a, n) = denoiser()
        .prefilter_aux(&albedo, &normal, &Run::new(Quality::High))
        .unwrap();
    assert!(rmse(&a, &albedo_truth) * 2.0 < rmse(&albedo, &albedo_truth));
    assert!(a
        .pixels()
        .iter()
        .all(|p| p.min_element() >= 0.0 && p.max_element() <= 1.0));
    assert!(n.pixels().iter().all(|p| p.abs().max_element() <= 1.0));
    let small = flat(4, 4, Rgb::Z);
    let e = denoiser()
        .prefilter_aux(&albedo, &small, &Run::new(Quality::Fast))
        .unwrap_err();
    assert!(e.to_string().contains("4x4"), "{e}");
}

#[test]
fn mirror_reflects_into_range() {
    let got: Vec<u32> = (0..7).map(|i| mirror(i, 3)).collect();
    assert_eq!(got, [0, 1, 2, 2, 1, 0, 0]);
    assert!((0..40).all(|i| mirror(i, 1) == 0));
}

#[test]
fn a_cancelled_run_stops_before_it_starts() {
    let run = Run::new(Quality::Fast);
    run.cancel.cancel();
    let e = denoiser()
        .denoise(&flat(64, 64, Rgb::splat(0.5)), None, &run)
        .unwrap_err();
    assert!(matches!(e, DenoiseError::Cancelled), "{e}");
}

/// A cancel while OIDN executes a large image ends the run within a fraction of a
/// second (its progress monitor), not after the whole filter.
#[test]
fn a_cancel_during_a_large_denoise_ends_it_at_once() {
    let input = noisy(&flat(1024, 1024, Rgb::splat(0.5)), 0.3, 11);
    let run = Run::new(Quality::High);
    let t = std::time::Instant::now();
    denoiser().denoise(&input, None, &run).unwrap();
    let whole = t.elapsed();
    let cancel = run.cancel.clone();
    let canceller = std::thread::spawn(move || {
        std::thread::sleep(whole / 4);
        let at = std::time::Instant::now();
        cancel.cancel();
        at
    });
    let e = denoiser().denoise(&input, None, &run).unwrap_err();
    let ended = std::time::Instant::now();
    let cancelled_at = canceller.join().unwrap();
    assert!(matches!(e, DenoiseError::Cancelled), "{e}");
    let late = ended.duration_since(cancelled_at);
    assert!(
        late < whole / 4 + std::time::Duration::from_millis(50),
        "ended {late:?} after the cancel; the whole denoise takes {whole:?}"
    );
}

/// With `max_memory_mb` OIDN works in overlapping tiles: the picture stays the untiled
/// one's up to the seams.
#[test]
fn bounded_scratch_memory_gives_the_same_picture() {
    let truth = LinearImage::from_fn(768, 512, |x, y| {
        Rgb::new(x as f32 / 768.0, y as f32 / 512.0, 0.25)
    });
    let input = noisy(&truth, 0.2, 5);
    let whole = denoiser()
        .denoise(&input, None, &Run::new(Quality::High))
        .unwrap();
    let tiled = denoiser()
        .denoise(
            &input,
            None,
            &Run {
                max_memory_mb: Some(64),
                ..Run::new(Quality::High)
            },
        )
        .unwrap();
    let apart = rmse(&whole, &tiled);
    assert!(apart < 0.01, "tiled differs by RMSE {apart}");
    assert!(rmse(&tiled, &truth) * 2.0 < rmse(&input, &truth));
}

#[test]
fn a_very_long_thin_image_is_denoised() {
    let input = noisy(&flat(100_000, 1, Rgb::splat(0.5)), 0.2, 9);
    let out = denoiser()
        .denoise(&input, None, &Run::new(Quality::Fast))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((out.width(), out.height()), (100_000, 1));
}

/// Strips are stitched without seams: a picture split in two strips equals, in the
/// strips' kept middles, the picture denoised whole.
#[test]
fn strips_join_without_seams() {
    let truth = LinearImage::from_fn(MAX_SIDE + 500, 40, |x, y| {
        Rgb::new((x % 97) as f32 / 97.0, y as f32 / 40.0, 0.3)
    });
    let input = noisy(&truth, 0.1, 13);
    let d = denoiser();
    // One scale for all: OIDN's automatic one is measured per image, so per strip.
    let run = Run {
        input_scale: Some(1.0),
        ..Run::new(Quality::Fast)
    };
    let strips = d.denoise(&input, None, &run).unwrap();
    // The same middle denoised from a window that never needed strips, on the same
    // 16-pixel grid.
    let from = MAX_SIDE - 2 * STRIP_OVERLAP - 1024;
    let window = LinearImage::from_fn(2000, 40, |x, y| *input.get(from + x, y));
    let direct = d.denoise(&window, None, &run).unwrap();
    let mut worst = 0f32;
    for x in 300..1700 {
        for y in 0..40 {
            let a = *strips.get(from + x, y);
            let b = *direct.get(x, y);
            worst = worst.max((a - b).abs().max_element());
        }
    }
    assert!(worst < 0.02, "strips differ from one run by up to {worst}");
}

/// A cancelled run does not wait for the device another run holds.
#[test]
fn a_cancel_ends_the_wait_for_a_busy_device() {
    let d = denoiser();
    let busy = d.device.lock().unwrap_or_else(PoisonError::into_inner);
    let run = Run::new(Quality::Fast);
    let input = flat(64, 64, Rgb::splat(0.5));
    std::thread::scope(|s| {
        let waiting = s.spawn(|| d.denoise(&input, None, &run));
        std::thread::sleep(std::time::Duration::from_millis(50));
        assert!(!waiting.is_finished(), "it waits for the device");
        let t = std::time::Instant::now();
        run.cancel.cancel();
        let r = waiting.join().unwrap();
        assert!(matches!(r, Err(DenoiseError::Cancelled)), "{:?}", r.err());
        assert!(
            t.elapsed() < std::time::Duration::from_millis(100),
            "{:?}",
            t.elapsed()
        );
    });
    drop(busy);
}
