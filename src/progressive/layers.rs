//! The diagnostic layers of a frame as PNG: `image`, `samples`, `distance`, `classes`.

use super::{ClassCell, Frame, SampleCell};
use crate::raster::{self, CodecError, Image};

/// The layer names of service-api.md, in display order.
pub const LAYERS: [&str; 4] = ["image", "samples", "distance", "classes"];

/// Encodes one layer as PNG. `exposure` applies to the `image` layer.
pub fn encode_layer(frame: &Frame, layer: &str, exposure: f32) -> Result<Option<Vec<u8>>, CodecError> {
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

/// Placeholder grey scale until `raster::colormap` has the JND colour scale (issue #3).
fn distance_colours(d: &Image<f32>) -> Image<[u8; 3]> {
    d.map(|&v| {
        let g = ((v / 4.0).clamp(0.0, 1.0) * 255.0) as u8;
        [g, g, g]
    })
}
