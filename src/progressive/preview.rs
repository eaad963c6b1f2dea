//! A first picture within a few hundred milliseconds at any image size. The loop's first
//! frame needs the object-id map and the normals (two primary rays per pixel) and the
//! first sample set at the scene's samples per pixel: 1.4 s at 1024×768 and 4 s at 2048²
//! on two cores. Before that, a coarse grid of pixels is traced with a few samples each
//! and interpolated bilinearly: a blurred, noisy but honest picture of the scene, shown and
//! never judged (the loop's first frame replaces it; nothing of it is reused).

use super::noise::Twin;
use super::{ClassCell, Frame, RenderStats, SampleCell};
use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage, PixelCoord, Rgb};
use crate::scene::BACKGROUND_ID;
use crate::tracer::{self, PixelOracle};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

/// Images with fewer pixels get no preview: their first frame comes about as fast
/// (76 ms at 320×240 on two cores).
pub const FROM_PIXELS: usize = 1 << 18;

/// Grid points traced, about, whatever the image size: the preview's cost is this many
/// times [`SAMPLES`] paths.
const POINTS: f64 = 1024.0;

/// Samples per grid point, at most the scene's.
const SAMPLES: u32 = 4;

/// How much brighter than every neighbour a grid point may be (a peak of the picture
/// itself, a highlight, rarely stands out more between points a grid cell apart).
const SPECKLE: f32 = 2.0;

/// Its own seed, so no estimate of the render repeats the preview's paths.
const SEED: u64 = 0x7072_6576_6965_7721;

/// The preview of a `w × h` image: grid points `spacing` pixels apart traced with
/// `min(samples, SAMPLES)` paths each, despeckled ([`despeckle`]) and interpolated.
pub fn preview(
    oracle: &impl PixelOracle,
    samples: u32,
    seed: u64,
    cancel: &CancelToken,
) -> Result<LinearImage, Cancelled> {
    let (w, h) = oracle.size();
    let grid = Grid::new(w, h);
    let twin = Twin {
        inner: oracle,
        samples: samples.clamp(1, SAMPLES),
        seed: seed ^ SEED,
    };
    let values = tracer::trace_pixels(&twin, &grid.points(), cancel)?;
    let values = despeckle(&grid, &values);
    Ok(grid.interpolate(&values))
}

/// The preview as a frame of a render in `mode` (iteration 0, `preview`, nothing traced):
/// only its image means anything; the other layers are the cheapest valid ones (a
/// 2048² frame's layers are ~70 MB, and this frame is on the path to the first picture).
pub fn frame(
    oracle: &impl PixelOracle,
    samples: u32,
    seed: u64,
    mode: &str,
    cancel: &CancelToken,
) -> Result<Frame, Cancelled> {
    let start = Instant::now();
    let image = preview(oracle, samples, seed, cancel)?;
    let (w, h) = oracle.size();
    let ms = start.elapsed().as_secs_f64() * 1e3;
    Ok(Frame {
        iteration: 0,
        image,
        samples: Image::filled(w, h, SampleCell::Interpolated),
        distance: None,
        classes: Image::filled(w, h, ClassCell::None),
        objects: Arc::new(Image::filled(w, h, BACKGROUND_ID)),
        stats: RenderStats {
            mode: mode.into(),
            width: w,
            height: h,
            trace_ms: ms,
            total_ms: ms,
            ..RenderStats::default()
        },
        last: false,
        preview: true,
    })
}

/// Grid points every `spacing` pixels along each axis, and the last row and column.
struct Grid {
    w: u32,
    h: u32,
    spacing: u32,
    /// Points per row and per column.
    nx: usize,
    ny: usize,
}

impl Grid {
    fn new(w: u32, h: u32) -> Self {
        let n = f64::from(w) * f64::from(h);
        let spacing = (n / POINTS).sqrt().ceil().max(1.0) as u32;
        let along = |len: u32| (len.saturating_sub(1)).div_ceil(spacing) as usize + 1;
        Self {
            w,
            h,
            spacing,
            nx: along(w),
            ny: along(h),
        }
    }

    /// Coordinate of grid line `k` along an axis `len` pixels long.
    fn at(&self, k: usize, len: u32) -> u32 {
        (k as u32 * self.spacing).min(len.saturating_sub(1))
    }

    fn points(&self) -> Vec<PixelCoord> {
        (0..self.ny)
            .flat_map(|j| (0..self.nx).map(move |i| (i, j)))
            .map(|(i, j)| PixelCoord::new(self.at(i, self.w), self.at(j, self.h)))
            .collect()
    }

    /// Bilinear interpolation of the grid's `values` (row-major) over every pixel.
    fn interpolate(&self, values: &[Rgb]) -> LinearImage {
        let (w, h) = (self.w as usize, self.h as usize);
        let mut out = vec![Rgb::ZERO; w * h];
        let axis = |p: usize, len: u32, count: usize| {
            let k = (p / self.spacing as usize).min(count.saturating_sub(2));
            let (a, b) = (self.at(k, len), self.at(k + 1, len));
            let t = if b > a {
                (p as f32 - a as f32) / (b - a) as f32
            } else {
                0.0
            };
            (k, (k + 1).min(count - 1), t.clamp(0.0, 1.0))
        };
        let columns: Vec<(usize, usize, f32)> = (0..w).map(|x| axis(x, self.w, self.nx)).collect();
        // Each grid row interpolated along x once (ny × w values), then every image row
        // is one blend of two of them: the same arithmetic, in the same order, as blending
        // the four corners per pixel, for a third of the work on the path to the first
        // picture (48 MB written at 2048²).
        let lines: Vec<Vec<Rgb>> = (0..self.ny)
            .into_par_iter()
            .map(|j| {
                let r = &values[j * self.nx..];
                columns
                    .iter()
                    .map(|&(i0, i1, tx)| r[i0] * (1.0 - tx) + r[i1] * tx)
                    .collect()
            })
            .collect();
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let (j0, j1, ty) = axis(y, self.h, self.ny);
            let (top, bottom) = (&lines[j0], &lines[j1]);
            for ((px, &t), &b) in row.iter_mut().zip(top).zip(bottom) {
                *px = t * (1.0 - ty) + b * ty;
            }
        });
        Image::from_vec(self.w, self.h, out).expect("size matches by construction")
    }
}

/// A few paths per point leave fireflies, and interpolation would spread each over a
/// whole grid cell: a point more than [`SPECKLE`] times as bright as all its neighbours is
/// lowered to that (per channel). Non-finite values become 0 (vision-model.md §2.9).
fn despeckle(grid: &Grid, values: &[Rgb]) -> Vec<Rgb> {
    let clean = |c: Rgb| {
        let f = |v: f32| if v.is_finite() { v.max(0.0) } else { 0.0 };
        Rgb::new(f(c.x), f(c.y), f(c.z))
    };
    let values: Vec<Rgb> = values.iter().map(|&c| clean(c)).collect();
    let (nx, ny) = (grid.nx as i64, grid.ny as i64);
    (0..values.len())
        .map(|k| {
            let (i, j) = ((k as i64) % nx, (k as i64) / nx);
            let mut cap = Rgb::splat(f32::NEG_INFINITY);
            for (di, dj) in [
                (-1, -1),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                let (a, b) = (i + di, j + dj);
                if (0..nx).contains(&a) && (0..ny).contains(&b) {
                    cap = cap.max(values[(b * nx + a) as usize]);
                }
            }
            if cap.x.is_finite() {
                values[k].min(cap * SPECKLE)
            } else {
                values[k]
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ObjectId;

    /// A linear ramp in x and y, with a firefly at one pixel, exact (no noise).
    struct Ramp(u32, u32);
    impl PixelOracle for Ramp {
        fn size(&self) -> (u32, u32) {
            (self.0, self.1)
        }
        fn radiance(&self, p: PixelCoord) -> Rgb {
            self.radiance_with(p, 1, 0)
        }
        fn radiance_with(&self, p: PixelCoord, _: u32, _: u64) -> Rgb {
            if (p.x, p.y) == (32, 32) {
                return Rgb::splat(1e6);
            }
            Rgb::new(p.x as f32 * 0.01, p.y as f32 * 0.02, 0.5)
        }
        fn object_id(&self, _: PixelCoord) -> ObjectId {
            0
        }
    }

    #[test]
    fn a_ramp_is_reproduced_exactly_and_a_firefly_is_not_spread() {
        for (w, h) in [(700, 500), (1024, 768), (1, 1), (3, 2), (400, 1)] {
            let img = preview(&Ramp(w, h), 32, 1, &CancelToken::new()).expect("not cancelled");
            assert_eq!((img.width(), img.height()), (w, h));
            for (x, y) in [(0, 0), (w - 1, h - 1), (w / 3, h / 2), (w - 1, 0)] {
                let want = Rgb::new(x as f32 * 0.01, y as f32 * 0.02, 0.5);
                let got = *img.get(x, y);
                if (w, h) == (1024, 768) && (x as i64 - 32).abs() < 64 && (y as i64 - 32).abs() < 64
                {
                    continue; // around the firefly, checked below
                }
                assert!(
                    (got - want).abs().max_element() < 1e-3,
                    "{w}×{h} at ({x}, {y}): {got} vs {want}"
                );
            }
            assert!(img.pixels().iter().all(|c| c.is_finite()));
        }
        // At 1024×768 the grid spacing is 28: (32, 32) is no grid point; at 700×500, 19.
        let g = Grid::new(1024, 768);
        assert_eq!(g.spacing, 28);
        let fly = Grid {
            w: 64,
            h: 64,
            spacing: 32,
            nx: 3,
            ny: 3,
        };
        let img = fly.interpolate(&despeckle(
            &fly,
            &fly.points()
                .iter()
                .map(|&p| Ramp(64, 64).radiance(p))
                .collect::<Vec<_>>(),
        ));
        assert!(
            img.get(32, 32).max_element() < 3.0,
            "the firefly is capped by its neighbours"
        );
    }

    #[test]
    fn interpolation_by_grid_rows_equals_blending_the_four_corners_bit_for_bit() {
        for (w, h) in [(2048, 2048), (1024, 768), (700, 500), (3, 2), (1, 1)] {
            let g = Grid::new(w, h);
            let values: Vec<Rgb> = (0..g.nx * g.ny)
                .map(|k| {
                    let k = k as f32;
                    Rgb::new(
                        (k * 0.37).sin().abs(),
                        (k * 1.3).cos().abs() * 3.0,
                        k * 1e-3,
                    )
                })
                .collect();
            let img = g.interpolate(&values);
            let corners = |p: usize, len: u32, count: usize| {
                let k = (p / g.spacing as usize).min(count.saturating_sub(2));
                let (a, b) = (g.at(k, len), g.at(k + 1, len));
                let t = if b > a {
                    (p as f32 - a as f32) / (b - a) as f32
                } else {
                    0.0
                };
                (k, (k + 1).min(count - 1), t.clamp(0.0, 1.0))
            };
            for (x, y) in [
                (0, 0),
                (w - 1, h - 1),
                (w / 3, h / 2),
                (w - 1, 0),
                (w / 7, h - 1),
            ] {
                let (i0, i1, tx) = corners(x as usize, w, g.nx);
                let (j0, j1, ty) = corners(y as usize, h, g.ny);
                let (r0, r1) = (&values[j0 * g.nx..], &values[j1 * g.nx..]);
                let top = r0[i0] * (1.0 - tx) + r0[i1] * tx;
                let bottom = r1[i0] * (1.0 - tx) + r1[i1] * tx;
                let want = top * (1.0 - ty) + bottom * ty;
                let got = *img.get(x, y);
                assert_eq!(
                    got.to_array().map(f32::to_bits),
                    want.to_array().map(f32::to_bits)
                );
            }
        }
    }

    #[test]
    fn it_costs_about_a_thousand_points_at_any_size() {
        for (w, h) in [(512, 512), (1024, 768), (2048, 2048), (4096, 4096)] {
            let g = Grid::new(w, h);
            let n = g.nx * g.ny;
            assert!((700..=1400).contains(&n), "{w}×{h}: {n} points");
        }
    }

    #[test]
    fn cancel_is_honoured() {
        let c = CancelToken::new();
        c.cancel();
        assert!(preview(&Ramp(600, 600), 4, 1, &c).is_err());
    }
}
