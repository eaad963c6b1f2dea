//! Colour scales for the diagnostic layers (samples, distance, classes).
//! The distance scale and its legend.
//!
//! Distances are in JNDs (vision-model.md §2.7). The scale is perceptually ordered (an
//! inferno-like ramp, dark = invisible, bright = very visible) and logarithmic-ish,
//! `t = log2(1 + 2d) / log2(17)`, so the interesting range around 1 JND gets as much of the
//! ramp as the large errors: ticks 0, 0.5, 1, 2, 4 and 8+ JND (8 and above saturate).

use super::codec::{encode_png_rgb8, CodecError};
use super::Image;

/// Distances at or above this many JNDs get the top colour.
pub const TOP_JND: f32 = 8.0;
/// Legend ticks (JND).
pub const TICKS: [f32; 6] = [0.0, 0.5, 1.0, 2.0, 4.0, 8.0];

/// Inferno-like stops at t = 0, 1/8, …, 1 (sampled from matplotlib's inferno by eye: dark
/// purple → red → orange → pale yellow; monotone in lightness).
const STOPS: [[f32; 3]; 9] = [
    [0.0, 0.0, 4.0],
    [31.0, 12.0, 72.0],
    [85.0, 15.0, 109.0],
    [136.0, 34.0, 106.0],
    [186.0, 54.0, 85.0],
    [227.0, 89.0, 51.0],
    [249.0, 140.0, 10.0],
    [249.0, 201.0, 50.0],
    [252.0, 255.0, 164.0],
];

/// Position of `d` JND on the scale, in [0, 1]. NaN and negatives map to 0.
#[must_use]
pub fn scale_position(d: f32) -> f32 {
    let d = if d.is_nan() {
        0.0
    } else {
        d.clamp(0.0, TOP_JND)
    };
    (1.0 + 2.0 * d).log2() / (1.0 + 2.0 * TOP_JND).log2()
}

/// The colour at scale position `t` ∈ [0, 1].
#[must_use]
pub fn ramp(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * (STOPS.len() - 1) as f32;
    let i = (t as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    std::array::from_fn(|k| (a[k] + (b[k] - a[k]) * f + 0.5) as u8)
}

/// Colour of a distance in JND.
#[must_use]
pub fn distance_colour(d: f32) -> [u8; 3] {
    ramp(scale_position(d))
}

/// The distance map coloured, same size (for the progressive renderer's `distance` layer).
#[must_use]
pub fn distance_rgb8(map: &Image<f32>) -> Image<[u8; 3]> {
    map.map(|&d| distance_colour(d))
}

/// 3×5 glyphs, rows top to bottom, bit 2 = left column.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '+' => [0, 2, 7, 2, 0],
        'J' => [1, 1, 1, 5, 7],
        'N' => [5, 7, 7, 7, 5],
        'D' => [6, 5, 5, 5, 6],
        _ => [0; 5],
    }
}

/// Width in pixels of `s` drawn at `scale` (4 px advance per glyph at scale 1).
fn text_width(s: &str, scale: u32) -> u32 {
    (s.chars().count() as u32 * 4).saturating_sub(1) * scale
}

fn draw_text(img: &mut Image<[u8; 3]>, s: &str, x0: i64, y0: i64, scale: u32, colour: [u8; 3]) {
    for (ci, c) in s.chars().enumerate() {
        let g = glyph(c);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3u32 {
                if bits & (4 >> col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let x = x0 + i64::from((ci as u32 * 4 + col) * scale + dx);
                        let y = y0 + i64::from(row as u32 * scale + dy);
                        if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height()
                        {
                            img.set(x as u32, y as u32, colour);
                        }
                    }
                }
            }
        }
    }
}

fn tick_label(d: f32) -> String {
    if d >= TOP_JND {
        format!("{}+", d as u32)
    } else if d.fract() == 0.0 {
        format!("{}", d as u32)
    } else {
        format!("{d}").trim_start_matches('0').to_string()
    }
}

/// The coloured map with a legend strip underneath: the ramp, tick marks and labels at
/// 0, .5, 1, 2, 4, 8+ and the unit "JND". The canvas is at least 120 px wide so the legend
/// stays readable for tiny maps (the map sits top-left on a dark background).
#[must_use]
pub fn distance_with_legend(map: &Image<f32>) -> Image<[u8; 3]> {
    const BG: [u8; 3] = [24, 24, 24];
    const FG: [u8; 3] = [230, 230, 230];
    let w = map.width().max(120);
    // Text and bar grow with the map so the legend stays legible at any size.
    let scale = (w / 256).clamp(1, 4);
    let bar_h = 6 * scale;
    let legend_h = 4 + bar_h + 2 + 2 * scale + 5 * scale + 4;
    let h = map.height() + legend_h;
    let mut img = Image::filled(w, h, BG);
    for y in 0..map.height() {
        for x in 0..map.width() {
            img.set(x, y, distance_colour(*map.get(x, y)));
        }
    }
    let unit = "JND";
    let margin = 4 + scale * 4; // room for half a label at the left end
    let x0 = margin;
    let x1 = w
        .saturating_sub(text_width(unit, scale) + 2 * margin)
        .max(x0 + 2);
    let bar_y = map.height() + 4;
    for x in x0..x1 {
        let c = ramp((x - x0) as f32 / (x1 - x0 - 1).max(1) as f32);
        for y in bar_y..bar_y + bar_h {
            img.set(x, y, c);
        }
    }
    let tick_y = bar_y + bar_h;
    let label_y = tick_y + 2 + 2 * scale;
    for d in TICKS {
        let tx = x0 + (scale_position(d) * (x1 - x0 - 1) as f32).round() as u32;
        for y in tick_y..tick_y + 2 * scale {
            for dx in 0..scale {
                if tx + dx < w {
                    img.set(tx + dx, y, FG);
                }
            }
        }
        let label = tick_label(d);
        let lx = i64::from(tx) - i64::from(text_width(&label, scale) / 2);
        draw_text(&mut img, &label, lx, i64::from(label_y), scale, FG);
    }
    draw_text(
        &mut img,
        unit,
        i64::from(x1 + margin),
        i64::from(bar_y),
        scale,
        FG,
    );
    img
}

/// PNG of [`distance_with_legend`].
pub fn distance_png_with_legend(map: &Image<f32>) -> Result<Vec<u8>, CodecError> {
    encode_png_rgb8(&distance_with_legend(map))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lightness(c: [u8; 3]) -> f32 {
        0.2126 * f32::from(c[0]) + 0.7152 * f32::from(c[1]) + 0.0722 * f32::from(c[2])
    }

    #[test]
    fn scale_is_monotone_and_saturates() {
        assert_eq!(scale_position(0.0), 0.0);
        assert!((scale_position(TOP_JND) - 1.0).abs() < 1e-6);
        assert_eq!(scale_position(100.0), scale_position(TOP_JND));
        assert_eq!(scale_position(f32::NAN), 0.0);
        assert_eq!(scale_position(-3.0), 0.0);
        let mut prev = -1.0;
        let mut prev_l = -1.0;
        for i in 0..=80 {
            let d = i as f32 * 0.1;
            let t = scale_position(d);
            assert!(t > prev);
            prev = t;
            let l = lightness(distance_colour(d));
            assert!(l >= prev_l - 0.5, "lightness must not fall: {d}");
            prev_l = l;
        }
        assert_eq!(distance_colour(0.0), [0, 0, 4]);
        assert_eq!(distance_colour(50.0), [252, 255, 164]);
        // 1 JND sits a third of the way up: visibly distinct from both ends.
        assert!((scale_position(1.0) - 0.388).abs() < 0.01);
    }

    #[test]
    fn legend_is_drawn_below_the_map() {
        let map = Image::from_fn(300, 20, |x, _| x as f32 / 30.0);
        let img = distance_with_legend(&map);
        assert_eq!(img.width(), 300);
        assert!(img.height() > 20 + 20);
        assert_eq!(*img.get(0, 0), distance_colour(0.0));
        assert_eq!(*img.get(299, 0), distance_colour(299.0 / 30.0));
        // Some label pixels are drawn in the legend area.
        let fg = (20..img.height())
            .flat_map(|y| (0..300).map(move |x| (x, y)))
            .filter(|&(x, y)| *img.get(x, y) == [230, 230, 230])
            .count();
        assert!(fg > 50);
        let tiny = distance_with_legend(&Image::filled(1, 1, 0.5));
        assert_eq!(tiny.width(), 120);
        assert!(distance_png_with_legend(&map).is_ok());
        assert_eq!(tick_label(0.5), ".5");
        assert_eq!(tick_label(8.0), "8+");
        assert_eq!(tick_label(2.0), "2");
    }
}
