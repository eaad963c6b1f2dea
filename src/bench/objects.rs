//! "Objects keep their colour": over the pixels of each object the object-id
//! map gives, the progressive image's mean linear radiance must be within the larger of
//! 6 % and 3 × the reference's own error of the converged render's (the truth's).
//!
//! The error is **luminance-weighted**: Σ_c w_c |p_c − t_c| / Σ_c w_c t_c with Rec.709's
//! luminance weights w = (0.2126, 0.7152, 0.0722). A plain per-channel relative error
//! would divide by a near-zero channel on any saturated object (the blue of a red wall)
//! and fail it on noise no one can see; this one counts each channel's error in
//! proportion to what it adds to the brightness, so a hue shift still counts.

use crate::raster::{Image, LinearImage};
use crate::scene::{ObjectId, BACKGROUND_ID};
use serde::Serialize;

/// Objects covering less of the image than this are not judged (0.5 %).
pub const MIN_COVERAGE: f64 = 0.005;
/// The smallest allowed error (6 %).
pub const MIN_TOLERANCE: f64 = 0.06;
/// The allowed error grows to this many times the reference's own error (3×).
pub const REFERENCE_FACTOR: f64 = 3.0;
/// Rec.709 luminance weights (linear RGB).
const LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];
/// Below this displayed mean luminance (linear, after exposure: 1/1000 of display white)
/// a relative error means nothing; the denominator is floored there.
const DARK_FLOOR: f64 = 1e-3;

/// One judged object.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ObjectColour {
    pub object: ObjectId,
    /// Share of the image's pixels.
    pub coverage: f64,
    /// Luminance-weighted relative error of the progressive image's mean.
    pub progressive_error: f64,
    /// The same for the reference (its own Monte Carlo error).
    pub reference_error: f64,
    /// max([`MIN_TOLERANCE`], [`REFERENCE_FACTOR`] × `reference_error`).
    pub allowed: f64,
}

impl ObjectColour {
    /// `progressive_error / allowed`: ≤ 1 passes.
    #[must_use]
    pub fn ratio(&self) -> f64 {
        self.progressive_error / self.allowed
    }
}

/// Every object covering at least [`MIN_COVERAGE`] of the image, in object-id order
/// (the background, [`BACKGROUND_ID`], is not an object). `exposure` only sets the dark
/// floor of the relative error.
#[must_use]
pub fn object_colours(
    ids: &Image<ObjectId>,
    progressive: &LinearImage,
    reference: &LinearImage,
    truth: &LinearImage,
    exposure: f32,
) -> Vec<ObjectColour> {
    assert!(
        [progressive, reference, truth]
            .iter()
            .all(|i| (i.width(), i.height()) == (ids.width(), ids.height())),
        "the object-id map and the images have one size"
    );
    // Per object: pixel count and the three images' channel sums, in f64 (a 512² sum of
    // f32 loses the last digits the 6 % test needs on dark objects).
    let mut sums: std::collections::BTreeMap<ObjectId, (u64, [[f64; 3]; 3])> =
        std::collections::BTreeMap::new();
    for (i, &id) in ids.pixels().iter().enumerate() {
        if id == BACKGROUND_ID {
            continue;
        }
        let e = sums.entry(id).or_insert((0, [[0.0; 3]; 3]));
        e.0 += 1;
        for (acc, img) in e.1.iter_mut().zip([progressive, reference, truth]) {
            let p = img.pixels()[i];
            for (a, v) in acc.iter_mut().zip([p.x, p.y, p.z]) {
                *a += f64::from(v);
            }
        }
    }
    let total = ids.len().max(1) as f64;
    let floor = DARK_FLOOR / f64::from(exposure).max(f64::MIN_POSITIVE);
    sums.into_iter()
        .filter(|(_, (n, _))| *n as f64 / total >= MIN_COVERAGE)
        .map(|(object, (n, [p, r, t]))| {
            let mean = |s: [f64; 3]| s.map(|v| v / n as f64);
            let (p, r, t) = (mean(p), mean(r), mean(t));
            let progressive_error = relative_error(p, t, floor);
            let reference_error = relative_error(r, t, floor);
            ObjectColour {
                object,
                coverage: n as f64 / total,
                progressive_error,
                reference_error,
                allowed: MIN_TOLERANCE.max(REFERENCE_FACTOR * reference_error),
            }
        })
        .collect()
}

/// Luminance-weighted relative error of `test` against `truth` (module docs), the
/// denominator floored at `floor`.
fn relative_error(test: [f64; 3], truth: [f64; 3], floor: f64) -> f64 {
    let diff: f64 = (0..3).map(|c| LUMA[c] * (test[c] - truth[c]).abs()).sum();
    let lum: f64 = (0..3).map(|c| LUMA[c] * truth[c]).sum();
    diff / lum.max(floor)
}

/// The worst object's `ratio` (0 when no object is large enough to judge).
#[must_use]
pub fn worst_ratio(objects: &[ObjectColour]) -> f64 {
    objects.iter().map(ObjectColour::ratio).fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Rgb;

    fn rgb(r: f32, g: f32, b: f32) -> Rgb {
        Rgb::new(r, g, b)
    }

    /// 20×10: object 0 the left half, object 1 the right half but one column, and one
    /// background column (the background is never judged).
    fn ids() -> Image<ObjectId> {
        Image::from_fn(20, 10, |x, _| match x {
            0..=9 => 0,
            10..=18 => 1,
            _ => BACKGROUND_ID,
        })
    }

    fn split(left: Rgb, right: Rgb) -> LinearImage {
        Image::from_fn(20, 10, |x, _| if x < 10 { left } else { right })
    }

    #[test]
    fn exact_images_pass_with_zero_error_and_the_background_is_skipped() {
        let t = split(rgb(0.5, 0.2, 0.1), rgb(0.1, 0.1, 0.8));
        let o = object_colours(&ids(), &t, &t, &t, 1.0);
        assert_eq!(o.iter().map(|c| c.object).collect::<Vec<_>>(), [0, 1]);
        assert!((o[0].coverage - 0.5).abs() < 1e-12 && (o[1].coverage - 0.45).abs() < 1e-12);
        for c in &o {
            assert_eq!((c.progressive_error, c.reference_error), (0.0, 0.0));
            assert_eq!(c.allowed, MIN_TOLERANCE);
        }
        assert_eq!(worst_ratio(&o), 0.0);
    }

    #[test]
    fn a_grey_object_five_percent_dark_passes_and_seven_percent_fails() {
        let t = split(Rgb::splat(0.4), Rgb::splat(0.4));
        let o = object_colours(
            &ids(),
            &split(Rgb::splat(0.38), Rgb::splat(0.4)),
            &t,
            &t,
            1.0,
        );
        assert!((o[0].progressive_error - 0.05).abs() < 1e-6, "{o:?}");
        assert!(worst_ratio(&o) <= 1.0);
        let o = object_colours(
            &ids(),
            &split(Rgb::splat(0.372), Rgb::splat(0.4)),
            &t,
            &t,
            1.0,
        );
        assert!((o[0].progressive_error - 0.07).abs() < 1e-6, "{o:?}");
        assert!(worst_ratio(&o) > 1.0 && (worst_ratio(&o) - 0.07 / 0.06).abs() < 1e-5);
    }

    #[test]
    fn the_tolerance_grows_with_the_references_own_error() {
        let t = split(Rgb::splat(0.5), Rgb::splat(0.5));
        // The reference is 4 % off on object 0: 3 × 4 % = 12 % is allowed there.
        let r = split(Rgb::splat(0.52), Rgb::splat(0.5));
        let p = split(Rgb::splat(0.45), Rgb::splat(0.5));
        let o = object_colours(&ids(), &p, &r, &t, 1.0);
        assert!((o[0].allowed - 0.12).abs() < 1e-6, "{o:?}");
        assert!((o[0].ratio() - 0.10 / 0.12).abs() < 1e-5, "{o:?}");
    }

    #[test]
    fn the_error_weighs_channels_by_luminance_and_dark_objects_are_floored() {
        // A red object: its blue channel doubling (0.01 → 0.02) is a tiny error, its green
        // channel off by the same amount weighs ten times more.
        let t = split(rgb(0.6, 0.05, 0.01), Rgb::splat(0.3));
        let blue = object_colours(
            &ids(),
            &split(rgb(0.6, 0.05, 0.02), Rgb::splat(0.3)),
            &t,
            &t,
            1.0,
        );
        let green = object_colours(
            &ids(),
            &split(rgb(0.6, 0.06, 0.01), Rgb::splat(0.3)),
            &t,
            &t,
            1.0,
        );
        let lum = 0.2126 * 0.6 + 0.7152 * 0.05 + 0.0722 * 0.01;
        assert!((blue[0].progressive_error - 0.0722 * 0.01 / lum).abs() < 1e-6);
        assert!(green[0].progressive_error > 9.0 * blue[0].progressive_error);
        // A black object (truth 0) is judged against the floor, not divided by zero.
        let t = split(Rgb::ZERO, Rgb::splat(0.3));
        let o = object_colours(
            &ids(),
            &split(Rgb::splat(1e-5), Rgb::splat(0.3)),
            &t,
            &t,
            1.0,
        );
        assert!(o[0].progressive_error.is_finite() && o[0].progressive_error < 0.06);
    }

    #[test]
    fn objects_under_half_a_percent_are_not_judged() {
        // 200×100 image, object 7 covers 99 pixels (0.495 %), object 8 the rest.
        let ids = Image::from_fn(200, 100, |x, y| if y == 0 && x < 99 { 7 } else { 8 });
        let t = Image::filled(200, 100, Rgb::splat(0.5));
        let o = object_colours(&ids, &Image::filled(200, 100, Rgb::ZERO), &t, &t, 1.0);
        assert_eq!(o.iter().map(|c| c.object).collect::<Vec<_>>(), [8]);
    }
}
