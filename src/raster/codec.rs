//! PNG and EXR encoding and decoding, in memory (callers do the file IO).

use super::{srgb_decode, srgb_encode, Image, LinearImage, Rgb};
use image::{ImageFormat, Rgb32FImage, RgbImage};
use std::io::Cursor;

#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error("could not decode image: {0}")]
    Decode(String),
    #[error("could not encode image: {0}")]
    Encode(String),
    #[error("image is empty (0 pixels)")]
    Empty,
}

/// Encodes 8-bit RGB pixels as PNG.
pub fn encode_png_rgb8(img: &Image<[u8; 3]>) -> Result<Vec<u8>, CodecError> {
    let flat: Vec<u8> = img.pixels().iter().flatten().copied().collect();
    let buf = RgbImage::from_raw(img.width(), img.height(), flat)
        .ok_or_else(|| CodecError::Encode("buffer size mismatch".into()))?;
    let mut out = Cursor::new(Vec::new());
    buf.write_to(&mut out, ImageFormat::Png)
        .map_err(|e| CodecError::Encode(e.to_string()))?;
    Ok(out.into_inner())
}

/// The display encoding of scene-format.md: linear value × `exposure`, clamped to [0, 1],
/// then the sRGB transfer curve. NaN becomes 0 (never propagated into a file).
#[must_use]
pub fn to_display_rgb8(img: &LinearImage, exposure: f32) -> Image<[u8; 3]> {
    let q = |v: f32| (srgb_encode(v * exposure) * 255.0 + 0.5) as u8;
    img.map(|p| [q(p.x), q(p.y), q(p.z)])
}

/// PNG of a linear image as a person sees it on the scene's display.
pub fn encode_png_display(img: &LinearImage, exposure: f32) -> Result<Vec<u8>, CodecError> {
    encode_png_rgb8(&to_display_rgb8(img, exposure))
}

/// Linear half/float OpenEXR of the raw radiance (no exposure, no clamp).
pub fn encode_exr(img: &LinearImage) -> Result<Vec<u8>, CodecError> {
    let flat: Vec<f32> = img.pixels().iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    let buf = Rgb32FImage::from_raw(img.width(), img.height(), flat)
        .ok_or_else(|| CodecError::Encode("buffer size mismatch".into()))?;
    let mut out = Cursor::new(Vec::new());
    buf.write_to(&mut out, ImageFormat::OpenExr)
        .map_err(|e| CodecError::Encode(e.to_string()))?;
    Ok(out.into_inner())
}

/// Decodes PNG (as sRGB, to linear [0, 1]) or EXR (linear values as stored).
pub fn decode_image(bytes: &[u8]) -> Result<LinearImage, CodecError> {
    let fmt = image::guess_format(bytes).map_err(|e| CodecError::Decode(e.to_string()))?;
    let dynimg = image::load_from_memory_with_format(bytes, fmt)
        .map_err(|e| CodecError::Decode(e.to_string()))?;
    if dynimg.width() == 0 || dynimg.height() == 0 {
        return Err(CodecError::Empty);
    }
    let img = match fmt {
        ImageFormat::OpenExr | ImageFormat::Hdr => {
            let f = dynimg.to_rgb32f();
            let (w, h) = f.dimensions();
            let data = f
                .pixels()
                .map(|p| Rgb::new(p.0[0], p.0[1], p.0[2]))
                .collect();
            Image::from_vec(w, h, data)
        }
        _ => {
            let b = dynimg.to_rgb8();
            let (w, h) = b.dimensions();
            let data = b
                .pixels()
                .map(|p| {
                    Rgb::new(
                        srgb_decode(f32::from(p.0[0]) / 255.0),
                        srgb_decode(f32::from(p.0[1]) / 255.0),
                        srgb_decode(f32::from(p.0[2]) / 255.0),
                    )
                })
                .collect();
            Image::from_vec(w, h, data)
        }
    };
    img.ok_or_else(|| CodecError::Decode("inconsistent image size".into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_is_within_quantisation() {
        let img = Image::from_fn(5, 3, |x, y| Rgb::new(x as f32 / 4.0, y as f32 / 2.0, 0.25));
        let png = encode_png_display(&img, 1.0).unwrap();
        let back = decode_image(&png).unwrap();
        assert_eq!((back.width(), back.height()), (5, 3));
        for (a, b) in img.pixels().iter().zip(back.pixels()) {
            assert!((*a - *b).abs().max_element() < 0.01, "{a} vs {b}");
        }
    }

    #[test]
    fn exr_round_trip_keeps_hdr_values() {
        let img = Image::from_fn(4, 4, |x, _| Rgb::new(x as f32 * 1000.0, 1e-4, 17.0));
        let exr = encode_exr(&img).unwrap();
        let back = decode_image(&exr).unwrap();
        for (a, b) in img.pixels().iter().zip(back.pixels()) {
            assert!(((*a - *b).abs() / a.max(Rgb::splat(1e-3))).max_element() < 1e-3);
        }
    }

    #[test]
    fn garbage_is_a_decode_error() {
        assert!(decode_image(b"not an image").is_err());
    }
}
