//! PNG and EXR encoding and decoding, in memory (callers do the file IO).

use super::{srgb_decode, srgb_encode, Image, LinearImage, Rgb};
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::ImageFormat;

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
    encode_png_flat_rgb8(img.width(), img.height(), &flat, FilterType::Adaptive)
}

/// PNG of `width × height` packed RGB bytes, with fdeflate's fast mode (the `image`
/// crate's default level): measured on a 512² render, 1.2 ms and 196 kB, against 54 ms
/// (and 15 % smaller) at zlib's default level, which a stream of frames cannot afford.
fn encode_png_flat_rgb8(
    width: u32,
    height: u32,
    flat: &[u8],
    filter: FilterType,
) -> Result<Vec<u8>, CodecError> {
    use image::ImageEncoder;
    if flat.len() as u64 != u64::from(width) * u64::from(height) * 3 {
        return Err(CodecError::Encode("buffer size mismatch".into()));
    }
    // About a quarter of the raw size is typical for a rendered frame: one allocation.
    let mut out = Vec::with_capacity(flat.len() / 4 + 1024);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, filter)
        .write_image(flat, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| CodecError::Encode(e.to_string()))?;
    Ok(out)
}

/// The display encoding of scene-format.md: linear value × `exposure`, clamped to [0, 1],
/// then the sRGB transfer curve, rounded to 8 bits. NaN becomes 0 (never propagated into
/// a file).
#[must_use]
pub fn to_display_rgb8(img: &LinearImage, exposure: f32) -> Image<[u8; 3]> {
    let lut = DisplayLut::get();
    img.map(|p| lut.pixel(*p, exposure))
}

/// [`to_display_rgb8`] straight into packed bytes, the layout the PNG encoder takes (one
/// pass and one buffer instead of an image of arrays and a flattened copy).
fn to_display_flat_rgb8(img: &LinearImage, exposure: f32) -> Vec<u8> {
    let lut = DisplayLut::get();
    let mut flat = vec![0u8; img.pixels().len() * 3];
    for (o, p) in flat.chunks_exact_mut(3).zip(img.pixels()) {
        o.copy_from_slice(&lut.pixel(*p, exposure));
    }
    flat
}

/// The 8-bit displayed level of a linear value already × exposure, by the definition:
/// `round(255 · srgb(clamp(v)))`. [`to_display_rgb8`] gets exactly the same levels from
/// [`DisplayLut`] without a `powf` per channel (every frame of every job, and every
/// streamed frame, goes through it).
#[must_use]
pub fn display_level(v: f32) -> u8 {
    (srgb_encode(v) * 255.0 + 0.5) as u8
}

/// Exact [`display_level`] by table, indexed by the top 16 bits of the f32 (sign,
/// exponent, 7 mantissa bits): for 0 < v ≤ 1 that is a bucket of 1/128 of an octave.
/// The level is monotone in v and no bucket holds two level thresholds (the closest two
/// are 3e-4 apart in linear terms, near v = 0.003 where a bucket is 2e-5 wide; near 1 they
/// are 9e-3 apart for buckets of 4e-3; `buckets_hold_at_most_one_threshold` checks every
/// bucket), so the level of v is the level at its bucket's start, plus one if v reaches
/// the next threshold: one load, one compare. Measured on a 512² frame: 0.6 ms against
/// 1.9 ms for the previous 16-bit-quantised table with two corrections.
struct DisplayLut {
    /// `start[i]`: the level of the smallest f32 whose top 16 bits are i (i ≤ 1.0's).
    start: Vec<u8>,
    /// `up[k]`: the smallest f32 whose level exceeds k (k = 0..=254); `up[255]` = +∞.
    up: [f32; 256],
}

/// Bucket index of 1.0, the last one [`DisplayLut::level`] reads.
const LUT_LAST: usize = (0x3f80_0000u32 >> 16) as usize;

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
            let start = (0..=LUT_LAST as u32)
                .map(|i| display_level(f32::from_bits(i << 16)))
                .collect();
            DisplayLut { start, up }
        })
    }

    /// The displayed levels of one linear pixel.
    #[inline]
    fn pixel(&self, p: Rgb, exposure: f32) -> [u8; 3] {
        [p.x, p.y, p.z].map(|v| self.level(v * exposure))
    }

    #[inline]
    fn level(&self, v: f32) -> u8 {
        // NaN gives 0; `min` below is the clamp of the definition (+∞ included).
        if v.is_nan() || v <= 0.0 {
            return 0;
        }
        let v = v.min(1.0);
        let g = self.start[(v.to_bits() >> 16) as usize];
        g + u8::from(v >= self.up[usize::from(g)])
    }
}

/// PNG of a linear image as a person sees it on the scene's display.
///
/// Every streamed frame goes through here. The `Sub` filter rather than the adaptive
/// choice per row: on a 512² render 0.87 ms instead of 1.15 ms of filtering and
/// compression, for a file 10 % larger (216 kB vs 196 kB); with the display conversion
/// (0.6 ms) a frame costs ~1.5 ms of CPU taken from the render it runs beside.
pub fn encode_png_display(img: &LinearImage, exposure: f32) -> Result<Vec<u8>, CodecError> {
    encode_png_flat_rgb8(
        img.width(),
        img.height(),
        &to_display_flat_rgb8(img, exposure),
        FilterType::Sub,
    )
}

/// PNG of a smooth picture (the interpolated preview, `progressive::preview`) as a person
/// sees it on the scene's display: the same pixels as [`encode_png_display`], with the
/// `Paeth` filter. On a smooth 2048² image fdeflate then finds long matches: 18 ms and
/// 0.3 MB against 77 ms and 2.9 MB with `Sub` (whose choice suits noisy renders).
///
/// The display conversion runs on every core (rayon): the preview is encoded while
/// nothing else runs, before its watchers are woken.
pub fn encode_png_display_smooth(img: &LinearImage, exposure: f32) -> Result<Vec<u8>, CodecError> {
    use rayon::prelude::*;
    let lut = DisplayLut::get();
    let mut flat = vec![0u8; img.pixels().len() * 3];
    flat.par_chunks_mut(3 * 4096)
        .zip(img.pixels().par_chunks(4096))
        .for_each(|(o, p)| {
            for (o, p) in o.chunks_exact_mut(3).zip(p) {
                o.copy_from_slice(&lut.pixel(*p, exposure));
            }
        });
    encode_png_flat_rgb8(img.width(), img.height(), &flat, FilterType::Paeth)
}

/// JPEG (baseline, quality `quality` of 100) of a linear image as a person sees it on the
/// scene's display: the same 8-bit sRGB levels as [`encode_png_display`], lossy.
pub fn encode_jpeg_display(
    img: &LinearImage,
    exposure: f32,
    quality: u8,
) -> Result<Vec<u8>, CodecError> {
    if img.width() == 0 || img.height() == 0 {
        return Err(CodecError::Empty);
    }
    let flat = to_display_flat_rgb8(img, exposure);
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100))
        .encode(
            &flat,
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| CodecError::Encode(e.to_string()))?;
    Ok(out)
}

/// Linear float OpenEXR of the raw radiance (no exposure, no clamp).
///
/// Through the `exr` crate directly (the one behind `image`), lossless ZIP in blocks of 16
/// scanlines: every finished job stores one, and uncompressed it was 23.1 MB of a 1600×1200
/// job's 25.0 MB on disk (README, "Bytes on disk"). 32-bit float R, G, B, increasing y.
pub fn encode_exr(img: &LinearImage) -> Result<Vec<u8>, CodecError> {
    use exr::prelude::{
        Encoding, Image as ExrImage, Layer, LayerAttributes, SpecificChannels, Vec2, WritableImage,
    };
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w == 0 || h == 0 {
        return Err(CodecError::Empty);
    }
    let px = img.pixels();
    let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
        let c = px[p.y() * w + p.x()];
        (c.x, c.y, c.z)
    });
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        channels,
    );
    let mut out = std::io::Cursor::new(Vec::with_capacity(w * h * 12 + 1024));
    ExrImage::from_layer(layer)
        .write()
        .non_parallel()
        .to_buffered(&mut out)
        .map_err(|e| CodecError::Encode(e.to_string()))?;
    Ok(out.into_inner())
}

/// The width and height a PNG's header declares (`None` if `bytes` does not start as a
/// PNG does), without decoding it.
#[must_use]
pub fn png_size(bytes: &[u8]) -> Option<(u32, u32)> {
    const SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";
    let header = bytes.get(..24)?;
    if !header.starts_with(SIGNATURE) || &header[12..16] != b"IHDR" {
        return None;
    }
    let be = |at: usize| {
        u32::from_be_bytes([header[at], header[at + 1], header[at + 2], header[at + 3]])
    };
    Some((be(16), be(20)))
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
    fn buckets_hold_at_most_one_threshold() {
        // The premise of `DisplayLut::level`: across each bucket (top 16 bits of the f32)
        // the level rises by at most one.
        let lut = super::DisplayLut::get();
        for i in 0..super::LUT_LAST as u32 {
            let first = f32::from_bits(i << 16);
            let last = f32::from_bits(((i + 1) << 16) - 1).min(1.0);
            let rise = super::display_level(last) - super::display_level(first);
            assert!(
                rise <= 1,
                "bucket {i} ({first:e}..{last:e}) rises by {rise}"
            );
            assert_eq!(lut.start[i as usize], super::display_level(first));
        }
    }

    #[test]
    fn display_bytes_match_the_image_of_levels() {
        let img = Image::from_fn(7, 5, |x, y| {
            Rgb::new(
                x as f32 / 6.0,
                y as f32 * 0.3,
                [f32::NAN, -1.0, 1e9, 0.5, 1e-5][y as usize],
            )
        });
        let flat = super::to_display_flat_rgb8(&img, 1.7);
        let levels: Vec<u8> = to_display_rgb8(&img, 1.7)
            .pixels()
            .iter()
            .flatten()
            .copied()
            .collect();
        assert_eq!(flat, levels);
        assert_eq!(&flat[..3], &[0, 0, 0]); // (0, 0, NaN): black
                                            // The PNG holds exactly those levels.
        let png = encode_png_display(&img, 1.7).unwrap();
        let back = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(back.dimensions(), (7, 5));
        assert_eq!(super::png_size(&png), Some((7, 5)));
        assert_eq!(super::png_size(&png[..20]), None);
        assert_eq!(
            super::png_size(b"GIF89a and more than twenty-four bytes"),
            None
        );
        assert_eq!(back.into_raw(), levels);
    }

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
    fn exr_keeps_every_value_exactly_and_its_layout() {
        // A non-square image (rows and columns not confused), infinities and NaN kept as
        // stored (the EXR is the raw radiance), decoded by the `exr` crate behind `image`.
        let img = Image::from_fn(3, 2, |x, y| {
            Rgb::new(
                x as f32 + 10.0 * y as f32,
                -0.5,
                [f32::INFINITY, 1e-30][y as usize],
            )
        });
        let back = decode_image(&encode_exr(&img).unwrap()).unwrap();
        assert_eq!((back.width(), back.height()), (3, 2));
        for (a, b) in img.pixels().iter().zip(back.pixels()) {
            assert_eq!((a.x, a.y, a.z), (b.x, b.y, b.z));
        }
        let mut nan = Image::filled(1, 1, Rgb::ZERO);
        nan.pixels_mut()[0] = Rgb::new(f32::NAN, 1.0, 2.0);
        let back = decode_image(&encode_exr(&nan).unwrap()).unwrap();
        assert!(back.pixels()[0].x.is_nan() && back.pixels()[0].z == 2.0);
    }

    #[test]
    fn garbage_is_a_decode_error() {
        assert!(decode_image(b"not an image").is_err());
    }
}
