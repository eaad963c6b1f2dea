//! `glimpse render SCENE.json --output OUT.png`: one scene without a server.

use super::phases::{self, Phases, StatsFile};
use crate::cancel::CancelToken;
use crate::progressive::eta::{self, Eta, EtaTracker, PassEta};
use crate::progressive::{self, RenderOptions};
use crate::raster::{self, LinearImage};
use crate::scene::{Limits, RenderMode};
use crate::service::iterations::{to_forget, Kept, KEPT_LAYERS, MAX_KEPT, MAX_KEPT_BYTES};
use crate::service::store::ITERATIONS_DIR;
use crate::tracer::PathTracer;
use anyhow::Context;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// The scene: a document (.json, scene-format.md) or a file to import (.pbrt, .gltf,
    /// .glb, .obj), chosen by extension.
    pub scene: PathBuf,
    /// The image to write; its extension names the format: .png (8-bit sRGB as shown on
    /// the scene's display), .jpg/.jpeg (the same, lossy, quality 92) or .exr (linear
    /// radiance, 32-bit float). Any other extension is refused before rendering.
    #[arg(long, value_name = "OUT.png|OUT.jpg|OUT.exr")]
    pub output: PathBuf,
    /// How pixels are chosen: `progressive` (F&P04's perceptual loop), `guo` (the same
    /// loop with Guo 1998's statistical oracle), `reference` (every pixel traced) or
    /// `adaptive` (every pixel, in passes of samples placed where the vision model still
    /// sees error in the denoised picture). Default: the scene's `render.mode`, which
    /// defaults to progressive.
    #[arg(long, value_parser = parse_mode, value_name = "reference|progressive|guo|adaptive")]
    pub mode: Option<RenderMode>,
    /// Write the final statistics as JSON: the render's (progressive::RenderStats) and
    /// `phases`: `load_ms` (read, import, validate), `build_ms` (BVH, lights),
    /// `render_ms`, `samples` (paths traced), `samples_per_second`, `primitives`, and
    /// `memory` in bytes resident: `peak_bytes` (whole command), `load_peak_bytes` (by the
    /// end of the load), `loaded_bytes` (the loaded scene), `built_bytes` (once the tracer
    /// is built), `final_bytes` (at the end); null where the system does not say.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Also write the linear HDR image as OpenEXR.
    #[arg(long)]
    pub exr: Option<PathBuf>,
    /// Write every layer of the last frame (image, samples, distance, classes, objects)
    /// into this folder, and each earlier iteration's image, samples, distance and classes
    /// into its `iterations/` (`0003-distance.png`; the last 64 within 128 MiB, thinned
    /// evenly on longer runs): at the end every triangle is final, so the last frame's
    /// distance and classes are one flat colour and the earlier ones show the method.
    #[arg(long, value_name = "DIR")]
    pub layers: Option<PathBuf>,
    /// Override `render.samples_per_pixel` (at least 1).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub spp: Option<u32>,
    /// Override `render.seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override the image size, as WIDTHxHEIGHT.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Override `progressive.t0` (JND): a triangle whose distance is below it is final,
    /// and the lower it is (down to 0.25), the more the interpolation averages away noise.
    /// Higher is faster and less accurate; 0 traces every pixel (the reference exactly).
    /// Adaptive mode: the visible error (JND) at which a tile needs no more samples (where
    /// the reference itself would show more, t0 × half of the reference's); 0 gives every
    /// pixel all its samples (the reference exactly without the denoiser).
    #[arg(long, value_parser = parse_t0)]
    pub t0: Option<f32>,
    /// Progressive and Guo modes: stop after tracing this many pixels, given as a count
    /// (`20000`) or a share of the image (`30%`). The last frame is the answer so far.
    #[arg(long, value_parser = parse_pixel_budget)]
    pub max_pixels: Option<PixelBudget>,
    /// Progressive, Guo and adaptive modes: stop after this many seconds (checked between
    /// batches of pixels; the first sample set, or adaptive's first pass, is always traced
    /// whole).
    #[arg(long, value_parser = parse_seconds)]
    pub max_time: Option<std::time::Duration>,
    /// Progressive mode: classify on the raw frame distances, as F&P04 published them
    /// (no Monte Carlo noise compensation; see README).
    #[arg(long)]
    pub no_noise_compensation: bool,
    /// Denoise the picture with Intel Open Image Denoise (every pass in adaptive mode,
    /// the last frame in the others). Default: the scene's `render.denoise`, which is on
    /// in adaptive mode only.
    #[arg(long, conflicts_with = "no_denoise")]
    pub denoise: bool,
    /// Do not denoise, whatever the scene says.
    #[arg(long)]
    pub no_denoise: bool,
    /// Adaptive mode: stop after tracing this many paths over the image (at least one
    /// per pixel: the first pass traces every pixel).
    #[arg(long, value_name = "N")]
    pub max_samples: Option<u64>,
}

/// The format `--output` names by its extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputFormat {
    Png,
    Jpeg,
    Exr,
}

impl OutputFormat {
    /// The format of `path` by its extension (any case), or a sentence saying why not.
    pub fn of(path: &Path) -> Result<Self, String> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("png") => Ok(Self::Png),
            Some("jpg" | "jpeg") => Ok(Self::Jpeg),
            Some("exr") => Ok(Self::Exr),
            Some(other) => Err(format!(
                "--output {}: cannot write .{other} images; name a .png, .jpg, .jpeg or .exr file",
                path.display()
            )),
            None => Err(format!(
                "--output {} has no extension; name a .png, .jpg, .jpeg or .exr file",
                path.display()
            )),
        }
    }

    /// `image` encoded in this format (display formats through `exposure`).
    pub fn encode(self, image: &LinearImage, exposure: f32) -> anyhow::Result<Vec<u8>> {
        Ok(match self {
            Self::Png => raster::encode_png_display(image, exposure)?,
            Self::Jpeg => raster::encode_jpeg_display(image, exposure, JPEG_QUALITY)?,
            Self::Exr => raster::encode_exr(image)?,
        })
    }
}

/// JPEG quality for `--output x.jpg` (of 100): the common "high" setting; use .png or
/// .exr when every level matters.
const JPEG_QUALITY: u8 = 92;

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
        "adaptive" => Ok(RenderMode::Adaptive),
        _ => Err(format!(
            "unknown mode {s:?}: expected reference, progressive, guo or adaptive"
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
    // Refused before any work: a wrong extension must not cost a render.
    let format = OutputFormat::of(&a.output).map_err(anyhow::Error::msg)?;
    let mut phases = Phases::default();
    let t = Instant::now();
    let mut scene = load_scene(a)?;
    let opts = render_options(a, &scene)?;
    phases.load_ms = ms_since(t);
    crate::service::trim::release_free_memory();
    let loaded = phases::resident();
    phases.memory.load_peak_bytes = loaded.map(|r| r.peak_bytes);
    phases.memory.loaded_bytes = loaded.map(|r| r.now_bytes);
    let t = Instant::now();
    let tracer = PathTracer::new(&scene);
    phases.build_ms = ms_since(t);
    phases.primitives = tracer.primitive_count() as u64;
    // The tracer holds its own copy of every primitive: the scene's is no longer read.
    scene.release_geometry();
    crate::service::trim::release_free_memory();
    phases.memory.built_bytes = phases::resident().map(|r| r.now_bytes);
    // Asked before any work: a render that cannot denoise as asked is refused, not
    // returned noisy.
    crate::progressive::denoiser_for(&scene, &opts)?;
    let mut iterations = a
        .layers
        .as_ref()
        .map(|dir| IterationFiles::new(dir, scene.display.exposure));
    let t = Instant::now();
    let frame = render_with_progress(&scene, &tracer, &opts, &mut iterations)?;
    phases.render_ms = ms_since(t);
    phases.samples = Phases::samples_of(&frame.stats, scene.render.samples_per_pixel);
    phases.samples_per_second = Phases::rate(phases.samples, phases.render_ms);
    let end = phases::resident();
    phases.memory.peak_bytes = end.map(|r| r.peak_bytes);
    phases.memory.final_bytes = end.map(|r| r.now_bytes);
    write_outputs(a, format, &frame, &phases, scene.display.exposure)?;
    if let Some(e) = iterations.and_then(|f| f.error) {
        return Err(e);
    }
    eprintln!(
        "{}: {}x{} {} in {}, {:.1} % of pixels traced",
        a.output.display(),
        scene.width,
        scene.height,
        frame.stats.mode,
        eta::seconds(frame.stats.total_ms),
        frame.stats.pixel_fraction * 100.0
    );
    Ok(())
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The render options of the command line `a` for `scene`, refused with one sentence
/// when the render cannot be done as asked: fewer paths than pixels, or more memory than
/// this machine has free. The denoiser's scratch is what the free memory leaves it.
fn render_options(a: &RenderArgs, scene: &crate::scene::Scene) -> anyhow::Result<RenderOptions> {
    let pixels = u64::from(scene.width) * u64::from(scene.height);
    if let Some(n) = a.max_samples.filter(|&n| n < pixels) {
        anyhow::bail!(
            "--max-samples {n} is fewer than one path per pixel: the image has {}×{} = {pixels} \
             pixels and every one is traced at least once; give at least {pixels}",
            scene.width,
            scene.height
        );
    }
    let mut opts = RenderOptions {
        mode: a.mode,
        max_pixels: a.max_pixels.map(|b| b.resolve(pixels)),
        max_time: a.max_time,
        noise_compensation: a.no_noise_compensation.then_some(false),
        denoise: if a.denoise {
            Some(true)
        } else if a.no_denoise {
            Some(false)
        } else {
            None
        },
        max_samples: a.max_samples,
        denoise_memory_mb: None,
    };
    let need = progressive::memory::MemoryEstimate::of(scene, &opts);
    if let Some(free) = phases::available_memory() {
        if need.least_bytes() > free {
            anyhow::bail!(
                "a {}×{} render needs about {} of memory and this machine has {} free; \
                 render a smaller --size",
                scene.width,
                scene.height,
                progressive::memory::human_bytes(need.least_bytes()),
                progressive::memory::human_bytes(free)
            );
        }
        opts.denoise_memory_mb = need.denoise_scratch_mb(free);
    }
    Ok(opts)
}

/// The scene of `a`, its warnings printed, with the command line's overrides (samples
/// per pixel, seed, size, t0) applied.
fn load_scene(a: &RenderArgs) -> anyhow::Result<crate::scene::Scene> {
    let (mut scene, import_warnings) = crate::import::load_path(&a.scene, &Limits::command_line())
        .map_err(|e| {
            // An import's error already starts with the file it is about.
            let path = a.scene.display().to_string();
            let text = e.to_string();
            if text.starts_with(&path) {
                anyhow::anyhow!(text)
            } else {
                anyhow::anyhow!("{path}: {text}")
            }
        })?;
    for w in &import_warnings {
        eprintln!("warning: {w}");
    }
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(spp) = a.spp {
        scene.render.samples_per_pixel = spp;
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
    within_limits(&scene, &Limits::command_line())?;
    Ok(scene)
}

/// The command line's overrides of size and samples held to the limits a document is
/// (a 100000×100000 `--size` must be refused, not abort in an allocation).
fn within_limits(scene: &crate::scene::Scene, l: &Limits) -> anyhow::Result<()> {
    let (w, h) = (u64::from(scene.width), u64::from(scene.height));
    let pixels = w * h;
    if w > u64::from(l.max_width) || h > u64::from(l.max_height) || pixels > l.max_pixels {
        anyhow::bail!(
            "{w}×{h} is larger than the command line renders: at most {}×{} and {} pixels",
            l.max_width,
            l.max_height,
            l.max_pixels
        );
    }
    let spp = u64::from(scene.render.samples_per_pixel);
    if spp > u64::from(l.max_samples_per_pixel) || spp.saturating_mul(pixels) > l.max_sample_budget
    {
        anyhow::bail!(
            "{spp} samples per pixel × {pixels} pixels is more than the command line traces: \
             at most {} samples per pixel and {} samples in all",
            l.max_samples_per_pixel,
            l.max_sample_budget
        );
    }
    Ok(())
}

/// Renders `scene` with a progress bar on the terminal (the frame's line and ETA, or the
/// pass's while a pass traces every pixel), keeping each frame in `iterations` if asked.
fn render_with_progress(
    scene: &crate::scene::Scene,
    tracer: &PathTracer,
    opts: &RenderOptions,
    iterations: &mut Option<IterationFiles>,
) -> anyhow::Result<progressive::Frame> {
    let bar = progress_bar();
    let start = Instant::now();
    let mut tracker = EtaTracker::for_scene(scene);
    let mut on_frame = |f: &progressive::Frame| {
        if let Some(files) = iterations.as_mut() {
            files.keep(f);
        }
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        let eta = tracker.update(f, elapsed);
        let done = done_share(elapsed, &eta);
        bar.set_position(done.max(bar.position()));
        bar.set_message(frame_line(f, elapsed, &eta));
    };
    let pass = PassEta::default();
    let on_pixels = |done: usize, total: usize| {
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        let (line, share) = pass_line(&pass, done, total, elapsed);
        bar.set_position(share);
        bar.set_message(line);
    };
    let frame = progressive::render_reporting(
        scene,
        tracer,
        opts,
        &mut on_frame,
        &on_pixels,
        &CancelToken::new(),
    )
    .map_err(|_| anyhow::anyhow!("render cancelled"))?;
    bar.finish_and_clear();
    Ok(frame)
}

/// Writes the image in `format`, then the optional EXR, statistics and layers of `a`.
fn write_outputs(
    a: &RenderArgs,
    format: OutputFormat,
    frame: &progressive::Frame,
    phases: &Phases,
    exposure: f32,
) -> anyhow::Result<()> {
    let bytes = format.encode(&frame.image, exposure)?;
    std::fs::write(&a.output, bytes)
        .with_context(|| format!("cannot write {}", a.output.display()))?;
    if let Some(p) = &a.exr {
        std::fs::write(p, raster::encode_exr(&frame.image)?)
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if let Some(p) = &a.stats {
        let file = StatsFile {
            render: &frame.stats,
            phases,
        };
        std::fs::write(p, serde_json::to_vec_pretty(&file)?)
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if let Some(dir) = &a.layers {
        write_layers(dir, frame, exposure)?;
    }
    Ok(())
}

/// Steps of the progress bar.
const BAR_STEPS: u64 = 1000;

/// How far along a progressive render is, in bar steps: elapsed over elapsed plus the
/// time left (`None` while unknown, so the bar waits rather than guesses).
fn done_share(elapsed_ms: f64, eta: &Eta) -> u64 {
    let left = match eta {
        Eta::Done => 0.0,
        Eta::Left { ms, .. } => *ms,
        Eta::Finishing | Eta::Unknown => return 0,
    };
    let total = elapsed_ms + left;
    if total > 0.0 {
        ((elapsed_ms / total) * BAR_STEPS as f64).round() as u64
    } else {
        0
    }
}

/// The progress bar's words after a frame of the progressive or Guo loop.
fn frame_line(f: &progressive::Frame, elapsed_ms: f64, eta: &Eta) -> String {
    if f.preview {
        return format!(
            "preview · {} elapsed · analysing the scene",
            eta::seconds(elapsed_ms)
        );
    }
    format!(
        "iteration {} · {:.1} % of pixels traced · {} elapsed · {}",
        f.iteration + 1,
        f.stats.pixel_fraction * 100.0,
        eta::seconds(elapsed_ms),
        eta.describe()
    )
}

/// The progress bar's words and position during the reference's single pass: the time
/// left extrapolated from the pixels done so far (pixels cost about the same on average).
fn pass_line(pass: &PassEta, done: usize, total: usize, elapsed_ms: f64) -> (String, u64) {
    let share = if total == 0 {
        1.0
    } else {
        done as f64 / total as f64
    };
    let left = match pass.update(done, total, elapsed_ms) {
        Eta::Unknown => "estimating time left…".to_string(),
        Eta::Left { ms, .. } => format!("about {} left", eta::seconds(ms)),
        Eta::Finishing | Eta::Done => "finishing".to_string(),
    };
    let line = format!(
        "{:.1} % of pixels traced · {} elapsed · {left}",
        share * 100.0,
        eta::seconds(elapsed_ms)
    );
    (line, (share * BAR_STEPS as f64).round() as u64)
}

/// `--layers DIR`: each earlier iteration's layers in `DIR/iterations/`, bounded and
/// named as the service keeps them (`service::iterations`). Written as the frames come
/// (a frame is not kept in memory); the first error is reported after the render.
struct IterationFiles {
    dir: PathBuf,
    exposure: f32,
    kept: Vec<Kept>,
    error: Option<anyhow::Error>,
}

impl IterationFiles {
    fn new(dir: &Path, exposure: f32) -> Self {
        Self {
            dir: dir.join(ITERATIONS_DIR),
            exposure,
            kept: Vec::new(),
            error: None,
        }
    }

    fn keep(&mut self, f: &progressive::Frame) {
        // The last frame is written whole beside `iterations/` (`write_layers`); a
        // preview is no iteration.
        if f.last || f.preview || self.error.is_some() {
            return;
        }
        if let Err(e) = self.write(f) {
            self.error = Some(e);
        }
    }

    fn write(&mut self, f: &progressive::Frame) -> anyhow::Result<()> {
        std::fs::create_dir_all(&self.dir)
            .with_context(|| format!("cannot create {}", self.dir.display()))?;
        let mut bytes = 0u64;
        for layer in KEPT_LAYERS {
            let Some(png) = progressive::layers::encode_layer(f, layer.as_str(), self.exposure)?
            else {
                continue;
            };
            let p = self.file(f.iteration, layer.as_str());
            std::fs::write(&p, &png).with_context(|| format!("cannot write {}", p.display()))?;
            bytes += png.len() as u64;
        }
        self.kept.push(Kept {
            iteration: f.iteration,
            bytes,
        });
        for n in to_forget(&self.kept, MAX_KEPT, MAX_KEPT_BYTES) {
            for layer in KEPT_LAYERS {
                let _ = std::fs::remove_file(self.file(n, layer.as_str()));
            }
            self.kept.retain(|k| k.iteration != n);
        }
        Ok(())
    }

    fn file(&self, iteration: u32, layer: &str) -> PathBuf {
        self.dir.join(format!("{iteration:04}-{layer}.png"))
    }
}

/// The last frame's layers; the image as on the scene's display, like `--output`'s PNG.
fn write_layers(
    dir: &std::path::Path,
    frame: &progressive::Frame,
    exposure: f32,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for name in progressive::layers::LAYERS {
        let Some(png) = progressive::layers::encode_layer(frame, name, exposure)? else {
            continue;
        };
        let p = dir.join(format!("{name}.png"));
        std::fs::write(&p, png).with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(())
}

/// A bar with its words on a terminal; hidden when stderr is not a terminal (scripts).
fn progress_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(BAR_STEPS);
    if !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    if let Ok(style) = indicatif::ProgressStyle::with_template("{spinner} [{bar:30}] {msg}")
        .map(|s| s.progress_chars("=> "))
    {
        bar.set_style(style);
    }
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_format_follows_the_extension_or_is_refused() {
        assert_eq!(OutputFormat::of(Path::new("a.png")), Ok(OutputFormat::Png));
        assert_eq!(OutputFormat::of(Path::new("a.JPG")), Ok(OutputFormat::Jpeg));
        assert_eq!(
            OutputFormat::of(Path::new("d/a.jpeg")),
            Ok(OutputFormat::Jpeg)
        );
        assert_eq!(OutputFormat::of(Path::new("a.exr")), Ok(OutputFormat::Exr));
        let e = OutputFormat::of(Path::new("a.tiff")).unwrap_err();
        assert!(e.contains(".tiff") && e.contains(".png"), "{e}");
        assert!(OutputFormat::of(Path::new("image"))
            .unwrap_err()
            .contains("no extension"));
    }

    #[test]
    fn each_format_encodes_its_own_bytes() {
        let img = LinearImage::filled(4, 3, crate::raster::Rgb::new(0.2, 0.4, 0.8));
        let png = OutputFormat::Png.encode(&img, 1.0).unwrap();
        assert_eq!(&png[..4], b"\x89PNG");
        let jpg = OutputFormat::Jpeg.encode(&img, 1.0).unwrap();
        assert_eq!(&jpg[..3], &[0xFF, 0xD8, 0xFF]);
        let exr = OutputFormat::Exr.encode(&img, 1.0).unwrap();
        assert_eq!(&exr[..4], &[0x76, 0x2F, 0x31, 0x01]);
    }

    #[test]
    fn the_reference_pass_extrapolates_its_time_left() {
        let pass = PassEta::default();
        assert!(pass_line(&pass, 0, 1000, 5.0).0.contains("estimating"));
        let (line, pos) = pass_line(&pass, 250, 1000, 755.0);
        assert_eq!(pos, 250);
        assert!(line.contains("25.0 % of pixels traced"), "{line}");
        // 250 pixels in the 750 ms since the first report: 750 left take 2.25 s.
        assert!(line.contains("about 2.2 s left"), "{line}");
        assert!(pass_line(&pass, 1000, 1000, 5.0).0.contains("finishing"));
    }

    #[test]
    fn the_bar_moves_with_the_estimate_and_waits_when_unknown() {
        let eta = Eta::around(3000.0, 1.0);
        assert_eq!(done_share(1000.0, &eta), 250);
        assert_eq!(done_share(1000.0, &Eta::Unknown), 0);
        assert_eq!(done_share(1000.0, &Eta::Done), BAR_STEPS);
    }
}
