//! Image textures an import names (PNG, TGA), decoded with the pixel limit checked from
//! the header before any pixel buffer exists.
//!
//! The tracer does not map images onto surfaces yet: an imported image texture is
//! rendered as its mean colour (the importer says so in a warning). The mean is taken in
//! linear RGB, after undoing the sRGB curve where the file's colour space is sRGB.

use std::io::Cursor;

/// How a texture's 8-bit values encode light.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Srgb,
    Linear,
}

/// The mean linear RGB of an image file named `name` (its extension says the format:
/// TGA has no signature), refused beyond `max_pixels`.
pub fn mean_colour(
    name: &str,
    bytes: &[u8],
    encoding: Encoding,
    max_pixels: u64,
) -> Result<[f32; 3], String> {
    let format = image::ImageFormat::from_path(name).ok();
    let reader = || {
        let r = image::ImageReader::new(Cursor::new(bytes));
        match format {
            Some(f) => Ok(image::ImageReader::with_format(r.into_inner(), f)),
            None => r
                .with_guessed_format()
                .map_err(|e| format!("cannot read the image: {e}")),
        }
    };
    let (w, h) = reader()?
        .into_dimensions()
        .map_err(|e| format!("cannot read the image header: {e}"))?;
    let pixels = u64::from(w) * u64::from(h);
    if pixels > max_pixels {
        return Err(format!(
            "{w}×{h} = {pixels} pixels exceeds the limit of {max_pixels} texture pixels"
        ));
    }
    let mut r = reader()?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(w);
    limits.max_image_height = Some(h);
    limits.max_alloc = Some(pixels.saturating_mul(16).max(1 << 20));
    r.limits(limits);
    let img = r
        .decode()
        .map_err(|e| format!("cannot decode the image: {e}"))?
        .into_rgb32f();
    let n = (u64::from(img.width()) * u64::from(img.height())).max(1) as f64;
    let mut sum = [0f64; 3];
    for p in img.pixels() {
        for (s, &v) in sum.iter_mut().zip(&p.0) {
            *s += f64::from(match encoding {
                Encoding::Srgb => crate::raster::srgb_decode(v),
                Encoding::Linear => v,
            });
        }
    }
    Ok(sum.map(|s| (s / n) as f32))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(w: u32, h: u32, px: &[u8]) -> Vec<u8> {
        let img = image::RgbImage::from_raw(w, h, px.to_vec()).unwrap();
        let mut out = Vec::new();
        img.write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png)
            .unwrap();
        out
    }

    #[test]
    fn mean_in_linear_light() {
        // Two pixels: sRGB 255 and 0 average to 0.5 in linear light (not sRGB 128).
        let b = png(2, 1, &[255, 255, 255, 0, 0, 0]);
        let m = mean_colour("t.png", &b, Encoding::Srgb, 10).unwrap();
        assert!((m[0] - 0.5).abs() < 1e-6, "{m:?}");
        // sRGB 188 is linear 0.5029 (IEC 61966-2-1); as linear data it is 188/255.
        let b = png(1, 1, &[188, 188, 188]);
        let s = mean_colour("t.png", &b, Encoding::Srgb, 10).unwrap()[0];
        assert!((s - 0.502_886).abs() < 1e-4, "{s}");
        let l = mean_colour("t.png", &b, Encoding::Linear, 10).unwrap()[0];
        assert!((l - 188.0 / 255.0).abs() < 1e-6, "{l}");
    }

    #[test]
    fn pixel_limit_and_garbage_are_refused() {
        let b = png(4, 4, &[0; 48]);
        assert!(mean_colour("t.png", &b, Encoding::Srgb, 15)
            .unwrap_err()
            .contains("limit of 15"));
        assert!(mean_colour("t.png", b"not an image", Encoding::Srgb, 15).is_err());
        assert!(mean_colour("t.png", &b[..30], Encoding::Srgb, 100).is_err());
    }
}
