//! How honest the time left is, and how soon the first picture comes.
//!
//! For every bundled example at its own size, a progressive render records after each
//! frame the estimate of `progressive::eta` and the time elapsed. Once the render has
//! ended (total T), the estimate standing at 25, 50 and 75 % of T (the last frame at or
//! before that moment) is compared with the time that was in fact left:
//! error = |estimate − left| / left, the estimate being the range's middle; "finishing"
//! counts as one mean iteration time left, and an unknown estimate counts as 100 % off. A
//! render traced whole because its paths are too cheap for the loop has one frame, at its
//! end: its time left is the pixel pass's ([`PassEta`], what the command line shows).
//! Medians over `RUNS` runs per scene, then per scene and over all scenes.
//!
//! Then the same on a generated corpus (`glimpse bench --corpus N --seed S`'s scenes, not
//! the ones the estimator was looked at on): `GLIMPSE_ETA_CORPUS` scenes (default 8) of
//! seed `GLIMPSE_ETA_SEED` (default 1), one run each, per scene and the median.
//!
//! Then the time from the start of a render to its first frame, for the Cornell box at
//! 320×240, 1024×768 and 2048² (medians of `RUNS`); a render's start is when a worker
//! begins (the service adds its queue and the scene's parse before it).
//!
//! Run: `cargo bench --bench eta` (4–6 minutes on 2 cores). `ETA_TRACE=FILE` appends
//! every frame's statistics to FILE as JSON lines (scene, run, elapsed ms, estimate, the
//! iteration's statistics, the noise twins' mean distance), to replay the estimator on them.

use glimpse::bench::corpus;
use glimpse::cancel::CancelToken;
use glimpse::progressive::eta::{Eta, EtaTracker, PassEta};
use glimpse::progressive::{self, Frame, RenderOptions};
use glimpse::scene::examples::EXAMPLES;
use glimpse::scene::{parse_scene, Limits, Scene, SceneOrigin};
use glimpse::tracer::PathTracer;
use std::io::Write;
use std::time::Instant;

/// Runs per bundled scene: a run of 0.2–1 s on a shared machine is noisy (one cell read
/// 18 % and 36 % in two runs), so the median needs more than three.
const RUNS: usize = 9;
const AT: [f64; 3] = [0.25, 0.5, 0.75];

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

/// (elapsed ms, estimate) after each frame (and each batch of a pixel pass), the total
/// time and the number of frames; with `ETA_TRACE=FILE`, every frame appended to FILE.
fn observe(scene: &Scene, run: usize) -> (Vec<(f64, Eta)>, f64, usize) {
    let tracer = PathTracer::new(scene);
    let mut tracker = EtaTracker::for_scene(scene);
    let start = Instant::now();
    let mut seen = Vec::new();
    let mut trace = std::env::var_os("ETA_TRACE").map(|path| {
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .expect("ETA_TRACE names a writable file")
    });
    let mut on_frame = |f: &Frame| {
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let eta = tracker.update(f, ms);
        if let Some(out) = &mut trace {
            let line = serde_json::json!({
                "scene": scene.name, "run": run, "ms": ms, "eta": eta.ms(),
                "finishing": eta == Eta::Finishing, "iteration": f.iteration,
                "preview": f.preview, "last": f.last, "t0": scene.progressive.t0,
                "pixel_fraction": f.stats.pixel_fraction,
                "spp": scene.render.samples_per_pixel,
                "pixels": u64::from(f.stats.width) * u64::from(f.stats.height),
                "it": f.stats.per_iteration.last(),
                "noise": f.stats.noise_distance_mean,
            });
            writeln!(out, "{line}").expect("trace written");
        }
        seen.push((ms, eta));
    };
    let passed = std::sync::Mutex::new(Vec::new());
    let pass = PassEta::default();
    let on_pixels = |done: usize, total: usize| {
        let ms = start.elapsed().as_secs_f64() * 1e3;
        let eta = pass.update(done, total, ms);
        passed.lock().expect("not poisoned").push((ms, eta));
    };
    let opts = RenderOptions {
        mode: Some(glimpse::scene::RenderMode::Progressive),
        ..RenderOptions::default()
    };
    let cancel = CancelToken::new();
    progressive::render_reporting(scene, &tracer, &opts, &mut on_frame, &on_pixels, &cancel)
        .expect("not cancelled");
    let total = start.elapsed().as_secs_f64() * 1e3;
    let frames = seen.len();
    seen.extend(passed.into_inner().expect("not poisoned"));
    seen.sort_by(|a, b| a.0.total_cmp(&b.0));
    (seen, total, frames)
}

/// Relative error of the estimate standing at `share` of the run.
fn error_at(seen: &[(f64, Eta)], total: f64, share: f64) -> f64 {
    let at = share * total;
    let Some(&(ms, eta)) = seen.iter().rev().find(|(ms, _)| *ms <= at) else {
        return 1.0;
    };
    let left = total - ms;
    let per_iteration = ms / seen.iter().filter(|(m, _)| *m <= at).count() as f64;
    let guess = match eta {
        Eta::Left { ms, .. } => ms,
        Eta::Finishing => per_iteration,
        Eta::Done => 0.0,
        Eta::Unknown => return 1.0,
    };
    (guess - left).abs() / left.max(1e-9)
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

/// Per scene, the median errors at [`AT`] over `runs` runs, printed; returns them.
fn study(name: &str, scene: &Scene, runs: usize) -> Vec<f64> {
    let mut per: Vec<Vec<f64>> = vec![Vec::new(); AT.len()];
    let mut totals = Vec::new();
    let mut frames = Vec::new();
    for run in 0..runs {
        let (seen, total, n) = observe(scene, run);
        for (k, &share) in AT.iter().enumerate() {
            per[k].push(error_at(&seen, total, share));
        }
        totals.push(total);
        frames.push(n as f64);
    }
    let m: Vec<f64> = per.into_iter().map(median).collect();
    println!(
        "  {name:<17} {:>5.0} % {:>5.0} % {:>5.0} %   (run {:.0} ms, {:.0} frames)",
        m[0] * 100.0,
        m[1] * 100.0,
        m[2] * 100.0,
        median(totals),
        median(frames)
    );
    m
}

/// The median over scenes of each point's error, printed.
fn summary(all: Vec<Vec<f64>>) {
    let m: Vec<f64> = all.into_iter().map(median).collect();
    println!(
        "  {:<17} {:>5.0} % {:>5.0} % {:>5.0} %   (target ≤ 30 %)",
        "median",
        m[0] * 100.0,
        m[1] * 100.0,
        m[2] * 100.0
    );
}

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let mut all: Vec<Vec<f64>> = vec![Vec::new(); AT.len()];
    println!("ETA error (median of {RUNS} runs) at 25 / 50 / 75 % of the run:");
    for (name, text) in EXAMPLES {
        let scene = parse_scene(text, &SceneOrigin::Request, &Limits::command_line())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        for (k, v) in study(name, &scene, RUNS).into_iter().enumerate() {
            all[k].push(v);
        }
    }
    summary(all);

    let (n, seed) = (
        env_or("GLIMPSE_ETA_CORPUS", 8),
        env_or("GLIMPSE_ETA_SEED", 1),
    );
    println!("ETA error on a generated corpus ({n} scenes, seed {seed}, one run each):");
    let mut all: Vec<Vec<f64>> = vec![Vec::new(); AT.len()];
    for generated in corpus::generate(n as usize, seed) {
        let scene = parse_scene(
            &generated.document,
            &SceneOrigin::Request,
            &Limits::command_line(),
        )
        .unwrap_or_else(|e| panic!("{}: {e}", generated.name));
        for (k, v) in study(&generated.name, &scene, 1).into_iter().enumerate() {
            all[k].push(v);
        }
    }
    summary(all);

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
