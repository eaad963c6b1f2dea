//! The comparison a user makes: `adaptive` against what they already run, uniform path
//! tracing plus Intel Open Image Denoise in the same time, and against the reference
//! denoised. All judged by FLIP against the truth at the condition's ppd, in one run.
//!
//! Uniform + OIDN's time is its render plus the auxiliary images and the denoise (the
//! denoiser's cost is timed once on the reference and taken from the uniform render's
//! budget, so the two peers finish together).

use super::flip::flip;
use super::judge::{ratio, Case};
use super::objects::{object_colours, worst_ratio};
use super::{median, ms};
use crate::denoise::{Aux, Denoiser, Quality, Run};
use crate::progressive::{self, uniform, RenderOptions};
use crate::raster::LinearImage;
use crate::scene::{RenderMode, Scene};
use crate::tracer;
use serde::Serialize;
use std::time::{Duration, Instant};

/// `adaptive` is to be at most this share of uniform + OIDN's FLIP at equal time.
pub const VS_UNIFORM_TARGET: f64 = 0.85;
/// … and reach the reference's quality (Q ≤ 1) in at most this share of its time.
pub const TIME_TARGET: f64 = 0.25;

/// One scene at one condition: adaptive and the denoised peers.
#[derive(Clone, Debug, Serialize)]
pub struct DenoisedRow {
    pub adaptive_ms: f64,
    /// Adaptive time ÷ reference time (medians).
    pub time_ratio: f64,
    /// Paths traced ÷ the reference's.
    pub sample_ratio: f64,
    pub adaptive_flip: f64,
    /// FLIP(adaptive, truth) ÷ FLIP(reference, truth).
    pub q: f64,
    pub stop_reason: String,
    /// Uniform + OIDN in adaptive's time: its FLIP, samples per pixel and whole time.
    pub uniform_oidn_flip: f64,
    pub uniform_oidn_spp: u32,
    pub uniform_oidn_ms: f64,
    /// The reference denoised: the best the reference's samples give.
    pub reference_oidn_flip: f64,
    /// `adaptive_flip / uniform_oidn_flip` (≤ [`VS_UNIFORM_TARGET`] passes).
    pub vs_uniform_oidn: f64,
    /// The auxiliary images and one `High` denoise at this size, ms.
    pub oidn_ms: f64,
    /// Adaptive's largest object colour error ÷ its allowance (≤ 1: objects keep their
    /// colour; 0 when no object is judged), as the progressive column's.
    pub worst_object_ratio: f64,
}

impl DenoisedRow {
    /// Closer to the truth than uniform + OIDN by the target margin.
    #[must_use]
    pub fn beats_uniform(&self) -> bool {
        self.vs_uniform_oidn <= VS_UNIFORM_TARGET
    }

    #[must_use]
    pub fn objects_pass(&self) -> bool {
        self.worst_object_ratio <= 1.0
    }

    /// The reference's quality in at most a quarter of its time.
    #[must_use]
    pub fn fast_enough(&self) -> bool {
        self.q <= 1.0 && self.time_ratio <= TIME_TARGET
    }
}

/// The scene (its ppd already set) judged: adaptive timed over `case.runs`, the peers
/// once. `reference` is the reference image, with its median time and its FLIP against
/// the truth at this condition (already measured by the caller).
pub fn judge(
    case: &Case,
    scene: &Scene,
    reference: &LinearImage,
    (reference_ms, reference_flip): (f64, f64),
) -> anyhow::Result<DenoisedRow> {
    let denoiser = Denoiser::shared()?;
    let (exposure, ppd) = (scene.display.exposure, scene.display.pixels_per_degree);
    let opts = RenderOptions {
        mode: Some(RenderMode::Adaptive),
        denoise: Some(true),
        ..RenderOptions::default()
    };
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..case.runs.max(1) {
        let t = Instant::now();
        let f = progressive::render(scene, case.tracer, &opts, &mut |_| {}, case.cancel)?;
        times.push(ms(t));
        last = Some(f);
    }
    let adaptive = last.expect("at least one run");
    let adaptive_ms = median(&mut times);

    let t = Instant::now();
    let aux = tracer::aux::aux_maps(case.tracer, case.cancel)?;
    let aux_ms = ms(t);
    let run = Run {
        input_scale: progressive::denoise_input_scale(scene),
        ..Run::new(Quality::High)
    };
    let denoise = |img: &LinearImage| {
        let a = Aux {
            albedo: &aux.albedo,
            normal: &aux.normal,
            clean: true,
        };
        denoiser.denoise(img, Some(&a), &run)
    };
    let reference_oidn = denoise(reference)?;
    let oidn_ms = ms(t);

    let t = Instant::now();
    let budget = Duration::from_secs_f64(((adaptive_ms - oidn_ms) / 1e3).max(1e-3));
    let (uniform, spp) = uniform::render_equal_time(scene, case.tracer, budget, case.cancel)?;
    let uniform_oidn = denoise(&uniform)?;
    // Its render and denoise, and the auxiliary images it needs (traced once above).
    let uniform_oidn_ms = ms(t) + aux_ms;

    let adaptive_flip = flip(case.truth, &adaptive.image, exposure, ppd).mean;
    let uniform_oidn_flip = flip(case.truth, &uniform_oidn, exposure, ppd).mean;
    let reference_samples = f64::from(scene.width)
        * f64::from(scene.height)
        * f64::from(scene.render.samples_per_pixel);
    Ok(DenoisedRow {
        adaptive_ms,
        time_ratio: adaptive_ms / reference_ms,
        sample_ratio: adaptive.stats.samples_traced as f64 / reference_samples.max(1.0),
        adaptive_flip,
        q: ratio(adaptive_flip, reference_flip),
        stop_reason: adaptive.stats.stop_reason.clone().unwrap_or_default(),
        uniform_oidn_flip,
        uniform_oidn_spp: spp,
        uniform_oidn_ms,
        reference_oidn_flip: flip(case.truth, &reference_oidn, exposure, ppd).mean,
        vs_uniform_oidn: ratio(adaptive_flip, uniform_oidn_flip),
        oidn_ms,
        worst_object_ratio: worst_ratio(&object_colours(
            case.ids,
            &adaptive.image,
            reference,
            case.truth,
            exposure,
        )),
    })
}
