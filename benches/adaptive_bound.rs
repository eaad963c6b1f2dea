//! How much placing samples unevenly can gain in front of the denoiser, measured with the
//! truth in hand: the bound any adaptive sampler (ours or another) works under.
//!
//! For each scene and total budget of N samples per pixel, all at equal samples (no time
//! is charged for estimating anything, so these are upper bounds on an adaptive mode's
//! gain at equal time):
//! - **uniform**: N spp everywhere, denoised (OIDN `High`, clean albedo and normal).
//! - **oracle, α**: N/2 spp everywhere, denoised; each 8×8 tile's true error (LDR-FLIP
//!   against the truth at the scene's ppd, pooled) decides where the other N/2 go:
//!   tile totals ∝ errorᵅ (never fewer than the first pass gave), then all denoised.
//!   α = 2/3 minimises the mean error if a tile's denoised error falls as 1/√n; α = 1
//!   the squared error; α = 2 places samples more unevenly still.
//! - **benefit**: the same, the weights being how much each tile's true error fell from
//!   N/2 to N spp uniform (what a sample is worth there, measured, not assumed).
//! - **estimate**: the same rule at α = 1 with the tile errors `adaptive` itself predicts
//!   (two denoised halves judged by the vision model, `progressive::adaptive::estimate`)
//!   instead of the truth's.
//! - **raw**: uniform and oracle α = 1 without the denoiser, for scale.
//!
//! Printed: FLIP to the truth of each and its ratio to uniform's, what one estimate costs
//! (two `Fast` denoises and the vision model) in samples per pixel of tracing, and each
//! OIDN quality's FLIP and cost on the uniform picture. The truth's own error is printed
//! first: FLIP between its two halves, raw and denoised.
//!
//! `cargo bench --bench adaptive_bound`, options through the environment:
//! - `BOUND_MIN_SIDE=PX` (default 512): every scene scaled up to PX on its long side.
//! - `BOUND_SPP=16,32` the budgets N (even; empty for none).
//! - `BOUND_TRUTH=N` (default 1024): the truth's samples per pixel (two cached halves).
//! - `BOUND_SCENES=a.json,b.pbrt` (default every scenes/*.json); `BOUND_CORPUS=K` adds K
//!   generated corpus scenes (seed 1).
//! - `BOUND_CACHE=DIR` (default target/bound-truth): where truths are cached.
//! - `BOUND_DENOISED_TRUTH=0`: judge against the raw truth (default: the truth denoised,
//!   whose own error is far below what a denoised picture's FLIP can resolve otherwise).
//! - `BOUND_LOOP_SPP=N`: also render the scene at N spp in reference mode and in
//!   `adaptive` mode at its default t0, and print Q (adaptive's FLIP over the
//!   reference's) and their time ratio: where the real loop stands beside the bound.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glimpse::bench::{self, corpus, flip, truth, BenchConfig, Loaded};
use glimpse::cancel::CancelToken;
use glimpse::denoise::{Aux, Denoiser, Quality, Run};
use glimpse::metric::MetricParams;
use glimpse::progressive::adaptive::estimate::{self, Filter};
use glimpse::progressive::adaptive::pixels::Pixels;
use glimpse::progressive::adaptive::TILE;
use glimpse::progressive::{self, denoise_input_scale, display_model, RenderOptions};
use glimpse::raster::{Image, LinearImage, Rgb};
use glimpse::scene::{RenderMode, Scene};
use glimpse::tracer::{self, aux::AuxMaps, PathTracer};
use glimpse::vision::VisionModel;

/// Seed of the truth's second half, against the scene's own (any other).
const HALF_SEED: u64 = 0x5bd1_e995;
/// The tile-error exponents of the oracle rule.
const ALPHAS: [f64; 3] = [2.0 / 3.0, 1.0, 2.0];

struct Options {
    min_side: u32,
    spp: Vec<u32>,
    truth_spp: u32,
    scenes: Vec<PathBuf>,
    corpus: usize,
    cache: PathBuf,
    denoised_truth: bool,
    loop_spp: u32,
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name).ok().map_or(default, |v| {
        v.parse()
            .unwrap_or_else(|_| panic!("{name}={v} is not understood"))
    })
}

fn options() -> Options {
    let scenes = std::env::var("BOUND_SCENES").map_or_else(
        |_| {
            let mut v: Vec<PathBuf> = std::fs::read_dir("scenes")
                .expect("scenes/")
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "json"))
                .collect();
            v.sort();
            v
        },
        |s| s.split(',').map(PathBuf::from).collect(),
    );
    Options {
        min_side: env_or("BOUND_MIN_SIDE", 512),
        spp: std::env::var("BOUND_SPP")
            .unwrap_or_else(|_| "16,32".into())
            .split(',')
            .filter(|s| !s.trim().is_empty())
            .map(|s| s.trim().parse().expect("BOUND_SPP"))
            .collect(),
        truth_spp: env_or("BOUND_TRUTH", 1024),
        scenes,
        corpus: env_or("BOUND_CORPUS", 0),
        cache: env_or("BOUND_CACHE", PathBuf::from("target/bound-truth")),
        denoised_truth: env_or("BOUND_DENOISED_TRUTH", 1) != 0,
        loop_spp: env_or("BOUND_LOOP_SPP", 0),
    }
}

/// What one scene needs: its tracer, guides, denoiser settings and truth.
struct Bench<'a> {
    scene: &'a Scene,
    tracer: PathTracer,
    aux: AuxMaps,
    denoiser: &'static Denoiser,
    truth: LinearImage,
}

/// A denoise at `quality` and the scene's display.
fn scene_run(scene: &Scene, quality: Quality) -> Run {
    Run {
        input_scale: denoise_input_scale(scene),
        ..Run::new(quality)
    }
}

impl Bench<'_> {
    fn denoise(&self, img: &LinearImage, quality: Quality) -> LinearImage {
        let aux = Aux {
            albedo: &self.aux.albedo,
            normal: &self.aux.normal,
            clean: true,
        };
        self.denoiser
            .denoise(img, Some(&aux), &scene_run(self.scene, quality))
            .expect("the denoiser runs")
    }

    fn flip_map(&self, img: &LinearImage) -> (f64, Image<f32>) {
        let d = &self.scene.display;
        let (s, map) = flip::flip_with_map(&self.truth, img, d.exposure, d.pixels_per_degree);
        (s.mean, map)
    }

    fn flip(&self, img: &LinearImage) -> f64 {
        self.flip_map(img).0
    }

    fn trace(&self, px: &mut Pixels, extra: &[u32]) {
        px.trace(
            &self.tracer,
            extra,
            self.scene.render.seed,
            None,
            &CancelToken::new(),
        )
        .expect("never cancelled");
    }

    fn pixels(&self) -> usize {
        (self.scene.width * self.scene.height) as usize
    }

    /// N/2 spp everywhere, then the other N/2 placed by `tile_error`; FLIP of the denoised
    /// (or raw) result.
    fn reallocated(&self, n: u32, tile_error: &[f64], alpha: f64, denoised: bool) -> f64 {
        let mut px = Pixels::new(self.scene.width, self.scene.height);
        self.trace(&mut px, &vec![n / 2; self.pixels()]);
        let extra = spread(self.scene.width, self.scene.height, tile_error, alpha, n);
        self.trace(&mut px, &extra);
        let img = px.mean();
        self.flip(&if denoised {
            self.denoise(&img, Quality::High)
        } else {
            img
        })
    }
}

/// Per-pixel extra samples: tile totals ∝ errorᵅ with a mean of `n` per pixel, never below
/// the first pass's n/2 (water-filling: the level λ found by bisection).
fn spread(w: u32, h: u32, tile_error: &[f64], alpha: f64, n: u32) -> Vec<u32> {
    let tw = w.div_ceil(TILE);
    let first = f64::from(n / 2);
    let weight: Vec<f64> = tile_error.iter().map(|e| e.max(1e-9).powf(alpha)).collect();
    let pixels_of = |t: usize| {
        let (tx, ty) = ((t as u32 % tw) * TILE, (t as u32 / tw) * TILE);
        f64::from(TILE.min(w - tx) * TILE.min(h - ty))
    };
    let budget = f64::from(n / 2) * f64::from(w) * f64::from(h);
    let spent = |lambda: f64| -> f64 {
        weight
            .iter()
            .enumerate()
            .map(|(t, &wt)| (lambda * wt - first).max(0.0) * pixels_of(t))
            .sum()
    };
    let (mut lo, mut hi) = (0.0, 1.0);
    while spent(hi) < budget {
        hi *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if spent(mid) < budget {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let mut extra = vec![0u32; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let t = ((y / TILE) * tw + x / TILE) as usize;
            extra[(y * w + x) as usize] = (hi * weight[t] - first).max(0.0).round() as u32;
        }
    }
    extra
}

/// The truth's two cached halves of independent seeds and FLIP between them (the mean's
/// own error is about that over √2).
fn truth_of(loaded: &Loaded, o: &Options) -> ((LinearImage, LinearImage), f64) {
    let s = &loaded.scene;
    let half_spp = (o.truth_spp / 2).max(1);
    let key = format!("{}\nhalves", loaded.document);
    let half = |seed: u64| {
        let t = PathTracer::new(s);
        truth::cached_render(s, &key, &t, &o.cache, (half_spp, seed), &CancelToken::new())
            .expect("truth")
            .0
    };
    let (a, b) = (
        half(s.render.seed ^ 0x1234_5678),
        half(s.render.seed ^ HALF_SEED),
    );
    let d = &s.display;
    let halves = flip::flip(&a, &b, d.exposure, d.pixels_per_degree).mean;
    ((a, b), halves)
}

/// The vision model's predicted visible error of the first pass, pooled per tile, and
/// what making it cost (ms).
fn predicted(b: &Bench, px: &Pixels) -> (Vec<f64>, f64) {
    let t = Instant::now();
    let filter = Filter::Denoised {
        denoiser: b.denoiser,
        aux: b.aux.clone(),
        run: scene_run(b.scene, Quality::Fast),
    };
    let (h0, h1) = px.halves();
    let pic = estimate::picture((&h0, &h1), &filter, Quality::Fast).expect("denoiser");
    let model = VisionModel::new(display_model(b.scene), b.scene.width, b.scene.height);
    let p = &b.scene.progressive;
    let params = MetricParams {
        homogeneity: p.homogeneity,
        epsilon: p.epsilon,
        seed: b.scene.render.seed,
    };
    let visible = estimate::visible_error(&model, &pic, &params).expect("the model judges");
    let pooled = estimate::pool_mean(&visible, TILE);
    (
        pooled.iter().map(|&v| f64::from(v)).collect(),
        t.elapsed().as_secs_f64() * 1e3,
    )
}

fn pool(map: &Image<f32>) -> Vec<f64> {
    estimate::pool_mean(map, TILE)
        .iter()
        .map(|&v| f64::from(v))
        .collect()
}

fn judge(loaded: &Loaded, o: &Options) {
    let scene = &loaded.scene;
    let tracer = PathTracer::new(scene);
    let mut b = Bench {
        scene,
        aux: tracer::aux::aux_maps(&tracer, &CancelToken::new()).expect("never cancelled"),
        tracer,
        denoiser: Denoiser::shared().expect("Intel OIDN (bash scripts/oidn.sh)"),
        truth: LinearImage::filled(1, 1, Rgb::ZERO),
    };
    let ((ta, tb), raw_halves) = truth_of(loaded, o);
    let d = &scene.display;
    let (da, db) = (b.denoise(&ta, Quality::High), b.denoise(&tb, Quality::High));
    let denoised_halves = flip::flip(&da, &db, d.exposure, d.pixels_per_degree).mean;
    let mean = LinearImage::from_fn(ta.width(), ta.height(), |x, y| {
        (*ta.get(x, y) + *tb.get(x, y)) * 0.5
    });
    b.truth = if o.denoised_truth {
        b.denoise(&mean, Quality::High)
    } else {
        mean
    };
    println!(
        "{:<22} truth's halves differ by FLIP {raw_halves:.4} raw, {denoised_halves:.4} \
         denoised; judged against the {} truth",
        scene.name,
        if o.denoised_truth { "denoised" } else { "raw" }
    );
    if o.loop_spp > 0 {
        the_loop(&b, o.loop_spp);
    }
    for &n in &o.spp {
        bound_row(&b, n.max(2) & !1);
    }
}

/// Uniform against the reallocations at a budget of `n` samples per pixel.
fn bound_row(b: &Bench, n: u32) {
    let t = Instant::now();
    let mut uniform = Pixels::new(b.scene.width, b.scene.height);
    b.trace(&mut uniform, &vec![n; b.pixels()]);
    let ms_per_spp = t.elapsed().as_secs_f64() * 1e3 / f64::from(n);
    let uniform_raw = uniform.mean();
    let (u, uniform_map) = b.flip_map(&b.denoise(&uniform_raw, Quality::High));
    print_qualities(b, &uniform_raw, n, ms_per_spp);
    let u_raw = b.flip(&uniform_raw);

    // The first half of every reallocation: the same paths as uniform's first n/2.
    let mut first = Pixels::new(b.scene.width, b.scene.height);
    b.trace(&mut first, &vec![n / 2; b.pixels()]);
    let first_raw = first.mean();
    let true_error = pool(&b.flip_map(&b.denoise(&first_raw, Quality::High)).1);
    let true_raw_error = pool(&b.flip_map(&first_raw).1);
    let (guess, estimate_ms) = predicted(b, &first);

    let oracle: Vec<String> = ALPHAS
        .iter()
        .map(|&a| format!("{:.3}", b.reallocated(n, &true_error, a, true) / u))
        .collect();
    // What doubling the samples did to each tile's true error: the benefit a sample
    // brings there, measured rather than assumed.
    let benefit: Vec<f64> = true_error
        .iter()
        .zip(&pool(&uniform_map))
        .map(|(a, b)| (a - b).max(0.0))
        .collect();
    let by_benefit = b.reallocated(n, &benefit, 1.0, true) / u;
    let est = b.reallocated(n, &guess, 1.0, true) / u;
    let raw = b.reallocated(n, &true_raw_error, 1.0, false) / u_raw;
    println!(
        "{:<22} {n:>4} spp  uniform+OIDN {u:.4}  oracle α=⅔,1,2 ×{}  benefit ×{by_benefit:.3}  \
         estimate ×{est:.3}  | raw {u_raw:.4} oracle ×{raw:.3}  | estimate costs {:.1} spp",
        b.scene.name,
        oracle.join(" ×"),
        estimate_ms / ms_per_spp,
    );
}

/// What each OIDN quality gives and costs on the uniform picture (the cost in samples per
/// pixel of tracing).
fn print_qualities(b: &Bench, img: &LinearImage, n: u32, ms_per_spp: f64) {
    let cells: Vec<String> = [Quality::Fast, Quality::Balanced, Quality::High]
        .into_iter()
        .map(|q| {
            let t = Instant::now();
            let d = b.denoise(img, q);
            let cost = t.elapsed().as_secs_f64() * 1e3 / ms_per_spp;
            format!("{q:?} {:.4} ({cost:.1} spp)", b.flip(&d))
        })
        .collect();
    println!(
        "{:<22} {n:>4} spp  OIDN quality: {}",
        b.scene.name,
        cells.join(", ")
    );
}

/// The reference and `adaptive` at `spp`, judged against the truth.
fn the_loop(b: &Bench, spp: u32) {
    let mut scene = b.scene.clone();
    scene.render.samples_per_pixel = spp;
    // The tracer holds the sample count the reference traces.
    let tracer = PathTracer::new(&scene);
    let run = |mode| {
        let opts = RenderOptions {
            mode: Some(mode),
            ..RenderOptions::default()
        };
        let t = Instant::now();
        let f = progressive::render(&scene, &tracer, &opts, &mut |_| {}, &CancelToken::new())
            .expect("never cancelled");
        (t.elapsed().as_secs_f64(), b.flip(&f.image), f.stats)
    };
    let (rt, rf, _) = run(RenderMode::Reference);
    let (at, af, stats) = run(RenderMode::Adaptive);
    println!(
        "{:<22} {spp:>4} spp  reference {rf:.4} in {rt:.1} s  adaptive {af:.4} in {at:.1} s \
         ({:.1} spp, {} passes, {})  Q {:.2} at {:.2}× the time",
        scene.name,
        stats.samples_traced as f64 / f64::from(scene.width * scene.height),
        stats.iterations,
        stats.stop_reason.unwrap_or_default(),
        af / rf,
        at / rt,
    );
}

fn load(path: &Path, o: &Options) -> Loaded {
    let mut cfg = BenchConfig::new(PathBuf::from("scenes"), PathBuf::from("target"), false);
    cfg.min_side = Some(o.min_side);
    bench::load(path, &cfg).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn main() {
    let o = options();
    println!(
        "adaptive bound: FLIP to a {}-spp truth at the declared ppd, equal samples, ratios \
         to uniform; min side {} px",
        o.truth_spp, o.min_side
    );
    for f in &o.scenes {
        judge(&load(f, &o), &o);
    }
    let dir = o.cache.join("corpus");
    std::fs::create_dir_all(&dir).expect("corpus folder");
    for g in corpus::generate(o.corpus, 1) {
        let path = dir.join(format!("{}.json", g.name));
        std::fs::write(&path, &g.document).expect("corpus document written");
        judge(&load(&path, &o), &o);
    }
}
