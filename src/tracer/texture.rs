//! Textures: solid (3-D) ones evaluated at the world-space hit position (scene-format.md
//! "textures"), images at the surface's texture coordinates.

use crate::scene::{ImageMap, Texture, TextureImage, Wrap};
use glam::{Vec2, Vec3};
use std::sync::Arc;

/// The albedo of `tex` at world position `p` and texture coordinates `uv`; `images` are
/// the scene's.
#[inline]
#[must_use]
pub fn eval(tex: &Texture, p: Vec3, uv: Vec2, images: &[Arc<TextureImage>]) -> Vec3 {
    match *tex {
        Texture::Constant(c) => c,
        Texture::Image(m) => images
            .get(m.image as usize)
            .map_or(Vec3::ZERO, |img| image_lookup(img, &m, uv)),
        Texture::Checker { scale, a, b } => {
            // 3-D checker of period `scale`: parity of Σ floor(p / scale). A tiny scale can
            // put p / scale beyond i64 (or at ∞): the casts saturate and the sum wraps, so
            // the parity is still defined (features far below a pixel: any parity will do).
            let q = (p / scale).floor();
            let s = (q.x as i64)
                .wrapping_add(q.y as i64)
                .wrapping_add(q.z as i64);
            if s.rem_euclid(2) == 0 {
                a
            } else {
                b
            }
        }
        Texture::Noise { scale, a, b } => {
            // Perlin noise is in about [-1, 1]; map to a blend weight in [0, 1].
            let n = perlin(p / scale);
            let t = (0.5 + 0.5 * n).clamp(0.0, 1.0);
            a + (b - a) * t
        }
    }
}

/// Bilinear lookup of `map`'s image at `uv`: texel (i, j) is centred on ((i + ½) / W,
/// (j + ½) / H), so a lookup at a texel's centre returns that texel exactly, and one on
/// the edge between two texels their mean; outside [0, 1) the image's `wrap` decides which
/// texel a neighbour is (`Black`: none, zero). Non-finite coordinates read (0, 0).
#[must_use]
pub fn image_lookup(img: &TextureImage, map: &ImageMap, uv: Vec2) -> Vec3 {
    let st = uv * map.scale + map.offset;
    let st = if st.is_finite() { st } else { Vec2::ZERO };
    let (w, h) = (i64::from(img.width), i64::from(img.height));
    let x = st.x * img.width as f32 - 0.5;
    let y = st.y * img.height as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    // Saturating casts: coordinates beyond i64 land on its ends, still wrapped below.
    let (x0, y0) = (x0 as i64, y0 as i64);
    let texel = |i: i64, j: i64| -> Vec3 {
        match (wrap(i, w, map.wrap), wrap(j, h, map.wrap)) {
            (Some(i), Some(j)) => img.texels[(j * w + i) as usize],
            _ => Vec3::ZERO,
        }
    };
    let (x1, y1) = (x0.saturating_add(1), y0.saturating_add(1));
    let top = texel(x0, y0) * (1.0 - fx) + texel(x1, y0) * fx;
    let bottom = texel(x0, y1) * (1.0 - fx) + texel(x1, y1) * fx;
    (top * (1.0 - fy) + bottom * fy) * map.factor
}

/// The texel index that `i` stands for in an image `n` texels wide, or `None` (black).
#[inline]
fn wrap(i: i64, n: i64, mode: Wrap) -> Option<i64> {
    match mode {
        Wrap::Repeat => Some(i.rem_euclid(n)),
        Wrap::Clamp => Some(i.clamp(0, n - 1)),
        Wrap::Mirror => {
            // Period 2n: the image, then its mirror image.
            let m = i.rem_euclid(2 * n);
            Some(if m < n { m } else { 2 * n - 1 - m })
        }
        Wrap::Black => (0..n).contains(&i).then_some(i),
    }
}

/// Hash of an integer lattice point (coordinates wrapped to i32: a scene far from the
/// origin still gets noise, with a period of 2^32 features).
#[inline]
fn lattice_hash(x: i64, y: i64, z: i64) -> u32 {
    let h = (x as u32 as u64) | ((y as u32 as u64) << 32);
    let h = super::rng::mix64(h ^ super::rng::mix64(z as u32 as u64 ^ 0x5851_f42d_4c95_7f2d));
    (h >> 32) as u32
}

/// Gradient at a lattice point: one of Perlin's 12 cube-edge directions (Perlin 2002,
/// "Improving Noise").
#[inline]
fn grad(hash: u32, d: Vec3) -> f32 {
    match hash % 12 {
        0 => d.x + d.y,
        1 => -d.x + d.y,
        2 => d.x - d.y,
        3 => -d.x - d.y,
        4 => d.x + d.z,
        5 => -d.x + d.z,
        6 => d.x - d.z,
        7 => -d.x - d.z,
        8 => d.y + d.z,
        9 => -d.y + d.z,
        10 => d.y - d.z,
        _ => -d.y - d.z,
    }
}

#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Single-octave gradient noise with unit feature size: band-limited around frequency 1,
/// zero at every lattice point, continuous with continuous derivatives. Total: at a
/// non-finite point (a tiny texture scale makes p / scale overflow to ∞) the features are
/// infinitely fine and the noise is their mean, 0, instead of NaN.
#[must_use]
pub fn perlin(p: Vec3) -> f32 {
    if !p.is_finite() {
        return 0.0;
    }
    let fl = p.floor();
    let (ix, iy, iz) = (fl.x as i64, fl.y as i64, fl.z as i64);
    let f = p - fl;
    let (u, v, w) = (fade(f.x), fade(f.y), fade(f.z));
    let mut acc = [0.0f32; 8];
    for (k, a) in acc.iter_mut().enumerate() {
        let (dx, dy, dz) = ((k & 1) as i64, ((k >> 1) & 1) as i64, ((k >> 2) & 1) as i64);
        // Wrapping: far out (|p| ≥ 2^63, saturated casts) the lattice wraps like the hash.
        let h = lattice_hash(
            ix.wrapping_add(dx),
            iy.wrapping_add(dy),
            iz.wrapping_add(dz),
        );
        *a = grad(h, f - Vec3::new(dx as f32, dy as f32, dz as f32));
    }
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let x00 = lerp(acc[0], acc[1], u);
    let x10 = lerp(acc[2], acc[3], u);
    let x01 = lerp(acc[4], acc[5], u);
    let x11 = lerp(acc[6], acc[7], u);
    lerp(lerp(x00, x10, v), lerp(x01, x11, v), w)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A texture scale far below the coordinates' precision (validation accepts any
    /// positive scale) puts p / scale beyond i64 or at ∞: still a blend of `a` and `b`,
    /// never a panic (integer overflow) or NaN. Found by `tests/scene_fuzz.rs`.
    #[test]
    fn extreme_texture_coordinates_give_a_blend_of_the_two_colours() {
        let (a, b) = (Vec3::new(0.1, 0.2, 0.3), Vec3::new(0.9, 0.8, 0.7));
        for scale in [1e-30f32, 1e-45, 1e-9] {
            for p in [
                Vec3::new(1e9, -1e9, 3.0),
                Vec3::new(9.5, 0.25, -7.0),
                Vec3::splat(-1e9),
                Vec3::ZERO,
            ] {
                for t in [
                    Texture::Checker { scale, a, b },
                    Texture::Noise { scale, a, b },
                ] {
                    let c = eval(&t, p, Vec2::ZERO, &[]);
                    assert!(
                        c.is_finite() && c.cmpge(a.min(b)).all() && c.cmple(a.max(b)).all(),
                        "{t:?} at {p}: {c}"
                    );
                }
            }
        }
        // Beyond i64 the noise is 0 (every lattice gradient sees a zero offset): mid-blend.
        let mid = eval(
            &Texture::Noise { scale: 1e-30, a, b },
            Vec3::splat(1e9),
            Vec2::ZERO,
            &[],
        );
        assert!((mid - (a + b) * 0.5).abs().max_element() < 1e-6, "{mid}");
    }

    fn eval_at(t: &Texture, p: Vec3) -> Vec3 {
        eval(t, p, Vec2::ZERO, &[])
    }

    /// A 2×2 image: red, green / blue, white (row 0 on top).
    fn quad_image() -> TextureImage {
        TextureImage {
            width: 2,
            height: 2,
            texels: vec![Vec3::X, Vec3::Y, Vec3::Z, Vec3::ONE],
        }
    }

    fn map(wrap: Wrap) -> ImageMap {
        ImageMap {
            image: 0,
            factor: Vec3::ONE,
            wrap,
            scale: Vec2::ONE,
            offset: Vec2::ZERO,
        }
    }

    #[test]
    fn image_lookups_at_texel_centres_and_edges() {
        let img = quad_image();
        let at = |u: f32, v: f32, w: Wrap| image_lookup(&img, &map(w), Vec2::new(u, v));
        for w in [Wrap::Repeat, Wrap::Clamp, Wrap::Mirror, Wrap::Black] {
            // Texel centres return the texel exactly.
            assert_eq!(at(0.25, 0.25, w), Vec3::X, "{w:?}");
            assert_eq!(at(0.75, 0.25, w), Vec3::Y, "{w:?}");
            assert_eq!(at(0.25, 0.75, w), Vec3::Z, "{w:?}");
            assert_eq!(at(0.75, 0.75, w), Vec3::ONE, "{w:?}");
            // Between two texels: their mean; the image's centre: all four.
            assert_eq!(at(0.5, 0.25, w), Vec3::new(0.5, 0.5, 0.0), "{w:?}");
            assert_eq!(at(0.5, 0.5, w), Vec3::new(0.5, 0.5, 0.5), "{w:?}");
            // A quarter of the way from red's centre to green's.
            let q = at(0.375, 0.25, w);
            assert!((q - Vec3::new(0.75, 0.25, 0.0)).abs().max_element() < 1e-6);
        }
        // At the image's left edge (u = 0, red row): the wrap decides the other neighbour.
        assert_eq!(at(0.0, 0.25, Wrap::Repeat), Vec3::new(0.5, 0.5, 0.0)); // green wraps in
        assert_eq!(at(0.0, 0.25, Wrap::Clamp), Vec3::X);
        assert_eq!(at(0.0, 0.25, Wrap::Mirror), Vec3::X); // red's mirror image is red
        assert_eq!(at(0.0, 0.25, Wrap::Black), Vec3::X * 0.5);
        // Whole periods: repeat shifts by one image, mirror flips every other copy.
        assert_eq!(at(1.25, 0.25, Wrap::Repeat), Vec3::X);
        assert_eq!(at(-0.75, 0.75, Wrap::Repeat), Vec3::Z);
        assert_eq!(at(1.25, 0.25, Wrap::Mirror), Vec3::Y);
        assert_eq!(at(1.75, 0.25, Wrap::Mirror), Vec3::X);
        assert_eq!(at(5.25, 9.25, Wrap::Clamp), Vec3::ONE);
        assert_eq!(at(1.25, 0.25, Wrap::Black), Vec3::ZERO);
        // Factor, scale and offset; non-finite and far coordinates stay in the image.
        let m = ImageMap {
            factor: Vec3::splat(0.5),
            scale: Vec2::splat(2.0),
            offset: Vec2::new(0.5, 0.0),
            ..map(Wrap::Repeat)
        };
        // uv (0.125, 0.125) → st (0.75, 0.25): green, halved.
        assert_eq!(image_lookup(&img, &m, Vec2::splat(0.125)), Vec3::Y * 0.5);
        for uv in [
            Vec2::NAN,
            Vec2::splat(f32::INFINITY),
            Vec2::splat(1e30),
            Vec2::splat(-3e18),
        ] {
            for w in [Wrap::Repeat, Wrap::Clamp, Wrap::Mirror, Wrap::Black] {
                let c = image_lookup(&img, &map(w), uv);
                assert!(c.is_finite() && c.cmple(Vec3::ONE).all(), "{uv} {w:?}: {c}");
            }
        }
        // Through `eval`, with the scene's image list.
        let images = [Arc::new(img.clone())];
        let t = Texture::Image(map(Wrap::Repeat));
        assert_eq!(
            eval(&t, Vec3::ZERO, Vec2::new(0.75, 0.75), &images),
            Vec3::ONE
        );
    }

    #[test]
    fn checker_parity_and_period() {
        let t = Texture::Checker {
            scale: 2.0,
            a: Vec3::ONE,
            b: Vec3::ZERO,
        };
        assert_eq!(eval_at(&t, Vec3::new(0.5, 0.5, 0.5)), Vec3::ONE);
        assert_eq!(eval_at(&t, Vec3::new(2.5, 0.5, 0.5)), Vec3::ZERO);
        assert_eq!(eval_at(&t, Vec3::new(-0.5, 0.5, 0.5)), Vec3::ZERO);
        assert_eq!(eval_at(&t, Vec3::new(4.5, 0.5, 0.5)), Vec3::ONE);
        assert_eq!(eval_at(&t, Vec3::new(2.5, 2.5, 0.5)), Vec3::ONE);
    }

    #[test]
    fn noise_is_bounded_zero_on_lattice_and_varies() {
        let t = Texture::Noise {
            scale: 3.0,
            a: Vec3::splat(0.2),
            b: Vec3::splat(0.8),
        };
        let mut lo = f32::MAX;
        let mut hi = f32::MIN;
        for i in 0..2000 {
            let p = Vec3::new(
                i as f32 * 0.37,
                (i % 17) as f32 * 1.3,
                1e5 + i as f32 * 0.11,
            );
            let c = eval(&t, p, Vec2::ZERO, &[]);
            assert!(c.x >= 0.2 - 1e-6 && c.x <= 0.8 + 1e-6);
            lo = lo.min(c.x);
            hi = hi.max(c.x);
        }
        assert!(hi - lo > 0.2, "noise barely varies: {lo}..{hi}");
        assert_eq!(perlin(Vec3::new(3.0, -4.0, 7.0)), 0.0);
        // Continuity: a tiny step changes the value by a tiny amount.
        let p = Vec3::new(0.3, 0.6, 0.9);
        assert!((perlin(p) - perlin(p + Vec3::splat(1e-4))).abs() < 1e-3);
    }
}
