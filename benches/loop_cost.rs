//! Where a progressive render's time goes, against the reference's.
//!
//! For each scene the progressive loop is forced (`progressive.force_loop`, so scenes the
//! cost probe would trace whole are measured too) and timed beside the reference, three
//! alternating runs, medians. The loop's time is split by its own statistics into the
//! trace of the pixels it chose, the vision model and metric, the triangulation with the
//! reconstruction and shading, the analysis (object ids, normals, footprints and the cost
//! probe) and the rest, each as a share of the reference's time. The trace's share over
//! the share of pixels traced is what a pixel costs inside the loop against an average
//! pixel of the reference: dearer pixels (contours, highlights), the noise twins, and the
//! next triangulation built on the other core while the trace runs all count there.
//!
//! The median of each column over a generated corpus says how far the loop is from a
//! time target: even with the loop's own work free, a render cannot take less than its
//! trace column.
//!
//! Run: `cargo bench --bench loop_cost` (5–7 minutes on 2 cores): the five bundled
//! examples and `GLIMPSE_LOOP_COST_CORPUS` generated scenes (default 40) of each seed in
//! `GLIMPSE_LOOP_COST_SEEDS` (default `1,2`).

use glimpse::bench::{corpus, median};
use glimpse::cancel::CancelToken;
use glimpse::progressive::{self, RenderOptions, RenderStats};
use glimpse::scene::examples::EXAMPLES;
use glimpse::scene::{parse_scene, Limits, RenderMode, Scene, SceneOrigin};
use glimpse::tracer::PathTracer;
use std::time::Instant;

const RUNS: usize = 3;

/// One scene's costs, each a share of the reference's time.
struct Row {
    name: String,
    traced: f64,
    total: f64,
    trace: f64,
    metric: f64,
    shading: f64,
    analysis: f64,
}

impl Row {
    fn rest(&self) -> f64 {
        self.total - self.trace - self.metric - self.shading - self.analysis
    }

    /// A pixel traced by the loop against an average pixel of the reference.
    fn pixel_premium(&self) -> f64 {
        self.trace / self.traced.max(1e-9)
    }

    fn columns(&self) -> [f64; 8] {
        [
            self.traced,
            self.total,
            self.trace,
            self.metric,
            self.shading,
            self.analysis,
            self.rest(),
            self.pixel_premium(),
        ]
    }
}

const HEADER: &str = "| scene | traced | loop × ref | trace | metric | shading | analysis | rest | pixel cost × ref |";

/// Wall time of one render in `mode`, and its statistics.
fn timed(scene: &Scene, tracer: &PathTracer, mode: RenderMode) -> (f64, RenderStats) {
    let opts = RenderOptions {
        mode: Some(mode),
        ..RenderOptions::default()
    };
    let start = Instant::now();
    let frame = progressive::render(scene, tracer, &opts, &mut |_| {}, &CancelToken::new())
        .expect("never cancelled");
    (start.elapsed().as_secs_f64() * 1e3, frame.stats)
}

/// The reference and the forced loop, alternating; the loop's parts from the run of median
/// total time.
fn measure(name: &str, scene: &Scene) -> Row {
    let mut scene = scene.clone();
    scene.progressive.force_loop = true;
    let tracer = PathTracer::new(&scene);
    let mut refs = Vec::with_capacity(RUNS);
    let mut loops = Vec::with_capacity(RUNS);
    for _ in 0..RUNS {
        refs.push(timed(&scene, &tracer, RenderMode::Reference).0);
        loops.push(timed(&scene, &tracer, RenderMode::Progressive));
    }
    loops.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (total, st) = &loops[RUNS / 2];
    let reference = median(&mut refs);
    Row {
        name: name.to_string(),
        traced: st.pixel_fraction,
        total: total / reference,
        trace: st.trace_ms / reference,
        metric: st.metric_ms / reference,
        shading: st.triangulate_ms / reference,
        analysis: st.analysis_ms / reference,
    }
}

fn print_row(name: &str, c: [f64; 8]) {
    println!(
        "| {name} | {:.1} % | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
        100.0 * c[0],
        c[1],
        c[2],
        c[3],
        c[4],
        c[5],
        c[6],
        c[7]
    );
}

fn print_medians(label: &str, rows: &[Row]) {
    let cols: Vec<[f64; 8]> = rows.iter().map(Row::columns).collect();
    let med: [f64; 8] =
        std::array::from_fn(|k| median(&mut cols.iter().map(|c| c[k]).collect::<Vec<_>>()));
    print_row(&format!("**median, {label} ({})**", rows.len()), med);
    let fast = rows.iter().filter(|r| r.total <= 0.5).count();
    let trace_fast = rows.iter().filter(|r| r.trace <= 0.35).count();
    println!(
        "\n{label}: the loop took ≤ 0.5× the reference's time on {fast} of {}; its trace alone \
         took ≤ 0.35× on {trace_fast}.\n",
        rows.len()
    );
}

fn env_or<T: std::str::FromStr>(key: &str, default: T) -> T {
    std::env::var(key)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    println!("{HEADER}\n|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut bundled = Vec::new();
    for (name, text) in EXAMPLES {
        let scene = parse_scene(text, &SceneOrigin::Request, &Limits::command_line())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let row = measure(name, &scene);
        print_row(&row.name, row.columns());
        bundled.push(row);
    }
    let n: usize = env_or("GLIMPSE_LOOP_COST_CORPUS", 40);
    let seeds: String = env_or("GLIMPSE_LOOP_COST_SEEDS", "1,2".to_string());
    let mut generated = Vec::new();
    for seed in seeds
        .split(',')
        .filter_map(|s| s.trim().parse::<u64>().ok())
    {
        for doc in corpus::generate(n, seed) {
            let scene = parse_scene(
                &doc.document,
                &SceneOrigin::Request,
                &Limits::command_line(),
            )
            .unwrap_or_else(|e| panic!("{}: {e}", doc.name));
            let row = measure(&doc.name, &scene);
            print_row(&row.name, row.columns());
            generated.push(row);
        }
    }
    println!();
    print_medians("bundled", &bundled);
    if !generated.is_empty() {
        print_medians("generated", &generated);
    }
}
