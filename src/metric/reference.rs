//! The quad-tree of vision-model.md §3.2 transcribed plainly, kept as the oracle the
//! optimised [`super::block_map`] must match bit for bit (same map, leaves and pixel
//! count for the same inputs and seed); tests.rs compares the two. Test-only: it copies
//! every cell's samples and seeds at each split.

use super::{samples_for_area, Cell, DistanceMap, Leaf, MetricParams, MIN_SPLIT};
use crate::raster::{Image, PixelCoord};
use crate::vision::{ContrastStack, VisionModel};
use rand::Rng;

/// The plain adaptive block map between two decomposed images, seeded with `seeds` (the
/// renderer's traced pixels), deterministic for a given `params.seed`.
///
/// Breadth-first: each tree level draws its cells' samples (seeds first, then uniform
/// random pixels without replacement), evaluates all new pixels of the level in one
/// parallel batch, then decides leaf or split per cell.
///
/// Long on purpose: one plain, top-to-bottom transcription of §3.2 is what makes it an
/// oracle a reader can check against the spec line by line.
#[must_use]
pub(super) fn block_map_reference(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    seeds: &[PixelCoord],
    params: &MetricParams,
) -> DistanceMap {
    let (w, h) = (a.width().min(b.width()), a.height().min(b.height()));
    let mut map = Image::filled(w, h, 0f32);
    if w == 0 || h == 0 {
        return DistanceMap {
            map,
            leaves: Vec::new(),
            pixels_evaluated: 0,
        };
    }
    let hom = if params.homogeneity.is_finite() {
        params.homogeneity
    } else {
        0.8
    };
    let eps = if params.epsilon.is_finite() {
        f64::from(params.epsilon.max(0.0))
    } else {
        1.0
    };
    let max_depth = u32::BITS - (w.max(h) - 1).leading_zeros(); // ceil(log2 max(W, H))
                                                                // `taken` marks evaluated (or about to be) pixels; cells are disjoint, so one mask
                                                                // serves every cell.
    let mut taken = vec![false; w as usize * h as usize];
    let idx = |p: PixelCoord| p.y as usize * w as usize + p.x as usize;
    // Seeds: in bounds, first occurrence only.
    let mut seen = vec![false; taken.len()];
    let mut root_seeds = Vec::new();
    for &p in seeds {
        if p.x < w && p.y < h && !seen[idx(p)] {
            seen[idx(p)] = true;
            root_seeds.push(p);
        }
    }
    drop(seen);
    let mut frontier = vec![Cell {
        x: 0,
        y: 0,
        w,
        h,
        depth: 0,
        samples: Vec::new(),
        seeds: root_seeds,
    }];
    let mut leaves = Vec::new();
    let mut evaluated = 0usize;
    let mut batch: Vec<PixelCoord> = Vec::new();
    let mut values: Vec<f32> = Vec::new();
    let mut order: Vec<u32> = Vec::new();
    let mut sorted: Vec<PixelCoord> = Vec::new();
    let mut sorted_values: Vec<f32> = Vec::new();
    while !frontier.is_empty() {
        // 1. Choose each cell's new samples.
        batch.clear();
        let mut ranges = Vec::with_capacity(frontier.len());
        for cell in &mut frontier {
            let start = batch.len();
            let want = samples_for_area(cell.area());
            let mut need = want.saturating_sub(cell.samples.len());
            let mut rng = cell.rng(params.seed);
            // Seeds first (F&P04 initialise the metric with the rendering sample set); a
            // random subset of them when there are more than needed.
            // (Already-evaluated pixels cannot be here by construction; filter anyway.)
            let mut seeds = std::mem::take(&mut cell.seeds);
            seeds.retain(|&p| !taken[idx(p)]);
            let mut unused = Vec::new();
            if seeds.len() <= need {
                batch.extend_from_slice(&seeds);
            } else {
                let mut s = seeds;
                for i in 0..need {
                    let j = rng.random_range(i..s.len());
                    s.swap(i, j);
                }
                batch.extend_from_slice(&s[..need]);
                unused = s.split_off(need);
            }
            cell.seeds = unused;
            for &p in &batch[start..] {
                taken[idx(p)] = true;
            }
            need -= batch.len() - start;
            let free =
                (cell.area() as usize).saturating_sub(cell.samples.len() + (batch.len() - start));
            let need = need.min(free);
            if need > 0 {
                if need * 2 <= free {
                    // Sparse: rejection sampling is cheap.
                    let mut got = 0;
                    while got < need {
                        let p = PixelCoord::new(
                            cell.x + rng.random_range(0..cell.w),
                            cell.y + rng.random_range(0..cell.h),
                        );
                        if !taken[idx(p)] {
                            taken[idx(p)] = true;
                            batch.push(p);
                            got += 1;
                        }
                    }
                } else {
                    // Dense (then the cell is small, < 6000 px): partial shuffle of the free pixels.
                    let mut pool: Vec<PixelCoord> = (cell.y..cell.y + cell.h)
                        .flat_map(|y| (cell.x..cell.x + cell.w).map(move |x| PixelCoord::new(x, y)))
                        .filter(|&p| !taken[idx(p)])
                        .collect();
                    for i in 0..need {
                        let j = rng.random_range(i..pool.len());
                        pool.swap(i, j);
                        taken[idx(pool[i])] = true;
                    }
                    batch.extend_from_slice(&pool[..need]);
                }
            }
            ranges.push(start..batch.len());
        }
        // 2. Evaluate the whole level's new pixels at once (parallel inside).
        // Random positions hit the level planes all over memory; evaluating in raster order
        // keeps the lookups cache-friendly. Values are scattered back to batch order.
        order.clear();
        order.extend(0..batch.len() as u32);
        order.sort_unstable_by_key(|&i| {
            let p = batch[i as usize];
            (p.y, p.x)
        });
        sorted.clear();
        sorted.extend(order.iter().map(|&i| batch[i as usize]));
        sorted_values.clear();
        sorted_values.resize(batch.len(), 0.0);
        model.distances_at(a, b, &sorted, &mut sorted_values);
        values.clear();
        values.resize(batch.len(), 0.0);
        for (&i, &v) in order.iter().zip(&sorted_values) {
            values[i as usize] = v;
        }
        evaluated += batch.len();
        // 3. Decide per cell.
        let mut next = Vec::new();
        for (mut cell, r) in frontier.drain(..).zip(ranges) {
            cell.samples.extend(
                batch[r.clone()]
                    .iter()
                    .copied()
                    .zip(values[r].iter().copied()),
            );
            let n = cell.samples.len().max(1);
            let mean = cell.samples.iter().map(|s| f64::from(s.1)).sum::<f64>() / n as f64;
            let close = cell
                .samples
                .iter()
                .filter(|s| (f64::from(s.1) - mean).abs() <= eps)
                .count();
            let homog = close as f64 / n as f64;
            let full = cell.samples.len() as u64 >= cell.area();
            let small = cell.w < MIN_SPLIT && cell.h < MIN_SPLIT;
            if homog >= f64::from(hom) || full || small || cell.depth >= max_depth {
                for y in cell.y..cell.y + cell.h {
                    let row = &mut map.pixels_mut()[y as usize * w as usize..]
                        [cell.x as usize..(cell.x + cell.w) as usize];
                    row.fill(mean as f32);
                }
                if full {
                    // Fully sampled leaves keep the exact per-pixel values (§3.2).
                    for &(p, d) in &cell.samples {
                        map.set(p.x, p.y, d);
                    }
                }
                leaves.push(Leaf {
                    x: cell.x,
                    y: cell.y,
                    width: cell.w,
                    height: cell.h,
                    samples: cell.samples.len() as u32,
                    mean: mean as f32,
                    homogeneity: homog as f32,
                });
            } else {
                split(cell, &mut next);
            }
        }
        frontier = next;
    }
    DistanceMap {
        map,
        leaves,
        pixels_evaluated: evaluated,
    }
}

/// Splits each dimension ≥ 8 px into floor/ceil halves (2 or 4 children); children inherit
/// the parent's samples and unused seeds that fall inside them.
pub(super) fn split(cell: Cell, out: &mut Vec<Cell>) {
    let xs: Vec<(u32, u32)> = if cell.w >= MIN_SPLIT {
        vec![
            (cell.x, cell.w / 2),
            (cell.x + cell.w / 2, cell.w - cell.w / 2),
        ]
    } else {
        vec![(cell.x, cell.w)]
    };
    let ys: Vec<(u32, u32)> = if cell.h >= MIN_SPLIT {
        vec![
            (cell.y, cell.h / 2),
            (cell.y + cell.h / 2, cell.h - cell.h / 2),
        ]
    } else {
        vec![(cell.y, cell.h)]
    };
    for &(y, ch) in &ys {
        for &(x, cw) in &xs {
            let mut c = Cell {
                x,
                y,
                w: cw,
                h: ch,
                depth: cell.depth + 1,
                samples: Vec::new(),
                seeds: Vec::new(),
            };
            c.samples = cell
                .samples
                .iter()
                .copied()
                .filter(|s| contains(&c, s.0))
                .collect();
            c.seeds = cell
                .seeds
                .iter()
                .copied()
                .filter(|&p| contains(&c, p))
                .collect();
            out.push(c);
        }
    }
}

fn contains(c: &Cell, p: PixelCoord) -> bool {
    p.x >= c.x && p.y >= c.y && p.x - c.x < c.w && p.y - c.y < c.h
}
