//! The first sample set (F&P04 §4.1): denser around the contours of the object-id map,
//! but not on them.

use crate::raster::{Image, PixelCoord};
use crate::scene::ObjectId;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;

/// σ of the edge-avoiding filter, in pixels: the samples land within a few pixels of an
/// object boundary, on both sides of it ([D]; F&P04 only say "gaussian-like").
pub const EDGE_SIGMA: f32 = 2.0;

/// Share of the sample budget spread uniformly; the rest follows the edge filter ([D]).
pub const BASE_SHARE: f64 = 0.5;

/// Contour map: pixels with a 4-neighbour of a different object id (§4.1). Rows in
/// parallel: this and the blur run once per render over every pixel, before the first
/// trace (a 4096² first sample set took 1.4 s with both serial and the blur per pixel,
/// 0.6 s now, the rest mostly allocation; measured on a loaded 2-core machine).
#[must_use]
pub fn contour_map(ids: &Image<ObjectId>) -> Vec<bool> {
    let (w, h) = (ids.width(), ids.height());
    let mut out = vec![false; ids.len()];
    if w == 0 {
        return out;
    }
    out.par_chunks_mut(w as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let y = y as u32;
            for (x, o) in (0..w).zip(row.iter_mut()) {
                let id = *ids.get(x, y);
                *o = (x > 0 && *ids.get(x - 1, y) != id)
                    || (x + 1 < w && *ids.get(x + 1, y) != id)
                    || (y > 0 && *ids.get(x, y - 1) != id)
                    || (y + 1 < h && *ids.get(x, y + 1) != id);
            }
        });
    out
}

/// The normalised Gaussian taps of [`blur`], radius r = ⌈3σ⌉: (r, taps −r..=r).
fn gaussian_taps(sigma: f32) -> (isize, Vec<f32>) {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let ks: f32 = k.iter().sum();
    (r, k.iter().map(|v| v / ks).collect())
}

/// Separable Gaussian blur of a 0/1 map (edge-clamped), radius 3σ.
fn blur(map: &[bool], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let (r, k) = gaussian_taps(sigma);
    let src: Vec<f32> = map.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect();
    let mut tmp = vec![0f32; w * h];
    if w == 0 {
        return tmp;
    }
    // Rows in parallel, and tap by tap along a row (vectorised): each pixel's sum keeps the
    // tap order of the plain per-pixel loop, so the result is bitwise that loop's.
    let ri = r as usize;
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let s = &src[y * w..(y + 1) * w];
        if w > 2 * ri {
            let len = w - 2 * ri;
            for (j, &kv) in k.iter().enumerate() {
                for (o, &v) in row[ri..ri + len].iter_mut().zip(&s[j..j + len]) {
                    *o += kv * v;
                }
            }
        }
        // The first and last r pixels read clamped neighbours (all pixels if the row is short).
        let border = (0..ri.min(w)).chain(w.saturating_sub(ri).max(ri.min(w))..w);
        let border: Vec<usize> = if w > 2 * ri {
            border.collect()
        } else {
            (0..w).collect()
        };
        for x in border {
            let mut acc = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let xx = (x as isize + j as isize - r).clamp(0, w as isize - 1) as usize;
                acc += kv * s[xx];
            }
            row[x] = acc;
        }
    });
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (j, &kv) in k.iter().enumerate() {
            let yy = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize;
            for (o, &v) in row.iter_mut().zip(&tmp[yy * w..(yy + 1) * w]) {
                *o += kv * v;
            }
        }
    });
    out
}

/// Per-pixel sampling probability (§4.1): a uniform base plus the blurred contour map with
/// the contour itself removed ("around the edges, but not on the edges"), scaled so the
/// expected count is `rate × pixels` (before clamping to 1). Contour pixels get 0: F&P04
/// call this critical because the interpolation looks for discontinuities between samples.
#[must_use]
pub fn probability_map(contour: &[bool], w: u32, h: u32, rate: f32) -> Vec<f32> {
    let (wu, hu) = (w as usize, h as usize);
    let n = wu * hu;
    let rate = f64::from(rate.clamp(0.0, 1.0));
    if n == 0 {
        return Vec::new();
    }
    let mut g = blur(contour, wu, hu, EDGE_SIGMA);
    for (v, &c) in g.iter_mut().zip(contour) {
        if c {
            *v = 0.0;
        }
    }
    let free = contour.iter().filter(|&&c| !c).count().max(1) as f64;
    let target = rate * n as f64;
    let gsum: f64 = g.iter().map(|&v| f64::from(v)).sum();
    let (base, edge_scale) = if gsum > 0.0 {
        (
            BASE_SHARE * target / free,
            (1.0 - BASE_SHARE) * target / gsum,
        )
    } else {
        (target / free, 0.0)
    };
    g.iter()
        .zip(contour)
        .map(|(&v, &c)| {
            if c {
                0.0
            } else {
                (base + edge_scale * f64::from(v)).min(1.0) as f32
            }
        })
        .collect()
}

/// The first sample set: a deterministic per-pixel draw (row-major, PCG seeded from
/// `seed`) against [`probability_map`], plus the four image corners, always, so the
/// Delaunay triangulation covers the whole image (every pixel centre lies in the hull).
#[must_use]
pub fn initial_samples(ids: &Image<ObjectId>, rate: f32, seed: u64) -> Vec<PixelCoord> {
    let (w, h) = (ids.width(), ids.height());
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let contour = contour_map(ids);
    let prob = probability_map(&contour, w, h, rate);
    let mut rng = Pcg64::seed_from_u64(seed ^ 0x5EED_F1E5_7000_0001);
    let mut chosen = vec![false; prob.len()];
    for (c, &p) in chosen.iter_mut().zip(&prob) {
        let r: f32 = rng.random();
        *c = r < p;
    }
    for (x, y) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)] {
        chosen[ids.index(x, y)] = true;
    }
    chosen
        .iter()
        .enumerate()
        .filter(|(_, &c)| c)
        .map(|(i, _)| PixelCoord::new((i % w as usize) as u32, (i / w as usize) as u32))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Left half object 0, right half object 1: a vertical edge at x = 31|32.
    fn split_ids(w: u32, h: u32) -> Image<ObjectId> {
        Image::from_fn(w, h, |x, _| u32::from(x >= w / 2))
    }

    #[test]
    fn contour_marks_both_sides_of_an_id_change() {
        let ids = split_ids(8, 3);
        let c = contour_map(&ids);
        for y in 0..3 {
            for x in 0..8 {
                assert_eq!(c[(y * 8 + x) as usize], x == 3 || x == 4);
            }
        }
    }

    #[test]
    fn probability_is_zero_on_edges_higher_near_them_and_sums_to_the_rate() {
        let (w, h) = (64u32, 64u32);
        let ids = split_ids(w, h);
        let c = contour_map(&ids);
        let p = probability_map(&c, w, h, 0.02);
        let at = |x: u32, y: u32| p[(y * w + x) as usize];
        assert_eq!(at(31, 10), 0.0);
        assert_eq!(at(32, 10), 0.0);
        assert!(
            at(30, 10) > 3.0 * at(5, 10),
            "{} vs {}",
            at(30, 10),
            at(5, 10)
        );
        let sum: f64 = p.iter().map(|&v| f64::from(v)).sum();
        let target = 0.02 * f64::from(w * h);
        assert!((sum - target).abs() < 0.02 * target, "{sum} vs {target}");
    }

    #[test]
    fn the_blur_is_bitwise_the_plain_per_pixel_loop() {
        // The plain loop: each pixel sums its clamped taps in order, one pass per axis.
        fn plain(map: &[bool], w: usize, h: usize, sigma: f32) -> Vec<f32> {
            let (r, k) = gaussian_taps(sigma);
            let at = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
            let src: Vec<f32> = map.iter().map(|&b| f32::from(u8::from(b))).collect();
            let mut tmp = vec![0f32; w * h];
            let mut out = vec![0f32; w * h];
            for y in 0..h {
                for x in 0..w {
                    let mut s = 0.0;
                    for (j, kv) in k.iter().enumerate() {
                        s += kv * src[y * w + at(x as isize + j as isize - r, w)];
                    }
                    tmp[y * w + x] = s;
                }
            }
            for y in 0..h {
                for x in 0..w {
                    let mut s = 0.0;
                    for (j, kv) in k.iter().enumerate() {
                        s += kv * tmp[at(y as isize + j as isize - r, h) * w + x];
                    }
                    out[y * w + x] = s;
                }
            }
            out
        }
        // Rows longer than the kernel, exactly 2r + 1, shorter, and a single pixel.
        for (w, h) in [(40usize, 23usize), (13, 13), (7, 30), (1, 1), (30, 1)] {
            let map: Vec<bool> = (0..w * h).map(|i| (i * 7 + i / w) % 11 < 3).collect();
            let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
            assert_eq!(
                bits(blur(&map, w, h, EDGE_SIGMA)),
                bits(plain(&map, w, h, EDGE_SIGMA)),
                "{w}x{h}"
            );
        }
    }

    #[test]
    fn the_first_sample_set_does_not_depend_on_the_thread_count() {
        // Two discs and a bar: curved and straight contours, several ids.
        let ids = Image::from_fn(97, 61, |x, y| {
            let d = |cx: i64, cy: i64| (i64::from(x) - cx).pow(2) + (i64::from(y) - cy).pow(2);
            if d(30, 30) < 300 {
                1
            } else if d(70, 20) < 120 {
                2
            } else {
                u32::from(y > 50) * 3
            }
        });
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                (
                    probability_map(&contour_map(&ids), 97, 61, 0.05),
                    initial_samples(&ids, 0.05, 7),
                )
            })
        };
        let (p1, s1) = run(1);
        for threads in [2, 5] {
            let (p, s) = run(threads);
            assert!(p.iter().zip(&p1).all(|(a, b)| a.to_bits() == b.to_bits()));
            assert_eq!(s, s1, "{threads} threads");
        }
        assert!(s1.len() > 100, "{}", s1.len());
    }

    #[test]
    fn no_edges_gives_the_uniform_rate_and_corners_are_always_in() {
        let ids = Image::filled(50, 40, 7u32);
        let s = initial_samples(&ids, 0.0, 1);
        assert_eq!(s.len(), 4);
        let s = initial_samples(&ids, 0.05, 1);
        assert!(s.len() > 60 && s.len() < 160, "{}", s.len());
        assert_eq!(s, initial_samples(&ids, 0.05, 1), "deterministic");
        assert_ne!(s, initial_samples(&ids, 0.05, 2));
        let one = initial_samples(&Image::filled(1, 1, 0u32), 0.01, 3);
        assert_eq!(one, vec![PixelCoord::new(0, 0)]);
    }
}
