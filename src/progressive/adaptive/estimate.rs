//! What a pass shows and how much error it still has that a person would see.
//!
//! The error of the (denoised) picture is estimated from two independent half images:
//! for Monte Carlo estimates A and B of equal count, the mean (A + B)/2 is off by about
//! (A − B)/2 (the half-buffer rule). With a denoiser D, each half is denoised on its
//! own and e ≈ (D(A) − D(B))/2: what the denoiser removed cancels out, what it could
//! not remove does not. The vision model then measures the distance between the picture
//! I and I + e at the scene's display and viewing distance (masking, adaptation, ppd):
//! the error a person would see, in JND, per pixel.

use crate::denoise::{Aux, DenoiseError, Denoiser, Quality, Run};
use crate::metric::{block_map, MetricParams};
use crate::raster::{Image, LinearImage, Rgb};
use crate::tracer::aux::AuxMaps;
use crate::vision::VisionModel;

/// How passes are reconstructed: as traced, or through the denoiser.
pub enum Filter<'a> {
    Raw,
    Denoised {
        denoiser: &'a Denoiser,
        aux: AuxMaps,
        /// How each denoise runs (its quality is [`Filter::apply`]'s).
        run: Run,
    },
}

impl Filter<'_> {
    /// `img` reconstructed at `quality` (the raw filter returns it as it is).
    pub fn apply(&self, img: &LinearImage, quality: Quality) -> Result<LinearImage, DenoiseError> {
        match self {
            Filter::Raw => Ok(img.clone()),
            Filter::Denoised { denoiser, aux, run } => {
                let aux = Aux {
                    albedo: &aux.albedo,
                    normal: &aux.normal,
                    clean: true,
                };
                let run = Run {
                    quality,
                    ..run.clone()
                };
                denoiser.denoise(img, Some(&aux), &run)
            }
        }
    }

    #[must_use]
    pub fn denoises(&self) -> bool {
        matches!(self, Filter::Denoised { .. })
    }
}

/// A pass's picture as the vision model judges it, and its estimated error.
pub struct Picture {
    /// (D(A) + D(B))/2: the picture of all the samples as far as masking and adaptation
    /// are concerned (the frame itself is D(A + B), reconstructed apart).
    pub image: LinearImage,
    /// Signed error estimate per pixel, (D(A) − D(B))/2.
    pub error: LinearImage,
}

/// The picture and its error from the two halves, each reconstructed at `quality`.
pub fn picture(
    halves: (&LinearImage, &LinearImage),
    filter: &Filter<'_>,
    quality: Quality,
) -> Result<Picture, DenoiseError> {
    let a = filter.apply(halves.0, quality)?;
    let b = filter.apply(halves.1, quality)?;
    let pair = |f: fn(Rgb, Rgb) -> Rgb| {
        Image::from_vec(
            a.width(),
            a.height(),
            a.pixels()
                .iter()
                .zip(b.pixels())
                .map(|(a, b)| f(*a, *b))
                .collect(),
        )
        .expect("halves of one size")
    };
    Ok(Picture {
        image: pair(|a, b| (a + b) * 0.5),
        error: pair(|a, b| (a - b) * 0.5),
    })
}

/// The error a person would see in `pic` (JND per pixel): the vision model's distance
/// between the picture and the picture plus its error, over the adaptive block map.
/// `None` when the model cannot judge the images (then every tile counts as unfinished).
#[must_use]
pub fn visible_error(
    model: &VisionModel,
    pic: &Picture,
    params: &MetricParams,
) -> Option<Image<f32>> {
    let sane = |v: Rgb| {
        let f = |c: f32| {
            if c.is_finite() {
                c.clamp(0.0, 1e8)
            } else {
                0.0
            }
        };
        Rgb::new(f(v.x), f(v.y), f(v.z))
    };
    let base = pic.image.map(|&v| sane(v));
    let off = Image::from_vec(
        base.width(),
        base.height(),
        base.pixels()
            .iter()
            .zip(pic.error.pixels())
            .map(|(&v, &e)| sane(v + e))
            .collect(),
    )?;
    let a = model.decompose(&base).ok()?;
    let b = model.decompose(&off).ok()?;
    Some(block_map(model, &a, &b, &[], params).map)
}

/// The error a person would see in the reference (every pixel at `max_spp`, not
/// denoised), predicted per pixel from the raw halves: their half-buffer error, scaled by
/// √(n / `max_spp`) at a pixel of n samples (Monte Carlo error falls as 1/√n), judged as
/// [`visible_error`] judges the picture's. The adaptive loop does not ask a tile for much
/// less error than the full render would leave there ([`super::REFERENCE_SHARE`] of it):
/// the promise is a picture no further from the truth than the reference.
#[must_use]
pub fn reference_visible(
    model: &VisionModel,
    raw: (&LinearImage, &LinearImage),
    counts: &Image<u32>,
    max_spp: u32,
    params: &MetricParams,
) -> Option<Image<f32>> {
    let pic = picture(raw, &Filter::Raw, Quality::Fast).ok()?;
    let max = f64::from(max_spp.max(1));
    let error = Image::from_vec(
        pic.error.width(),
        pic.error.height(),
        pic.error
            .pixels()
            .iter()
            .zip(counts.pixels())
            .map(|(&e, &n)| e * (f64::from(n) / max).sqrt().min(1.0) as f32)
            .collect(),
    )?;
    visible_error(model, &Picture { error, ..pic }, params)
}

/// Per-tile pooling of a per-pixel map: the mean over each `tile`×`tile` block,
/// row-major over the tiles.
#[must_use]
pub fn pool_mean(map: &Image<f32>, tile: u32) -> Vec<f32> {
    let (tw, th) = (map.width().div_ceil(tile), map.height().div_ceil(tile));
    let mut sum = vec![0f64; (tw * th) as usize];
    let mut n = vec![0u32; (tw * th) as usize];
    for y in 0..map.height() {
        for x in 0..map.width() {
            let t = ((y / tile) * tw + x / tile) as usize;
            let v = *map.get(x, y);
            sum[t] += if v.is_finite() { f64::from(v) } else { 1e6 };
            n[t] += 1;
        }
    }
    sum.iter()
        .zip(&n)
        .map(|(s, &k)| (s / f64::from(k.max(1))) as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pooling_averages_each_tile_and_keeps_partial_tiles() {
        let map = Image::from_fn(5, 3, |x, _| x as f32);
        // Tiles of 4: columns 0..4 (mean 1.5) and column 4 (mean 4).
        assert_eq!(pool_mean(&map, 4), [1.5, 4.0]);
    }

    #[test]
    fn the_reference_leaves_less_error_the_more_samples_it_has_left_to_add() {
        use crate::vision::DisplayModel;
        let (w, h) = (64, 64);
        let model = VisionModel::new(
            DisplayModel {
                peak_luminance: 100.0,
                black_luminance: 0.5,
                exposure: 1.0,
                pixels_per_degree: 40.0,
            },
            w,
            h,
        );
        // Two halves differing by a checker of ±0.1 around 0.3: visible noise at 8 spp.
        let a = Image::from_fn(w, h, |x, y| Rgb::splat(0.3 + 0.1 * ((x + y) % 2) as f32));
        let b = Image::from_fn(w, h, |x, y| {
            Rgb::splat(0.3 + 0.1 * ((x + y + 1) % 2) as f32)
        });
        let counts = Image::filled(w, h, 8u32);
        let params = MetricParams {
            homogeneity: 0.5,
            epsilon: 0.5,
            seed: 1,
        };
        let mean = |m: Image<f32>| m.pixels().iter().sum::<f32>() / m.len() as f32;
        let at = |max| mean(reference_visible(&model, (&a, &b), &counts, max, &params).unwrap());
        let (now, ref64, ref1024) = (at(8), at(64), at(1024));
        assert!(now > ref64 && ref64 > ref1024, "{now} {ref64} {ref1024}");
        // Fewer samples than already traced: the error is the picture's own, never more.
        assert_eq!(at(4), now);
    }

    #[test]
    fn raw_error_is_half_the_difference_of_the_halves() {
        let a = Image::filled(2, 2, Rgb::splat(1.0));
        let b = Image::filled(2, 2, Rgb::splat(0.5));
        let p = picture((&a, &b), &Filter::Raw, Quality::Fast).unwrap();
        assert!(p.image.pixels().iter().all(|v| *v == Rgb::splat(0.75)));
        assert!(p.error.pixels().iter().all(|e| *e == Rgb::splat(0.25)));
    }
}
