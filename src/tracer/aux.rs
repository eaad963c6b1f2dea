//! The denoiser's auxiliary images (OIDN `RT` filter: `albedo`, `normal`), one
//! [`PixelOracle::aux_features`] per pixel.

use super::{per_pixel, AuxFeatures, PixelOracle};
use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage, PixelCoord};

/// The albedo and normal images of a whole frame.
#[derive(Clone, Debug)]
pub struct AuxMaps {
    pub albedo: LinearImage,
    pub normal: LinearImage,
}

/// Every pixel's [`PixelOracle::aux_features`], in parallel batches, cancellable.
pub fn aux_maps(oracle: &impl PixelOracle, cancel: &CancelToken) -> Result<AuxMaps, Cancelled> {
    let (w, h) = oracle.size();
    let pixels: Vec<PixelCoord> = (0..h)
        .flat_map(|y| (0..w).map(move |x| PixelCoord { x, y }))
        .collect();
    let features = per_pixel(&pixels, cancel, |p| oracle.aux_features(p))?;
    let image = |f: fn(&AuxFeatures) -> glam::Vec3| {
        Image::from_vec(w, h, features.iter().map(f).collect()).expect("one feature per pixel")
    };
    Ok(AuxMaps {
        albedo: image(|a| a.albedo),
        normal: image(|a| a.normal),
    })
}
