//! Image textures inside a scene document: a `data:` URI holding a PNG, JPEG or TGA file,
//! decoded into linear RGB texels with every size checked from the header before a pixel
//! buffer exists.
//!
//! A document carries its images inline (as glTF may) so that it stays self-contained: a
//! job stores its document and parses it again after a restart, and a request can never
//! name a file of the server's.

use super::{TextureImage, Vec3};
use base64::Engine as _;
use std::io::Cursor;

/// Most texels all the image textures of one document may hold together (16.7 M, 201 MB
/// of linear f32 RGB): checked against each image's header before it is decoded.
pub const MAX_TEXTURE_PIXELS: u64 = 1 << 24;

/// How an image's values encode light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// The sRGB transfer curve (IEC 61966-2-1): PNG and JPEG colour, glTF base colour.
    Srgb,
    /// Values are linear already (pbrt-v4's reading of TGA files).
    Linear,
}

/// The media types a texture's `data:` URI may name, with the decoder for each.
const FORMATS: [(&str, image::ImageFormat); 4] = [
    ("image/png", image::ImageFormat::Png),
    ("image/jpeg", image::ImageFormat::Jpeg),
    ("image/x-tga", image::ImageFormat::Tga),
    ("image/tga", image::ImageFormat::Tga),
];

/// The `data:` URI of an image file's bytes (the inverse of [`decode`]'s first step).
#[must_use]
pub fn data_uri(format: image::ImageFormat, bytes: &[u8]) -> Option<String> {
    let mime = FORMATS.iter().find(|(_, f)| *f == format)?.0;
    Some(format!(
        "data:{mime};base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    ))
}

/// The image format of a file name's extension, if Glimpse reads it as a texture.
#[must_use]
pub fn format_of_name(name: &str) -> Option<image::ImageFormat> {
    let f = image::ImageFormat::from_path(name).ok()?;
    FORMATS.iter().any(|(_, g)| *g == f).then_some(f)
}

/// Width and height from an image file's header, without decoding its pixels.
pub fn dimensions(format: image::ImageFormat, bytes: &[u8]) -> Result<(u32, u32), String> {
    image::ImageReader::with_format(Cursor::new(bytes), format)
        .into_dimensions()
        .map_err(|e| format!("cannot read the image header: {e}"))
}

/// Why an image texture was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ImageError {
    /// Sound, but beyond the texel limit (`too_large`).
    TooLarge(String),
    /// Not an image Glimpse can read.
    Invalid(String),
}

impl std::fmt::Display for ImageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ImageError::TooLarge(m) | ImageError::Invalid(m) => f.write_str(m),
        }
    }
}

/// Decodes a texture's `data:` URI. `budget` is the number of texels the document may
/// still use; the image's header is checked against it (and the decoder's allocation
/// capped to the header's size) before any pixel is decoded.
pub fn decode(uri: &str, encoding: Encoding, budget: u64) -> Result<TextureImage, ImageError> {
    decode_inner(uri, encoding, budget).map_err(|(too_large, m)| {
        if too_large {
            ImageError::TooLarge(m)
        } else {
            ImageError::Invalid(m)
        }
    })
}

fn decode_inner(
    uri: &str,
    encoding: Encoding,
    budget: u64,
) -> Result<TextureImage, (bool, String)> {
    let bad = |m: &str| (false, m.to_string());
    let rest = uri
        .strip_prefix("data:")
        .ok_or_else(|| bad("must be a data: URI (data:image/png;base64,...)"))?;
    let (mime, payload) = rest
        .split_once(";base64,")
        .ok_or_else(|| bad("must be a base64 data: URI (data:image/png;base64,...)"))?;
    let format = FORMATS
        .iter()
        .find(|(m, _)| m.eq_ignore_ascii_case(mime))
        .map(|(_, f)| *f)
        .ok_or_else(|| {
            bad(&format!(
                "media type \"{}\" is not an image Glimpse reads (image/png, image/jpeg, image/x-tga)",
                clip(mime)
            ))
        })?;
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(payload.trim())
        .map_err(|e| bad(&format!("the base64 payload does not decode: {e}")))?;
    let (w, h) = dimensions(format, &bytes).map_err(|e| bad(&e))?;
    let pixels = u64::from(w) * u64::from(h);
    if pixels == 0 {
        return Err(bad("the image has no pixels"));
    }
    if pixels > budget {
        return Err((true, format!(
            "{w}×{h} = {pixels} texels exceeds the {budget} left of this document's limit of {MAX_TEXTURE_PIXELS} texture pixels"
        )));
    }
    let mut reader = image::ImageReader::with_format(Cursor::new(&bytes), format);
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(w);
    limits.max_image_height = Some(h);
    // The largest buffer a decoder needs: 16-bit RGBA, plus slack for its own state.
    limits.max_alloc = Some(pixels.saturating_mul(8).saturating_add(1 << 20));
    reader.limits(limits);
    let img = reader
        .decode()
        .map_err(|e| bad(&format!("cannot decode the image: {e}")))?
        .into_rgb32f();
    let texels = img
        .pixels()
        .map(|p| {
            let v = Vec3::from(p.0);
            match encoding {
                Encoding::Srgb => v.map(crate::raster::srgb_decode),
                Encoding::Linear => v,
            }
        })
        .collect();
    Ok(TextureImage {
        width: img.width(),
        height: img.height(),
        texels,
    })
}

/// At most 32 characters of something a document said (an error echoes no more of it).
fn clip(s: &str) -> String {
    s.chars().take(32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn png(w: u32, h: u32, px: &[u8]) -> Vec<u8> {
        let img = image::RgbImage::from_raw(w, h, px.to_vec()).unwrap();
        let mut out = Vec::new();
        img.write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png)
            .unwrap();
        out
    }

    #[test]
    fn srgb_and_linear_decoding_at_known_values() {
        // sRGB 188 is linear 0.5029 (IEC 61966-2-1); read as linear it is 188/255; sRGB 255
        // and 0 are exactly 1 and 0. Row 0 is the top row of the file.
        let uri = data_uri(
            image::ImageFormat::Png,
            &png(2, 2, &[188, 188, 188, 255, 255, 255, 0, 0, 0, 10, 20, 30]),
        )
        .unwrap();
        let s = decode(&uri, Encoding::Srgb, 4).unwrap();
        assert_eq!((s.width, s.height), (2, 2));
        assert!((s.texels[0].x - 0.502_886).abs() < 1e-4, "{}", s.texels[0]);
        assert_eq!(s.texels[1], Vec3::ONE);
        assert_eq!(s.texels[2], Vec3::ZERO);
        // sRGB 10/255 = 0.0392 is on the curve's linear segment: 0.0392 / 12.92 = 0.003035.
        assert!((s.texels[3].x - 0.003_035).abs() < 1e-5, "{}", s.texels[3]);
        let l = decode(&uri, Encoding::Linear, 4).unwrap();
        assert!((l.texels[0].x - 188.0 / 255.0).abs() < 1e-6);
        assert!((l.texels[3].z - 30.0 / 255.0).abs() < 1e-6);
    }

    #[test]
    fn tga_and_jpeg_decode() {
        let img = image::RgbImage::from_raw(2, 1, vec![255, 0, 0, 0, 0, 255]).unwrap();
        let mut tga = Vec::new();
        img.write_to(&mut Cursor::new(&mut tga), image::ImageFormat::Tga)
            .unwrap();
        let t = decode(
            &data_uri(image::ImageFormat::Tga, &tga).unwrap(),
            Encoding::Linear,
            10,
        )
        .unwrap();
        assert_eq!(t.texels, vec![Vec3::X, Vec3::Z]);
        let grey = image::RgbImage::from_pixel(8, 8, image::Rgb([128, 128, 128]));
        let mut jpg = Vec::new();
        grey.write_to(&mut Cursor::new(&mut jpg), image::ImageFormat::Jpeg)
            .unwrap();
        let j = decode(
            &data_uri(image::ImageFormat::Jpeg, &jpg).unwrap(),
            Encoding::Linear,
            64,
        )
        .unwrap();
        assert!(j.texels.iter().all(|t| (t.x - 128.0 / 255.0).abs() < 0.02));
    }

    #[test]
    fn limits_and_garbage_are_refused_with_a_reason() {
        let b = png(4, 4, &[0; 48]);
        let uri = data_uri(image::ImageFormat::Png, &b).unwrap();
        assert!(matches!(
            decode(&uri, Encoding::Srgb, 15),
            Err(ImageError::TooLarge(m)) if m.contains("16 texels")
        ));
        for (bad, why) in [
            ("textures/wood.png", "data: URI"),
            ("data:image/png,abc", "base64"),
            ("data:image/gif;base64,R0lG", "image/gif"),
            ("data:image/png;base64,@@@", "base64"),
            ("data:image/png;base64,bm90IGFuIGltYWdl", "header"),
        ] {
            let e = decode(bad, Encoding::Srgb, 100).unwrap_err().to_string();
            assert!(e.contains(why), "{bad}: {e}");
        }
        // A truncated file: the header may pass, the pixels do not.
        let cut = data_uri(image::ImageFormat::Png, &b[..b.len() - 20]).unwrap();
        assert!(decode(&cut, Encoding::Srgb, 100).is_err());
    }
}
