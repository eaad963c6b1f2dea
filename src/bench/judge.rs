//! The judge that knows the truth: one scene seen at a declared viewing
//! condition (its `display.pixels_per_degree` set to `ppd` for the progressive render and
//! for FLIP), judged against the converged render ([`super::truth`]).
//!
//! Q = FLIP(progressive, truth) / FLIP(reference, truth): Q ≤ 1 means the progressive
//! picture is at least as close to the truth as the reference. Beside it: the time ratio
//! (medians of alternating runs), the floor comparison of the rest of the study (FLIP
//! against the independent reference over the reference's own noise floor), whether
//! objects keep their colour ([`super::objects`]) and a contact sheet ([`super::sheet`]).

use super::flip::{flip, flip_with_map};
use super::objects::{object_colours, worst_ratio, ObjectColour};
use super::sheet::contact_sheet;
use super::{median, ms};
use crate::cancel::CancelToken;
use crate::progressive::{self, RenderOptions};
use crate::raster::{encode_png_rgb8, Image, LinearImage};
use crate::scene::{ObjectId, RenderMode, Scene};
use crate::tracer::{self, PathTracer};
use anyhow::Context;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// Q and time a scene must reach at every condition ("Q ≤ 1.0 at no more than
/// 0.5× the reference's time").
pub const Q_TARGET: f64 = 1.0;
pub const TIME_TARGET: f64 = 0.5;

/// What one scene needs to be judged at any condition.
pub struct Case<'a> {
    pub scene: &'a Scene,
    pub tracer: &'a PathTracer,
    pub truth: &'a LinearImage,
    /// The truth's two independent halves (their mean is `truth`): its own error.
    pub truth_halves: (&'a LinearImage, &'a LinearImage),
    /// The independent reference (same samples, another seed): the floor comparison.
    pub judge: &'a LinearImage,
    /// The object-id map (one primary ray per pixel): the objects whose colour is judged.
    pub ids: &'a Image<ObjectId>,
    /// Alternating reference/progressive runs whose medians make the time ratio.
    pub runs: usize,
    pub cancel: &'a CancelToken,
}

/// One scene at one condition.
#[derive(Clone, Debug, Serialize)]
pub struct Condition {
    pub ppd: f32,
    pub reference_ms: f64,
    pub progressive_ms: f64,
    /// Progressive time ÷ reference time (medians of the alternating runs).
    pub time_ratio: f64,
    pub pixel_fraction: f64,
    /// The render found its paths too cheap for the loop and traced every pixel
    /// (stop reason `reference_cheaper`): its picture is the reference.
    pub traced_whole: bool,
    /// FLIP(progressive, truth) and FLIP(reference, truth), means.
    pub progressive_flip: f64,
    pub reference_flip: f64,
    /// `progressive_flip / reference_flip`.
    pub q: f64,
    /// FLIP between the truth's two halves: the truth's own error, to be at most
    /// [`super::truth::SELF_ERROR_SHARE`] of `reference_flip` (or the truth was capped).
    pub truth_self_flip: f64,
    /// FLIP(progressive, independent reference) ÷ FLIP(reference, independent reference):
    /// the floor comparison, which cannot see error hidden under the reference's noise.
    pub floor_ratio: f64,
    pub objects: Vec<ObjectColour>,
    /// The largest object error ÷ its allowance (≤ 1 passes; 0 when no object is judged).
    pub worst_object_ratio: f64,
    /// The contact sheet, relative to the output folder.
    pub sheet: String,
    /// `adaptive` beside uniform + OIDN and the reference + OIDN ([`super::denoised`]).
    pub denoised: Option<super::denoised::DenoisedRow>,
}

impl Condition {
    /// Q ≤ 1.0 at ≤ 0.5× the time.
    #[must_use]
    pub fn passes(&self) -> bool {
        self.q <= Q_TARGET && self.time_ratio <= TIME_TARGET
    }

    /// What `time_ratio` holds beyond the traced pixels' own share (`pixel_fraction`, what
    /// they cost the reference): the analysis's primary rays, the noise twins and the loop's
    /// whole-image work (triangulation, reconstruction, shading, the vision model).
    #[must_use]
    pub fn overhead_ratio(&self) -> f64 {
        self.time_ratio - self.pixel_fraction
    }

    /// Why the progressive render did not reach [`TIME_TARGET`]; `None` when it did.
    #[must_use]
    pub fn slow_because(&self) -> Option<SlowBecause> {
        if self.time_ratio <= TIME_TARGET {
            None
        } else if self.traced_whole {
            Some(SlowBecause::CheapPaths)
        } else if self.overhead_ratio() >= self.pixel_fraction {
            Some(SlowBecause::Overhead)
        } else {
            Some(SlowBecause::Pixels)
        }
    }

    #[must_use]
    pub fn objects_pass(&self) -> bool {
        self.worst_object_ratio <= 1.0
    }
}

/// Why a progressive render took more than [`TIME_TARGET`] of the reference's time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SlowBecause {
    /// The work beyond the traced pixels outweighed them: the scene's pixels are too cheap
    /// (few samples, short paths) for skipping most of them to pay for that work.
    Overhead,
    /// The traced pixels outweighed the rest: the picture needed many of them.
    Pixels,
    /// The render traced every pixel from the start: its paths are too cheap for the loop
    /// to pay for its own work (`progressive::driver::cost`).
    CheapPaths,
}

/// The scene at `ppd`: timed, judged, its contact sheet written to
/// `out_dir/sheets/<scene>-<ppd>ppd.png`.
pub fn at_condition(case: &Case, ppd: f32, out_dir: &Path) -> anyhow::Result<Condition> {
    let mut scene = case.scene.clone();
    scene.display.pixels_per_degree = ppd;
    let (mut ref_times, mut prog_times) = (Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..case.runs.max(1) {
        let t = Instant::now();
        let reference = tracer::render_reference(case.tracer, case.cancel, &|_, _| {})?;
        ref_times.push(ms(t));
        let t = Instant::now();
        let prog = render_mode(&scene, case, RenderMode::Progressive)?;
        prog_times.push(ms(t));
        last = Some((reference, prog));
    }
    let (reference, prog) = last.context("at least one timing run")?;
    let (reference_ms, progressive_ms) = (median(&mut ref_times), median(&mut prog_times));
    let exposure = scene.display.exposure;
    let (prog_score, map) = flip_with_map(case.truth, &prog.image, exposure, ppd);
    let reference_flip = flip(case.truth, &reference, exposure, ppd).mean;
    let floor = flip(case.judge, &reference, exposure, ppd).mean;
    let objects = object_colours(case.ids, &prog.image, &reference, case.truth, exposure);

    let sheet = format!("sheets/{}-{}ppd.png", file_stem(&scene.name), ppd);
    let path = out_dir.join(&sheet);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let png = encode_png_rgb8(&contact_sheet(
        &reference,
        &prog.image,
        case.truth,
        &map,
        exposure,
    ))?;
    std::fs::write(&path, png).with_context(|| format!("cannot write {}", path.display()))?;

    Ok(Condition {
        ppd,
        reference_ms,
        progressive_ms,
        time_ratio: progressive_ms / reference_ms,
        pixel_fraction: prog.stats.pixel_fraction,
        traced_whole: prog.stats.stop_reason.as_deref() == Some("reference_cheaper"),
        progressive_flip: prog_score.mean,
        reference_flip,
        q: ratio(prog_score.mean, reference_flip),
        truth_self_flip: flip(case.truth_halves.0, case.truth_halves.1, exposure, ppd).mean,
        floor_ratio: ratio(flip(case.judge, &prog.image, exposure, ppd).mean, floor),
        worst_object_ratio: worst_ratio(&objects),
        objects,
        sheet,
        denoised: Some(super::denoised::judge(
            case,
            &scene,
            &reference,
            (reference_ms, reference_flip),
        )?),
    })
}

/// One point of the t0 sweep at one condition.
#[derive(Clone, Debug, Serialize)]
pub struct SweepPoint {
    pub ppd: f32,
    pub t0: f32,
    /// One run ÷ the scene's reference time (median).
    pub time_ratio: f64,
    pub pixel_fraction: f64,
    /// FLIP against the independent reference (the floor comparison's numerator).
    pub flip: f64,
    /// FLIP(progressive, truth) / FLIP(reference, truth).
    pub q: f64,
}

/// The t0 sweep at `ppd`: one run of `mode` per t0, timed against `reference_ms`.
pub fn sweep(
    case: &Case,
    (reference, reference_ms): (&LinearImage, f64),
    mode: RenderMode,
    ppd: f32,
    t0s: &[f32],
) -> anyhow::Result<Vec<SweepPoint>> {
    let exposure = case.scene.display.exposure;
    let reference_flip = flip(case.truth, reference, exposure, ppd).mean;
    t0s.iter()
        .map(|&t0| {
            let mut scene = case.scene.clone();
            scene.display.pixels_per_degree = ppd;
            scene.progressive.t0 = t0;
            let t = Instant::now();
            let f = render_mode(&scene, case, mode)?;
            Ok(SweepPoint {
                ppd,
                t0,
                time_ratio: ms(t) / reference_ms,
                pixel_fraction: f.stats.pixel_fraction,
                flip: flip(case.judge, &f.image, exposure, ppd).mean,
                q: ratio(
                    flip(case.truth, &f.image, exposure, ppd).mean,
                    reference_flip,
                ),
            })
        })
        .collect()
}

fn render_mode(scene: &Scene, case: &Case, mode: RenderMode) -> anyhow::Result<progressive::Frame> {
    let opts = RenderOptions {
        mode: Some(mode),
        ..RenderOptions::default()
    };
    Ok(progressive::render(
        scene,
        case.tracer,
        &opts,
        &mut |_| {},
        case.cancel,
    )?)
}

/// A scene name as a file name: anything but ASCII letters, digits, `-`, `_` and `.`
/// becomes `_`, so no name (`../x`, `a/b`) can place a file outside the sheets folder.
pub(crate) fn file_stem(name: &str) -> String {
    let stem: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    if stem.is_empty() || stem.chars().all(|c| c == '.') {
        format!("scene{stem}")
    } else {
        stem
    }
}

/// `a / b`, where two identical images (b = 0: a reference equal to its truth, as on a
/// black scene) make a = 0 too and count as equal (1), not as NaN.
pub(crate) fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        a / b
    } else if a > 0.0 {
        f64::INFINITY
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_slow_render_says_whether_its_pixels_the_rest_or_its_cheap_paths_made_it_slow() {
        let mut c = Condition {
            ppd: 60.0,
            reference_ms: 100.0,
            progressive_ms: 80.0,
            time_ratio: 0.8,
            pixel_fraction: 0.2,
            traced_whole: false,
            progressive_flip: 0.1,
            reference_flip: 0.1,
            q: 1.0,
            truth_self_flip: 0.0,
            floor_ratio: 1.0,
            objects: Vec::new(),
            worst_object_ratio: 0.0,
            sheet: String::new(),
            denoised: None,
        };
        assert_eq!(c.slow_because(), Some(SlowBecause::Overhead));
        c.pixel_fraction = 0.6;
        assert_eq!(c.slow_because(), Some(SlowBecause::Pixels));
        (c.pixel_fraction, c.time_ratio, c.traced_whole) = (1.0, 1.02, true);
        assert_eq!(c.slow_because(), Some(SlowBecause::CheapPaths));
        c.time_ratio = TIME_TARGET;
        assert_eq!(c.slow_because(), None);
    }

    #[test]
    fn a_scene_name_cannot_leave_the_sheets_folder() {
        assert_eq!(file_stem("cornell-box"), "cornell-box");
        assert_eq!(file_stem("../../etc/x"), ".._.._etc_x");
        assert_eq!(file_stem("a b/c\\d"), "a_b_c_d");
        assert_eq!(file_stem(""), "scene");
        assert_eq!(file_stem(".."), "scene..");
        assert_eq!(file_stem("é"), "_");
    }

    #[test]
    fn a_ratio_of_two_perfect_images_is_one_and_never_nan() {
        assert_eq!(ratio(0.0, 0.0), 1.0);
        assert_eq!(ratio(0.1, 0.0), f64::INFINITY);
        assert!((ratio(0.05, 0.1) - 0.5).abs() < 1e-12);
    }
}
