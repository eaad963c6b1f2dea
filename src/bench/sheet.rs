//! The contact sheet a person looks at: reference | progressive | truth | FLIP
//! map of the progressive image against the truth, side by side in one PNG, each panel as
//! the display shows it (exposure, clamp, sRGB), small images enlarged by whole pixels so
//! blotches and grain are visible.

use super::flip::magma;
use crate::raster::{codec::to_display_rgb8, Image, LinearImage};

/// Pixels of white between panels.
const GAP: u32 = 4;
/// Panels are enlarged (nearest neighbour) until their long side reaches this, at most 4×.
const MIN_LONG_SIDE: u32 = 256;

/// The four panels in one image: reference | progressive | truth | FLIP map (magma).
#[must_use]
pub fn contact_sheet(
    reference: &LinearImage,
    progressive: &LinearImage,
    truth: &LinearImage,
    flip_map: &Image<f32>,
    exposure: f32,
) -> Image<[u8; 3]> {
    let panels = [
        to_display_rgb8(reference, exposure),
        to_display_rgb8(progressive, exposure),
        to_display_rgb8(truth, exposure),
        magma(flip_map),
    ];
    let (w, h) = (reference.width(), reference.height());
    assert!(
        panels.iter().all(|p| (p.width(), p.height()) == (w, h)),
        "the panels have one size"
    );
    let k = enlargement(w, h);
    let (pw, ph) = (w * k, h * k);
    let n = panels.len() as u32;
    Image::from_fn(n * pw + (n - 1) * GAP, ph, |x, y| {
        let (i, px) = (x / (pw + GAP), x % (pw + GAP));
        if px >= pw {
            [255; 3]
        } else {
            *panels[i as usize].get(px / k, y / k)
        }
    })
}

/// The whole-pixel factor for a `w × h` panel ([`MIN_LONG_SIDE`], at most 4).
fn enlargement(w: u32, h: u32) -> u32 {
    let long = w.max(h).max(1);
    MIN_LONG_SIDE.div_ceil(long).clamp(1, 4)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Rgb;

    #[test]
    fn panels_sit_side_by_side_in_order_enlarged_by_whole_pixels() {
        let (w, h) = (64, 32);
        let grey = |v: f32| Image::filled(w, h, Rgb::splat(v));
        let map = Image::filled(w, h, 1.0f32);
        let s = contact_sheet(&grey(0.0), &grey(0.5), &grey(1.0), &map, 1.0);
        // 64 → 256: 4× (the cap).
        assert_eq!((s.width(), s.height()), (4 * 256 + 3 * GAP, 128));
        let at = |panel: u32| *s.get(panel * (256 + GAP) + 100, 77);
        assert_eq!(at(0), [0; 3]);
        assert_eq!(at(1), [188; 3], "0.5 linear shown as sRGB");
        assert_eq!(at(2), [255; 3]);
        assert_eq!(at(3), *magma(&map).get(0, 0));
        assert_eq!(*s.get(256, 0), [255; 3], "the gap");
    }

    #[test]
    fn enlargement_reaches_the_long_side_and_never_shrinks() {
        assert_eq!(enlargement(96, 64), 3);
        assert_eq!(enlargement(128, 128), 2);
        assert_eq!(enlargement(512, 384), 1);
        assert_eq!(enlargement(1, 1), 4);
    }
}
