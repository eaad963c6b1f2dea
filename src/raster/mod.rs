//! Pixel buffers and colour encoding: the leaf of the crate (imports nothing of ours).
//!
//! Images are row-major, origin at the top-left, `y` growing downwards, as in the
//! PNG files we write and in the paper's figures.

pub mod codec;
pub mod colormap;

pub use codec::{
    decode_image, encode_exr, encode_jpeg_display, encode_png_display, encode_png_display_smooth,
    encode_png_rgb8, png_size, CodecError,
};

/// Linear RGB with Rec.709/sRGB primaries (scene-format.md "Units").
pub type Rgb = glam::Vec3;

/// A pixel position in image space.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PixelCoord {
    pub x: u32,
    pub y: u32,
}

impl PixelCoord {
    #[must_use]
    pub const fn new(x: u32, y: u32) -> Self {
        Self { x, y }
    }
}

/// The Morton (Z-order) key of (x, y): their bits interleaved, x's in the even places, so
/// every aligned 2^k × 2^k square of pixels is one run of 4^k consecutive keys.
#[must_use]
pub fn morton(x: u32, y: u32) -> u64 {
    fn spread(v: u32) -> u64 {
        let mut v = u64::from(v);
        v = (v | (v << 16)) & 0x0000_FFFF_0000_FFFF;
        v = (v | (v << 8)) & 0x00FF_00FF_00FF_00FF;
        v = (v | (v << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
        v = (v | (v << 2)) & 0x3333_3333_3333_3333;
        v = (v | (v << 1)) & 0x5555_5555_5555_5555;
        v
    }
    spread(x) | (spread(y) << 1)
}

/// A width × height buffer of `T`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<T> {
    width: u32,
    height: u32,
    data: Vec<T>,
}

/// What the renderer produces: linear radiance per pixel.
pub type LinearImage = Image<Rgb>;

impl<T: Clone> Image<T> {
    /// An image filled with `value`.
    #[must_use]
    pub fn filled(width: u32, height: u32, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width as usize * height as usize],
        }
    }
}

impl<T> Image<T> {
    /// Wraps `data` (row-major). Returns `None` if the length does not match.
    #[must_use]
    pub fn from_vec(width: u32, height: u32, data: Vec<T>) -> Option<Self> {
        (data.len() == width as usize * height as usize).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// Builds an image by calling `f(x, y)` for every pixel.
    #[must_use]
    pub fn from_fn(width: u32, height: u32, mut f: impl FnMut(u32, u32) -> T) -> Self {
        let mut data = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self {
            width,
            height,
            data,
        }
    }

    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }
    #[must_use]
    pub fn len(&self) -> usize {
        self.data.len()
    }
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }
    #[must_use]
    pub fn index(&self, x: u32, y: u32) -> usize {
        debug_assert!(x < self.width && y < self.height);
        y as usize * self.width as usize + x as usize
    }
    #[must_use]
    pub fn get(&self, x: u32, y: u32) -> &T {
        &self.data[self.index(x, y)]
    }
    pub fn set(&mut self, x: u32, y: u32, v: T) {
        let i = self.index(x, y);
        self.data[i] = v;
    }
    #[must_use]
    pub fn pixels(&self) -> &[T] {
        &self.data
    }
    pub fn pixels_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
    #[must_use]
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }
    /// Applies `f` to every pixel, keeping the size.
    #[must_use]
    pub fn map<U>(&self, f: impl FnMut(&T) -> U) -> Image<U> {
        Image {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(f).collect(),
        }
    }
}

impl LinearImage {
    /// Mean linear RGB in f64 (accumulating big images in f32 loses digits).
    #[must_use]
    pub fn mean(&self) -> [f64; 3] {
        let mut s = [0f64; 3];
        for p in &self.data {
            s[0] += f64::from(p.x);
            s[1] += f64::from(p.y);
            s[2] += f64::from(p.z);
        }
        let n = self.data.len().max(1) as f64;
        [s[0] / n, s[1] / n, s[2] / n]
    }

    /// True if any component is NaN or infinite.
    #[must_use]
    pub fn has_non_finite(&self) -> bool {
        self.data.iter().any(|p| !p.is_finite())
    }

    /// This image shrunk so that its longer side is `max_side` pixels (the aspect kept,
    /// the shorter side rounded up), each pixel the mean of the pixels it covers; `None` if it is no larger than that already. Rows in parallel (rayon).
    #[must_use]
    pub fn shrunk_to(&self, max_side: u32) -> Option<LinearImage> {
        use rayon::prelude::*;
        let long = self.width.max(self.height);
        if long <= max_side || max_side == 0 {
            return None;
        }
        let side = |len: u32| {
            let s = u64::from(len) * u64::from(max_side);
            (s.div_ceil(u64::from(long)) as u32).clamp(1, len)
        };
        let (w, h) = (side(self.width), side(self.height));
        // The source pixels [start, end) that output pixel `k` of `out` covers along an
        // axis `len` long (neighbours share the pixel their edge cuts).
        let span = |k: u32, out: u32, len: u32| {
            let (k, out, len) = (u64::from(k), u64::from(out), u64::from(len));
            let start = k * len / out;
            let end = ((k + 1) * len).div_ceil(out).max(start + 1).min(len);
            (start as usize, end as usize)
        };
        let columns: Vec<(usize, usize)> = (0..w).map(|x| span(x, w, self.width)).collect();
        let stride = self.width as usize;
        let mut data = vec![Rgb::ZERO; w as usize * h as usize];
        data.par_chunks_mut(w as usize)
            .enumerate()
            .for_each(|(y, row)| {
                let (y0, y1) = span(y as u32, h, self.height);
                for (out, &(x0, x1)) in row.iter_mut().zip(&columns) {
                    let sum: Rgb = (y0..y1)
                        .flat_map(|sy| &self.data[sy * stride + x0..sy * stride + x1])
                        .sum();
                    *out = sum / ((y1 - y0) * (x1 - x0)) as f32;
                }
            });
        Image::from_vec(w, h, data)
    }
}

/// The sRGB transfer curve (IEC 61966-2-1) of a linear value in [0, 1].
#[must_use]
pub fn srgb_encode(v: f32) -> f32 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Inverse of [`srgb_encode`].
#[must_use]
pub fn srgb_decode(e: f32) -> f32 {
    let e = e.clamp(0.0, 1.0);
    if e <= 0.040_45 {
        e / 12.92
    } else {
        ((e + 0.055) / 1.055).powf(2.4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_interleaves_bits() {
        assert_eq!(morton(0, 0), 0);
        assert_eq!(morton(1, 0), 1);
        assert_eq!(morton(0, 1), 2);
        assert_eq!(morton(3, 3), 15);
        assert_eq!(morton(5, 9), 0b1001_0011);
        assert_eq!(morton(0xffff, 0xffff), 0xffff_ffff);
        assert_eq!(morton(u32::MAX, 0), 0x5555_5555_5555_5555);
    }

    #[test]
    fn srgb_round_trip_and_known_values() {
        assert_eq!(srgb_encode(0.0), 0.0);
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_encode(0.5) - 0.735_357).abs() < 1e-5);
        for i in 0..=255 {
            let e = i as f32 / 255.0;
            assert!((srgb_encode(srgb_decode(e)) - e).abs() < 1e-5);
        }
        assert_eq!(srgb_encode(f32::NAN), 0.0);
        assert!((srgb_encode(f32::INFINITY) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn a_shrunk_image_keeps_its_aspect_and_means() {
        let img = Image::from_fn(2048, 1536, |x, _| Rgb::splat((x / 4) as f32));
        let small = img.shrunk_to(512).unwrap();
        assert_eq!((small.width(), small.height()), (512, 384));
        // Each output pixel is the mean of a 4 × 4 block, whose columns share a value.
        assert_eq!(*small.get(3, 7), Rgb::splat(3.0));
        assert!(img.shrunk_to(2048).is_none());
        assert!(img.shrunk_to(4096).is_none());
        // Uneven factors and a thin image: no side below 1 pixel, every pixel covered.
        let thin = Image::from_fn(1000, 3, |x, y| Rgb::splat((x + y) as f32));
        let t = thin.shrunk_to(300).unwrap();
        assert_eq!((t.width(), t.height()), (300, 1));
        assert!(t.pixels().iter().all(|p| p.is_finite() && p.x >= 0.0));
        let mean = |i: &LinearImage| i.mean()[0];
        assert!((mean(&t) - mean(&thin)).abs() < 0.01 * mean(&thin));
    }

    #[test]
    fn image_indexing_is_row_major() {
        let img = Image::from_fn(3, 2, |x, y| x + 10 * y);
        assert_eq!(img.pixels(), &[0, 1, 2, 10, 11, 12]);
        assert_eq!(*img.get(2, 1), 12);
        assert!(Image::from_vec(2, 2, vec![0u8; 3]).is_none());
    }
}
