//! Unit tests of the quad-tree internals (vision-model.md §3.2); behaviour tests are in
//! tests/vision_metric.rs.
use super::*;

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
