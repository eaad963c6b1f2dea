//! How honest the time left is, and how soon the first picture comes.
//!
//! For every bundled example at its own size, a progressive render records after each
//! frame the estimate of `progressive::eta` and the time elapsed. Once the render has
//! ended (total T), the estimate standing at 25, 50 and 75 % of T (the last frame at or
//! before that moment) is judged against the time that was in fact left, two ways:
//! - **coverage**: does the range shown contain the time left? "Finishing" does when at
//!   most [`FINISHING_ITERATIONS`] mean iteration times are left; an unknown estimate, or
//!   none yet, is a miss. Per cell the share of runs covered; per set and overall the
//!   mean over cells (target ≥ 80 %), with the median width (high − low) / middle;
//! - **error** of the middle: |estimate − left| / left, "finishing" counting as one mean
//!   iteration time, unknown as 100 % off (medians over runs, then over scenes).
//!
//! A render traced whole because its paths are too cheap for the loop has one frame, at
//! its end: its time left is the pixel pass's ([`PassEta`], what the command line shows).
//!
//! Then the same on a generated corpus (`glimpse bench --corpus N --seed S`'s scenes):
//! `GLIMPSE_ETA_CORPUS` scenes (default 8) of seed `GLIMPSE_ETA_SEED` (default 1), one run
//! each. The estimator's spreads were tuned on seed 1 (32 scenes); seed 2 checks them.
//!
//! Then the time from the start of a render to its first frame, for the Cornell box at
//! 320×240, 1024×768 and 2048² (medians of `RUNS`); a render's start is when a worker
//! begins (the service adds its queue and the scene's parse before it).
//!
//! Run: `cargo bench --bench eta` (1–6 minutes on 2 cores). `ETA_TRACE=FILE` appends
//! every frame, pixel-pass batch and run end to FILE as JSON lines; `ETA_REPLAY=FILE`
//! renders nothing and replays the current estimator on such a trace, printing the same
//! tables (`ETA_CELLS=1`: every cell too), so the estimator can be tuned offline.

use glimpse::bench::corpus;
use glimpse::cancel::CancelToken;
use glimpse::progressive::eta::{Eta, EtaTracker, Observed, PassEta};
use glimpse::progressive::{self, Frame, IterationStats, RenderOptions};
use glimpse::scene::examples::EXAMPLES;
use glimpse::scene::{parse_scene, Limits, Scene, SceneOrigin};
use glimpse::tracer::PathTracer;
use std::io::{BufRead, Write};
use std::time::Instant;

/// Runs per bundled scene: a run of 0.2–1 s on a shared machine is noisy (one cell read
/// 18 % and 36 % in two runs), so the median needs more than three.
const RUNS: usize = 9;
const AT: [f64; 3] = [0.25, 0.5, 0.75];

/// "Finishing" contains the time left when at most this many mean iteration times are
/// left (the mean iteration time being the time so far over the frames so far, or the
/// time so far before the first frame): "about one iteration", with room for the last
/// iteration, which traces every open pixel at once and so runs longer than the mean.
const FINISHING_ITERATIONS: f64 = 1.5;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// One estimate standing during a run: when, what, and how many frames had come.
#[derive(Clone, Copy)]
struct Seen {
    ms: f64,
    eta: Eta,
    frames: usize,
}

/// One run: every estimate in time order, and the run's total time.
struct Run {
    seen: Vec<Seen>,
    total: f64,
}

/// What the estimator reads of a frame, and the frame's trace line: the same fields, so
/// that a replay of the trace sees what the render saw.
#[derive(serde::Serialize, serde::Deserialize, Default)]
#[serde(default)]
struct TraceLine {
    /// "bundled" or "corpus-<seed>".
    set: String,
    scene: String,
    run: usize,
    /// "frame", "pass" (a batch of a single pass over every pixel) or "end".
    kind: String,
    ms: f64,
    eta: Option<f64>,
    low: Option<f64>,
    high: Option<f64>,
    finishing: bool,
    iteration: u32,
    preview: bool,
    last: bool,
    t0: f64,
    max_iterations: u32,
    pixel_fraction: f64,
    final_mean_distance: f64,
    spp: u32,
    pixels: u64,
    it: Option<IterationStats>,
    noise: f64,
    done: usize,
    total: usize,
}

impl TraceLine {
    fn observed(&self) -> Observed {
        let last = self.it.as_ref();
        Observed {
            iteration: self.iteration,
            preview: self.preview,
            last: self.last,
            mean_distance: last.map_or(self.final_mean_distance, |s| s.mean_distance),
            open_pixels: last.map_or(0, |s| s.open_pixels),
            finishing: last.is_some_and(|s| s.finishing),
            pixel_fraction: self.pixel_fraction,
        }
    }
}

fn range_of(eta: Eta) -> (Option<f64>, Option<f64>) {
    match eta {
        Eta::Left {
            low_ms, high_ms, ..
        } => (Some(low_ms), Some(high_ms)),
        _ => (None, None),
    }
}

/// A render of `scene` with every estimate recorded; with `ETA_TRACE=FILE`, every frame
/// and pass batch appended to FILE.
fn observe(set: &str, scene: &Scene, run: usize) -> Run {
    let tracer = PathTracer::new(scene);
    let mut tracker = EtaTracker::for_scene(scene);
    let start = Instant::now();
    let mut seen = Vec::new();
    let mut lines = Vec::new();
    let base = TraceLine {
        set: set.into(),
        scene: scene.name.clone(),
        run,
        t0: f64::from(scene.progressive.t0),
        max_iterations: scene.progressive.max_iterations,
        spp: scene.render.samples_per_pixel,
        pixels: u64::from(scene.width) * u64::from(scene.height),
        ..TraceLine::default()
    };
    let mut on_frame = |f: &Frame| {
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let eta = tracker.update(f, ms);
        let (low, high) = range_of(eta);
        lines.push(TraceLine {
            kind: "frame".into(),
            ms,
            eta: eta.ms(),
            low,
            high,
            finishing: eta == Eta::Finishing,
            iteration: f.iteration,
            preview: f.preview,
            last: f.last,
            pixel_fraction: f.stats.pixel_fraction,
            final_mean_distance: f.stats.final_mean_distance,
            it: f.stats.per_iteration.last().cloned(),
            noise: f.stats.noise_distance_mean,
            ..base.clone_head()
        });
        seen.push((ms, eta, !f.preview));
    };
    let passed = std::sync::Mutex::new(Vec::new());
    let pass = PassEta::default();
    let on_pixels = |done: usize, total: usize| {
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let eta = pass.update(done, total, ms);
        passed
            .lock()
            .expect("not poisoned")
            .push((ms, eta, done, total));
    };
    let opts = RenderOptions {
        mode: Some(glimpse::scene::RenderMode::Progressive),
        ..RenderOptions::default()
    };
    let cancel = CancelToken::new();
    progressive::render_reporting(scene, &tracer, &opts, &mut on_frame, &on_pixels, &cancel)
        .expect("not cancelled");
    let total = start.elapsed().as_secs_f64() * 1e3;
    for (ms, eta, done, all) in passed.into_inner().expect("not poisoned") {
        let (low, high) = range_of(eta);
        lines.push(TraceLine {
            kind: "pass".into(),
            ms,
            eta: eta.ms(),
            low,
            high,
            finishing: eta == Eta::Finishing,
            done,
            total: all,
            ..base.clone_head()
        });
        seen.push((ms, eta, false));
    }
    lines.push(TraceLine {
        kind: "end".into(),
        ms: total,
        ..base.clone_head()
    });
    if let Some(path) = std::env::var_os("ETA_TRACE") {
        let mut out = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .expect("ETA_TRACE names a writable file");
        for line in &lines {
            let text = serde_json::to_string(line).expect("serialisable");
            writeln!(out, "{text}").expect("trace written");
        }
    }
    Run {
        seen: in_time_order(seen),
        total,
    }
}

impl TraceLine {
    /// The fields that name a run and its render, the rest default.
    fn clone_head(&self) -> Self {
        Self {
            set: self.set.clone(),
            scene: self.scene.clone(),
            run: self.run,
            t0: self.t0,
            max_iterations: self.max_iterations,
            spp: self.spp,
            pixels: self.pixels,
            ..Self::default()
        }
    }
}

/// (ms, estimate, counts as a frame) sorted by time, with the frames so far counted.
fn in_time_order(mut seen: Vec<(f64, Eta, bool)>) -> Vec<Seen> {
    seen.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut frames = 0;
    seen.into_iter()
        .map(|(ms, eta, frame)| {
            frames += usize::from(frame);
            Seen { ms, eta, frames }
        })
        .collect()
}

/// The estimator replayed on a recorded trace (`ETA_REPLAY=FILE`): each run's frames
/// through a fresh [`EtaTracker`], its pass batches through a fresh [`PassEta`], in the
/// order and at the times recorded. Runs in the order they first appear, per set.
#[allow(clippy::type_complexity)]
fn replay(path: &str) -> Vec<(String, String, Run)> {
    let file = std::fs::File::open(path).expect("ETA_REPLAY names a readable file");
    let mut runs: Vec<(String, String, usize, Vec<TraceLine>)> = Vec::new();
    for line in std::io::BufReader::new(file).lines() {
        let line = line.expect("readable");
        let t: TraceLine = serde_json::from_str(&line).expect("a trace line");
        // A run's lines are written together, so a run is a stretch of lines of one key
        // (two bench runs appended to one file stay apart).
        match runs.last_mut() {
            Some(r) if r.0 == t.set && r.1 == t.scene && r.2 == t.run => r.3.push(t),
            _ => runs.push((t.set.clone(), t.scene.clone(), t.run, vec![t])),
        }
    }
    runs.into_iter()
        .filter_map(|(set, scene, _, lines)| {
            let head = lines.first()?;
            let mut tracker =
                EtaTracker::for_render(head.t0, head.max_iterations, head.pixels, head.spp);
            let pass = PassEta::default();
            let mut seen = Vec::new();
            let mut total = None;
            let mut passes: Vec<&TraceLine> = lines.iter().filter(|l| l.kind == "pass").collect();
            passes.sort_by(|a, b| a.ms.total_cmp(&b.ms));
            for l in passes {
                seen.push((l.ms, pass.update(l.done, l.total, l.ms), false));
            }
            for l in &lines {
                match l.kind.as_str() {
                    "frame" => seen.push((l.ms, tracker.observe(&l.observed(), l.ms), !l.preview)),
                    "end" => total = Some(l.ms),
                    _ => {}
                }
            }
            let total = total?;
            Some((
                set,
                scene,
                Run {
                    seen: in_time_order(seen),
                    total,
                },
            ))
        })
        .collect()
}

/// How the estimate standing at a share of the run fared.
#[derive(Clone, Copy)]
struct Cell {
    /// |middle − left| / left ("finishing" as one mean iteration, unknown as 1).
    error: f64,
    /// The range (or "finishing") contains the time left.
    covered: bool,
    /// (high − low) / middle, for a range.
    width: Option<f64>,
}

/// The estimate standing at `share` of the run (the last one at or before that moment)
/// against the time in fact left.
fn cell_at(run: &Run, share: f64) -> Cell {
    const MISS: Cell = Cell {
        error: 1.0,
        covered: false,
        width: None,
    };
    let at = share * run.total;
    let Some(s) = run.seen.iter().rev().find(|s| s.ms <= at) else {
        return MISS;
    };
    let left = run.total - s.ms;
    let per_iteration = s.ms / s.frames.max(1) as f64;
    let (guess, covered, width) = match s.eta {
        Eta::Left {
            ms,
            low_ms,
            high_ms,
            ..
        } => (
            ms,
            low_ms <= left && left <= high_ms,
            Some((high_ms - low_ms) / ms.max(1e-9)),
        ),
        Eta::Finishing => (
            per_iteration,
            left <= FINISHING_ITERATIONS * per_iteration,
            None,
        ),
        Eta::Done => (0.0, left <= FINISHING_ITERATIONS * per_iteration, None),
        Eta::Unknown => return MISS,
    };
    Cell {
        error: (guess - left).abs() / left.max(1e-9),
        covered,
        width,
    }
}

/// One scene's runs: per share the cells of every run.
struct SceneCells {
    name: String,
    per_share: Vec<Vec<Cell>>,
    totals: Vec<f64>,
    frames: Vec<f64>,
}

impl SceneCells {
    fn new(name: &str, runs: &[Run]) -> Self {
        Self {
            name: name.into(),
            per_share: AT
                .iter()
                .map(|&share| runs.iter().map(|r| cell_at(r, share)).collect())
                .collect(),
            totals: runs.iter().map(|r| r.total).collect(),
            frames: runs
                .iter()
                .map(|r| r.seen.iter().map(|s| s.frames).max().unwrap_or(0) as f64)
                .collect(),
        }
    }

    /// Per share, the fraction of runs whose range contained the time left.
    fn coverage(&self) -> Vec<f64> {
        self.per_share
            .iter()
            .map(|cells| {
                mean(
                    &cells
                        .iter()
                        .map(|c| f64::from(u8::from(c.covered)))
                        .collect::<Vec<_>>(),
                )
            })
            .collect()
    }

    fn widths(&self) -> Vec<f64> {
        self.per_share
            .iter()
            .flatten()
            .filter_map(|c| c.width)
            .collect()
    }

    fn print(&self) {
        let e: Vec<f64> = self
            .per_share
            .iter()
            .map(|cells| median(cells.iter().map(|c| c.error).collect()))
            .collect();
        let c = self.coverage();
        println!(
            "  {:<17} {:>5.0} % {:>5.0} % {:>5.0} %   {:>4.0} % {:>4.0} % {:>4.0} %   {:>5.2}   (run {:.0} ms, {:.0} frames)",
            self.name,
            e[0] * 100.0,
            e[1] * 100.0,
            e[2] * 100.0,
            c[0] * 100.0,
            c[1] * 100.0,
            c[2] * 100.0,
            median(self.widths()),
            median(self.totals.clone()),
            median(self.frames.clone())
        );
    }
}

const HEADER: &str =
    "  scene              error at 25 / 50 / 75 %   covered at 25 / 50 / 75 %   width";

/// The median over scenes of each share's error, the mean coverage over scenes of each
/// share and over all, and the median width, printed; returns (coverage, widths).
fn summary(label: &str, scenes: &[SceneCells]) -> (f64, Vec<f64>) {
    let errors: Vec<f64> = (0..AT.len())
        .map(|k| {
            median(
                scenes
                    .iter()
                    .map(|s| median(s.per_share[k].iter().map(|c| c.error).collect()))
                    .collect(),
            )
        })
        .collect();
    let coverage: Vec<f64> = (0..AT.len())
        .map(|k| mean(&scenes.iter().map(|s| s.coverage()[k]).collect::<Vec<_>>()))
        .collect();
    let widths: Vec<f64> = scenes.iter().flat_map(SceneCells::widths).collect();
    let overall = mean(&coverage);
    println!(
        "  {:<17} {:>5.0} % {:>5.0} % {:>5.0} %   {:>4.0} % {:>4.0} % {:>4.0} %   {:>5.2}   (median error, target ≤ 30 %)",
        "median / mean",
        errors[0] * 100.0,
        errors[1] * 100.0,
        errors[2] * 100.0,
        coverage[0] * 100.0,
        coverage[1] * 100.0,
        coverage[2] * 100.0,
        median(widths.clone()),
    );
    println!(
        "  {label}: range contains the time left in {:.1} % of cells (target ≥ 80 %), median width {:.2}",
        overall * 100.0,
        median(widths.clone())
    );
    (overall, widths)
}

/// Bundled and corpus together: every (scene, share) cell weighing the same.
fn overall(bundled: &[SceneCells], corpus: &[SceneCells]) {
    let cells: Vec<f64> = bundled
        .iter()
        .chain(corpus)
        .flat_map(SceneCells::coverage)
        .collect();
    let widths: Vec<f64> = bundled
        .iter()
        .chain(corpus)
        .flat_map(SceneCells::widths)
        .collect();
    println!(
        "Overall: range contains the time left in {:.1} % of {} (scene, share) cells, median width (high − low) / middle {:.2}",
        mean(&cells) * 100.0,
        cells.len(),
        median(widths)
    );
}

fn first_frame_ms(scene: &Scene) -> f64 {
    let tracer = PathTracer::new(scene);
    let start = Instant::now();
    let mut first = None;
    let cancel = CancelToken::new();
    let mut on_frame = |_: &Frame| {
        if first.is_none() {
            first = Some(start.elapsed().as_secs_f64() * 1e3);
            cancel.cancel();
        }
    };
    let _ = progressive::render(
        scene,
        &tracer,
        &RenderOptions::default(),
        &mut on_frame,
        &cancel,
    );
    first.unwrap_or(f64::NAN)
}

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn main() {
    if let Ok(path) = std::env::var("ETA_REPLAY") {
        replay_main(&path);
        return;
    }
    println!("ETA error (median of {RUNS} runs) and coverage (share of runs) by scene:");
    println!("{HEADER}");
    let mut bundled = Vec::new();
    for (name, text) in EXAMPLES {
        let scene = parse_scene(text, &SceneOrigin::Request, &Limits::command_line())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let runs: Vec<Run> = (0..RUNS)
            .map(|run| observe("bundled", &scene, run))
            .collect();
        let cells = SceneCells::new(name, &runs);
        cells.print();
        bundled.push(cells);
    }
    summary("bundled", &bundled);

    let (n, seed) = (
        env_or("GLIMPSE_ETA_CORPUS", 8),
        env_or("GLIMPSE_ETA_SEED", 1),
    );
    println!("ETA on a generated corpus ({n} scenes, seed {seed}, one run each):");
    println!("{HEADER}");
    let set = format!("corpus-{seed}");
    let mut generated_cells = Vec::new();
    for generated in corpus::generate(n as usize, seed) {
        let scene = parse_scene(
            &generated.document,
            &SceneOrigin::Request,
            &Limits::command_line(),
        )
        .unwrap_or_else(|e| panic!("{}: {e}", generated.name));
        let cells = SceneCells::new(&generated.name, &[observe(&set, &scene, 0)]);
        cells.print();
        generated_cells.push(cells);
    }
    summary("corpus", &generated_cells);
    overall(&bundled, &generated_cells);

    println!("First frame after the render starts (median of {RUNS}), cornell-box:");
    let text = EXAMPLES
        .iter()
        .find(|(n, _)| *n == "cornell-box")
        .map(|(_, t)| *t)
        .expect("bundled");
    for (w, h) in [(320, 240), (1024, 768), (2048, 2048)] {
        let mut scene =
            parse_scene(text, &SceneOrigin::Request, &Limits::command_line()).expect("valid");
        scene.width = w;
        scene.height = h;
        let t: Vec<f64> = (0..RUNS).map(|_| first_frame_ms(&scene)).collect();
        println!("  {w}x{h}: {:.0} ms (target ≤ 300 ms)", median(t));
    }
}

/// The tables of `main` from a recorded trace, the estimator replayed (no render runs);
/// with `ETA_CELLS=1`, every cell's estimate and time left as tab-separated lines too.
fn replay_main(path: &str) {
    let runs = replay(path);
    let mut sets: Vec<String> = runs.iter().map(|r| r.0.clone()).collect();
    sets.dedup();
    let cells_out = std::env::var_os("ETA_CELLS").is_some();
    let mut by_set = Vec::new();
    for set in &sets {
        println!("Replayed {set}:");
        println!("{HEADER}");
        let mut names: Vec<&String> = runs.iter().filter(|r| &r.0 == set).map(|r| &r.1).collect();
        names.dedup();
        let mut scenes = Vec::new();
        for name in names {
            let of: Vec<Run> = runs
                .iter()
                .filter(|r| &r.0 == set && &r.1 == name)
                .map(|r| Run {
                    seen: r.2.seen.clone(),
                    total: r.2.total,
                })
                .collect();
            if cells_out {
                for (i, run) in of.iter().enumerate() {
                    for &share in &AT {
                        print_cell(set, name, i, run, share);
                    }
                }
            }
            let cells = SceneCells::new(name, &of);
            cells.print();
            scenes.push(cells);
        }
        summary(set, &scenes);
        by_set.push(scenes);
    }
    if by_set.len() >= 2 {
        overall(&by_set[0], &by_set[1]);
    }
}

/// `cell  set scene run share kind middle low high left per-iteration frames`.
fn print_cell(set: &str, name: &str, i: usize, run: &Run, share: f64) {
    let at = share * run.total;
    let Some(s) = run.seen.iter().rev().find(|s| s.ms <= at) else {
        return;
    };
    let (kind, mid, low, high) = match s.eta {
        Eta::Left {
            ms,
            low_ms,
            high_ms,
            ..
        } => ("left", ms, low_ms, high_ms),
        Eta::Finishing => ("finishing", 0.0, 0.0, 0.0),
        Eta::Done => ("done", 0.0, 0.0, 0.0),
        Eta::Unknown => ("unknown", 0.0, 0.0, 0.0),
    };
    println!(
        "cell\t{set}\t{name}\t{i}\t{share}\t{kind}\t{mid}\t{low}\t{high}\t{}\t{}\t{}",
        run.total - s.ms,
        s.ms / s.frames.max(1) as f64,
        s.frames
    );
}
