//! Which triangles are final, which get a sample near their centre (smooth) and which get
//! their contour traced (complex): F&P04 §4.2. Two oracles decide: [`Perceptual`], the
//! perceptual distance between successive frames with the noise compensation of
//! [`crate::progressive::noise`], and [`Guo`], Mitchell's contrast test on each triangle's
//! traced contour (spec §4.3).

use super::judge::Judge;
use super::samples::SampleSet;
use super::Mesh;
use crate::progressive::classify::{classify, guarded_t1, triangle_distances};
use crate::progressive::complex::{rupture_direction, Boundary, ContourPixel, ContourWalker};
use crate::progressive::guo;
use crate::progressive::mesh::{untextured, Tri};
use crate::progressive::noise::{
    signal_distance, spans_contour, triangle_noise, visible_discontinuity, NoiseLevel,
};
use crate::progressive::TriangleClass;
use crate::raster::{Image, LinearImage, PixelCoord, Rgb};
use crate::scene::ObjectId;
use rayon::prelude::*;
use std::time::Instant;

/// What a classifier looks at: the current frame, the one before it, its triangulation
/// and the samples under it.
pub(super) struct View<'a> {
    pub samples: &'a SampleSet,
    pub mesh: &'a Mesh,
    pub ids: &'a [ObjectId],
    /// The previous frame; `None` for the first.
    pub prev: Option<&'a LinearImage>,
    pub cur: &'a LinearImage,
    pub iteration: u32,
}

/// The classes of the current triangles and what the frame shows of the decision.
pub(super) struct Classification {
    pub classes: Vec<TriangleClass>,
    /// The distance map between the two frames (JNDs): the `distance` layer.
    pub distance: Option<Image<f32>>,
    /// Its mean; NaN without a map.
    pub mean_distance: f64,
    /// Whether the classes mean anything yet (the first frame has no distance to judge).
    pub shown: bool,
    pub metric_ms: f64,
}

impl Classification {
    /// Every one of `count` triangles in `class`.
    pub(super) fn uniform(class: TriangleClass, count: usize, shown: bool) -> Self {
        Self {
            classes: vec![class; count],
            distance: None,
            mean_distance: f64::NAN,
            shown,
            metric_ms: 0.0,
        }
    }
}

/// One oracle of F&P04 §4.2's classification.
pub(super) trait Classifier {
    fn classify(&mut self, view: &View, contours: &mut ContourWalker) -> Classification;

    /// T1 as used so far (statistics).
    fn t1(&self) -> Option<f64>;

    /// The direction along which a complex triangle's interior is interpolated between
    /// its contour's values (F&P04 §4.2, spec §4.4); `shown` are the contour pixels'
    /// displayed values, `shown_at` any traced pixel's.
    fn fill_direction(
        &self,
        tr: &Tri,
        contour: &[ContourPixel],
        shown: &[Rgb],
        shown_at: &dyn Fn(PixelCoord) -> Rgb,
    ) -> Option<(f64, f64)>;

    /// Whether the oracle discounts noise: the loop then shades the noise twin of the
    /// first sample set and hands it to [`Self::learn_noise`] once, after the first frame
    /// and before the first pair of frames is judged.
    fn wants_noise(&self) -> bool {
        false
    }

    /// The distance noise alone makes between `first` (the first frame) and `twin` (the
    /// same triangulation over independent estimates of the same pixels, `seeds`), and
    /// the local noise level; the distance map once measured (`None`: no compensation).
    fn learn_noise(
        &mut self,
        _first: &LinearImage,
        _twin: &LinearImage,
        _seeds: &[PixelCoord],
        _level: Option<NoiseLevel>,
    ) -> Option<&[f32]> {
        None
    }
}

/// What the noise twin of the first sample set measured ([`crate::progressive::noise`]).
pub(super) struct NoiseEstimate {
    /// The distance map noise alone produces.
    pub map: Vec<f32>,
    /// The local noise amplitude, as displayed.
    pub level: Option<NoiseLevel>,
}

/// F&P04's oracle: the judge's distance between successive frames, per triangle, against
/// T0 and T1; with `noise`, the distance noise alone explains is discounted first.
pub(super) struct Perceptual<'j> {
    pub judge: &'j mut dyn Judge,
    pub t0: f64,
    /// From the scene, or the mean of the first distance map (F&P04 §5).
    pub t1: Option<f64>,
    pub noise: Option<NoiseEstimate>,
    /// Noise compensation on, and anything can become final (T0 > 0).
    pub compensates: bool,
    pub exposure: f32,
}

impl Classifier for Perceptual<'_> {
    fn classify(&mut self, v: &View, _: &mut ContourWalker) -> Classification {
        let count = v.mesh.tris.len();
        let Some(prev) = v.prev else {
            // §4.2: the second picture needs one sample near every centre.
            return Classification::uniform(TriangleClass::Smooth, count, false);
        };
        let t = Instant::now();
        let seeds = v.samples.traced_coords();
        let map = self.judge.distance(prev, v.cur, &seeds, v.iteration);
        let metric_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut c = match map {
            Some(map) if map.len() == v.samples.n => self.classes_from(v, map),
            _ => Classification::uniform(TriangleClass::Smooth, count, true),
        };
        c.metric_ms = metric_ms;
        c
    }

    fn t1(&self) -> Option<f64> {
        self.t1
    }

    fn fill_direction(
        &self,
        _: &Tri,
        contour: &[ContourPixel],
        shown: &[Rgb],
        _: &dyn Fn(PixelCoord) -> Rgb,
    ) -> Option<(f64, f64)> {
        rupture_direction(contour, shown)
    }

    fn wants_noise(&self) -> bool {
        self.compensates
    }

    fn learn_noise(
        &mut self,
        first: &LinearImage,
        twin: &LinearImage,
        seeds: &[PixelCoord],
        level: Option<NoiseLevel>,
    ) -> Option<&[f32]> {
        let map = self.judge.noise_distance(first, twin, seeds)?;
        if map.len() != first.pixels().len() {
            return None;
        }
        self.noise = Some(NoiseEstimate {
            map: map.into_vec(),
            level,
        });
        self.noise.as_ref().map(|e| &e.map[..])
    }
}

impl Perceptual<'_> {
    fn classes_from(&mut self, v: &View, map: Image<f32>) -> Classification {
        let raster = &v.mesh.raster;
        let mut td = triangle_distances(raster, map.pixels());
        let (sum, count) = map
            .pixels()
            .iter()
            .filter(|d| d.is_finite())
            .fold((0f64, 0usize), |(s, c), &d| (s + f64::from(d), c + 1));
        let mean = sum / count.max(1) as f64;
        // The object-id map is exact: a triangle across an object contour keeps F&P04's raw
        // distance, and is complex whatever the noise says.
        let on_contour: Option<Vec<bool>> = self.noise.as_ref().map(|_| {
            (0..td.len())
                .into_par_iter()
                .map(|t| spans_contour(raster, t, v.ids))
                .collect()
        });
        if let (Some(noise), Some(edge)) = (&self.noise, &on_contour) {
            let tn = triangle_noise(raster, &noise.map);
            td.par_iter_mut()
                .zip(&tn)
                .zip(edge)
                .filter(|(_, &e)| !e)
                .for_each(|((d, dn), _)| *d = signal_distance(*d, *dn));
        }
        // T1 is the mean of the first *raw* map (F&P04 §5), guarded (§2.9). A mean of the
        // compensated distances is dragged towards 0 by the many triangles whose distance
        // is all noise, and then every non-final triangle is complex: measured, a flat noisy
        // field was traced at 66 % instead of 10 %.
        let t0 = self.t0;
        let t1 = *self.t1.get_or_insert_with(|| guarded_t1(t0, mean));
        let mut classes: Vec<TriangleClass> = td.iter().map(|&d| classify(d, t0, t1)).collect();
        if let (Some(edge), Some(level)) = (
            &on_contour,
            self.noise.as_ref().and_then(|n| n.level.as_ref()),
        ) {
            demote_noise_complex(&mut classes, v, edge, level, self.exposure);
        }
        Classification {
            classes,
            // No NaN in any layer: a NaN distance is "unknown", shown as 0 but judged +∞
            // (never final) by triangle_distances.
            distance: Some(map.map(|&d| if d.is_nan() { 0.0 } else { d })),
            mean_distance: mean,
            shown: true,
            metric_ms: 0.0,
        }
    }
}

/// Noise-aware classification, second half ([`crate::progressive::noise`] point 5): a
/// complex triangle (its contour gets traced, its interior interpolated across a
/// discontinuity) must show a discontinuity its samples can see: it spans an object
/// contour (exact id map), or its vertices differ by Mitchell's contrast beyond the local
/// noise ([`visible_discontinuity`]). Otherwise its large distance is smooth variation or
/// noise the twin map under-estimated, and it is refined at its centre like a smooth
/// triangle. Measured on the bench scenes: without this, a third of the traced pixels
/// went to the contours of such triangles, whose tracing then fed more noise into the
/// next frame.
fn demote_noise_complex(
    classes: &mut [TriangleClass],
    v: &View,
    on_contour: &[bool],
    noise: &NoiseLevel,
    exposure: f32,
) {
    let s = v.samples;
    let albedo = s.albedo.as_deref();
    for ((c, tr), &edge) in classes.iter_mut().zip(&v.mesh.tris).zip(on_contour) {
        if *c != TriangleClass::Complex || edge {
            continue;
        }
        let at = tr.v.map(|p| s.index(p));
        // A texture's own contrast is no discontinuity: the albedo map reproduces it.
        let rad = at.map(|i| s.rad[i]);
        let rad = albedo
            .and_then(|a| untextured(rad, [a[at[0]]?, a[at[1]]?, a[at[2]]?]))
            .unwrap_or(rad);
        let shown = rad.map(|x| guo::displayed(x, exposure));
        if !visible_discontinuity(shown, at.map(|i| v.ids[i]), at.map(|i| noise.at(i))) {
            *c = TriangleClass::Smooth;
        }
    }
}

/// Guo 1998's oracle (spec §4.3): a triangle whose traced contour shows Mitchell's
/// contrast (noise discounted) is complex; a small calm one is final (when T0 > 0); the
/// rest are smooth.
pub(super) struct Guo {
    pub t1: Option<f64>,
    pub exposure: f32,
    /// Whether anything may become final (T0 > 0).
    pub finals: bool,
}

impl Classifier for Guo {
    fn classify(&mut self, v: &View, contours: &mut ContourWalker) -> Classification {
        let s = v.samples;
        let classes = v
            .mesh
            .tris
            .iter()
            .map(|tr| {
                let samples = guo::noise_discounted(
                    contours
                        .walk(tr)
                        .iter()
                        .map(|c| s.index(c.p))
                        .filter(|&i| s.traced[i])
                        .map(|i| (s.rad[i], s.variance[i], v.ids[i])),
                );
                if guo::is_edge(samples.iter().copied(), self.exposure) {
                    TriangleClass::Complex
                } else if self.finals
                    && tr.longest_edge() <= guo::CALM_EDGE
                    && guo::is_calm(samples, self.exposure)
                {
                    TriangleClass::Final
                } else {
                    TriangleClass::Smooth
                }
            })
            .collect();
        Classification {
            classes,
            distance: None,
            mean_distance: f64::NAN,
            shown: true,
            metric_ms: 0.0,
        }
    }

    fn t1(&self) -> Option<f64> {
        self.t1
    }

    fn fill_direction(
        &self,
        tr: &Tri,
        contour: &[ContourPixel],
        shown: &[Rgb],
        shown_at: &dyn Fn(PixelCoord) -> Rgb,
    ) -> Option<(f64, f64)> {
        let b = Boundary::new(tr, contour, shown_at);
        guo::least_discrepancy_direction(&b, contour, shown, tr.longest_edge())
    }
}
