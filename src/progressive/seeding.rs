//! The first sample set (F&P04 §4.1): denser around the contours of the object-id map,
//! but not on them.

use crate::raster::{Image, PixelCoord};
use crate::scene::ObjectId;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// σ of the edge-avoiding filter, in pixels: the samples land within a few pixels of an
/// object boundary, on both sides of it ([D]; F&P04 only say "gaussian-like").
pub const EDGE_SIGMA: f32 = 2.0;

/// Share of the sample budget spread uniformly; the rest follows the edge filter ([D]).
pub const BASE_SHARE: f64 = 0.5;

/// Contour map: pixels with a 4-neighbour of a different object id (§4.1).
#[must_use]
pub fn contour_map(ids: &Image<ObjectId>) -> Vec<bool> {
    let (w, h) = (ids.width(), ids.height());
    let mut out = vec![false; ids.len()];
    for y in 0..h {
        for x in 0..w {
            let id = *ids.get(x, y);
            let differs = (x > 0 && *ids.get(x - 1, y) != id)
                || (x + 1 < w && *ids.get(x + 1, y) != id)
                || (y > 0 && *ids.get(x, y - 1) != id)
                || (y + 1 < h && *ids.get(x, y + 1) != id);
            out[ids.index(x, y)] = differs;
        }
    }
    out
}

/// Separable Gaussian blur of a 0/1 map (edge-clamped), radius 3σ.
fn blur(map: &[bool], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let ks: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| v / ks).collect();
    let src: Vec<f32> = map.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect();
    let mut tmp = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let xx = (x as isize + j as isize - r).clamp(0, w as isize - 1) as usize;
                s += kv * src[y * w + xx];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let yy = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize;
                s += kv * tmp[yy * w + x];
            }
            out[y * w + x] = s;
        }
    }
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
