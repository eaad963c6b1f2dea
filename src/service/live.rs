//! One frame of a running job as every reader shares it: the stream, `GET .../frame`,
//! the kept iterations and the final files.

use super::metrics::Metrics;
use super::store::{Layer, Progress};
use crate::progressive::{layers, Frame};
use bytes::Bytes;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// One frame as the stream serves it. The PNG of the image layer is encoded at most once,
/// lazily, only when someone takes it (a watcher, `GET .../frame`, or the final file),
/// and shared by all of them: a frame that nobody watches costs the render nothing but
/// its copy, and a watcher that falls behind skips to the newest frame (the `watch`
/// channel), so the encoder never works on frames nobody will see.
pub struct LiveFrame {
    pub iteration: u32,
    /// A preview before the first iteration (`Frame::preview`): image layer only.
    pub preview: bool,
    /// The image's size in pixels (a relayed frame's, as its PNG declares it).
    pub width: u32,
    pub height: u32,
    /// What the stream sends of a preview larger than [`PREVIEW_SIDE`]: a smaller PNG,
    /// encoded at once ([`LiveFrame::preview`]). `None` for every other frame, whose
    /// stream PNG is the image layer's.
    shown: Option<StreamPng>,
    /// The frame's pixels and layers; `None` for a frame relayed from a worker on
    /// another node, which carries its image layer's PNG only ([`relay`]). Set at once,
    /// except a preview's, set by the render's thread just after it is published
    /// ([`LiveFrame::preview`]); readers wait for it ([`LiveFrame::pixels`]).
    pixels: std::sync::OnceLock<Option<Frame>>,
    /// The scene's display exposure, for the `image` layer.
    pub exposure: f32,
    pub progress: Progress,
    /// The layers this frame has (`distance` is absent in reference mode).
    pub layers: Vec<Layer>,
    /// A std `OnceLock` (not tokio's `OnceCell`) so the worker thread can wait for the
    /// encoding a watcher already started instead of encoding the final frame twice.
    png: std::sync::OnceLock<Result<Bytes, String>>,
    /// The other layers' PNGs and the EXR ([`OTHER_ENCODINGS`]), likewise encoded once when
    /// first asked for and shared by every request and the final files: one encoding per
    /// frame, not one per request (a 4096² EXR is 201 MB).
    others: [std::sync::OnceLock<Result<Option<Bytes>, String>>; OTHER_ENCODINGS.len()],
    metrics: Arc<Metrics>,
}

/// Longest side, in pixels, of the PNG the stream sends of a preview: the viewer shows it
/// scaled up to the image's size. The preview is interpolated from about a thousand
/// traced points, so a smaller copy loses nothing one can see, and at 2048² its full-size
/// PNG (2.4 MB for the Cornell box, 40–120 ms to encode on a loaded machine) was most of
/// the time between the POST and the first picture on the client (docs/measurements.md,
/// "The first frame at the client"). `GET .../frame` and the job's files still get the
/// full size.
pub const PREVIEW_SIDE: u32 = 512;

/// The PNG a stream sends for a frame, with its size and the image's it stands for.
#[derive(Clone)]
pub struct StreamPng {
    pub png: Bytes,
    pub width: u32,
    pub height: u32,
}

/// The encodings [`LiveFrame::encoded`] caches besides the image PNG: (layer, EXR?).
pub(super) const OTHER_ENCODINGS: [(Layer, bool); 5] = [
    (Layer::Samples, false),
    (Layer::Distance, false),
    (Layer::Classes, false),
    (Layer::Objects, false),
    (Layer::Image, true),
];

impl LiveFrame {
    pub(super) fn new(
        frame: Frame,
        exposure: f32,
        progress: Progress,
        metrics: Arc<Metrics>,
    ) -> Self {
        let layers = Layer::ALL
            .into_iter()
            .filter(|l| *l != Layer::Distance || frame.distance.is_some())
            .filter(|l| *l == Layer::Image || !frame.preview)
            .collect();
        Self {
            iteration: frame.iteration,
            preview: frame.preview,
            width: frame.image.width(),
            height: frame.image.height(),
            shown: None,
            pixels: std::sync::OnceLock::from(Some(frame)),
            exposure,
            progress,
            layers,
            png: std::sync::OnceLock::new(),
            others: Default::default(),
            metrics,
        }
    }

    /// A preview frame (`Frame::preview`), the PNG the stream sends of it already encoded
    /// (shrunk to [`PREVIEW_SIDE`] if it is larger) and its pixels not yet copied: the copy
    /// (48 MB at 2048², kept for the full-size PNG, the EXR and the final files should
    /// the job stop at the preview) is made after watchers have the PNG, by
    /// [`LiveFrame::keep_preview_pixels`]. Blocking (the encoding).
    pub(super) fn preview(
        frame: &Frame,
        exposure: f32,
        progress: Progress,
        metrics: Arc<Metrics>,
    ) -> Self {
        let shrunk = frame.image.shrunk_to(PREVIEW_SIDE);
        let sent = shrunk.as_ref().unwrap_or(&frame.image);
        let (width, height) = (sent.width(), sent.height());
        let encoded = crate::raster::encode_png_display_smooth(sent, exposure)
            .map(Bytes::from)
            .map_err(|e| e.to_string());
        metrics.frames_encoded.fetch_add(1, Ordering::Relaxed);
        // Not shrunk (or not encoded), what is sent is the image layer's own PNG.
        let (png, shown) = match (encoded, shrunk.is_some()) {
            (Ok(png), true) => (
                std::sync::OnceLock::new(),
                Some(StreamPng { png, width, height }),
            ),
            (encoded, _) => (std::sync::OnceLock::from(encoded), None),
        };
        Self {
            iteration: frame.iteration,
            preview: true,
            width: frame.image.width(),
            height: frame.image.height(),
            shown,
            pixels: std::sync::OnceLock::new(),
            exposure,
            progress,
            layers: vec![Layer::Image],
            png,
            others: Default::default(),
            metrics,
        }
    }

    /// Keeps a copy of the preview's pixels (`frame` is the one [`LiveFrame::preview`]
    /// was made of); readers waiting for them go on.
    pub(super) fn keep_preview_pixels(&self, frame: &Frame) {
        let _ = self.pixels.set(Some(frame.clone()));
    }

    /// The frame's pixels (`None` for a relayed frame), waiting for a preview's copy.
    fn pixels(&self) -> Option<&Frame> {
        self.pixels.wait().as_ref()
    }

    /// The PNG the stream sends of this frame: a large preview's smaller one, else the
    /// image layer's (encoded once, off the async runtime).
    pub async fn stream_png(self: &Arc<Self>) -> Result<StreamPng, String> {
        if let Some(shown) = &self.shown {
            return Ok(shown.clone());
        }
        Ok(StreamPng {
            png: self.image_png().await?,
            width: self.width,
            height: self.height,
        })
    }

    /// The PNG of the image layer, encoded once, off the async runtime.
    pub async fn image_png(self: &Arc<Self>) -> Result<Bytes, String> {
        if let Some(r) = self.png.get() {
            return r.clone();
        }
        let me = Arc::clone(self);
        tokio::task::spawn_blocking(move || me.image_png_blocking())
            .await
            .map_err(|e| format!("encoder stopped: {e}"))?
    }

    /// The PNG of the image layer, encoded once (waits if another thread is encoding it).
    /// Blocking.
    pub fn image_png_blocking(&self) -> Result<Bytes, String> {
        self.png
            .get_or_init(|| {
                self.metrics.frames_encoded.fetch_add(1, Ordering::Relaxed);
                self.encode_layer_blocking(Layer::Image)?
                    .map(Bytes::from)
                    .ok_or_else(|| "no image layer".to_owned())
            })
            .clone()
    }

    /// A frame that another node rendered, or a finished job's stored one: its image
    /// layer's PNG, and the layers the stored files hold.
    pub(super) fn relayed(
        progress: Progress,
        png: Bytes,
        layers: Vec<Layer>,
        metrics: Arc<Metrics>,
    ) -> Self {
        let (width, height) = crate::raster::png_size(&png).unwrap_or_default();
        Self {
            iteration: progress.iteration,
            preview: false,
            width,
            height,
            shown: None,
            pixels: std::sync::OnceLock::from(None),
            exposure: 1.0,
            progress,
            layers,
            png: std::sync::OnceLock::from(Ok(png)),
            others: Default::default(),
            metrics,
        }
    }

    /// True for the last frame of a render that ran to its end.
    pub fn is_last(&self) -> bool {
        // A preview, whose pixels may still be on their way, is never the last frame.
        matches!(self.pixels.get(), Some(Some(f)) if f.last)
    }

    /// Pixels of the frame this node rendered (0 for a relayed one).
    pub fn pixel_count(&self) -> usize {
        self.pixels()
            .map_or(0, |f| f.image.width() as usize * f.image.height() as usize)
    }

    /// Encodes one layer as PNG (`None` if the frame lacks it). Blocking.
    pub fn encode_layer_blocking(&self, layer: Layer) -> Result<Option<Vec<u8>>, String> {
        let Some(frame) = self.pixels() else {
            return Ok(None);
        };
        layers::encode_layer(frame, layer.as_str(), self.exposure).map_err(|e| e.to_string())
    }

    /// One layer as PNG, or the image as EXR, encoded once and shared (`None` if the
    /// frame lacks the layer or the layer is unknown). Blocking.
    pub fn encoded_blocking(&self, layer: Layer, exr: bool) -> Result<Option<Bytes>, String> {
        if layer == Layer::Image && !exr {
            return self.image_png_blocking().map(Some);
        }
        let Some(k) = OTHER_ENCODINGS.iter().position(|e| *e == (layer, exr)) else {
            return Ok(None);
        };
        self.others[k]
            .get_or_init(|| {
                let bytes = match (self.pixels(), exr) {
                    (None, _) => Ok(None),
                    (Some(frame), true) => crate::raster::encode_exr(&frame.image)
                        .map(Some)
                        .map_err(|e| e.to_string()),
                    (Some(_), false) => self.encode_layer_blocking(layer),
                };
                bytes.map(|b| b.map(Bytes::from))
            })
            .clone()
    }
}
