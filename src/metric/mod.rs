//! The adaptive perceptual metric of Albin et al. (2002) as used by F&P04 §3.2: a quad-tree
//! that evaluates the vision-model distance on a random fraction of the pixels.
//! Algorithm: vision-model.md §3.2.
//!
//! Two corrections to F&P04's wording, argued in vision-model.md §3.2: a cell is a leaf when
//! its homogeneity h ≥ H (F&P04's text reads the other way round), and h's denominator is
//! the number of samples, not of pixels.

use crate::raster::{Image, PixelCoord};
use crate::vision::{ContrastStack, VisionModel};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// The subdivision test's parameters (scene `progressive.homogeneity`, `epsilon`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetricParams {
    /// H: a cell is homogeneous (a leaf) when at least this fraction of its samples lies
    /// within `epsilon` of the cell mean.
    pub homogeneity: f32,
    /// ε, in JNDs.
    pub epsilon: f32,
    /// Seeds the random sample positions; derive it from (job seed, frame index).
    pub seed: u64,
}

impl Default for MetricParams {
    /// H = 0.8, ε = 1 JND [F04].
    fn default() -> Self {
        Self {
            homogeneity: 0.8,
            epsilon: 1.0,
            seed: 0,
        }
    }
}

/// One leaf of the quad-tree.
#[derive(Clone, Debug, PartialEq)]
pub struct Leaf {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
    pub samples: u32,
    pub mean: f32,
    pub homogeneity: f32,
}

/// A distance map: per pixel, the distance in JNDs (block means for adaptive maps).
#[derive(Clone, Debug)]
pub struct DistanceMap {
    pub map: Image<f32>,
    pub leaves: Vec<Leaf>,
    /// Pixels at which the vision model was evaluated.
    pub pixels_evaluated: usize,
}

impl DistanceMap {
    /// Mean over the image (f64 accumulation).
    #[must_use]
    pub fn mean(&self) -> f64 {
        let n = self.map.len().max(1) as f64;
        self.map.pixels().iter().map(|&d| f64::from(d)).sum::<f64>() / n
    }
}

/// Samples per cell of `area` pixels (vision-model.md §3.2, [F04]): 2000 above 10 000 px,
/// 500 from 1000 to 10 000, a third (rounded up, [D]) below 1000.
#[must_use]
pub fn samples_for_area(area: u64) -> usize {
    if area > 10_000 {
        2000
    } else if area >= 1000 {
        500
    } else {
        area.div_ceil(3) as usize
    }
}

/// A cell waiting for its decision.
struct Cell {
    x: u32,
    y: u32,
    w: u32,
    h: u32,
    depth: u32,
    /// Evaluated samples inside the cell (inherited from the parent or drawn here).
    samples: Vec<(PixelCoord, f32)>,
    /// The renderer's traced pixels inside the cell not yet evaluated.
    seeds: Vec<PixelCoord>,
}

impl Cell {
    fn area(&self) -> u64 {
        u64::from(self.w) * u64::from(self.h)
    }
    /// Per-cell RNG stream: (params.seed, cell rectangle) → reproducible and independent of
    /// the order cells are visited in (§3.2 "seed from the cell id").
    fn rng(&self, seed: u64) -> Pcg64Mcg {
        let mut h = seed ^ 0x9e37_79b9_7f4a_7c15;
        for v in [self.x, self.y, self.w, self.h] {
            h = splitmix(h ^ u64::from(v));
        }
        Pcg64Mcg::seed_from_u64(h)
    }
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Cells smaller than this in both directions are never split (vision-model.md §3.2, [D]).
const MIN_SPLIT: u32 = 8;

/// The adaptive block map between two decomposed images, seeded with `seeds` (the
/// renderer's traced pixels), deterministic for a given `params.seed`.
///
/// Breadth-first: each tree level draws its cells' samples (seeds first, then uniform
/// random pixels without replacement), evaluates all new pixels of the level in one
/// parallel batch, then decides leaf or split per cell.
///
/// The quad-tree (without the dense fallback) is bit-identical to the plain transcription of
/// §3.2 (`reference.rs`, a test-only oracle; the unit tests compare them on noisy pairs)
/// but cheaper on progressive frames, where every traced pixel is a seed and the tree goes
/// deep. What changed, all without touching the sampling order
/// or the order samples are summed in:
/// - a split distributes the parent's samples and unused seeds to its children in one pass
///   (the old code filtered the whole parent list once per child) and reads the unused
///   seeds in place (no `split_off` copy); sample/seed vectors are recycled between cells;
/// - the unused-seed re-filter is gone (an unused seed is never taken: a cell draws random
///   pixels only after using all its seeds), as is the second n-sized dedup mask;
/// - each level's batch is ordered by one `u64` sort of (pixel index, batch index) keys
///   instead of a comparison sort with indirect (y, x) lookups.
#[must_use]
pub fn block_map(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    seeds: &[PixelCoord],
    params: &MetricParams,
) -> DistanceMap {
    quad_tree(model, a, b, seeds, params, DENSE_SHARE)
}

fn quad_tree(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    seeds: &[PixelCoord],
    params: &MetricParams,
    dense_share: f64,
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
    let n = w as usize * h as usize;
    // `taken` marks evaluated (or about to be) pixels; cells are disjoint, so one mask
    // serves every cell.
    let mut taken = vec![false; n];
    let idx = |p: PixelCoord| p.y as usize * w as usize + p.x as usize;
    // Seeds: in bounds, first occurrence only. `taken` doubles as the "seen" mask and is
    // cleared again afterwards (O(seeds), cheaper than a second n-sized mask).
    let mut root_seeds = Vec::with_capacity(seeds.len().min(n));
    for &p in seeds {
        if p.x < w && p.y < h && !taken[idx(p)] {
            taken[idx(p)] = true;
            root_seeds.push(p);
        }
    }
    for &p in &root_seeds {
        taken[idx(p)] = false;
    }
    let mut frontier = vec![Cell {
        x: 0,
        y: 0,
        w,
        h,
        depth: 0,
        samples: Vec::new(),
        seeds: root_seeds,
    }];
    let mut next: Vec<Cell> = Vec::new();
    let mut pools = Pools::default();
    let mut leaves = Vec::new();
    let mut evaluated = 0usize;
    let mut batch: Vec<PixelCoord> = Vec::new();
    let mut values: Vec<f32> = Vec::new();
    let mut keys: Vec<u64> = Vec::new();
    let mut sorted: Vec<PixelCoord> = Vec::new();
    let mut sorted_values: Vec<f32> = Vec::new();
    let mut free_px: Vec<PixelCoord> = Vec::new();
    // Per cell of the level: its batch range and how many of its seeds it used.
    let mut ranges: Vec<(usize, usize, usize)> = Vec::new();
    while !frontier.is_empty() {
        // 0. A tree that would evaluate most of the image anyway (a noisy pair keeps every
        // cell inhomogeneous) costs more than evaluating every pixel at once: the sampling,
        // sorting and per-cell decisions come on top of the evaluations. Then every pixel
        // of the cells left is evaluated, in raster order, and kept exactly.
        let planned: usize = frontier
            .iter()
            .map(|c| {
                let have = c.samples.len();
                samples_for_area(c.area())
                    .saturating_sub(have)
                    .min((c.area() as usize).saturating_sub(have))
            })
            .sum();
        if (evaluated + planned) as f64 > dense_share * n as f64 {
            evaluated +=
                evaluate_densely(model, a, b, &frontier, &taken, &mut map, &mut leaves, eps);
            break;
        }
        // 1. Choose each cell's new samples (same draws, same order as the reference).
        batch.clear();
        ranges.clear();
        for cell in &mut frontier {
            let start = batch.len();
            let want = samples_for_area(cell.area());
            let mut need = want.saturating_sub(cell.samples.len());
            let mut rng = cell.rng(params.seed);
            // Seeds first (F&P04 initialise the metric with the rendering sample set); a
            // random subset of them when there are more than needed. Unused seeds stay in
            // `cell.seeds[used..]` for the children.
            let s = &mut cell.seeds;
            debug_assert!(s.iter().all(|&p| !taken[idx(p)]));
            let used = if s.len() <= need {
                s.len()
            } else {
                for i in 0..need {
                    let j = rng.random_range(i..s.len());
                    s.swap(i, j);
                }
                need
            };
            batch.extend_from_slice(&s[..used]);
            for &p in &s[..used] {
                taken[idx(p)] = true;
            }
            need -= used;
            let free = (cell.area() as usize).saturating_sub(cell.samples.len() + used);
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
                    // Dense (then the cell is small, < 6000 px): partial shuffle of the free
                    // pixels, in raster order as the reference lists them.
                    free_px.clear();
                    for y in cell.y..cell.y + cell.h {
                        for x in cell.x..cell.x + cell.w {
                            let p = PixelCoord::new(x, y);
                            if !taken[idx(p)] {
                                free_px.push(p);
                            }
                        }
                    }
                    for i in 0..need {
                        let j = rng.random_range(i..free_px.len());
                        free_px.swap(i, j);
                        taken[idx(free_px[i])] = true;
                    }
                    batch.extend_from_slice(&free_px[..need]);
                }
            }
            ranges.push((start, batch.len(), used));
        }
        // 2. Evaluate the whole level's new pixels at once (parallel inside).
        // Random positions hit the level planes all over memory; evaluating in raster order
        // keeps the lookups cache-friendly. Values are scattered back to batch order. The
        // order cannot change a value (the kernel is per lane).
        keys.clear();
        if n <= u32::MAX as usize && batch.len() <= u32::MAX as usize {
            // (raster index, batch index) in one u64: a plain integer sort.
            keys.extend(
                batch
                    .iter()
                    .enumerate()
                    .map(|(i, &p)| ((idx(p) as u64) << 32) | i as u64),
            );
            keys.sort_unstable();
        } else {
            // Over 2^32 pixels: batch order (slower lookups, same values).
            keys.extend(0..batch.len() as u64);
        }
        sorted.clear();
        sorted.extend(keys.iter().map(|&k| batch[(k & 0xffff_ffff) as usize]));
        sorted_values.clear();
        sorted_values.resize(batch.len(), 0.0);
        model.distances_at(a, b, &sorted, &mut sorted_values);
        values.clear();
        values.resize(batch.len(), 0.0);
        for (&k, &v) in keys.iter().zip(&sorted_values) {
            values[(k & 0xffff_ffff) as usize] = v;
        }
        evaluated += batch.len();
        // 3. Decide per cell.
        for (mut cell, &(start, end, used)) in frontier.drain(..).zip(&ranges) {
            cell.samples.extend(
                batch[start..end]
                    .iter()
                    .copied()
                    .zip(values[start..end].iter().copied()),
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
                pools.recycle(cell);
            } else {
                split_fast(cell, used, &mut next, &mut pools);
            }
        }
        std::mem::swap(&mut frontier, &mut next);
    }
    DistanceMap {
        map,
        leaves,
        pixels_evaluated: evaluated,
    }
}

/// Share of the image beyond which the quad-tree stops and evaluates every pixel of the
/// cells it has left (the tree's own work then outweighs what it saves).
pub const DENSE_SHARE: f64 = 0.4;

/// Every pixel of `cells` evaluated (those not yet in a cell's samples, `taken`) and
/// written exactly into `map`, one leaf per cell; returns the number of pixels evaluated.
#[allow(clippy::too_many_arguments)]
fn evaluate_densely(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    cells: &[Cell],
    taken: &[bool],
    map: &mut Image<f32>,
    leaves: &mut Vec<Leaf>,
    eps: f64,
) -> usize {
    let w = map.width() as usize;
    let mut coords: Vec<PixelCoord> = Vec::new();
    for c in cells {
        for y in c.y..c.y + c.h {
            coords.extend(
                (c.x..c.x + c.w)
                    .map(|x| PixelCoord::new(x, y))
                    .filter(|p| !taken[p.y as usize * w + p.x as usize]),
            );
        }
    }
    let mut values = vec![0f32; coords.len()];
    model.distances_at(a, b, &coords, &mut values);
    for (&p, &d) in coords.iter().zip(&values) {
        map.set(p.x, p.y, d);
    }
    for c in cells {
        for &(p, d) in &c.samples {
            map.set(p.x, p.y, d);
        }
        let mut v = Vec::with_capacity(c.area() as usize);
        for y in c.y..c.y + c.h {
            v.extend((c.x..c.x + c.w).map(|x| *map.get(x, y)));
        }
        let k = v.len().max(1) as f64;
        let mean = v.iter().map(|&d| f64::from(d)).sum::<f64>() / k;
        let close = v
            .iter()
            .filter(|&&d| (f64::from(d) - mean).abs() <= eps)
            .count();
        leaves.push(Leaf {
            x: c.x,
            y: c.y,
            width: c.w,
            height: c.h,
            samples: v.len() as u32,
            mean: mean as f32,
            homogeneity: (close as f64 / k) as f32,
        });
    }
    coords.len()
}

/// Emptied sample and seed vectors of finished cells, reused by new ones (the tree has
/// hundreds to thousands of cells per call; their lists would otherwise be fresh heap
/// allocations grown from zero).
#[derive(Default)]
struct Pools {
    samples: Vec<Vec<(PixelCoord, f32)>>,
    seeds: Vec<Vec<PixelCoord>>,
}

impl Pools {
    fn recycle(&mut self, cell: Cell) {
        let (mut s, mut p) = (cell.samples, cell.seeds);
        s.clear();
        p.clear();
        self.samples.push(s);
        self.seeds.push(p);
    }
}

/// [`split`]'s result in one pass: same children in the same order (rows of halves top
/// first, left half first), each with the parent's samples and unused seeds
/// (`cell.seeds[used..]`) that fall inside it, in the parent's order.
fn split_fast(cell: Cell, used: usize, out: &mut Vec<Cell>, pools: &mut Pools) {
    let (nx, hw) = if cell.w >= MIN_SPLIT {
        (2, cell.w / 2)
    } else {
        (1, cell.w)
    };
    let (ny, hh) = if cell.h >= MIN_SPLIT {
        (2, cell.h / 2)
    } else {
        (1, cell.h)
    };
    let first = out.len();
    for cy in 0..ny {
        for cx in 0..nx {
            let (x, cw) = if cx == 0 {
                (cell.x, hw)
            } else {
                (cell.x + hw, cell.w - hw)
            };
            let (y, ch) = if cy == 0 {
                (cell.y, hh)
            } else {
                (cell.y + hh, cell.h - hh)
            };
            out.push(Cell {
                x,
                y,
                w: cw,
                h: ch,
                depth: cell.depth + 1,
                samples: pools.samples.pop().unwrap_or_default(),
                seeds: pools.seeds.pop().unwrap_or_default(),
            });
        }
    }
    // Which child a pixel of the parent falls in (with one half per axis, always the first).
    let (mx, my) = (cell.x + hw, cell.y + hh);
    let child = |p: PixelCoord| {
        let cx = usize::from(nx == 2 && p.x >= mx);
        let cy = usize::from(ny == 2 && p.y >= my);
        first + cy * nx + cx
    };
    for &s in &cell.samples {
        out[child(s.0)].samples.push(s);
    }
    for &p in &cell.seeds[used.min(cell.seeds.len())..] {
        out[child(p)].seeds.push(p);
    }
    pools.recycle(cell);
}

/// The per-pixel map (every pixel evaluated) in the same form.
#[must_use]
pub fn full_map(model: &VisionModel, a: &ContrastStack, b: &ContrastStack) -> DistanceMap {
    let map = model.full_map(a, b);
    let pixels_evaluated = map.len();
    DistanceMap {
        map,
        leaves: Vec::new(),
        pixels_evaluated,
    }
}

/// §3.2 transcribed plainly, the bit-exact oracle of [`block_map`] in the tests.
#[cfg(test)]
mod reference;

#[cfg(test)]
mod tests;
