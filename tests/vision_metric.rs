//! The adaptive quad-tree block map (vision-model.md §3.2).

use glimpse::metric::{self, samples_for_area, MetricParams};
use glimpse::raster::{Image, LinearImage, PixelCoord, Rgb};
use glimpse::vision::{ContrastStack, DisplayModel, VisionModel};

fn model(w: u32, h: u32) -> VisionModel {
    let d = DisplayModel {
        peak_luminance: 100.0,
        black_luminance: 0.5,
        exposure: 1.0,
        pixels_per_degree: 28.0,
    };
    VisionModel::new(d, w, h)
}

fn noise_field(w: u32, h: u32, seed: u64) -> Image<f32> {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    Image::from_fn(w, h, |_, _| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    })
}

/// A rendered-looking frame: shading, a checker of 16-px squares, fine detail.
fn textured(w: u32, h: u32) -> LinearImage {
    Image::from_fn(w, h, |x, y| {
        let (fx, fy) = (x as f32, y as f32);
        let shade = 0.25 + 0.2 * fx / w as f32;
        let checker = if ((x / 16) + (y / 16)) % 2 == 0 {
            0.15
        } else {
            0.0
        };
        let v = shade + checker + 0.05 * (fx * 0.9).sin() * (fy * 0.7).cos();
        Rgb::new(v * 1.1, v, v * 0.8)
    })
}

/// Multiplicative noise `amp` where `mask(x, y)`, like Monte Carlo noise in some regions.
fn noisy(img: &LinearImage, amp: f32, seed: u64, mask: impl Fn(u32, u32) -> bool) -> LinearImage {
    let n = noise_field(img.width(), img.height(), seed);
    Image::from_fn(img.width(), img.height(), |x, y| {
        let p = *img.get(x, y);
        if mask(x, y) {
            p * (1.0 + 2.0 * amp * n.get(x, y))
        } else {
            p
        }
    })
}

fn stacks(m: &VisionModel, a: &LinearImage, b: &LinearImage) -> (ContrastStack, ContrastStack) {
    (m.decompose(a).unwrap(), m.decompose(b).unwrap())
}

#[test]
fn sample_counts_follow_f04() {
    assert_eq!(samples_for_area(512 * 512), 2000);
    assert_eq!(samples_for_area(10_001), 2000);
    assert_eq!(samples_for_area(10_000), 500);
    assert_eq!(samples_for_area(1000), 500);
    assert_eq!(samples_for_area(999), 333);
    assert_eq!(samples_for_area(10), 4);
    assert_eq!(samples_for_area(1), 1);
}

#[test]
fn identical_frames_give_one_leaf_of_zero() {
    let (w, h) = (64, 48);
    let m = model(w, h);
    let a = textured(w, h);
    let (sa, sb) = stacks(&m, &a, &a);
    let bm = metric::block_map(&m, &sa, &sb, &[], &MetricParams::default());
    assert_eq!(bm.leaves.len(), 1);
    assert_eq!(bm.leaves[0].mean, 0.0);
    assert_eq!(bm.leaves[0].homogeneity, 1.0);
    assert_eq!(bm.pixels_evaluated, 500); // 3072 px → N = 500 [F04]
    assert!(bm.map.pixels().iter().all(|&d| d == 0.0));
}

#[test]
fn block_map_is_deterministic_for_a_seed() {
    let (w, h) = (96, 80);
    let m = model(w, h);
    let a = textured(w, h);
    let b = noisy(&a, 0.3, 5, |x, _| x > 40);
    let (sa, sb) = stacks(&m, &a, &b);
    let seeds: Vec<PixelCoord> = (0..200)
        .map(|i| PixelCoord::new((i * 37) % w, (i * 11) % h))
        .collect();
    let p = MetricParams {
        homogeneity: 0.8,
        epsilon: 1.0,
        seed: 42,
    };
    let one = metric::block_map(&m, &sa, &sb, &seeds, &p);
    let two = metric::block_map(&m, &sa, &sb, &seeds, &p);
    assert_eq!(one.map.pixels(), two.map.pixels());
    assert_eq!(one.leaves, two.leaves);
    assert_eq!(one.pixels_evaluated, two.pixels_evaluated);
    let other = metric::block_map(&m, &sa, &sb, &seeds, &MetricParams { seed: 43, ..p });
    assert_ne!(
        one.map.pixels(),
        other.map.pixels(),
        "a different seed draws other samples"
    );
}

#[test]
fn heterogeneous_half_is_refined_and_quiet_half_is_not() {
    // Left half identical, right half very noisy: the tree must split where the distance
    // varies (h < H) and keep big leaves where it does not (the corrected §3.2 direction).
    let (w, h) = (128, 128);
    let m = model(w, h);
    let a = textured(w, h);
    let b = noisy(&a, 0.4, 9, |x, _| x >= 64);
    let (sa, sb) = stacks(&m, &a, &b);
    let bm = metric::block_map(&m, &sa, &sb, &[], &MetricParams::default());
    assert!(bm.leaves.len() > 4);
    let area = |l: &metric::Leaf| l.width * l.height;
    let biggest_left = bm
        .leaves
        .iter()
        .filter(|l| l.x + l.width <= 64)
        .map(area)
        .max()
        .unwrap_or(0);
    let biggest_right = bm
        .leaves
        .iter()
        .filter(|l| l.x >= 80)
        .map(area)
        .max()
        .unwrap_or(0);
    assert!(
        biggest_left >= 32 * 32,
        "quiet side leaves too small: {biggest_left}"
    );
    assert!(
        biggest_right < biggest_left,
        "{biggest_right} vs {biggest_left}"
    );
    let total: u32 = bm.leaves.iter().map(area).sum();
    assert_eq!(total, w * h, "leaves tile the image");
    for l in &bm.leaves {
        assert!(l.samples >= 1 && (0.0..=1.0).contains(&l.homogeneity));
    }
}

#[test]
fn adaptive_mean_tracks_full_mean_with_fewer_evaluations() {
    let (w, h) = (160, 128);
    let m = model(w, h);
    let a = textured(w, h);
    // Noise everywhere, stronger in one corner: a realistic progressive frame pair.
    let b = noisy(&noisy(&a, 0.04, 3, |_, _| true), 0.2, 4, |x, y| {
        x < 60 && y < 50
    });
    let (sa, sb) = stacks(&m, &a, &b);
    let full = metric::full_map(&m, &sa, &sb);
    assert_eq!(full.pixels_evaluated, (w * h) as usize);
    let bm = metric::block_map(
        &m,
        &sa,
        &sb,
        &[],
        &MetricParams {
            seed: 7,
            ..MetricParams::default()
        },
    );
    let (fm, am) = (full.mean(), bm.mean());
    assert!(fm > 0.5, "pair must differ visibly: {fm}");
    assert!((am - fm).abs() < 0.1 * fm, "adaptive {am} vs full {fm}");
    assert!(
        bm.pixels_evaluated < full.pixels_evaluated / 2,
        "{}",
        bm.pixels_evaluated
    );
}

#[test]
fn leaves_hold_every_sample_once_and_paint_their_mean() {
    let (w, h) = (96, 64);
    let m = model(w, h);
    let a = textured(w, h);
    let b = noisy(&a, 0.3, 2, |x, y| x < 50 && y > 20);
    let (sa, sb) = stacks(&m, &a, &b);
    let seeds: Vec<PixelCoord> = (0..300)
        .map(|i| PixelCoord::new((i * 7) % w, (i * 13) % h))
        .collect();
    let bm = metric::block_map(&m, &sa, &sb, &seeds, &MetricParams::default());
    let held: usize = bm.leaves.iter().map(|l| l.samples as usize).sum();
    assert_eq!(
        held, bm.pixels_evaluated,
        "children inherit, nothing is evaluated twice"
    );
    for l in &bm.leaves {
        if u64::from(l.samples) < u64::from(l.width * l.height) {
            assert_eq!(*bm.map.get(l.x, l.y), l.mean);
            assert_eq!(*bm.map.get(l.x + l.width - 1, l.y + l.height - 1), l.mean);
        }
    }
    // 1×1: the single cell is fully sampled and keeps its exact (here 0: no band) value.
    let m1 = model(1, 1);
    let (s1, s2) = stacks(
        &m1,
        &textured(1, 1),
        &noisy(&textured(1, 1), 0.4, 1, |_, _| true),
    );
    let bm = metric::block_map(&m1, &s1, &s2, &[], &MetricParams::default());
    assert_eq!(
        (bm.leaves.len(), bm.pixels_evaluated, *bm.map.get(0, 0)),
        (1, 1, 0.0)
    );
}
