//! The independent judge: NVIDIA's LDR-FLIP (Andersson et al. 2020) through the `nv-flip`
//! crate, on the display-referred images a person sees (vision-model.md §5.4: judge what
//! the user sees, LDR-FLIP at the scene's pixels per degree, not FLIP's default 67).

use crate::raster::{codec::to_display_rgb8, Image, LinearImage};

/// Mean FLIP and 99th weighted percentile between a reference and a test image.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct FlipScore {
    pub mean: f64,
    pub p99: f64,
}

/// LDR-FLIP of `test` against `reference`, both shown with `exposure` at `ppd`.
#[must_use]
pub fn flip(reference: &LinearImage, test: &LinearImage, exposure: f32, ppd: f32) -> FlipScore {
    flip_with_map(reference, test, exposure, ppd).0
}

/// [`flip`] and FLIP's per-pixel error map (values in [0, 1], row-major), which the contact
/// sheet shows.
#[must_use]
pub fn flip_with_map(
    reference: &LinearImage,
    test: &LinearImage,
    exposure: f32,
    ppd: f32,
) -> (FlipScore, Image<f32>) {
    assert_eq!(
        (reference.width(), reference.height()),
        (test.width(), test.height()),
        "FLIP compares images of one size"
    );
    let pack = |img: &LinearImage| -> nv_flip::FlipImageRgb8 {
        let rgb = to_display_rgb8(img, exposure);
        let flat: Vec<u8> = rgb.pixels().iter().flatten().copied().collect();
        nv_flip::FlipImageRgb8::with_data(img.width(), img.height(), &flat)
    };
    let map = nv_flip::flip(pack(reference), pack(test), ppd);
    let mut pool = nv_flip::FlipPool::from_image(&map);
    let score = FlipScore {
        mean: f64::from(pool.mean()),
        p99: f64::from(pool.get_percentile(0.99, true)),
    };
    let errors = Image::from_vec(map.width(), map.height(), map.to_vec())
        .expect("nv-flip returns a map of the images' size");
    (score, errors)
}

/// FLIP's error map in its own magma colour scale (nv-flip's LUT: black for no error,
/// through purple and orange, to pale yellow for the largest), as FLIP's tools show it.
#[must_use]
pub fn magma(errors: &Image<f32>) -> Image<[u8; 3]> {
    let lut = nv_flip::magma_lut().to_vec();
    errors.map(|&e| {
        // The same index as nv-flip's own `apply_color_lut`: round(e × 255); NaN → 0.
        let i = (e.clamp(0.0, 1.0) * 255.0).round() as usize * 3;
        [lut[i], lut[i + 1], lut[i + 2]]
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Rgb;

    #[test]
    fn identical_images_score_zero_and_differences_score_more() {
        let a = Image::from_fn(32, 32, |x, y| Rgb::splat(((x + y) % 7) as f32 / 7.0));
        assert!(flip(&a, &a, 1.0, 28.0).mean < 1e-6);
        let b = a.map(|p| *p * 0.5);
        let c = a.map(|p| *p * 0.9);
        let (fb, fc) = (flip(&a, &b, 1.0, 28.0).mean, flip(&a, &c, 1.0, 28.0).mean);
        assert!(
            fb > fc && fc > 0.0,
            "halving ({fb}) must be worse than -10% ({fc})"
        );
    }

    #[test]
    fn the_map_matches_the_score_and_magma_spans_black_to_pale_yellow() {
        let a = Image::from_fn(24, 16, |x, _| Rgb::splat(x as f32 / 24.0));
        let b = a.map(|p| *p * 0.6);
        let (score, map) = flip_with_map(&a, &b, 1.0, 45.0);
        assert_eq!((map.width(), map.height()), (24, 16));
        let mean = map.pixels().iter().map(|&v| f64::from(v)).sum::<f64>() / map.len() as f64;
        assert!((mean - score.mean).abs() < 1e-4, "{mean} vs {}", score.mean);
        let c = magma(&Image::from_vec(2, 1, vec![0.0, 1.0]).unwrap());
        let (lo, hi) = (c.get(0, 0), c.get(1, 0));
        let sum = |p: &[u8; 3]| p.iter().map(|&v| u32::from(v)).sum::<u32>();
        assert!(sum(lo) < 30 && sum(hi) > 600, "{lo:?} {hi:?}");
    }
}
