//! Image textures an import names (PNG, JPEG, TGA): checked from the header against the
//! pixel limit and carried into the document inline, as the `data:` URI of the file's own
//! bytes (`scene::image` decodes it during validation, within the document's texel limit).

use crate::scene::doc::{ImageTextureDoc, WrapDoc};
pub use crate::scene::image::Encoding;

/// The document texture of an image file named `name` (TGA has no signature, so the
/// extension decides; `mime` when a glTF image says it), refused beyond `max_pixels`.
pub fn image_texture(
    name: &str,
    mime: Option<&str>,
    bytes: &[u8],
    encoding: Encoding,
    max_pixels: u64,
) -> Result<ImageTextureDoc, String> {
    let format = match mime {
        Some(m) if m.eq_ignore_ascii_case("image/png") => Some(image::ImageFormat::Png),
        Some(m) if m.eq_ignore_ascii_case("image/jpeg") => Some(image::ImageFormat::Jpeg),
        _ => crate::scene::image::format_of_name(name),
    }
    .or_else(|| {
        image::guess_format(bytes)
            .ok()
            .filter(|f| matches!(f, image::ImageFormat::Png | image::ImageFormat::Jpeg))
    })
    .ok_or("not a PNG, JPEG or TGA image")?;
    let (w, h) = crate::scene::image::dimensions(format, bytes)?;
    let pixels = u64::from(w) * u64::from(h);
    if pixels > max_pixels {
        return Err(format!(
            "{w}×{h} = {pixels} pixels exceeds the limit of {max_pixels} texture pixels"
        ));
    }
    let data = crate::scene::image::data_uri(format, bytes).ok_or("not a texture format")?;
    Ok(ImageTextureDoc {
        data,
        encoding,
        wrap: WrapDoc::Repeat,
        uv_scale: [1.0, 1.0],
        uv_offset: [0.0, 0.0],
        factor: [1.0; 3],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    fn png(w: u32, h: u32, px: &[u8]) -> Vec<u8> {
        let img = image::RgbImage::from_raw(w, h, px.to_vec()).unwrap();
        let mut out = Vec::new();
        img.write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png)
            .unwrap();
        out
    }

    #[test]
    fn the_file_goes_inline_and_decodes_to_its_texels() {
        let b = png(2, 1, &[255, 255, 255, 188, 188, 188]);
        let t = image_texture("t.png", None, &b, Encoding::Srgb, 10).unwrap();
        assert!(t.data.starts_with("data:image/png;base64,"));
        let img = crate::scene::image::decode(&t.data, t.encoding, 10).unwrap();
        assert_eq!(img.texels[0], glam::Vec3::ONE);
        assert!((img.texels[1].x - 0.502_886).abs() < 1e-4);
        // A glTF image's media type wins over a name without an extension.
        let t = image_texture("images/0", Some("image/png"), &b, Encoding::Srgb, 10).unwrap();
        assert!(t.data.starts_with("data:image/png;"));
    }

    #[test]
    fn pixel_limit_and_garbage_are_refused() {
        let b = png(4, 4, &[0; 48]);
        assert!(image_texture("t.png", None, &b, Encoding::Srgb, 15)
            .unwrap_err()
            .contains("limit of 15"));
        assert!(image_texture("t.png", None, b"not an image", Encoding::Srgb, 15).is_err());
        assert!(image_texture("t.gif", None, b"GIF89a", Encoding::Srgb, 15).is_err());
        assert!(image_texture("t.png", None, &b[..10], Encoding::Srgb, 100).is_err());
    }
}
