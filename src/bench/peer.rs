//! The peer in the table: what a user would otherwise run. Where Mitsuba 3 is installed
//! (`pip install mitsuba`), its path tracer renders its own Cornell box at the time Glimpse's
//! progressive render took, and is judged by FLIP against Mitsuba's own converged render,
//! beside Glimpse judged against Glimpse's own converged render. Renderers differ in pixel
//! filters and edge conventions, so a shared reference would judge conventions, not
//! convergence.

use super::flip::{flip, FlipScore};
use super::BenchConfig;
use crate::cancel::CancelToken;
use crate::progressive::{self, RenderOptions};
use crate::raster::decode_image;
use crate::scene::RenderMode;
use crate::tracer::{self, PathTracer};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// Glimpse and Mitsuba on the Cornell box at equal time.
#[derive(Clone, Debug, Serialize)]
pub struct PeerResult {
    pub size: u32,
    pub glimpse_ms: f64,
    pub glimpse_flip: FlipScore,
    pub glimpse_converged_spp: u32,
    pub mitsuba_variant: String,
    pub mitsuba_ms: f64,
    pub mitsuba_spp: u32,
    pub mitsuba_flip: FlipScore,
    pub mitsuba_converged_spp: u32,
}

/// Runs the comparison, or says why it could not (`Err` is a sentence for the report).
pub fn run_mitsuba(cfg: &BenchConfig, scene_files: &[PathBuf]) -> Result<PeerResult, String> {
    let path = scene_files
        .iter()
        .find(|p| {
            p.file_stem()
                .is_some_and(|s| s.to_string_lossy().contains("cornell"))
        })
        .ok_or("no cornell-box scene in the scene folder")?;
    let probe = Command::new("python3")
        .args(["-c", "import mitsuba"])
        .output();
    if !probe.is_ok_and(|o| o.status.success()) {
        return Err(
            "Mitsuba 3 is not installed here (`pip install mitsuba`): peer column skipped".into(),
        );
    }
    let g = run_glimpse(cfg, path)?;
    let m_conv_spp = if cfg.quick { 256 } else { 1024 };
    let v = run_mitsuba_script(cfg, g.size, g.ms, m_conv_spp)?;
    let read = |k: &str| -> Result<crate::raster::LinearImage, String> {
        let p = v[k]
            .as_str()
            .ok_or(format!("mitsuba script output lacks {k}"))?;
        decode_image(&std::fs::read(p).map_err(|e| e.to_string())?).map_err(|e| e.to_string())
    };
    let (m_test, m_ref) = (read("test_exr")?, read("converged_exr")?);
    Ok(PeerResult {
        size: g.size,
        glimpse_ms: g.ms,
        glimpse_flip: g.flip,
        glimpse_converged_spp: g.converged_spp,
        mitsuba_variant: v["variant"].as_str().unwrap_or("?").into(),
        mitsuba_ms: v["ms"].as_f64().unwrap_or(f64::NAN),
        mitsuba_spp: v["spp"].as_u64().unwrap_or(0) as u32,
        mitsuba_flip: flip(&m_ref, &m_test, 1.0, g.ppd),
        mitsuba_converged_spp: m_conv_spp,
    })
}

/// Glimpse's side: its progressive render of the Cornell box, timed, and judged by FLIP
/// against its own converged render.
struct GlimpseRun {
    size: u32,
    ms: f64,
    flip: FlipScore,
    converged_spp: u32,
    /// The display's pixels per degree, for judging Mitsuba's images the same way.
    ppd: f32,
}

fn run_glimpse(cfg: &BenchConfig, path: &Path) -> Result<GlimpseRun, String> {
    let mut scene = super::load(path, cfg).map_err(|e| e.to_string())?.scene;
    // Mitsuba's built-in Cornell box is square; compare at one square size.
    let size = if cfg.quick { 128 } else { 512 };
    scene.width = size;
    scene.height = size;
    let cancel = CancelToken::new();
    let tracer = PathTracer::new(&scene);
    let converged_spp = scene.render.samples_per_pixel * if cfg.quick { 16 } else { 32 };
    let converged = tracer::render_reference_with(
        &tracer,
        Some((converged_spp, scene.render.seed ^ 1)),
        &cancel,
        &|_, _| {},
    )
    .map_err(|_| "cancelled")?;
    let t = Instant::now();
    let opts = RenderOptions {
        mode: Some(RenderMode::Progressive),
        ..RenderOptions::default()
    };
    let prog = progressive::render(&scene, &tracer, &opts, &mut |_| {}, &cancel)
        .map_err(|_| "cancelled")?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let exposure = scene.display.exposure;
    let ppd = scene.display.pixels_per_degree;
    Ok(GlimpseRun {
        size,
        ms,
        flip: flip(&converged, &prog.image, exposure, ppd),
        converged_spp,
        ppd,
    })
}

/// Mitsuba's side: `scripts/mitsuba_peer.py` renders for Glimpse's time (`glimpse_ms`)
/// and to `converged_spp`, and prints its results as JSON.
fn run_mitsuba_script(
    cfg: &BenchConfig,
    size: u32,
    glimpse_ms: f64,
    converged_spp: u32,
) -> Result<serde_json::Value, String> {
    let out = cfg.out_dir.join("mitsuba");
    std::fs::create_dir_all(&out).map_err(|e| e.to_string())?;
    let script = PathBuf::from("scripts/mitsuba_peer.py");
    let o = Command::new("python3")
        .arg(&script)
        .args([
            "--size",
            &size.to_string(),
            "--seconds",
            &format!("{:.3}", glimpse_ms / 1e3),
        ])
        .args(["--converged-spp", &converged_spp.to_string(), "--out"])
        .arg(&out)
        .output()
        .map_err(|e| format!("cannot run {}: {e}", script.display()))?;
    if !o.status.success() {
        return Err(format!(
            "mitsuba script failed: {}",
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .last()
                .unwrap_or("")
        ));
    }
    serde_json::from_slice(&o.stdout).map_err(|e| format!("mitsuba script output: {e}"))
}
