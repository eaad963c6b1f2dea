//! The independent judge: NVIDIA's LDR-FLIP (Andersson et al. 2020) through the `nv-flip`
//! crate, on the display-referred images a person sees (vision-model.md §5.4: judge what
//! the user sees, LDR-FLIP at the scene's pixels per degree, not FLIP's default 67).

use crate::raster::{codec::to_display_rgb8, LinearImage};

/// Mean FLIP and 99th weighted percentile between a reference and a test image.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct FlipScore {
    pub mean: f64,
    pub p99: f64,
}

/// LDR-FLIP of `test` against `reference`, both shown with `exposure` at `ppd`.
#[must_use]
pub fn flip(reference: &LinearImage, test: &LinearImage, exposure: f32, ppd: f32) -> FlipScore {
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
    FlipScore {
        mean: f64::from(pool.mean()),
        p99: f64::from(pool.get_percentile(0.99, true)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::{Image, Rgb};

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
}
