//! Pattanaik, Ferwerda, Fairchild & Greenberg (1998), used as an image metric
//! (shared/spec/vision-model.md §2). Owned by issue #3.
//!
//! The spatial decomposition runs on whole images ([`VisionModel::decompose`]); everything
//! after it is per pixel ([`VisionModel::distance_at`]), so the adaptive metric can
//! evaluate only chosen pixels.

use crate::raster::{Image, LinearImage};

/// The display a frame is shown on (scene-format.md `display`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DisplayModel {
    pub peak_luminance: f32,
    pub black_luminance: f32,
    pub exposure: f32,
    pub pixels_per_degree: f32,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VisionError {
    #[error("image has a non-finite value (NaN or infinity) at pixel ({x}, {y})")]
    NonFinite { x: u32, y: u32 },
    #[error("images differ in size: {a:?} vs {b:?}")]
    SizeMismatch { a: (u32, u32), b: (u32, u32) },
    #[error("image is empty")]
    Empty,
}

/// The model for one display and one image size (bands depend on both).
pub struct VisionModel {
    _private: (),
}

/// One image's multiscale decomposition (receptor pyramids), ready for per-pixel lookups.
pub struct ContrastStack {
    _private: (),
}

impl VisionModel {
    #[must_use]
    pub fn new(display: DisplayModel, width: u32, height: u32) -> Self {
        let _ = (display, width, height);
        todo!("issue #3")
    }

    /// Whole-image part of the model (§2.1–2.2). Refuses NaN/Inf.
    pub fn decompose(&self, img: &LinearImage) -> Result<ContrastStack, VisionError> {
        let _ = img;
        todo!("issue #3")
    }

    /// Perceptual distance in JNDs at pixel (x, y) between two decomposed images (§2.7).
    #[must_use]
    pub fn distance_at(&self, a: &ContrastStack, b: &ContrastStack, x: u32, y: u32) -> f32 {
        let _ = (a, b, x, y);
        todo!("issue #3")
    }

    /// Every pixel's distance (the full map, for comparison and tests).
    #[must_use]
    pub fn full_map(&self, a: &ContrastStack, b: &ContrastStack) -> Image<f32> {
        let _ = (a, b);
        todo!("issue #3")
    }
}
