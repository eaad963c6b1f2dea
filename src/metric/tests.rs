//! Tests of the adaptive quad-tree block map (vision-model.md §3.2): its internals, its
//! bit-identity with the plain transcription (reference.rs), the dense fallback, and its
//! behaviour on frames with and without Monte Carlo-like noise.
use super::reference::split;
use super::*;
use crate::raster::{LinearImage, Rgb};
use rand::Rng;

fn cell(x: u32, y: u32, w: u32, h: u32) -> Cell {
    Cell {
        x,
        y,
        w,
        h,
        depth: 0,
        samples: Vec::new(),
        seeds: Vec::new(),
    }
}

#[test]
fn split_halves_each_long_side_and_distributes_samples() {
    let mut c = cell(10, 20, 9, 16);
    c.samples = vec![
        (PixelCoord::new(10, 20), 1.0),
        (PixelCoord::new(18, 35), 2.0),
        (PixelCoord::new(14, 28), 3.0),
    ];
    c.seeds = vec![PixelCoord::new(13, 27)];
    let mut out = Vec::new();
    split(c, &mut out);
    let rects: Vec<(u32, u32, u32, u32)> = out.iter().map(|c| (c.x, c.y, c.w, c.h)).collect();
    assert_eq!(
        rects,
        vec![
            (10, 20, 4, 8),
            (14, 20, 5, 8),
            (10, 28, 4, 8),
            (14, 28, 5, 8)
        ]
    );
    assert_eq!(out.iter().map(|c| c.samples.len()).sum::<usize>(), 3);
    assert_eq!(out[0].samples[0].1, 1.0);
    assert_eq!(out[3].samples.len(), 2);
    assert_eq!(out[0].seeds, vec![PixelCoord::new(13, 27)]);
    assert!(out.iter().all(|c| c.depth == 1));
    // A thin cell splits along its long side only.
    let mut out = Vec::new();
    split(cell(0, 0, 40, 5), &mut out);
    assert_eq!(
        out.iter().map(|c| (c.w, c.h)).collect::<Vec<_>>(),
        vec![(20, 5), (20, 5)]
    );
}

#[test]
fn cell_streams_depend_on_seed_and_cell_only() {
    let a = cell(0, 0, 64, 64).rng(1).random::<u64>();
    let b = cell(0, 0, 64, 64).rng(1).random::<u64>();
    let c = cell(0, 0, 64, 64).rng(2).random::<u64>();
    let d = cell(0, 32, 64, 32).rng(1).random::<u64>();
    assert_eq!(a, b);
    assert_ne!(a, c);
    assert_ne!(a, d);
}

// Inputs of the bit-identity test: a rendered-looking frame and Monte Carlo-like noise.

fn model(w: u32, h: u32) -> VisionModel {
    let d = crate::vision::DisplayModel {
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

/// Shading, a checker of 16-px squares, fine detail.
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

/// The quad-tree without [`block_map`]'s dense fallback, however many pixels it evaluates.
fn sparse(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    seeds: &[PixelCoord],
    params: &MetricParams,
) -> DistanceMap {
    quad_tree(model, a, b, seeds, params, f64::INFINITY)
}

fn stacks(m: &VisionModel, a: &LinearImage, b: &LinearImage) -> (ContrastStack, ContrastStack) {
    (m.decompose(a).unwrap(), m.decompose(b).unwrap())
}

/// Bit-for-bit comparison of two block maps (map bits, leaves, pixel count).
fn assert_same(got: &DistanceMap, want: &DistanceMap, what: &str) {
    assert_eq!(
        got.pixels_evaluated, want.pixels_evaluated,
        "{what}: pixels"
    );
    assert_eq!(got.leaves, want.leaves, "{what}: leaves");
    let bits =
        |m: &DistanceMap| -> Vec<u32> { m.map.pixels().iter().map(|d| d.to_bits()).collect() };
    assert_eq!(
        (got.map.width(), got.map.height()),
        (want.map.width(), want.map.height())
    );
    assert!(bits(got) == bits(want), "{what}: map differs");
}

#[test]
fn optimised_block_map_equals_the_plain_transcription_bit_for_bit() {
    // The optimised quad-tree must give exactly what the plain transcription of §3.2
    // (reference.rs) gives. A noisy progressive-like pair, seeds as the renderer
    // passes them (many, raster order, some duplicated and out of range), several metric
    // seeds and (H, ε) so the tree goes deep, random and dense sampling both occur.
    let mut cases = 0;
    for &(w, h) in &[(96u32, 72u32), (1, 1), (1, 37), (45, 2), (9, 130)] {
        let m = model(w, h);
        let a = textured(w, h);
        let b = noisy(&noisy(&a, 0.15, 11, |_, _| true), 0.4, 12, |x, y| {
            x < w / 2 && y > h / 3
        });
        let (sa, sb) = stacks(&m, &a, &b);
        let every_other: Vec<PixelCoord> = (0..h)
            .flat_map(|y| (0..w).map(move |x| PixelCoord::new(x, y)))
            .filter(|p| (p.x * 7 + p.y * 3) % 5 < 2)
            .collect();
        let mut messy = every_other.clone();
        messy.extend(every_other.iter().rev().take(50).copied()); // duplicates
        messy.push(PixelCoord::new(w, 0)); // out of range
        messy.push(PixelCoord::new(0, h + 3));
        for seeds in [&[][..], &every_other[..], &messy[..]] {
            for (seed, homogeneity, epsilon) in [(1u64, 0.8f32, 1.0f32), (99, 0.95, 0.3)] {
                let p = MetricParams {
                    homogeneity,
                    epsilon,
                    seed,
                };
                let got = sparse(&m, &sa, &sb, seeds, &p);
                let want = reference::block_map_reference(&m, &sa, &sb, seeds, &p);
                let what = format!("{w}x{h}, {} seeds, {p:?}", seeds.len());
                assert_same(&got, &want, &what);
                cases += 1;
            }
        }
    }
    assert_eq!(cases, 30);
    // The big case must really exercise the deep tree (else the comparison proves little).
    let (w, h) = (96, 72);
    let m = model(w, h);
    let a = textured(w, h);
    let b = noisy(&a, 0.4, 12, |_, _| true);
    let (sa, sb) = stacks(&m, &a, &b);
    let p = MetricParams {
        homogeneity: 0.95,
        epsilon: 0.3,
        seed: 99,
    };
    let bm = block_map(&m, &sa, &sb, &[], &p);
    assert!(bm.leaves.len() > 20, "{} leaves", bm.leaves.len());
    assert!(bm.leaves.iter().any(|l| l.width < 8 && l.height < 8));
}

#[test]
fn a_tree_that_would_evaluate_most_pixels_evaluates_them_all_exactly() {
    let (w, h) = (256, 256);
    let m = model(w, h);
    let a = noisy(&textured(w, h), 0.4, 4, |_, _| true);
    let b = noisy(&textured(w, h), 0.4, 5, |_, _| true);
    let (sa, sb) = stacks(&m, &a, &b);
    // A strict homogeneity test on a noisy pair keeps every cell splitting.
    let p = MetricParams {
        homogeneity: 0.95,
        epsilon: 0.3,
        seed: 99,
    };
    let tree = sparse(&m, &sa, &sb, &[], &p);
    assert!(
        tree.pixels_evaluated as f64 > DENSE_SHARE * f64::from(w * h),
        "the pair must be noisy enough: {}",
        tree.pixels_evaluated
    );
    let bm = block_map(&m, &sa, &sb, &[], &p);
    let held: usize = bm.leaves.iter().map(|l| l.samples as usize).sum();
    assert_eq!(held, bm.pixels_evaluated, "nothing is evaluated twice");
    let full = m.full_map(&sa, &sb);
    let mut dense = 0;
    for l in &bm.leaves {
        if u64::from(l.samples) == u64::from(l.width * l.height) {
            dense += usize::from(l.width * l.height > 1);
            for y in l.y..l.y + l.height {
                for x in l.x..l.x + l.width {
                    assert_eq!(bm.map.get(x, y), full.get(x, y), "exact at ({x}, {y})");
                }
            }
        }
    }
    assert!(dense > 0, "the rest was evaluated densely");
}

// Behaviour of the block map.

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
    let bm = block_map(&m, &sa, &sb, &[], &MetricParams::default());
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
    let one = block_map(&m, &sa, &sb, &seeds, &p);
    let two = block_map(&m, &sa, &sb, &seeds, &p);
    assert_eq!(one.map.pixels(), two.map.pixels());
    assert_eq!(one.leaves, two.leaves);
    assert_eq!(one.pixels_evaluated, two.pixels_evaluated);
    let other = block_map(&m, &sa, &sb, &seeds, &MetricParams { seed: 43, ..p });
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
    let bm = block_map(&m, &sa, &sb, &[], &MetricParams::default());
    assert!(bm.leaves.len() > 4);
    let area = |l: &Leaf| l.width * l.height;
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
    let full = full_map(&m, &sa, &sb);
    assert_eq!(full.pixels_evaluated, (w * h) as usize);
    let bm = block_map(
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
    let bm = block_map(&m, &sa, &sb, &seeds, &MetricParams::default());
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
    let bm = block_map(&m1, &s1, &s2, &[], &MetricParams::default());
    assert_eq!(
        (bm.leaves.len(), bm.pixels_evaluated, *bm.map.get(0, 0)),
        (1, 1, 0.0)
    );
}
