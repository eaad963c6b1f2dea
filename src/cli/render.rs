//! `glimpse render SCENE.json --output OUT.png`: one scene without a server.

use crate::cancel::CancelToken;
use crate::progressive::{self, RenderOptions};
use crate::raster;
use crate::scene::{Limits, RenderMode};
use crate::tracer::PathTracer;
use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// The scene: a document (.json, scene-format.md) or a file to import (.pbrt).
    pub scene: PathBuf,
    #[arg(long)]
    pub output: PathBuf,
    #[arg(long, value_parser = parse_mode)]
    pub mode: Option<RenderMode>,
    /// Write the final statistics as JSON.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Also write the linear HDR image as OpenEXR.
    #[arg(long)]
    pub exr: Option<PathBuf>,
    /// Write the samples, distance, classes and objects layers of the last frame into this folder.
    #[arg(long)]
    pub layers: Option<PathBuf>,
    /// Override `render.samples_per_pixel`.
    #[arg(long)]
    pub spp: Option<u32>,
    /// Override `render.seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override the image size, as WIDTHxHEIGHT.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Override `progressive.t0` (JND): a triangle whose distance is below it is final.
    /// Higher is faster and less accurate; 0 traces every pixel (the reference exactly).
    #[arg(long, value_parser = parse_t0)]
    pub t0: Option<f32>,
    /// Progressive and Guo modes: stop after tracing this many pixels, given as a count
    /// (`20000`) or a share of the image (`30%`). The last frame is the answer so far.
    #[arg(long, value_parser = parse_pixel_budget)]
    pub max_pixels: Option<PixelBudget>,
    /// Progressive and Guo modes: stop after this many seconds (checked between batches of
    /// pixels; the first sample set is always traced whole).
    #[arg(long, value_parser = parse_seconds)]
    pub max_time: Option<std::time::Duration>,
    /// Progressive mode: classify on the raw frame distances, as F&P04 published them
    /// (no Monte Carlo noise compensation; see README).
    #[arg(long)]
    pub no_noise_compensation: bool,
}

/// `--max-pixels`: an absolute count or a share of the image's pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PixelBudget {
    Count(u64),
    Share(f64),
}

impl PixelBudget {
    /// The budget in pixels for a `pixels`-pixel image (a share rounds up: never 0 for a
    /// positive share).
    #[must_use]
    pub fn resolve(self, pixels: u64) -> u64 {
        match self {
            Self::Count(n) => n,
            Self::Share(f) => (f * pixels as f64).ceil() as u64,
        }
    }
}

fn parse_t0(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!(
            "t0 {s:?} must be a finite number of JNDs, at least 0"
        )),
    }
}

fn parse_pixel_budget(s: &str) -> Result<PixelBudget, String> {
    if let Some(p) = s.strip_suffix('%') {
        return match p.trim().parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 && v <= 100.0 => Ok(PixelBudget::Share(v / 100.0)),
            _ => Err(format!("pixel share {s:?} must be in (0%, 100%]")),
        };
    }
    match s.parse::<u64>() {
        Ok(n) if n > 0 => Ok(PixelBudget::Count(n)),
        _ => Err(format!(
            "pixel budget {s:?} must be a positive whole number or a percentage like 30%"
        )),
    }
}

fn parse_seconds(s: &str) -> Result<std::time::Duration, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1e7 => Ok(std::time::Duration::from_secs_f64(v)),
        _ => Err(format!("time {s:?} must be a positive number of seconds")),
    }
}

fn parse_mode(s: &str) -> Result<RenderMode, String> {
    match s {
        "reference" => Ok(RenderMode::Reference),
        "progressive" => Ok(RenderMode::Progressive),
        "guo" => Ok(RenderMode::Guo),
        _ => Err(format!(
            "unknown mode {s:?}: expected reference, progressive or guo"
        )),
    }
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("size {s:?} is not WIDTHxHEIGHT"))?;
    let w: u32 = w.parse().map_err(|_| format!("bad width in {s:?}"))?;
    let h: u32 = h.parse().map_err(|_| format!("bad height in {s:?}"))?;
    if w == 0 || h == 0 {
        return Err("size must be at least 1x1".into());
    }
    Ok((w, h))
}

pub fn run(a: &RenderArgs) -> anyhow::Result<()> {
    let (mut scene, import_warnings) = crate::import::load_path(&a.scene, &Limits::command_line())
        .map_err(|e| anyhow::anyhow!("{}: {e}", a.scene.display()))?;
    for w in &import_warnings {
        eprintln!("warning: {w}");
    }
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(spp) = a.spp {
        scene.render.samples_per_pixel = spp.max(1);
    }
    if let Some(seed) = a.seed {
        scene.render.seed = seed;
    }
    if let Some((w, h)) = a.size {
        scene.width = w;
        scene.height = h;
    }
    if let Some(t0) = a.t0 {
        scene.progressive.t0 = t0;
    }
    let tracer = PathTracer::new(&scene);
    let pixels = u64::from(scene.width) * u64::from(scene.height);
    let opts = RenderOptions {
        mode: a.mode,
        max_pixels: a.max_pixels.map(|b| b.resolve(pixels)),
        max_time: a.max_time,
        noise_compensation: a.no_noise_compensation.then_some(false),
    };
    let bar = progress_bar();
    let mut on_frame = |f: &progressive::Frame| {
        bar.set_message(format!(
            "iteration {} · {:.1}% traced · {:.0} ms",
            f.iteration,
            f.stats.pixel_fraction * 100.0,
            f.stats.total_ms
        ));
        bar.tick();
    };
    let frame = progressive::render(&scene, &tracer, &opts, &mut on_frame, &CancelToken::new())
        .map_err(|_| anyhow::anyhow!("render cancelled"))?;
    bar.finish_and_clear();
    let png = raster::encode_png_display(&frame.image, scene.display.exposure)?;
    std::fs::write(&a.output, png)
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    if let Some(p) = &a.exr {
        std::fs::write(p, raster::encode_exr(&frame.image)?)
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if let Some(p) = &a.stats {
        std::fs::write(p, serde_json::to_vec_pretty(&frame.stats)?)
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if let Some(dir) = &a.layers {
        write_layers(dir, &frame)?;
    }
    eprintln!(
        "{}: {}x{} {} in {:.0} ms, {:.1}% of pixels traced",
        a.output.display(),
        scene.width,
        scene.height,
        frame.stats.mode,
        frame.stats.total_ms,
        frame.stats.pixel_fraction * 100.0
    );
    Ok(())
}

fn write_layers(dir: &std::path::Path, frame: &progressive::Frame) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for (name, png) in progressive::layers::encode_all(frame)? {
        let p = dir.join(format!("{name}.png"));
        std::fs::write(&p, png).with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(())
}

/// A spinner with a message on a terminal; hidden when stderr is not a terminal.
fn progress_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new_spinner();
    if !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}
