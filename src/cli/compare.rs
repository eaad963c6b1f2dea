//! `glimpse compare A B`: the perceptual distance between two images.
//!
//! PNG is read as sRGB, EXR as linear values (`raster::decode_image`); both are shown on a
//! display of `--display-peak` cd/m² with black level 0.5 cd/m² and exposure 1 (the
//! project's display defaults), seen at `--ppd` pixels per degree. Distances are in JNDs
//! (vision-model.md §2.7); the default map is the adaptive quad-tree of §3.2, `--full`
//! evaluates every pixel.

use crate::metric::{self, DistanceMap, MetricParams};
use crate::raster::{colormap, decode_image, LinearImage};
use crate::vision::{DisplayModel, VisionModel};
use anyhow::{bail, Context};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    /// The first image: PNG (read as sRGB) or EXR (linear values).
    pub a: PathBuf,
    /// The second image, the same size as the first.
    pub b: PathBuf,
    /// Also write the statistics JSON here.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Write the distance map (coloured, with a JND legend) as PNG here.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// Evaluate every pixel instead of the adaptive quad-tree.
    #[arg(long)]
    pub full: bool,
    /// Display peak luminance, cd/m².
    #[arg(long, default_value_t = 100.0)]
    pub display_peak: f32,
    /// Viewing distance as pixels per degree of visual angle.
    #[arg(long, default_value_t = 28.0)]
    pub ppd: f32,
}

/// Display black level (cd/m²), scene-format.md default.
const BLACK: f32 = 0.5;

/// The statistics `compare` prints (cli.md), plus what was compared.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CompareStats {
    pub mean_distance: f64,
    pub max_distance: f64,
    pub p95_distance: f64,
    pub pixels_evaluated: usize,
    pub ms: f64,
    pub mode: &'static str,
    pub width: u32,
    pub height: u32,
    pub leaves: usize,
}

fn load(path: &Path) -> anyhow::Result<LinearImage> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    decode_image(&bytes)
        .with_context(|| format!("{} is not a readable PNG or EXR image", path.display()))
}

/// Mean, max and 95th percentile of a distance map (nearest-rank percentile).
#[must_use]
pub fn summarise(dm: &DistanceMap) -> (f64, f64, f64) {
    let mut v: Vec<f32> = dm.map.pixels().to_vec();
    if v.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let max = v.iter().copied().fold(0f32, f32::max);
    let k = ((0.95 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    let (_, p95, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    (dm.mean(), f64::from(max), f64::from(*p95))
}

/// Compares two decoded images; the whole command minus file IO (used by tests).
pub fn compare_images(
    a: &LinearImage,
    b: &LinearImage,
    args: &CompareArgs,
) -> anyhow::Result<(CompareStats, DistanceMap)> {
    let start = Instant::now();
    if !(args.display_peak.is_finite() && args.display_peak > 0.0) {
        bail!(
            "--display-peak must be a positive number of cd/m², got {}",
            args.display_peak
        );
    }
    if !(args.ppd.is_finite() && args.ppd > 0.0) {
        bail!("--ppd must be a positive number, got {}", args.ppd);
    }
    if (a.width(), a.height()) != (b.width(), b.height()) {
        bail!(
            "images differ in size: {} is {}x{} but {} is {}x{}",
            args.a.display(),
            a.width(),
            a.height(),
            args.b.display(),
            b.width(),
            b.height()
        );
    }
    // A display dimmer than the default black level keeps a proportionate black (0.5 %).
    let black = BLACK.min(0.005 * args.display_peak);
    let display = DisplayModel {
        peak_luminance: args.display_peak,
        black_luminance: black,
        exposure: 1.0,
        pixels_per_degree: args.ppd,
    };
    let model = VisionModel::new(display, a.width(), a.height());
    let sa = model
        .decompose(a)
        .with_context(|| format!("cannot compare {}", args.a.display()))?;
    let sb = model
        .decompose(b)
        .with_context(|| format!("cannot compare {}", args.b.display()))?;
    let dm = if args.full {
        metric::full_map(&model, &sa, &sb)
    } else {
        metric::block_map(&model, &sa, &sb, &[], &MetricParams::default())
    };
    let (mean, max, p95) = summarise(&dm);
    let stats = CompareStats {
        mean_distance: mean,
        max_distance: max,
        p95_distance: p95,
        pixels_evaluated: dm.pixels_evaluated,
        ms: start.elapsed().as_secs_f64() * 1e3,
        mode: if args.full { "full" } else { "adaptive" },
        width: a.width(),
        height: a.height(),
        leaves: dm.leaves.len(),
    };
    Ok((stats, dm))
}

/// The comparison in words, with units and a verdict: 1 JND is a difference a person
/// just notices (vision-model.md §2.7).
#[must_use]
pub fn sentence(s: &CompareStats, a: &CompareArgs) -> String {
    let verdict = if s.max_distance < 1.0 {
        "a person would see no difference anywhere"
    } else if s.p95_distance < 1.0 {
        "a person would see a difference in a few places only"
    } else if s.mean_distance < 1.0 {
        "a person would see a difference in places"
    } else {
        "a person would see the difference across the image"
    };
    let total = u64::from(s.width) * u64::from(s.height);
    format!(
        "{} and {} differ by {:.2} JND on average (95 % of pixels within {:.2} JND, at most {:.2} JND; 1 JND is just noticeable), seen at {} pixels per degree on a {} cd/m² display: {verdict}. {} of {} pixels evaluated ({}) in {:.0} ms.",
        a.a.display(),
        a.b.display(),
        s.mean_distance,
        s.p95_distance,
        s.max_distance,
        a.ppd,
        a.display_peak,
        s.pixels_evaluated,
        total,
        if s.mode == "full" { "every pixel" } else { "adaptive quad-tree" },
        s.ms
    )
}

pub fn run(a: &CompareArgs) -> anyhow::Result<()> {
    let img_a = load(&a.a)?;
    let img_b = load(&a.b)?;
    let (stats, dm) = compare_images(&img_a, &img_b, a)?;
    let json = serde_json::to_string_pretty(&stats)?;
    println!("{json}");
    // The JSON on stdout is for scripts; the sentence on stderr is for the person.
    eprintln!("{}", sentence(&stats, a));
    if let Some(p) = &a.stats {
        std::fs::write(p, format!("{json}\n"))
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if let Some(p) = &a.map {
        let png = colormap::distance_png_with_legend(&dm.map)?;
        std::fs::write(p, png).with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(())
}
