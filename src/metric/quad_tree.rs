//! The quad-tree behind [`super::block_map`] (vision-model.md §3.2), one tree level at a
//! time: choose each cell's new samples, evaluate the level's pixels in one batch, decide
//! leaf or split per cell. Bit-identical to the plain transcription in `reference.rs`.

use super::{samples_for_area, Cell, DistanceMap, Leaf, MetricParams, MIN_SPLIT};
use crate::raster::{Image, PixelCoord};
use crate::vision::{ContrastStack, VisionModel};
use rand::Rng;

/// Share of the image beyond which the quad-tree stops and evaluates every pixel of the
/// cells it has left (the tree's own work then outweighs what it saves).
pub const DENSE_SHARE: f64 = 0.4;

/// The quad-tree between `a` and `b`; past `dense_share` of the image evaluated, the cells
/// left are evaluated densely instead.
pub(super) fn quad_tree(
    model: &VisionModel,
    a: &ContrastStack,
    b: &ContrastStack,
    seeds: &[PixelCoord],
    params: &MetricParams,
    dense_share: f64,
) -> DistanceMap {
    let (w, h) = (a.width().min(b.width()), a.height().min(b.height()));
    if w == 0 || h == 0 {
        return DistanceMap {
            map: Image::filled(w, h, 0f32),
            leaves: Vec::new(),
            pixels_evaluated: 0,
        };
    }
    let mut tree = QuadTree::new(model, a, b, params, w, h);
    let mut frontier = vec![tree.root(seeds)];
    let mut next: Vec<Cell> = Vec::new();
    while !frontier.is_empty() {
        // A tree that would evaluate most of the image anyway (a noisy pair keeps every
        // cell inhomogeneous) costs more than evaluating every pixel at once: the sampling,
        // sorting and per-cell decisions come on top of the evaluations.
        if (tree.evaluated + planned(&frontier)) as f64 > dense_share * tree.taken.len() as f64 {
            tree.evaluate_densely(&frontier);
            break;
        }
        tree.draw_level(&mut frontier);
        tree.evaluate_level();
        tree.decide_level(&mut frontier, &mut next);
        std::mem::swap(&mut frontier, &mut next);
    }
    DistanceMap {
        map: tree.map,
        leaves: tree.leaves,
        pixels_evaluated: tree.evaluated,
    }
}

/// New samples the cells of a level would draw.
fn planned(frontier: &[Cell]) -> usize {
    frontier
        .iter()
        .map(|c| {
            let have = c.samples.len();
            samples_for_area(c.area())
                .saturating_sub(have)
                .min((c.area() as usize).saturating_sub(have))
        })
        .sum()
}

/// One call's state: what is evaluated so far, the map and leaves written, and the
/// buffers each level reuses.
struct QuadTree<'a> {
    model: &'a VisionModel,
    a: &'a ContrastStack,
    b: &'a ContrastStack,
    seed: u64,
    /// H: the homogeneous share that makes a leaf.
    homogeneity: f32,
    /// ε in JND.
    epsilon: f64,
    max_depth: u32,
    /// Evaluated (or about to be) pixels; cells are disjoint, so one mask serves every cell.
    taken: Vec<bool>,
    map: Image<f32>,
    leaves: Vec<Leaf>,
    evaluated: usize,
    pools: Pools,
    level: Level,
}

/// One level's batch: its pixels, their distances, and each cell's range in the batch
/// with how many of its seeds it used.
#[derive(Default)]
struct Level {
    batch: Vec<PixelCoord>,
    values: Vec<f32>,
    ranges: Vec<(usize, usize, usize)>,
    keys: Vec<u64>,
    sorted: Vec<PixelCoord>,
    sorted_values: Vec<f32>,
    free_px: Vec<PixelCoord>,
}

impl<'a> QuadTree<'a> {
    fn new(
        model: &'a VisionModel,
        a: &'a ContrastStack,
        b: &'a ContrastStack,
        params: &MetricParams,
        w: u32,
        h: u32,
    ) -> Self {
        let homogeneity = if params.homogeneity.is_finite() {
            params.homogeneity
        } else {
            0.8
        };
        let epsilon = if params.epsilon.is_finite() {
            f64::from(params.epsilon.max(0.0))
        } else {
            1.0
        };
        Self {
            model,
            a,
            b,
            seed: params.seed,
            homogeneity,
            epsilon,
            max_depth: u32::BITS - (w.max(h) - 1).leading_zeros(), // ceil(log2 max(W, H))
            taken: vec![false; w as usize * h as usize],
            map: Image::filled(w, h, 0f32),
            leaves: Vec::new(),
            evaluated: 0,
            pools: Pools::default(),
            level: Level::default(),
        }
    }

    fn idx(&self, p: PixelCoord) -> usize {
        p.y as usize * self.map.width() as usize + p.x as usize
    }

    /// The whole image as one cell, with the in-bounds seeds, first occurrence only.
    /// `taken` doubles as the "seen" mask and is cleared again afterwards (O(seeds),
    /// cheaper than a second n-sized mask).
    fn root(&mut self, seeds: &[PixelCoord]) -> Cell {
        let (w, h) = (self.map.width(), self.map.height());
        let mut root_seeds = Vec::with_capacity(seeds.len().min(self.taken.len()));
        for &p in seeds {
            let i = self.idx(p);
            if p.x < w && p.y < h && !self.taken[i] {
                self.taken[i] = true;
                root_seeds.push(p);
            }
        }
        for &p in &root_seeds {
            let i = self.idx(p);
            self.taken[i] = false;
        }
        Cell {
            x: 0,
            y: 0,
            w,
            h,
            depth: 0,
            samples: Vec::new(),
            seeds: root_seeds,
        }
    }

    /// Each cell's new samples (same draws, same order as the reference).
    fn draw_level(&mut self, frontier: &mut [Cell]) {
        self.level.batch.clear();
        self.level.ranges.clear();
        for cell in frontier {
            let start = self.level.batch.len();
            let mut rng = cell.rng(self.seed);
            let need = samples_for_area(cell.area()).saturating_sub(cell.samples.len());
            let used = self.take_seeds(cell, need, &mut rng);
            let free = (cell.area() as usize).saturating_sub(cell.samples.len() + used);
            let random = (need - used).min(free);
            if random > 0 && random * 2 <= free {
                self.draw_sparse(cell, random, &mut rng);
            } else if random > 0 {
                self.draw_dense(cell, random, &mut rng);
            }
            self.level
                .ranges
                .push((start, self.level.batch.len(), used));
        }
    }

    /// Seeds first (F&P04 initialise the metric with the rendering sample set); a random
    /// subset of them when there are more than needed. Unused seeds stay in
    /// `cell.seeds[used..]` for the children. Returns how many were used.
    fn take_seeds(&mut self, cell: &mut Cell, need: usize, rng: &mut impl Rng) -> usize {
        let s = &mut cell.seeds;
        debug_assert!(s.iter().all(|&p| !self.taken[self.idx(p)]));
        let used = if s.len() <= need {
            s.len()
        } else {
            for i in 0..need {
                let j = rng.random_range(i..s.len());
                s.swap(i, j);
            }
            need
        };
        self.level.batch.extend_from_slice(&s[..used]);
        for &p in &s[..used] {
            let i = self.idx(p);
            self.taken[i] = true;
        }
        used
    }

    /// `need` random free pixels of a cell at most half full: rejection sampling is cheap.
    fn draw_sparse(&mut self, cell: &Cell, need: usize, rng: &mut impl Rng) {
        let mut got = 0;
        while got < need {
            let p = PixelCoord::new(
                cell.x + rng.random_range(0..cell.w),
                cell.y + rng.random_range(0..cell.h),
            );
            let i = self.idx(p);
            if !self.taken[i] {
                self.taken[i] = true;
                self.level.batch.push(p);
                got += 1;
            }
        }
    }

    /// `need` random free pixels of a cell more than half full (then the cell is small,
    /// < 6000 px): a partial shuffle of the free pixels, in raster order as the reference
    /// lists them.
    fn draw_dense(&mut self, cell: &Cell, need: usize, rng: &mut impl Rng) {
        let mut free_px = std::mem::take(&mut self.level.free_px);
        free_px.clear();
        for y in cell.y..cell.y + cell.h {
            for x in cell.x..cell.x + cell.w {
                let p = PixelCoord::new(x, y);
                if !self.taken[self.idx(p)] {
                    free_px.push(p);
                }
            }
        }
        for i in 0..need {
            let j = rng.random_range(i..free_px.len());
            free_px.swap(i, j);
            let t = self.idx(free_px[i]);
            self.taken[t] = true;
        }
        self.level.batch.extend_from_slice(&free_px[..need]);
        self.level.free_px = free_px;
    }

    /// The whole level's new pixels at once (parallel inside). Random positions hit the
    /// level planes all over memory; evaluating in raster order keeps the lookups
    /// cache-friendly. Values are scattered back to batch order; the order cannot change a
    /// value (the kernel is per lane).
    fn evaluate_level(&mut self) {
        let n = self.taken.len();
        let l = &mut self.level;
        l.keys.clear();
        if n <= u32::MAX as usize && l.batch.len() <= u32::MAX as usize {
            // (raster index, batch index) in one u64: a plain integer sort.
            let w = self.map.width() as usize;
            l.keys.extend(
                l.batch
                    .iter()
                    .enumerate()
                    .map(|(i, &p)| ((p.y as usize * w + p.x as usize) as u64) << 32 | i as u64),
            );
            l.keys.sort_unstable();
        } else {
            // Over 2^32 pixels: batch order (slower lookups, same values).
            l.keys.extend(0..l.batch.len() as u64);
        }
        l.sorted.clear();
        l.sorted
            .extend(l.keys.iter().map(|&k| l.batch[(k & 0xffff_ffff) as usize]));
        l.sorted_values.clear();
        l.sorted_values.resize(l.batch.len(), 0.0);
        self.model
            .distances_at(self.a, self.b, &l.sorted, &mut l.sorted_values);
        l.values.clear();
        l.values.resize(l.batch.len(), 0.0);
        for (&k, &v) in l.keys.iter().zip(&l.sorted_values) {
            l.values[(k & 0xffff_ffff) as usize] = v;
        }
        self.evaluated += l.batch.len();
    }

    /// Leaf or split, per cell of the level; the children go to `next`.
    fn decide_level(&mut self, frontier: &mut Vec<Cell>, next: &mut Vec<Cell>) {
        let ranges = std::mem::take(&mut self.level.ranges);
        for (mut cell, &(start, end, used)) in frontier.drain(..).zip(&ranges) {
            let l = &self.level;
            cell.samples.extend(
                l.batch[start..end]
                    .iter()
                    .copied()
                    .zip(l.values[start..end].iter().copied()),
            );
            let (mean, homog) = mean_and_homogeneity(&cell.samples, self.epsilon);
            let full = cell.samples.len() as u64 >= cell.area();
            let small = cell.w < MIN_SPLIT && cell.h < MIN_SPLIT;
            if homog >= f64::from(self.homogeneity) || full || small || cell.depth >= self.max_depth
            {
                self.write_leaf(&cell, mean, homog, full);
                self.pools.recycle(cell);
            } else {
                split_fast(cell, used, next, &mut self.pools);
            }
        }
        self.level.ranges = ranges;
    }

    /// A leaf: its mean over its pixels, and, fully sampled, the exact per-pixel values
    /// (§3.2).
    fn write_leaf(&mut self, cell: &Cell, mean: f64, homog: f64, full: bool) {
        let w = self.map.width() as usize;
        for y in cell.y..cell.y + cell.h {
            let row = &mut self.map.pixels_mut()[y as usize * w..]
                [cell.x as usize..(cell.x + cell.w) as usize];
            row.fill(mean as f32);
        }
        if full {
            for &(p, d) in &cell.samples {
                self.map.set(p.x, p.y, d);
            }
        }
        self.leaves.push(Leaf {
            x: cell.x,
            y: cell.y,
            width: cell.w,
            height: cell.h,
            samples: cell.samples.len() as u32,
            mean: mean as f32,
            homogeneity: homog as f32,
        });
    }

    /// Every pixel of `cells` not yet evaluated, in raster order, written exactly into the
    /// map, one leaf per cell.
    fn evaluate_densely(&mut self, cells: &[Cell]) {
        let w = self.map.width() as usize;
        let mut coords: Vec<PixelCoord> = Vec::new();
        for c in cells {
            for y in c.y..c.y + c.h {
                coords.extend(
                    (c.x..c.x + c.w)
                        .map(|x| PixelCoord::new(x, y))
                        .filter(|p| !self.taken[p.y as usize * w + p.x as usize]),
                );
            }
        }
        let mut values = vec![0f32; coords.len()];
        self.model
            .distances_at(self.a, self.b, &coords, &mut values);
        for (&p, &d) in coords.iter().zip(&values) {
            self.map.set(p.x, p.y, d);
        }
        for c in cells {
            for &(p, d) in &c.samples {
                self.map.set(p.x, p.y, d);
            }
            let mut v = Vec::with_capacity(c.area() as usize);
            for y in c.y..c.y + c.h {
                v.extend((c.x..c.x + c.w).map(|x| *self.map.get(x, y)));
            }
            let k = v.len().max(1) as f64;
            let mean = v.iter().map(|&d| f64::from(d)).sum::<f64>() / k;
            let close = v
                .iter()
                .filter(|&&d| (f64::from(d) - mean).abs() <= self.epsilon)
                .count();
            self.leaves.push(Leaf {
                x: c.x,
                y: c.y,
                width: c.w,
                height: c.h,
                samples: v.len() as u32,
                mean: mean as f32,
                homogeneity: (close as f64 / k) as f32,
            });
        }
        self.evaluated += coords.len();
    }
}

/// A cell's mean distance and homogeneity h: the share of its samples within ε of the mean
/// (the denominator is the number of samples, vision-model.md §3.2).
fn mean_and_homogeneity(samples: &[(PixelCoord, f32)], epsilon: f64) -> (f64, f64) {
    let n = samples.len().max(1);
    let mean = samples.iter().map(|s| f64::from(s.1)).sum::<f64>() / n as f64;
    let close = samples
        .iter()
        .filter(|s| (f64::from(s.1) - mean).abs() <= epsilon)
        .count();
    (mean, close as f64 / n as f64)
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
