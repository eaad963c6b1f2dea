//! The interior of a complex triangle (F&P04 §4.2, spec §4.4): linear between the two
//! contour values met along one direction, the classifier's
//! ([`super::classifier::Classifier::fill_direction`]).

use super::classifier::Classifier;
use super::samples::SampleSet;
use crate::progressive::complex::{Boundary, ContourWalker};
use crate::progressive::guo;
use crate::progressive::mesh::{Raster, Tri, MIN_ALBEDO};
use crate::raster::{PixelCoord, Rgb};

/// Fills the untraced pixels of triangle `t` (of `raster`) in `out`. Left as shaded
/// (Gouraud) when the contour is not fully traced (a budget cut it) or has no rupture.
#[allow(clippy::too_many_arguments)]
pub(super) fn fill_complex(
    tr: &Tri,
    raster: &Raster,
    t: usize,
    samples: &SampleSet,
    classifier: &dyn Classifier,
    exposure: f32,
    contours: &mut ContourWalker,
    out: &mut [Rgb],
) {
    let s = samples;
    let w = s.w as usize;
    let contour = contours.walk(tr);
    if contour.iter().any(|c| !s.traced[s.index(c.p)]) {
        return;
    }
    let shown_at = |p: PixelCoord| guo::displayed(s.rad[s.index(p)], exposure);
    let shown: Vec<Rgb> = contour.iter().map(|c| shown_at(c.p)).collect();
    let Some(d) = classifier.fill_direction(tr, contour, &shown, &shown_at) else {
        return;
    };
    // On a textured surface the fill carries radiance ÷ albedo and multiplies each pixel's
    // albedo back, like `gouraud`: only when every pixel involved has a usable albedo.
    let usable = |i: usize| {
        s.albedo
            .as_deref()
            .and_then(|a| a[i])
            .filter(|a| a.min_element() >= MIN_ALBEDO)
    };
    let textured = s.albedo.is_some()
        && contour.iter().all(|c| usable(s.index(c.p)).is_some())
        && raster
            .pixels_of(t)
            .iter()
            .all(|&i| s.traced[i as usize] || usable(i as usize).is_some());
    let b = Boundary::new(tr, contour, |p| {
        let i = s.index(p);
        match usable(i).filter(|_| textured) {
            Some(a) => s.rad[i] / a,
            None => s.rad[i],
        }
    });
    for &i in raster.pixels_of(t) {
        let i = i as usize;
        if s.traced[i] {
            continue;
        }
        if let Some(v) = b.directional(((i % w) as f64, (i / w) as f64), d) {
            out[i] = match usable(i).filter(|_| textured) {
                Some(a) => v * a,
                None => v,
            };
        }
    }
}
