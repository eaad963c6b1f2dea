//! The Sobol samplers' error beside the independent sampler's, in one run: equal samples
//! (16, 32 and 64 per pixel), the same seed, each judged by LDR-FLIP at the scene's
//! declared pixels per degree and exposure against a converged truth, on every bundled
//! scene (scenes/*.json) and on a generated corpus (src/bench/corpus.rs). The targets,
//! for each sampler against the independent one: ≤ 0.8 on every bundled scene and on
//! the corpus median, at every sample count, and no scene worse by more than 2 %.
//!
//! Each sampler's render times (its paths', not the tracer's build) give its cost per
//! sample on the scene (all its renders' seconds ÷ their samples), and from that its
//! error at *equal time* beside the first sampler's: read off the straight line, in
//! log–log, through its two nearest measured counts, at the count it could have traced
//! in the first sampler's time.
//!
//! The truth is two renders of independent seeds, neither the compared renders' (Sobol,
//! half the truth's samples each, cached like `glimpse bench`'s truths); FLIP between
//! the two halves is printed beside the errors it must stay well under (the truth's own
//! error is about that over √2).
//!
//! `cargo bench --bench sampler`, options through the environment:
//! - `SAMPLER_CORPUS=N`: corpus scenes (default 6; 0 = none).
//! - `SAMPLER_BUNDLED=0`: the corpus alone.
//! - `SAMPLER_PUBLIC=DIR`: also every `DIR/NAME/scene-v4.pbrt` (`../shared/scenes-public`),
//!   imported as `glimpse bench` imports them (256 px on the long side), judged and
//!   reported beside the bundled scenes.
//! - `SAMPLER_MIN_SIDE=PX`: every scene scaled up to PX on its long side, as
//!   `glimpse bench --min-side` does (default: as written).
//! - `SAMPLER_PPD=N`: judge at N pixels per degree instead of each scene's declared
//!   viewing condition (the truths' cache is the same).
//! - `SAMPLER_SPP=16,32,64`: the sample counts compared.
//! - `SAMPLER_KINDS=independent,sobol,zsobol`: the samplers compared, the first the
//!   baseline of every ratio.
//! - `SAMPLER_CROPS=DIR`: side-by-side crops (each sampler, then the truth, at the first
//!   count) of every bundled scene written there as PNG.
//! - `SAMPLER_TRUTH=N`: the truth's samples per pixel (default 1024, even: two halves).
//! - `SAMPLER_CACHE=DIR`: where truths are cached (default target/sampler-truth).
//! - `SAMPLER_DENOISE=1`: judge every render and the truth after Intel Open Image Denoise
//!   (`High`, clean albedo and normal guides): which samples the denoiser makes most of
//!   (the library from `bash scripts/oidn.sh`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use glimpse::bench::{self, corpus, flip, truth, BenchConfig, Loaded};
use glimpse::cancel::CancelToken;
use glimpse::denoise::{Denoiser, Quality, Run};
use glimpse::progressive::adaptive::estimate::Filter;
use glimpse::progressive::denoise_input_scale;
use glimpse::raster::{codec::to_display_rgb8, LinearImage};
use glimpse::scene::SamplerKind;
use glimpse::scene::Scene;
use glimpse::tracer::{self, PathTracer};

/// What the truth's two halves xor into the scene's seed. Neither half may use the seed
/// of the compared renders: padded Sobol's samples are a function of (seed, pixel,
/// index) alone, so a half traced with the renders' own seed would contain a padded
/// Sobol render's samples and flatter its error.
const TRUTH_SEEDS: [u64; 2] = [0x2545_f491_4f6c_dd1d, 0x5bd1_e995];

struct Options {
    corpus: usize,
    bundled: bool,
    public: Option<PathBuf>,
    min_side: Option<u32>,
    ppd: Option<f32>,
    spp: Vec<u32>,
    kinds: Vec<SamplerKind>,
    crops: Option<PathBuf>,
    cache: PathBuf,
    truth_spp: u32,
    denoise: bool,
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .map(|v| {
            v.parse()
                .unwrap_or_else(|_| panic!("{name}={v} is not understood"))
        })
        .unwrap_or(default)
}

fn options() -> Options {
    let spp = std::env::var("SAMPLER_SPP").unwrap_or_else(|_| "16,32,64".into());
    Options {
        corpus: env_or("SAMPLER_CORPUS", 6),
        bundled: env_or("SAMPLER_BUNDLED", 1) != 0,
        public: std::env::var("SAMPLER_PUBLIC").ok().map(PathBuf::from),
        ppd: std::env::var("SAMPLER_PPD")
            .ok()
            .map(|v| v.parse().expect("SAMPLER_PPD")),
        min_side: std::env::var("SAMPLER_MIN_SIDE")
            .ok()
            .map(|v| v.parse().expect("SAMPLER_MIN_SIDE")),
        spp: {
            // Ascending: the equal-time reading interpolates between neighbours.
            let mut v: Vec<u32> = spp
                .split(',')
                .map(|s| s.trim().parse().expect("SAMPLER_SPP"))
                .collect();
            v.sort_unstable();
            v.dedup();
            v
        },
        kinds: std::env::var("SAMPLER_KINDS")
            .unwrap_or_else(|_| "independent,sobol,zsobol".into())
            .split(',')
            .map(|k| {
                serde_json::from_value(serde_json::Value::String(k.trim().into()))
                    .unwrap_or_else(|_| panic!("SAMPLER_KINDS: {k} is not a sampler"))
            })
            .collect(),
        crops: std::env::var("SAMPLER_CROPS").ok().map(PathBuf::from),
        cache: env_or("SAMPLER_CACHE", PathBuf::from("target/sampler-truth")),
        truth_spp: env_or("SAMPLER_TRUTH", 1024),
        denoise: env_or("SAMPLER_DENOISE", 0) != 0,
    }
}

/// One scene's errors: per sample count, one per sampler; each sampler's seconds per
/// sample per pixel over all its renders of the scene (only ever compared between
/// samplers); and the truth's own error.
struct SceneErrors {
    name: String,
    flips: Vec<Vec<f64>>,
    seconds_per_spp: Vec<f64>,
    truth_halves: f64,
}

impl SceneErrors {
    /// Sampler `j`'s error ÷ the baseline's at the time the baseline took for `spp[k]`:
    /// `j`'s error ([`bench::error_at_samples`]) at `spp[k]` × (the baseline's cost per
    /// sample ÷ `j`'s).
    fn equal_time_ratio(&self, spp: &[u32], j: usize, k: usize) -> f64 {
        let at = f64::from(spp[k]) * self.seconds_per_spp[0] / self.seconds_per_spp[j];
        let measured: Vec<(f64, f64)> = spp
            .iter()
            .zip(&self.flips)
            .map(|(&n, f)| (f64::from(n), f[j]))
            .collect();
        bench::error_at_samples(&measured, at) / self.flips[k][0]
    }
}

/// A render of `scene` with `kind`'s samples, and the seconds its paths took (the tracer's
/// build, the same for every sampler, left out).
fn render(scene: &Scene, kind: SamplerKind, spp: u32, seed: u64) -> (LinearImage, f64) {
    let mut s = scene.clone();
    s.render.sampler = kind;
    // As a user declaring `spp` gets it: the z-ordered sampler lays its blocks out for
    // the declared count.
    s.render.samples_per_pixel = spp;
    let t = PathTracer::new(&s);
    let start = Instant::now();
    let img = tracer::render_reference_with(&t, Some((spp, seed)), &CancelToken::new(), &|_, _| {})
        .expect("never cancelled");
    (img, start.elapsed().as_secs_f64())
}

/// The truth (mean of two cached halves of independent seeds) and FLIP between its halves.
fn truth_of(loaded: &Loaded, o: &Options) -> (LinearImage, f64) {
    let mut s = loaded.scene.clone();
    s.render.sampler = SamplerKind::Sobol;
    // Each half is half the truth.
    let half_spp = (o.truth_spp / 2).max(1);
    let key = format!("{}\nsampler sobol, halves", loaded.document);
    let half = |seed: u64| {
        let t = PathTracer::new(&s);
        let spp_seed = (half_spp, seed);
        truth::cached_render(&s, &key, &t, &o.cache, spp_seed, &CancelToken::new())
            .expect("truth")
            .0
    };
    let [a, b] = TRUTH_SEEDS.map(|x| half(s.render.seed ^ x));
    let d = &s.display;
    let halves = flip::flip(&a, &b, d.exposure, d.pixels_per_degree).mean;
    let mean = LinearImage::from_fn(a.width(), a.height(), |x, y| {
        (*a.get(x, y) + *b.get(x, y)) * 0.5
    });
    (mean, halves)
}

fn judge(loaded: &Loaded, o: &Options, crops: Option<&Path>) -> SceneErrors {
    let scene = &loaded.scene;
    let (truth, truth_halves) = truth_of(loaded, o);
    let d = &scene.display;
    let filter = filter_for(scene, o);
    let finish = |img: LinearImage| {
        filter
            .apply(&img, Quality::High)
            .expect("the denoiser runs")
    };
    let truth = finish(truth);
    let mut flips = Vec::new();
    let mut seconds = vec![0.0; o.kinds.len()];
    for (k, &spp) in o.spp.iter().enumerate() {
        let imgs: Vec<LinearImage> = o
            .kinds
            .iter()
            .zip(&mut seconds)
            .map(|(&kind, s)| {
                let (img, secs) = render(scene, kind, spp, scene.render.seed);
                *s += secs;
                finish(img)
            })
            .collect();
        flips.push(
            imgs.iter()
                .map(|img| flip::flip(&truth, img, d.exposure, d.pixels_per_degree).mean)
                .collect(),
        );
        if let (0, Some(dir)) = (k, crops) {
            let shown: Vec<&LinearImage> = imgs.iter().chain([&truth]).collect();
            write_crops(dir, &scene.name, spp, &shown, d.exposure);
        }
    }
    let samples: u32 = o.spp.iter().sum();
    SceneErrors {
        name: scene.name.clone(),
        flips,
        seconds_per_spp: seconds.iter().map(|s| s / f64::from(samples)).collect(),
        truth_halves,
    }
}

/// How every render and the truth are finished: as traced, or (`SAMPLER_DENOISE=1`)
/// through OIDN with the scene's first hits' albedo and normal as clean guides, as
/// `adaptive` denoises.
fn filter_for<'a>(scene: &Scene, o: &Options) -> Filter<'a> {
    if !o.denoise {
        return Filter::Raw;
    }
    Filter::Denoised {
        denoiser: Denoiser::shared().unwrap_or_else(|e| panic!("SAMPLER_DENOISE: {e}")),
        aux: tracer::aux::aux_maps(&PathTracer::new(scene), &CancelToken::new())
            .expect("never cancelled"),
        run: Run {
            input_scale: denoise_input_scale(scene),
            ..Run::new(Quality::High)
        },
    }
}

/// `dir/NAME-SPPspp.png`: the central crop (up to 160 px square) of each image side by
/// side, scaled 3× (nearest) so the grain is visible.
fn write_crops(dir: &Path, name: &str, spp: u32, imgs: &[&LinearImage], exposure: f32) {
    const SIDE: u32 = 160;
    const ZOOM: u32 = 3;
    let (w, h) = (imgs[0].width(), imgs[0].height());
    let (cw, ch) = (SIDE.min(w), SIDE.min(h));
    let (x0, y0) = ((w - cw) / 2, (h - ch) / 2);
    let shown: Vec<_> = imgs.iter().map(|i| to_display_rgb8(i, exposure)).collect();
    let gap = 4;
    let n = imgs.len() as u32;
    let out_w = n * cw * ZOOM + (n - 1) * gap;
    let mut out = image::RgbImage::new(out_w, ch * ZOOM);
    for (k, img) in shown.iter().enumerate() {
        let ox = k as u32 * (cw * ZOOM + gap);
        for y in 0..ch * ZOOM {
            for x in 0..cw * ZOOM {
                let p = img.get(x0 + x / ZOOM, y0 + y / ZOOM);
                out.put_pixel(ox + x, y, image::Rgb(*p));
            }
        }
    }
    std::fs::create_dir_all(dir).expect("crops folder");
    let path = dir.join(format!("{name}-{spp}spp.png"));
    out.save(&path).expect("crop written");
}

fn load(path: &Path, o: &Options) -> Loaded {
    let mut cfg = BenchConfig::new(PathBuf::from("scenes"), PathBuf::from("target"), false);
    cfg.min_side = o.min_side;
    let mut loaded = bench::load(path, &cfg).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    if let Some(ppd) = o.ppd {
        loaded.scene.display.pixels_per_degree = ppd;
    }
    loaded
}

/// The scene's errors and their ratios to the first sampler's at equal samples, then
/// each sampler's cost per sample and its ratio at equal time.
fn print_row(e: &SceneErrors, spp: &[u32]) {
    let cells: Vec<String> = e
        .flips
        .iter()
        .zip(spp)
        .map(|(f, n)| {
            let ratios: Vec<String> = f[1..].iter().map(|x| format!("×{:.3}", x / f[0])).collect();
            let values: Vec<String> = f.iter().map(|x| format!("{x:.4}")).collect();
            format!("{n:>3}: {} {}", values.join(" "), ratios.join(" "))
        })
        .collect();
    println!(
        "{:<24} {}   truth halves {:.4}",
        e.name,
        cells.join(" | "),
        e.truth_halves
    );
    let kinds = e.seconds_per_spp.len();
    let cost: Vec<String> = (1..kinds)
        .map(|j| format!("×{:.3}", e.seconds_per_spp[j] / e.seconds_per_spp[0]))
        .collect();
    let equal_time: Vec<String> = (0..spp.len())
        .map(|k| {
            let r: Vec<String> = (1..kinds)
                .map(|j| format!("×{:.3}", e.equal_time_ratio(spp, j, k)))
                .collect();
            format!("{:>3}: {}", spp[k], r.join(" "))
        })
        .collect();
    println!(
        "{:<24} cost per sample {}; at equal time {}",
        "",
        cost.join(" "),
        equal_time.join(" | ")
    );
}

/// The largest of `v`; NaN when it is empty (no scene of that kind was judged).
fn worst_of(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NAN, f64::max)
}

/// The median of `v`; NaN when it is empty ([`bench::median`]).
fn median_of(v: &[f64]) -> f64 {
    bench::median(&mut v.to_vec())
}

fn main() {
    let o = options();
    let names: Vec<&str> = o.kinds.iter().map(|k| k.as_str()).collect();
    println!(
        "sampler bench: FLIP vs truth at {}, {}, then each ÷ {}; spp {:?}, \
         min side {:?}, truth {} spp{}",
        o.ppd
            .map_or("the declared ppd".into(), |p| format!("{p} ppd")),
        names.join(", "),
        names[0],
        o.spp,
        o.min_side,
        o.truth_spp,
        if o.denoise { ", all denoised" } else { "" }
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir("scenes")
        .expect("scenes/")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    if !o.bundled {
        files.clear();
    }
    let mut bundled = Vec::new();
    for f in &files {
        let e = judge(&load(f, &o), &o, o.crops.as_deref());
        print_row(&e, &o.spp);
        bundled.push(e);
    }
    let public = o.public.as_deref().map_or_else(Vec::new, |dir| {
        bench::public_files(dir).unwrap_or_else(|e| panic!("SAMPLER_PUBLIC: {e:#}"))
    });
    for f in public {
        let e = judge(&load(&f, &o), &o, None);
        print_row(&e, &o.spp);
        bundled.push(e);
    }
    let corpus_dir = o.cache.join("corpus");
    std::fs::create_dir_all(&corpus_dir).expect("corpus folder");
    let mut corpus_rows = Vec::new();
    for g in corpus::generate(o.corpus, 1) {
        let path = corpus_dir.join(format!("{}.json", g.name));
        std::fs::write(&path, &g.document).expect("corpus document written");
        let e = judge(&load(&path, &o), &o, None);
        print_row(&e, &o.spp);
        corpus_rows.push(e);
    }
    verdict(&bundled, &corpus_rows, &o);
}

/// The targets, checked and printed for each sampler against the first.
fn verdict(bundled: &[SceneErrors], corpus_rows: &[SceneErrors], o: &Options) {
    for (j, kind) in o.kinds.iter().enumerate().skip(1) {
        let ratio = |e: &SceneErrors, k: usize| e.flips[k][j] / e.flips[k][0];
        let mut ok = true;
        for (k, n) in o.spp.iter().enumerate() {
            let equal_samples =
                |rows: &[SceneErrors]| -> Vec<f64> { rows.iter().map(|e| ratio(e, k)).collect() };
            let (b, c) = (equal_samples(bundled), equal_samples(corpus_rows));
            let worst = b.iter().chain(&c).copied().fold(0.0, f64::max);
            // NaN when no scene of the kind was judged (`SAMPLER_BUNDLED=0`).
            let (bundled_max, corpus_median) = (worst_of(&b), median_of(&c));
            let met = (bundled_max.is_nan() || bundled_max <= 0.8)
                && (corpus_median.is_nan() || corpus_median <= 0.8)
                && worst <= 1.02;
            ok &= met;
            println!(
                "{} {n:>3} spp: bundled worst ×{bundled_max:.3}, corpus median \
                 ×{corpus_median:.3}, worst of all ×{worst:.3}: {}",
                kind.as_str(),
                if met { "met" } else { "MISSED" }
            );
            let timed = |rows: &[SceneErrors]| -> Vec<f64> {
                rows.iter()
                    .map(|e| e.equal_time_ratio(&o.spp, j, k))
                    .collect()
            };
            let (b, c) = (timed(bundled), timed(corpus_rows));
            println!(
                "{} {n:>3} spp at equal time: bundled worst ×{:.3} median ×{:.3}, corpus \
                 worst ×{:.3} median ×{:.3}",
                kind.as_str(),
                worst_of(&b),
                median_of(&b),
                worst_of(&c),
                median_of(&c),
            );
        }
        println!(
            "{}: targets (≤ 0.8 bundled and corpus median, ≤ 1.02 everywhere): {}",
            kind.as_str(),
            if ok { "met" } else { "MISSED" }
        );
    }
}
