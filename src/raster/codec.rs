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
/// then the sRGB transfer curve, rounded to 8 bits. NaN becomes 0 (never propagated into
/// a file).
#[must_use]
pub fn to_display_rgb8(img: &LinearImage, exposure: f32) -> Image<[u8; 3]> {
    let lut = DisplayLut::get();
    img.map(|p| [p.x, p.y, p.z].map(|v| lut.level(v * exposure)))
}

/// The 8-bit displayed level of a linear value already × exposure, by the definition:
/// `round(255 · srgb(clamp(v)))`. [`to_display_rgb8`] gets exactly the same levels from
/// [`DisplayLut`] without a `powf` per channel (every frame of every job, and every
/// streamed frame, goes through it).
#[must_use]
pub fn display_level(v: f32) -> u8 {
    (srgb_encode(v) * 255.0 + 0.5) as u8
}

/// Exact [`display_level`] by table: a 16-bit quantisation of v gives the level to within
/// one (the closest two level thresholds are 3e-4 apart in linear terms, 20 table steps),
/// and the thresholds on either side correct it.
struct DisplayLut {
    /// `guess[i]`: the level of i / 65535.
    guess: Vec<u8>,
    /// `up[k]`: the smallest f32 whose level exceeds k (k = 0..=254); `up[255]` = +∞.
    up: [f32; 256],
}

impl DisplayLut {
    fn get() -> &'static Self {
        static LUT: std::sync::OnceLock<DisplayLut> = std::sync::OnceLock::new();
        LUT.get_or_init(|| {
            let mut up = [f32::INFINITY; 256];
            for (k, slot) in up.iter_mut().take(255).enumerate() {
                // Bisection on the bit patterns of [0, 1] (order-preserving for
                // non-negative floats): level(lo) ≤ k < level(hi).
                let (mut lo, mut hi) = (0u32, 1f32.to_bits());
                while hi - lo > 1 {
                    let mid = lo + (hi - lo) / 2;
                    if usize::from(display_level(f32::from_bits(mid))) > k {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                *slot = f32::from_bits(hi);
            }
            let guess = (0..=u16::MAX)
                .map(|i| display_level(f32::from(i) / 65535.0))
                .collect();
            DisplayLut { guess, up }
        })
    }

    fn level(&self, v: f32) -> u8 {
        if v.is_nan() || v <= 0.0 {
            return 0;
        }
        let v = v.min(1.0); // the clamp of the definition (+∞ included)
        let g = self.guess[(v * 65535.0) as usize];
        if v >= self.up[usize::from(g)] {
            g + 1
        } else if g > 0 && v < self.up[usize::from(g) - 1] {
            g - 1
        } else {
            g
        }
    }
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

    #[test]
    fn threshold_levels_equal_the_srgb_definition() {
        // Every f32 in [0, 1] with a stride of 97 bit patterns (≈ 11 M values), the
        // neighbourhood of every threshold, and the extremes.
        let lut = super::DisplayLut::get();
        let fast = |v: f32| lut.level(v);
        let (mut bits, mut checked) = (0u32, 0u32);
        while bits <= 1f32.to_bits() {
            let v = f32::from_bits(bits);
            assert_eq!(fast(v), super::display_level(v), "{v:e}");
            bits += 97;
            checked += 1;
        }
        assert!(checked > 10_000_000, "{checked}");
        for &th in lut.up.iter().take(255) {
            for d in -64i32..=64 {
                let v = f32::from_bits(th.to_bits().wrapping_add_signed(d));
                assert_eq!(fast(v), super::display_level(v), "{v:e}");
            }
        }
        for i in 0..=u16::MAX {
            let v = f32::from(i) / 65535.0;
            assert_eq!(fast(v), super::display_level(v), "{v:e}");
        }
        for v in [
            -1.0,
            -0.0,
            0.0,
            1.0,
            2.0,
            1e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ] {
            assert_eq!(fast(v), super::display_level(v), "{v}");
        }
    }
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
