//! `glimpse bench`: the speed-versus-accuracy study (the brief: "measure that trade").
//!
//! For every scene of a folder, in one process and one run, side by side:
//! * **reference**: every pixel traced at the scene's samples per pixel;
//! * **progressive**: F&P04 (`render.mode = "progressive"`), with the Monte Carlo noise
//!   compensation of `progressive::noise`, and once more without it (F&P04 as published);
//! * **guo**: Guo's oracle in the same machinery, stopped at the progressive run's ray
//!   budget, noise twins included (F&P04 §5.1 stop Guo "when the sampling rate becomes
//!   similar");
//! * **uniform**: every pixel traced with as many samples as fit in the progressive run's
//!   wall time (equal time);
//! * the progressive run's time split ([`TimeSplit`]): its traced pixels traced again
//!   alone, against the reference, and the rest (the loop's own price);
//! * the judge that knows the truth ([`judge`]): every scene at several declared
//!   viewing conditions (pixels per degree), Q = FLIP(progressive, truth) / FLIP(reference,
//!   truth) against a cached converged render ([`truth`]), the time ratio, whether objects
//!   keep their colour ([`objects`]) and a contact sheet ([`sheet`]);
//! * a sweep of `t0` at 28 and 60 ppd drawing the speed/accuracy curve (Q against time);
//! * with `--corpus N --seed S`, the same judge on N generated scenes ([`corpus`]).
//!
//! Each image is judged by LDR-FLIP against an *independent* reference (the same scene
//! traced with another seed), beside the reference's own noise floor (reference against
//! independent reference) and Glimpse's own metric, and against the truth. Ratios, not
//! absolute times, are the result: the machines are noisy, a ratio measured in one run is
//! not.

pub mod corpus;
pub mod denoised;
pub mod flip;
pub mod judge;
pub mod objects;
pub mod peer;
pub mod progress;
pub mod report;
pub mod sheet;
pub mod truth;

use crate::cancel::CancelToken;
use crate::metric::{self, MetricParams};
pub use crate::progressive::display_model;
use crate::progressive::{self, uniform, RenderOptions};
use crate::raster::{LinearImage, PixelCoord};
use crate::scene::{parse_scene, Limits, RenderMode, Scene, SceneOrigin};
use crate::tracer::{self, PathTracer};
use crate::vision::VisionModel;
use anyhow::Context;
use flip::{flip, FlipScore};
use judge::{Case, Condition, SweepPoint};
use progress::Progress;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// What to run.
#[derive(Clone, Debug)]
pub struct BenchConfig {
    pub scenes_dir: PathBuf,
    pub out_dir: PathBuf,
    /// Small images and few samples: the whole study in a few minutes (CI).
    pub quick: bool,
    /// Every scene's samples per pixel multiplied by this (≥ 1; 1 = the scenes as written).
    /// The loop's own work (analysis, vision model, metric, triangulation) does not grow
    /// with the samples, the tracing does: this shows how the time ratios move when a pixel
    /// costs more, as it does in the scenes F&P04 timed (§5: references of 4 to 50 minutes).
    pub spp_factor: u32,
    /// Every scene scaled up to at least this many pixels on its long side (`None`: as
    /// written).
    pub min_side: Option<u32>,
    /// The declared viewing conditions (pixels per degree) every bundled scene is judged at.
    pub conditions: Vec<f32>,
    /// Where converged renders are cached (default: `out_dir/cache`).
    pub cache_dir: PathBuf,
    /// Study the scenes of `scenes_dir` (false: the corpus alone).
    pub bundled: bool,
    pub corpus: Option<CorpusConfig>,
    /// `--public DIR`: the public scenes of DIR (each `NAME/scene-v4.pbrt`), studied like
    /// the bundled ones at [`PUBLIC_SIDE`] pixels, with samples chosen by
    /// [`public_samples`]. Not run in quick mode.
    pub public_dir: Option<PathBuf>,
    /// Judge every scene at the conditions only (the truth, Q and time, `adaptive` against
    /// uniform + OIDN), without the per-method table, the time split and the t0 sweeps.
    pub judge_only: bool,
    /// Alternating timed runs whose medians make each time ratio.
    pub runs: usize,
    /// The longest the truth of one scene may take to trace, estimated from the
    /// reference's time ([`truth::TruthCheck::cap_ms`]), seconds.
    pub truth_cap_s: f64,
}

/// `--corpus N --seed S`.
#[derive(Clone, Debug)]
pub struct CorpusConfig {
    pub scenes: usize,
    pub seed: u64,
    pub profile: corpus::Profile,
    /// Judge each corpus scene also at [`BenchConfig::conditions`], not only at its own
    /// declared pixels per degree.
    pub at_conditions: bool,
}

impl BenchConfig {
    /// The study's defaults for `scenes_dir` and `out_dir`: the four standard viewing
    /// conditions (two in quick mode), bundled scenes, no corpus, the cache under `out_dir`.
    #[must_use]
    pub fn new(scenes_dir: PathBuf, out_dir: PathBuf, quick: bool) -> Self {
        Self {
            cache_dir: out_dir.join("cache"),
            scenes_dir,
            out_dir,
            quick,
            spp_factor: 1,
            min_side: None,
            conditions: if quick {
                QUICK_CONDITIONS.to_vec()
            } else {
                STANDARD_CONDITIONS.to_vec()
            },
            bundled: true,
            corpus: None,
            public_dir: None,
            judge_only: false,
            runs: if quick { 1 } else { TIMING_RUNS },
            truth_cap_s: if quick {
                QUICK_TRUTH_CAP_S
            } else {
                TRUTH_CAP_S
            },
        }
    }

    /// The viewing conditions a truth must be converged at: every condition of the run,
    /// and the sweep's unless the scenes are judged at the conditions only.
    fn truth_ppds(&self) -> Vec<f32> {
        let mut p = self.conditions.clone();
        if !self.judge_only {
            let sweep: &[f32] = if self.quick {
                &QUICK_CONDITIONS[..1]
            } else {
                &SWEEP_CONDITIONS
            };
            p.extend(sweep.iter().filter(|s| !self.conditions.contains(s)));
        }
        p
    }
}

/// The default cap on one truth's tracing time, seconds: a 5 s reference gets a truth of
/// up to 32× its samples (its first 16× doubled once).
pub const TRUTH_CAP_S: f64 = 300.0;
/// `--quick`'s cap: the five examples stay within a few minutes.
pub const QUICK_TRUTH_CAP_S: f64 = 20.0;

/// The declared viewing conditions judged by default, pixels per degree: 28 is a 2004 display
/// seen from 50 cm (the scene format's default); 45, 60 and 90 modern desktop and laptop
/// displays at their usual distances.
pub const STANDARD_CONDITIONS: [f32; 4] = [28.0, 45.0, 60.0, 90.0];
/// `--quick`'s conditions: the old default and a modern display.
pub const QUICK_CONDITIONS: [f32; 2] = [28.0, 60.0];
/// The t0 sweep runs at these conditions, or at the first of
/// [`QUICK_CONDITIONS`] in quick mode.
pub const SWEEP_CONDITIONS: [f32; 2] = [28.0, 60.0];

/// One method's result on one scene.
#[derive(Clone, Debug, Serialize)]
pub struct MethodResult {
    pub method: String,
    pub ms: f64,
    /// `ms` over the reference's time.
    pub time_ratio: f64,
    pub pixels_traced: u64,
    pub pixel_fraction: f64,
    /// Samples per pixel of the uniform render (equal time).
    pub spp: Option<u32>,
    pub flip: FlipScore,
    /// Mean FLIP against the truth ([`truth::TRUTH_SPP_FACTOR`] × the scene's samples,
    /// another seed): the error against the picture a user actually wants. Blotches that an
    /// interpolation of noisy samples leaves are judged here against truth, not against
    /// another noisy image.
    pub converged_flip: f64,
    /// Glimpse's metric (adaptive block map mean, JNDs) against the independent reference.
    pub glimpse_distance: f64,
    /// Share of the render spent in the metric and the triangulation.
    pub overhead_share: Option<f64>,
}

/// A target of the study, checked on measured numbers.
#[derive(Clone, Debug, Serialize)]
pub struct TargetCheck {
    pub target: String,
    pub met: bool,
    pub detail: String,
}

/// Where the progressive render's time goes, against the reference's time: the pixels it
/// traced, traced again alone (the same list, no loop), and everything else. The first
/// part is what its pixel fraction must cost; the second is the loop's own price.
#[derive(Clone, Debug, Serialize)]
pub struct TimeSplit {
    /// Tracing the progressive run's pixels alone ÷ the reference's time.
    pub traced_alone_ratio: f64,
    /// Cost of one of those pixels ÷ the reference's mean cost per pixel: above 1 where the
    /// loop traces where the picture changes (edges, glossy and shadowed parts: longer paths).
    pub pixel_cost_ratio: f64,
    /// (progressive time − tracing alone) ÷ the reference's time: analysis (object ids,
    /// texture albedos), noise twins, vision model, metric, triangulation, shading.
    pub loop_ratio: f64,
    /// The loop's part, from the run's own statistics, in ms of that run.
    pub loop_parts: LoopParts,
}

/// The loop's own work in one progressive run (its [`progressive::RenderStats`]), ms.
#[derive(Clone, Debug, Serialize)]
pub struct LoopParts {
    /// The loop's tracing beyond the same pixels traced alone: the noise twins, the mesh
    /// built on a thread beside the trace, and each iteration's last batches.
    pub trace_beyond_alone_ms: f64,
    /// Object ids, first sample set, texture albedos.
    pub analysis_ms: f64,
    /// Vision model and adaptive metric (frames and noise twins).
    pub metric_ms: f64,
    /// Triangulation, rasterisation and shading not overlapped by the trace.
    pub triangulate_ms: f64,
    /// The rest: classification, work lists, frames.
    pub other_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct SceneResult {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub reference_ms: f64,
    /// FLIP between the reference and the independent reference (same spp, other seed).
    pub noise_floor: FlipScore,
    pub methods: Vec<MethodResult>,
    /// The t0 sweep at [`SWEEP_CONDITIONS`].
    pub sweep: Vec<SweepPoint>,
    /// The same sweep in adaptive mode (denoised).
    pub adaptive_sweep: Vec<SweepPoint>,
    /// The judge against the truth at each of [`BenchConfig::conditions`].
    pub conditions: Vec<Condition>,
    /// (normal exposure, exposure × 16) pixel fractions, for dark scenes.
    pub exposure_check: Option<(f64, f64)>,
    pub time_split: TimeSplit,
    pub targets: Vec<TargetCheck>,
    pub truth: truth::TruthInfo,
}

/// A scene judged against its truth at the conditions only: a generated one, or any with
/// `--judge-only`.
#[derive(Clone, Debug, Serialize)]
pub struct CorpusResult {
    pub scene: String,
    /// The document: relative to the output folder for a generated scene, else its path.
    pub file: String,
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub exposure: f32,
    /// The scene's own `display.pixels_per_degree`.
    pub declared_ppd: f32,
    /// At the declared ppd first, then at [`BenchConfig::conditions`] if asked.
    pub conditions: Vec<Condition>,
    pub truth: truth::TruthInfo,
}

/// Everything one run measured.
pub struct Study {
    pub scenes: Vec<SceneResult>,
    /// The bundled and public scenes with `--judge-only`.
    pub judged: Vec<CorpusResult>,
    pub corpus: Vec<CorpusResult>,
}

/// Runs the study and writes `report.md`, `results.json` and the plots into `out_dir`.
pub fn run(cfg: &BenchConfig) -> anyhow::Result<Study> {
    std::fs::create_dir_all(&cfg.out_dir)
        .with_context(|| format!("cannot create {}", cfg.out_dir.display()))?;
    let mut study = Study {
        scenes: Vec::new(),
        judged: Vec::new(),
        corpus: Vec::new(),
    };
    let files = if cfg.bundled {
        scene_files(&cfg.scenes_dir)?
    } else {
        Vec::new()
    };
    let public = match &cfg.public_dir {
        Some(dir) if !cfg.quick => public_files(dir)?,
        _ => Vec::new(),
    };
    let progress =
        Progress::new(files.len() + public.len() + cfg.corpus.as_ref().map_or(0, |c| c.scenes));
    let loaded = files
        .iter()
        .map(|p| (p, load(p, cfg)))
        .chain(public.iter().map(|p| (p, load_public(p, cfg))));
    for (path, l) in loaded {
        let l = l?;
        let scene = &l.scene;
        let (w, h, spp) = (scene.width, scene.height, scene.render.samples_per_pixel);
        progress.scene(&scene.name, &format!("{w}x{h}, {spp} spp"));
        if cfg.judge_only {
            let file = path.display().to_string();
            let r = judge_scene(cfg, &cfg.conditions, &l, file, &progress)?;
            progress.println(&report::corpus_line(&r));
            study.judged.push(r);
        } else {
            let r = bench_scene(&l, cfg, &progress)?;
            progress.println(&report::scene_table(&r));
            study.scenes.push(r);
        }
        progress.scene_done();
    }
    if let Some(c) = &cfg.corpus {
        study.corpus = run_corpus(cfg, c, &progress)?;
    }
    progress.stage("the peer renderer and the report");
    let peer = if cfg.bundled {
        peer::run_mitsuba(cfg, &files)
    } else {
        Err("the bundled scenes were not studied (--corpus-only)".into())
    };
    report::write(cfg, &study, &peer)?;
    progress.finish();
    Ok(study)
}

/// The public scenes of `dir`: every `NAME/scene-v4.pbrt`, sorted by NAME.
pub fn public_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the public scene folder {}", dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path().join("scene-v4.pbrt"))
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    anyhow::ensure!(
        !files.is_empty(),
        "no NAME/scene-v4.pbrt in the public scene folder {}",
        dir.display()
    );
    Ok(files)
}

/// Long side of a public scene in the study, pixels: the size people render.
pub const PUBLIC_SIDE: u32 = 512;
/// A public scene's reference should take about this long here, seconds ([`public_samples`]).
pub const PUBLIC_REFERENCE_S: f64 = 8.0;

/// A public scene at [`PUBLIC_SIDE`] on its long side, with [`public_samples`] per pixel
/// (its file's samples are for another renderer and another machine).
fn load_public(path: &Path, cfg: &BenchConfig) -> anyhow::Result<Loaded> {
    let as_written = BenchConfig {
        spp_factor: 1,
        min_side: None,
        quick: false,
        ..cfg.clone()
    };
    let mut l = load(path, &as_written)?;
    set_long_side(&mut l.scene, PUBLIC_SIDE);
    let tracer = PathTracer::new(&l.scene);
    let cancel = CancelToken::new();
    let seed = l.scene.render.seed;
    let pilot =
        || tracer::render_reference_with(&tracer, Some((PILOT_SPP, seed)), &cancel, &|_, _| {});
    pilot()?;
    let t = Instant::now();
    pilot()?;
    let per_sample_ms = ms(t) / f64::from(PILOT_SPP);
    l.scene.render.samples_per_pixel = public_samples(per_sample_ms, PUBLIC_REFERENCE_S);
    Ok(l)
}

/// Samples per pixel of the pilot renders (the first warms the caches, the second is timed).
const PILOT_SPP: u32 = 2;

/// Samples per pixel for a reference of about `target_s` when one sample per pixel takes
/// `per_sample_ms`: the largest power of two within it (so a noisy pilot rarely changes
/// the choice, and the truth's cache stays valid), from 16 to 4096: fewer samples than 16
/// is no reference anyone renders (and the adaptive loop's first pass alone costs more).
#[must_use]
pub fn public_samples(per_sample_ms: f64, target_s: f64) -> u32 {
    let fit = target_s * 1e3 / per_sample_ms.max(1e-9);
    let pow = fit.max(1.0).log2().floor().clamp(4.0, 12.0);
    1 << (pow as u32)
}

/// Scales the image so its long side is `side` pixels.
fn set_long_side(scene: &mut Scene, side: u32) {
    shrink(scene, side);
    grow(scene, side);
}

/// The `*.json` files of the scene folder, sorted, then the imported scenes of its
/// `imported/` folder (each `imported/NAME/scene-v4.pbrt`, sorted): public scenes whose
/// pixels cost far more than ours.
fn scene_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read scene folder {}", dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    anyhow::ensure!(!files.is_empty(), "no *.json scenes in {}", dir.display());
    let mut imported: Vec<PathBuf> = std::fs::read_dir(dir.join("imported"))
        .map(|rd| {
            rd.filter_map(Result::ok)
                .map(|e| e.path().join("scene-v4.pbrt"))
                .filter(|p| p.is_file())
                .collect()
        })
        .unwrap_or_default();
    imported.sort();
    files.extend(imported);
    Ok(files)
}

/// Longest side of an imported scene in the study (its file asks for 1024²: its truth,
/// at 16× the samples, would take hours).
const IMPORTED_MAX_SIDE: u32 = 256;

/// Generates the corpus into `out_dir/corpus/` and judges every scene against its truth.
fn run_corpus(
    cfg: &BenchConfig,
    c: &CorpusConfig,
    progress: &Progress,
) -> anyhow::Result<Vec<CorpusResult>> {
    let dir = cfg.out_dir.join("corpus");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut results = Vec::new();
    for (k, generated) in corpus::generate_in(c.scenes, c.seed, c.profile)
        .into_iter()
        .enumerate()
    {
        let file = format!("corpus/{}.json", generated.name);
        let path = cfg.out_dir.join(&file);
        std::fs::write(&path, &generated.document)
            .with_context(|| format!("cannot write {}", path.display()))?;
        let loaded = load(&path, cfg)?;
        let s = &loaded.scene;
        progress.scene(
            &s.name,
            &format!(
                "corpus {}/{}, {}x{}, {} spp, {} ppd, exposure {}",
                k + 1,
                c.scenes,
                s.width,
                s.height,
                s.render.samples_per_pixel,
                s.display.pixels_per_degree,
                s.display.exposure
            ),
        );
        let declared = loaded.scene.display.pixels_per_degree;
        let mut ppds = vec![declared];
        if c.at_conditions {
            ppds.extend(cfg.conditions.iter().filter(|&&p| p != declared));
        }
        let r = judge_scene(cfg, &ppds, &loaded, file, progress)?;
        progress.println(&report::corpus_line(&r));
        progress.scene_done();
        results.push(r);
    }
    Ok(results)
}

/// One scene against its truth at `ppds` (a corpus scene: its declared ppd first).
fn judge_scene(
    cfg: &BenchConfig,
    ppds: &[f32],
    loaded: &Loaded,
    file: String,
    progress: &Progress,
) -> anyhow::Result<CorpusResult> {
    let s = &loaded.scene;
    let cancel = CancelToken::new();
    let tracer = PathTracer::new(s);
    progress.stage("the independent reference and the converged render");
    let t = Instant::now();
    let judge = independent_reference(&tracer, s, &cancel)?;
    let check = truth::TruthCheck {
        reference: &judge,
        reference_ms: ms(t),
        ppds,
        cap_ms: cfg.truth_cap_s * 1e3,
    };
    let truth = truth::converged(
        s,
        &loaded.document,
        &tracer,
        &cfg.cache_dir,
        &check,
        &cancel,
    )?;
    let ids = tracer::object_id_map(&tracer);
    let case = Case {
        scene: s,
        tracer: &tracer,
        truth: &truth.image,
        truth_halves: (&truth.halves.0, &truth.halves.1),
        judge: &judge,
        ids: &ids,
        runs: cfg.runs,
        cancel: &cancel,
    };
    let conditions = ppds
        .iter()
        .map(|&ppd| {
            progress.stage(&format!("at {ppd} ppd"));
            judge::at_condition(&case, ppd, &cfg.out_dir)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(CorpusResult {
        scene: s.name.clone(),
        file,
        width: s.width,
        height: s.height,
        spp: s.render.samples_per_pixel,
        exposure: s.display.exposure,
        declared_ppd: s.display.pixels_per_degree,
        conditions,
        truth: truth.info,
    })
}

/// A scene as the bench runs it, and the document it came from (the truth's cache key).
#[derive(Debug)]
pub struct Loaded {
    pub scene: Scene,
    pub document: String,
}

/// Loads a scene; in quick mode shrinks it to at most 128 pixels on its long side. The
/// samples per pixel stay the scene's (times [`BenchConfig::spp_factor`]): fewer would make
/// the reference itself noisy, and a noisy reference is a different study (every method is
/// then judged mostly on noise).
pub fn load(path: &Path, cfg: &BenchConfig) -> anyhow::Result<Loaded> {
    let imported = crate::import::import_path(path, &Limits::command_line())
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let json = match &imported {
        // An import is studied as the document it produces (the truth's cache key).
        Some(i) => serde_json::to_string(&i.doc)?,
        None => std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?,
    };
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut scene = parse_scene(&json, &SceneOrigin::File { dir }, &Limits::command_line())
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    if scene.name.is_empty() {
        scene.name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
    }
    if imported.is_some() {
        // Named by its folder (every public scene's file is scene-v4.pbrt).
        if let Some(folder) = path.parent().and_then(Path::file_name) {
            scene.name = folder.to_string_lossy().into_owned();
        }
        shrink(&mut scene, IMPORTED_MAX_SIDE);
    }
    if cfg.spp_factor != 1 {
        let limits = Limits::command_line();
        // The scaled scene must pass what validation checks for the command line
        // (`Limits::command_line`): the samples per pixel and the render's sample budget.
        let spp = scene.render.samples_per_pixel;
        let pixels = u64::from(scene.width) * u64::from(scene.height);
        scene.render.samples_per_pixel = spp
            .checked_mul(cfg.spp_factor)
            .filter(|&v| {
                v >= 1
                    && v <= limits.max_samples_per_pixel
                    && u128::from(v) * u128::from(pixels) <= u128::from(limits.max_sample_budget)
            })
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: render.samples_per_pixel {spp} × --spp-factor {} is over the limits \
                     ({} samples per pixel, {} samples per render)",
                    path.display(),
                    cfg.spp_factor,
                    limits.max_samples_per_pixel,
                    limits.max_sample_budget
                )
            })?;
    }
    if let Some(side) = cfg.min_side {
        grow(&mut scene, side);
    }
    if cfg.quick {
        shrink(&mut scene, 128);
    }
    Ok(Loaded {
        scene,
        document: json,
    })
}

/// Scales the image down to at most `side` pixels on its long side.
fn shrink(scene: &mut Scene, side: u32) {
    let long = scene.width.max(scene.height);
    if long > side {
        let s = side as f32 / long as f32;
        scene.width = ((scene.width as f32 * s).round() as u32).max(1);
        scene.height = ((scene.height as f32 * s).round() as u32).max(1);
    }
}

/// Scales the image up to at least `side` pixels on its long side.
fn grow(scene: &mut Scene, side: u32) {
    let long = scene.width.max(scene.height);
    if long < side {
        let s = side as f32 / long as f32;
        scene.width = ((scene.width as f32 * s).round() as u32).max(1);
        scene.height = ((scene.height as f32 * s).round() as u32).max(1);
    }
}

/// The seed of the independent reference: any other seed will do; this one is fixed so
/// the study is repeatable.
const JUDGE_SEED_OFFSET: u64 = 0x9E37_79B9_7F4A_7C15;

/// The independent reference: the scene's samples, another seed.
fn independent_reference(
    tracer: &PathTracer,
    scene: &Scene,
    cancel: &CancelToken,
) -> anyhow::Result<LinearImage> {
    Ok(tracer::render_reference_with(
        tracer,
        Some((
            scene.render.samples_per_pixel,
            scene.render.seed ^ JUDGE_SEED_OFFSET,
        )),
        cancel,
        &|_, _| {},
    )?)
}

/// One bundled scene: the reference and the loop timed, the peers, the judges, the images.
fn bench_scene(
    loaded: &Loaded,
    cfg: &BenchConfig,
    progress: &Progress,
) -> anyhow::Result<SceneResult> {
    let scene = &loaded.scene;
    let cancel = CancelToken::new();
    let tracer = PathTracer::new(scene);
    let renders = Renders {
        tracer: &tracer,
        cancel: &cancel,
    };
    let runs = cfg.runs;
    let timed = timed_runs(&renders, scene, runs, progress)?;
    let time_split = time_split(
        &tracer,
        &timed.prog,
        timed.prog_ms,
        timed.reference_ms,
        runs,
        &cancel,
    )?;
    progress.stage("the independent reference and the converged render");
    let rows = Rows::new(loaded, &tracer, cfg, &cancel, &timed)?;
    progress.stage("without noise compensation, Guo, uniform");
    let peers = peers(&renders, scene, &timed)?;
    let methods = vec![
        rows.reference(&timed.reference)?,
        rows.of_loop("progressive", &timed.prog, timed.prog_ms)?,
        rows.of_loop(
            "progressive, no noise compensation",
            &peers.plain.0,
            peers.plain.1,
        )?,
        rows.of_loop("guo", &peers.guo.0, peers.guo.1)?,
        rows.uniform(&peers.uniform.0, peers.uniform.1, peers.uniform.2)?,
    ];

    let ids = tracer::object_id_map(&tracer);
    let case = Case {
        scene,
        tracer: &tracer,
        truth: &rows.truth.image,
        truth_halves: (&rows.truth.halves.0, &rows.truth.halves.1),
        judge: &rows.judge,
        ids: &ids,
        runs,
        cancel: &cancel,
    };
    let (sweep, adaptive_sweep, conditions) =
        against_truth(&case, &timed.reference, timed.reference_ms, cfg, progress)?;
    let exposure_check = exposure_check(&renders, scene, &timed.prog)?;
    write_images(
        cfg,
        scene,
        &[
            ("reference", &timed.reference),
            ("progressive", &timed.prog.image),
            ("guo", &peers.guo.0.image),
            ("uniform", &peers.uniform.0),
        ],
    )?;
    let targets = check_targets(&methods, rows.noise_floor, exposure_check);
    Ok(SceneResult {
        scene: scene.name.clone(),
        width: scene.width,
        height: scene.height,
        spp: scene.render.samples_per_pixel,
        reference_ms: timed.reference_ms,
        noise_floor: rows.noise_floor,
        methods,
        sweep,
        adaptive_sweep,
        conditions,
        exposure_check,
        time_split,
        targets,
        truth: rows.truth.info.clone(),
    })
}

/// One scene's renders through its tracer, timed.
struct Renders<'a> {
    tracer: &'a PathTracer,
    cancel: &'a CancelToken,
}

impl Renders<'_> {
    fn run(&self, scene: &Scene, opts: RenderOptions) -> anyhow::Result<(progressive::Frame, f64)> {
        let t = Instant::now();
        let frame = progressive::render(scene, self.tracer, &opts, &mut |_| {}, self.cancel)?;
        Ok((frame, ms(t)))
    }

    fn mode(
        &self,
        scene: &Scene,
        mode: RenderMode,
        max_pixels: Option<u64>,
    ) -> anyhow::Result<(progressive::Frame, f64)> {
        self.run(
            scene,
            RenderOptions {
                mode: Some(mode),
                max_pixels,
                ..RenderOptions::default()
            },
        )
    }
}

/// The reference and the progressive loop, each time the median of its runs.
struct Timed {
    reference: LinearImage,
    prog: progressive::Frame,
    reference_ms: f64,
    prog_ms: f64,
}

/// The time ratio is the target: reference and progressive run alternately, and each time
/// is the median of its runs (renders are deterministic, so every run gives the same
/// image). One run of each on this noisy machine could swing the ratio by ±0.05.
fn timed_runs(
    renders: &Renders,
    scene: &Scene,
    runs: usize,
    progress: &Progress,
) -> anyhow::Result<Timed> {
    progress.stage(&format!("reference and progressive, {runs} timed runs"));
    let (mut ref_times, mut prog_times) = (Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..runs {
        let t = Instant::now();
        let r = tracer::render_reference(renders.tracer, renders.cancel, &|_, _| {})?;
        ref_times.push(ms(t));
        let (f, f_ms) = renders.mode(scene, RenderMode::Progressive, None)?;
        prog_times.push(f_ms);
        last = Some((r, f));
    }
    let (reference, prog) = last.context("at least one timing run")?;
    Ok(Timed {
        reference,
        prog,
        reference_ms: median(&mut ref_times),
        prog_ms: median(&mut prog_times),
    })
}

/// What a row is judged against: the independent reference (another seed), the converged
/// truth, and Glimpse's own metric against the independent reference.
struct Rows<'a> {
    scene: &'a Scene,
    judge: LinearImage,
    truth: truth::Truth,
    model: VisionModel,
    judge_stack: crate::vision::ContrastStack,
    /// FLIP between the reference and the independent reference.
    noise_floor: FlipScore,
    reference_ms: f64,
}

impl<'a> Rows<'a> {
    fn new(
        loaded: &'a Loaded,
        tracer: &PathTracer,
        cfg: &BenchConfig,
        cancel: &CancelToken,
        timed: &Timed,
    ) -> anyhow::Result<Self> {
        let scene = &loaded.scene;
        let judge = independent_reference(tracer, scene, cancel)?;
        let noise_floor = flip(
            &judge,
            &timed.reference,
            scene.display.exposure,
            scene.display.pixels_per_degree,
        );
        let ppds = cfg.truth_ppds();
        let check = truth::TruthCheck {
            reference: &timed.reference,
            reference_ms: timed.reference_ms,
            ppds: &ppds,
            cap_ms: cfg.truth_cap_s * 1e3,
        };
        let truth = truth::converged(
            scene,
            &loaded.document,
            tracer,
            &cfg.cache_dir,
            &check,
            cancel,
        )?;
        let model = VisionModel::new(display_model(scene), scene.width, scene.height);
        let judge_stack = model.decompose(&judge)?;
        Ok(Self {
            scene,
            judge,
            truth,
            model,
            judge_stack,
            noise_floor,
            reference_ms: timed.reference_ms,
        })
    }

    /// A row with every pixel traced (the reference, or uniform at `spp`), whose FLIP
    /// against the independent reference is `flip`.
    fn traced_whole(
        &self,
        method: &str,
        (img, flip): (&LinearImage, FlipScore),
        ms: f64,
        spp: u32,
    ) -> anyhow::Result<MethodResult> {
        Ok(MethodResult {
            method: method.into(),
            ms,
            time_ratio: ms / self.reference_ms,
            pixels_traced: u64::from(self.scene.width) * u64::from(self.scene.height),
            pixel_fraction: 1.0,
            spp: Some(spp),
            flip,
            converged_flip: self.converged_flip(img),
            glimpse_distance: self.glimpse_distance(img)?,
            overhead_share: None,
        })
    }

    /// The reference's row: its FLIP is the noise floor, already measured.
    fn reference(&self, img: &LinearImage) -> anyhow::Result<MethodResult> {
        let spp = self.scene.render.samples_per_pixel;
        self.traced_whole("reference", (img, self.noise_floor), self.reference_ms, spp)
    }

    fn uniform(&self, img: &LinearImage, spp: u32, ms: f64) -> anyhow::Result<MethodResult> {
        self.traced_whole("uniform (equal time)", (img, self.flip(img)), ms, spp)
    }

    /// A row for a run of the progressive loop (progressive, uncompensated, Guo).
    fn of_loop(
        &self,
        method: &str,
        f: &progressive::Frame,
        ms: f64,
    ) -> anyhow::Result<MethodResult> {
        let st = &f.stats;
        Ok(MethodResult {
            method: method.into(),
            ms,
            time_ratio: ms / self.reference_ms,
            pixels_traced: st.pixels_traced,
            pixel_fraction: st.pixel_fraction,
            spp: Some(self.scene.render.samples_per_pixel),
            flip: self.flip(&f.image),
            converged_flip: self.converged_flip(&f.image),
            glimpse_distance: self.glimpse_distance(&f.image)?,
            overhead_share: Some((st.metric_ms + st.triangulate_ms) / st.total_ms.max(1e-9)),
        })
    }

    fn flip(&self, img: &LinearImage) -> FlipScore {
        let d = &self.scene.display;
        flip(&self.judge, img, d.exposure, d.pixels_per_degree)
    }

    fn converged_flip(&self, img: &LinearImage) -> f64 {
        let d = &self.scene.display;
        flip(&self.truth.image, img, d.exposure, d.pixels_per_degree).mean
    }

    fn glimpse_distance(&self, img: &LinearImage) -> anyhow::Result<f64> {
        let s = self.model.decompose(img)?;
        let params = MetricParams {
            homogeneity: self.scene.progressive.homogeneity,
            epsilon: self.scene.progressive.epsilon,
            seed: self.scene.render.seed,
        };
        Ok(metric::block_map(&self.model, &self.judge_stack, &s, &[], &params).mean())
    }
}

/// The peers of the progressive run, each a (result, milliseconds) pair.
struct Peers {
    /// F&P04 exactly as published (exact-oracle assumption): what the noise compensation
    /// buys.
    plain: (progressive::Frame, f64),
    /// Guo at equal rays: the progressive run's noise twins (traced, but not pixels of the
    /// image) count against Guo's budget too.
    guo: (progressive::Frame, f64),
    /// Every pixel at the samples that fit the progressive run's time: (image, spp, ms).
    uniform: (LinearImage, u32, f64),
}

fn peers(renders: &Renders, scene: &Scene, timed: &Timed) -> anyhow::Result<Peers> {
    let plain = renders.run(
        scene,
        RenderOptions {
            mode: Some(RenderMode::Progressive),
            noise_compensation: Some(false),
            ..RenderOptions::default()
        },
    )?;
    let budget = timed.prog.stats.pixels_traced + timed.prog.stats.noise_probe_pixels;
    let guo = renders.mode(scene, RenderMode::Guo, Some(budget))?;
    let t = Instant::now();
    let (uni, uni_spp) = uniform::render_equal_time(
        scene,
        renders.tracer,
        Duration::from_secs_f64(timed.prog_ms / 1e3),
        renders.cancel,
    )?;
    Ok(Peers {
        plain,
        guo,
        uniform: (uni, uni_spp, ms(t)),
    })
}

/// "Dark scenes cost less": the cellar shown 16× brighter must trace more pixels.
fn exposure_check(
    renders: &Renders,
    scene: &Scene,
    prog: &progressive::Frame,
) -> anyhow::Result<Option<(f64, f64)>> {
    if !scene.name.contains("cellar") {
        return Ok(None);
    }
    let mut bright = scene.clone();
    bright.display.exposure *= 16.0;
    let (f, _) = renders.mode(&bright, RenderMode::Progressive, None)?;
    Ok(Some((prog.stats.pixel_fraction, f.stats.pixel_fraction)))
}

/// A bundled scene against its truth: the t0 sweep at [`SWEEP_CONDITIONS`] (three t0 at
/// the first quick condition in quick mode), progressive then adaptive, then every
/// condition of the run.
fn against_truth(
    case: &Case,
    reference: &LinearImage,
    reference_ms: f64,
    cfg: &BenchConfig,
    progress: &Progress,
) -> anyhow::Result<(Vec<SweepPoint>, Vec<SweepPoint>, Vec<Condition>)> {
    let (t0s, sweep_ppds): (&[f32], &[f32]) = if cfg.quick {
        (&[0.5, 1.0, 2.0], &QUICK_CONDITIONS[..1])
    } else {
        (&[0.25, 0.5, 1.0, 2.0, 4.0], &SWEEP_CONDITIONS)
    };
    let (mut sweep, mut adaptive) = (Vec::new(), Vec::new());
    for &p in sweep_ppds {
        progress.stage(&format!("the t0 sweep at {p} ppd"));
        let r = (reference, reference_ms);
        sweep.extend(judge::sweep(case, r, RenderMode::Progressive, p, t0s)?);
        adaptive.extend(judge::sweep(case, r, RenderMode::Adaptive, p, t0s)?);
    }
    let conditions = cfg
        .conditions
        .iter()
        .map(|&p| {
            progress.stage(&format!("at {p} ppd"));
            judge::at_condition(case, p, &cfg.out_dir)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok((sweep, adaptive, conditions))
}

/// [`TimeSplit`]: the progressive run's traced pixels traced again, alone (median of
/// `runs`), against the reference's time.
fn time_split(
    tracer: &PathTracer,
    prog: &progressive::Frame,
    prog_ms: f64,
    reference_ms: f64,
    runs: usize,
    cancel: &CancelToken,
) -> anyhow::Result<TimeSplit> {
    let s = &prog.samples;
    let traced: Vec<PixelCoord> = (0..s.height())
        .flat_map(|y| (0..s.width()).map(move |x| PixelCoord::new(x, y)))
        .filter(|p| *s.get(p.x, p.y) != progressive::SampleCell::Interpolated)
        .collect();
    let mut times = Vec::new();
    for _ in 0..runs {
        let t = Instant::now();
        tracer::trace_pixels(tracer, &traced, cancel)?;
        times.push(ms(t));
    }
    let alone = median(&mut times);
    let per_ref_pixel = reference_ms / (f64::from(s.width()) * f64::from(s.height())).max(1.0);
    let st = &prog.stats;
    let counted = st.trace_ms + st.analysis_ms + st.metric_ms + st.triangulate_ms;
    Ok(TimeSplit {
        traced_alone_ratio: alone / reference_ms,
        pixel_cost_ratio: alone / traced.len().max(1) as f64 / per_ref_pixel,
        loop_ratio: (prog_ms - alone) / reference_ms,
        loop_parts: LoopParts {
            trace_beyond_alone_ms: st.trace_ms - alone,
            analysis_ms: st.analysis_ms,
            metric_ms: st.metric_ms,
            triangulate_ms: st.triangulate_ms,
            other_ms: st.total_ms - counted,
        },
    })
}

/// The study's per-scene targets, checked against this run's numbers (the report says by how much a
/// missed target is missed).
fn check_targets(
    m: &[MethodResult],
    floor: FlipScore,
    exposure: Option<(f64, f64)>,
) -> Vec<TargetCheck> {
    let get = |name: &str| {
        m.iter()
            .find(|r| r.method == name || r.method.starts_with(&format!("{name} (")))
    };
    let (Some(p), Some(g), Some(u)) = (get("progressive"), get("guo"), get("uniform")) else {
        return Vec::new();
    };
    let mut t = vec![
        TargetCheck {
            target: "progressive FLIP ≤ 1.1 × noise floor".into(),
            met: p.flip.mean <= 1.1 * floor.mean,
            detail: format!(
                "{:.4} vs floor {:.4} ({:.2}×)",
                p.flip.mean,
                floor.mean,
                p.flip.mean / floor.mean.max(1e-12)
            ),
        },
        TargetCheck {
            target: "progressive time ≤ 0.35 × reference".into(),
            met: p.time_ratio <= 0.35,
            detail: format!("{:.2}×", p.time_ratio),
        },
        TargetCheck {
            target: "progressive FLIP < Guo FLIP at equal pixels".into(),
            met: p.flip.mean < g.flip.mean,
            detail: format!(
                "{:.4} vs {:.4} ({:.1}% vs {:.1}% traced)",
                p.flip.mean,
                g.flip.mean,
                p.pixel_fraction * 100.0,
                g.pixel_fraction * 100.0
            ),
        },
        TargetCheck {
            target: "progressive FLIP < uniform FLIP at equal time".into(),
            met: p.flip.mean < u.flip.mean,
            detail: format!(
                "{:.4} vs {:.4} (uniform at {} spp)",
                p.flip.mean,
                u.flip.mean,
                u.spp.unwrap_or(0)
            ),
        },
    ];
    if let Some(share) = p.overhead_share {
        t.push(TargetCheck {
            target: "metric + triangulation < 10% of the progressive time".into(),
            met: share < 0.10,
            detail: format!("{:.1}%", share * 100.0),
        });
    }
    if let Some((dark, bright)) = exposure {
        t.push(TargetCheck {
            target: "dark scene traces fewer pixels than at exposure ×16".into(),
            met: dark < bright,
            detail: format!("{:.1}% vs {:.1}%", dark * 100.0, bright * 100.0),
        });
    }
    t
}

fn write_images(
    cfg: &BenchConfig,
    scene: &Scene,
    imgs: &[(&str, &LinearImage)],
) -> anyhow::Result<()> {
    for (name, img) in imgs {
        let p = cfg
            .out_dir
            .join(format!("{}-{name}.png", judge::file_stem(&scene.name)));
        std::fs::write(
            &p,
            crate::raster::encode_png_display(img, scene.display.exposure)?,
        )
        .with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(())
}

pub(crate) fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Runs of the reference and the progressive render whose median times make the ratio.
pub(crate) const TIMING_RUNS: usize = 3;

/// The median of a non-empty list (the upper middle of an even one); the study's and the
/// `loop_cost` benchmark's.
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The error read at `samples` off measured `(samples, error)` pairs in ascending order
/// of samples: along the straight line, in log–log, through the two nearest pairs (the
/// end segment's slope beyond either end); through a single pair, Monte Carlo's
/// error ∝ 1/√samples. What a sampler's error would be at the count another sampler's
/// time buys (`cargo bench --bench sampler`, at equal time).
#[must_use]
pub fn error_at_samples(measured: &[(f64, f64)], samples: f64) -> f64 {
    let logs: Vec<(f64, f64)> = measured.iter().map(|&(n, e)| (n.ln(), e.ln())).collect();
    let x = samples.ln();
    let i = logs
        .windows(2)
        .position(|w| x <= w[1].0)
        .unwrap_or(logs.len().saturating_sub(2));
    let y = match logs.get(i..i + 2) {
        Some(&[(x0, y0), (x1, y1)]) => y0 + (y1 - y0) * (x - x0) / (x1 - x0),
        _ => logs
            .first()
            .map_or(f64::NAN, |&(x0, y0)| y0 - 0.5 * (x - x0)),
    };
    y.exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_error_at_a_count_follows_the_measured_power_law() {
        let law = |n: f64| 0.3 * n.powf(-0.6);
        let measured: Vec<(f64, f64)> = [16.0, 32.0, 64.0].map(|n| (n, law(n))).to_vec();
        // On the pairs, between them, and beyond either end: the power law itself.
        for n in [16.0, 24.0, 32.0, 50.0, 64.0, 8.0, 13.9, 256.0] {
            let e = error_at_samples(&measured, n);
            assert!(
                (e / law(n) - 1.0).abs() < 1e-12,
                "{n}: {e} against {}",
                law(n)
            );
        }
    }

    #[test]
    fn the_error_at_a_count_bends_with_the_nearest_segment() {
        // Steep from 16 to 32, flat from 32 to 64 (a truth-limited error): 48 reads the
        // flat segment, 20 the steep one.
        let measured = [(16.0, 0.4), (32.0, 0.2), (64.0, 0.2)];
        assert!((error_at_samples(&measured, 48.0) - 0.2).abs() < 1e-12);
        let at20 = error_at_samples(&measured, 20.0);
        assert!((at20 - 0.4 * (16.0f64 / 20.0)).abs() < 1e-12, "{at20}");
    }

    #[test]
    fn one_measured_count_gives_monte_carlos_rate_and_none_gives_nan() {
        let e = error_at_samples(&[(16.0, 0.2)], 64.0);
        assert!((e - 0.1).abs() < 1e-12, "{e}");
        assert!(error_at_samples(&[], 64.0).is_nan());
    }

    #[test]
    fn a_public_scene_gets_the_largest_power_of_two_that_fits_its_reference_time() {
        assert_eq!(public_samples(1.0, 4.0), 2048, "4000 fit");
        assert_eq!(public_samples(10.0, 4.0), 256, "400 fit");
        assert_eq!(public_samples(1e3, 4.0), 16, "4 fit: 16");
        assert_eq!(public_samples(1e-6, 4.0), 4096, "at most 4096");
        assert_eq!(public_samples(0.0, 4.0), 4096, "a pilot too fast to time");
    }

    #[test]
    fn a_long_side_is_set_both_ways_keeping_the_aspect() {
        let doc = r#"{"version": 1, "image": {"width": 1280, "height": 720},
            "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "fov_y": 40},
            "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
            "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}]}"#;
        let mut s = parse_scene(doc, &SceneOrigin::Request, &Limits::command_line()).unwrap();
        set_long_side(&mut s, PUBLIC_SIDE);
        assert_eq!((s.width, s.height), (512, 288));
        (s.width, s.height) = (100, 200);
        set_long_side(&mut s, PUBLIC_SIDE);
        assert_eq!((s.width, s.height), (256, 512));
    }

    /// `--spp-factor` scales the samples and refuses a product over either command-line
    /// limit (samples per pixel, samples per render), naming the file and the factor.
    #[test]
    fn spp_factor_scales_and_is_held_to_both_limits() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.json");
        // 8192² is the command line's largest image (64 Mi pixels) and costs nothing to
        // parse: the budget 2^40 then allows exactly 16384 samples per pixel.
        std::fs::write(
            &path,
            r#"{"version": 1, "image": {"width": 8192, "height": 8192},
                "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "fov_y": 40},
                "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
                "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1,
                             "material": "w"}],
                "render": {"samples_per_pixel": 2}}"#,
        )
        .unwrap();
        let cfg = |spp_factor| BenchConfig {
            spp_factor,
            ..BenchConfig::new(dir.path().to_path_buf(), dir.path().to_path_buf(), false)
        };
        let spp = |f| load(&path, &cfg(f)).unwrap().scene.render.samples_per_pixel;
        assert_eq!(spp(1), 2);
        assert_eq!(spp(8192), 16384, "exactly at the budget");
        // Within 2^20 samples per pixel, over the 2^40 budget.
        let e = load(&path, &cfg(8193)).unwrap_err().to_string();
        assert!(
            e.contains("big.json") && e.contains("--spp-factor 8193"),
            "{e}"
        );
        // Over 2^20 samples per pixel; and a product that overflows u32.
        for f in [1 << 20, u32::MAX] {
            let e = load(&path, &cfg(f)).unwrap_err().to_string();
            assert!(e.contains(&format!("--spp-factor {f}")), "{e}");
        }
    }
}
