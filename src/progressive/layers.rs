//! The layers of a frame as PNG: `image`, `samples`, `distance`, `classes`, `objects`.

use super::{ClassCell, Frame, SampleCell};
use crate::raster::{self, CodecError, Image};
use crate::scene::{ObjectId, BACKGROUND_ID};

/// The layer names of service-api.md, in display order.
pub const LAYERS: [&str; 5] = ["image", "samples", "distance", "classes", "objects"];

/// Encodes one layer as PNG. `exposure` applies to the `image` layer.
pub fn encode_layer(
    frame: &Frame,
    layer: &str,
    exposure: f32,
) -> Result<Option<Vec<u8>>, CodecError> {
    if frame.preview && layer != "image" {
        return Ok(None);
    }
    Ok(Some(match layer {
        "image" => raster::encode_png_display(&frame.image, exposure)?,
        "samples" => raster::encode_png_rgb8(&frame.samples.map(|s| match s {
            SampleCell::Interpolated => [0, 0, 0],
            SampleCell::Traced => [200, 200, 200],
            SampleCell::New => [255, 64, 32],
        }))?,
        "classes" => raster::encode_png_rgb8(&frame.classes.map(|c| match c {
            ClassCell::None => [0, 0, 0],
            ClassCell::Final => [40, 160, 60],
            ClassCell::Smooth => [60, 110, 230],
            ClassCell::Complex => [230, 60, 50],
        }))?,
        "objects" => raster::encode_png_rgb8(&frame.objects.map(|&id| object_colour(id)))?,
        "distance" => match &frame.distance {
            Some(d) => raster::encode_png_rgb8(&distance_colours(d))?,
            None => return Ok(None),
        },
        _ => return Ok(None),
    }))
}

/// Every layer the frame has, as (name, PNG).
pub fn encode_all(frame: &Frame) -> Result<Vec<(&'static str, Vec<u8>)>, CodecError> {
    let mut out = Vec::new();
    for name in LAYERS {
        if let Some(png) = encode_layer(frame, name, 1.0)? {
            out.push((name, png));
        }
    }
    Ok(out)
}

/// A colour per object id, far apart for neighbouring ids (the golden-ratio hue sequence,
/// full saturation, two brightness levels); the background is black.
fn object_colour(id: ObjectId) -> [u8; 3] {
    if id == BACKGROUND_ID {
        return [0, 0, 0];
    }
    let hue = (f64::from(id) * 0.618_033_988_75).fract() * 6.0;
    let value = if id.is_multiple_of(2) { 255.0 } else { 170.0 };
    let x = 1.0 - (hue % 2.0 - 1.0).abs();
    let (r, g, b) = match hue as u32 {
        0 => (1.0, x, 0.0),
        1 => (x, 1.0, 0.0),
        2 => (0.0, 1.0, x),
        3 => (0.0, x, 1.0),
        4 => (x, 0.0, 1.0),
        _ => (1.0, 0.0, x),
    };
    [r, g, b].map(|c: f64| (c * value).round() as u8)
}

/// The JND colour scale of `raster::colormap`, at the frame's size so viewers
/// can overlay it; the legend variant (`colormap::distance_with_legend`) is larger.
fn distance_colours(d: &Image<f32>) -> Image<[u8; 3]> {
    raster::colormap::distance_rgb8(d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Rgb;

    #[test]
    fn every_layer_encodes_and_distance_is_optional() {
        let (w, h) = (5, 3);
        let mut frame = Frame {
            iteration: 1,
            image: Image::filled(w, h, Rgb::splat(0.5)),
            samples: Image::filled(w, h, SampleCell::New),
            distance: Some(Image::from_fn(w, h, |x, _| x as f32 * 3.0)),
            classes: Image::filled(w, h, ClassCell::Complex),
            objects: std::sync::Arc::new(Image::from_fn(w, h, |x, _| x)),
            stats: Default::default(),
            last: true,
            preview: false,
        };
        let all = encode_all(&frame).expect("encodes");
        let names: Vec<&str> = all.iter().map(|(n, _)| *n).collect();
        assert_eq!(names, LAYERS.to_vec());
        assert!(all.iter().all(|(_, png)| png.starts_with(b"\x89PNG")));
        // The colour scale is not grey: a large distance is coloured.
        let dist = distance_colours(frame.distance.as_ref().expect("set"));
        let top = *dist.get(4, 0);
        assert!(top[0] != top[2], "{top:?}");
        frame.distance = None;
        assert_eq!(encode_all(&frame).expect("encodes").len(), 4);
        // Neighbouring objects get different colours; the background is black.
        assert_ne!(object_colour(1), object_colour(2));
        assert_eq!(object_colour(BACKGROUND_ID), [0, 0, 0]);
        assert_eq!(encode_layer(&frame, "nope", 1.0).expect("ok"), None);
        // A preview has a picture and nothing else yet.
        frame.preview = true;
        let names: Vec<&str> = encode_all(&frame)
            .expect("encodes")
            .iter()
            .map(|(n, _)| *n)
            .collect();
        assert_eq!(names, ["image"]);
    }
}
