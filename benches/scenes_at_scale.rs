//! Real scenes at real size, Glimpse beside Mitsuba 3 in one run: veach-ajar and
//! veach-bidir (Bitterli's pbrt-v4 files) at 1280×720, 64 spp, and a generated glTF
//! terrain of 1.07 M triangles (scripts/gen_big_gltf.py) at 1280×720, 4 spp (its cost is
//! the load and the memory, not the light transport). Each renderer runs as its own child
//! process per scene, so memory is per process: Glimpse as `glimpse render --mode
//! reference --stats` (its `phases`), Mitsuba through `scripts/peer_import.py` on the
//! document `glimpse convert` wrote from the same file (binary PLY meshes, its native
//! input), runs interleaved G, M, G, M, … and each number the median of the runs.
//!
//! Per scene: load (file to scene), build (BVH, lights), render, samples per second,
//! peak and built resident MB (Glimpse: after the tracer is built; Mitsuba: after
//! mi.load_dict, its Python and Dr.Jit runtime included), bytes per triangle of that
//! resident set, the Glimpse/Mitsuba ratios, and the two pictures' mean radiance and
//! FLIP between them (exposure 1, 28 pixels per degree).
//!
//! `cargo bench --bench scenes_at_scale`; `SCALE_RUNS=3` for medians of 3 (default 1:
//! about 10 minutes on 2 shared cores; 3 runs took 28), `SCALE_SPP=N` for other samples
//! per pixel on the veach scenes, `GLIMPSE_PUBLIC_SCENES=DIR` where the public scenes are.

use std::path::{Path, PathBuf};
use std::process::Command;

use glimpse::raster::{decode_image, LinearImage};
use serde_json::Value;

const SIZE: (u32, u32) = (1280, 720);

/// One scene of the table: the file Glimpse imports and its samples per pixel.
struct Case {
    name: &'static str,
    file: PathBuf,
    spp: u32,
}

/// One renderer's phases for one run, in seconds and bytes.
#[derive(Clone, Copy, Debug, Default)]
struct Run {
    load_s: f64,
    build_s: f64,
    render_s: f64,
    samples_per_s: f64,
    peak_bytes: f64,
    built_bytes: f64,
    triangles: f64,
}

impl Run {
    fn from_glimpse(stats: &Value) -> Self {
        let p = &stats["phases"];
        let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
        Self {
            load_s: f(&p["load_ms"]) / 1e3,
            build_s: f(&p["build_ms"]) / 1e3,
            render_s: f(&p["render_ms"]) / 1e3,
            samples_per_s: f(&p["samples_per_second"]),
            peak_bytes: f(&p["memory"]["peak_bytes"]),
            built_bytes: f(&p["memory"]["built_bytes"]),
            triangles: f(&p["primitives"]),
        }
    }

    fn from_mitsuba(report: &Value) -> Self {
        let f = |k: &str| report[k].as_f64().unwrap_or(f64::NAN);
        Self {
            load_s: f("parse_s"),
            build_s: f("build_s"),
            render_s: f("render_s"),
            samples_per_s: f("samples_per_second"),
            peak_bytes: f("peak_rss_bytes"),
            built_bytes: f("loaded_rss_bytes"),
            triangles: f("triangles"),
        }
    }

    /// Field by field median of `runs` (the middle one; the mean of the two middle ones).
    fn median(runs: &[Run]) -> Run {
        let m = |g: fn(&Run) -> f64| {
            let mut v: Vec<f64> = runs.iter().map(g).collect();
            v.sort_by(f64::total_cmp);
            let n = v.len();
            if n % 2 == 1 {
                v[n / 2]
            } else {
                0.5 * (v[n / 2 - 1] + v[n / 2])
            }
        };
        Run {
            load_s: m(|r| r.load_s),
            build_s: m(|r| r.build_s),
            render_s: m(|r| r.render_s),
            samples_per_s: m(|r| r.samples_per_s),
            peak_bytes: m(|r| r.peak_bytes),
            built_bytes: m(|r| r.built_bytes),
            triangles: m(|r| r.triangles),
        }
    }

    fn row(&self, who: &str, scene: &str) -> String {
        let mb = 1024.0 * 1024.0;
        format!(
            "| {scene} | {who} | {:.0} | {:.2} | {:.2} | {:.2} | {:.1} | {:.3} | {:.0} | {:.0} | {:.0} |",
            self.triangles,
            self.load_s,
            self.build_s,
            self.load_s + self.build_s,
            self.render_s,
            self.samples_per_s / 1e6,
            self.peak_bytes / mb,
            self.built_bytes / mb,
            self.built_bytes / self.triangles,
        )
    }
}

/// Runs `cmd`, returning its stdout, or a sentence saying why not.
fn run(cmd: &mut Command) -> Result<String, String> {
    let out = cmd
        .output()
        .map_err(|e| format!("{cmd:?}: cannot start: {e}"))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = err.lines().rev().take(6).collect();
        return Err(format!("{cmd:?} failed: {}", tail.join(" / ")));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Where the public scenes are: `GLIMPSE_PUBLIC_SCENES`, else `shared/scenes-public`
/// beside the repository or beside its worktree folder.
fn public_scenes(repo: &Path) -> Option<PathBuf> {
    if let Ok(d) = std::env::var("GLIMPSE_PUBLIC_SCENES") {
        return Some(PathBuf::from(d));
    }
    ["../shared/scenes-public", "../../shared/scenes-public"]
        .iter()
        .map(|p| repo.join(p))
        .find(|p| p.is_dir())
}

/// The scenes that are present (each absent one said, with how to get it).
fn cases(repo: &Path, work: &Path, spp: u32) -> Vec<Case> {
    let public = public_scenes(repo);
    let mut out = Vec::new();
    let ajar = public
        .as_ref()
        .map(|p| p.join("veach-ajar-bitterli/scene-v4.pbrt"));
    match ajar.filter(|f| f.is_file()) {
        Some(file) => out.push(Case {
            name: "veach-ajar",
            file,
            spp,
        }),
        None => println!(
            "veach-ajar: ABSENT: the public scenes (shared/scenes-public/veach-ajar-bitterli, \
             see its SOURCE.md: github.com/gonsolo/bitterli, veach-ajar/pbrt) are not beside \
             the repository; set GLIMPSE_PUBLIC_SCENES=DIR"
        ),
    }
    let bidir = public
        .as_ref()
        .map(|p| p.join("veach-bidir-bitterli/scene-v4.pbrt"))
        .filter(|f| f.is_file())
        .unwrap_or_else(|| repo.join("scenes/imported/veach-bidir/scene-v4.pbrt"));
    out.push(Case {
        name: "veach-bidir",
        file: bidir,
        spp,
    });
    let big = work.join("terrain-1m.gltf");
    let gen = Command::new("python3")
        .arg(repo.join("scripts/gen_big_gltf.py"))
        .arg(&big)
        .output();
    match gen {
        Ok(o) if o.status.success() => out.push(Case {
            name: "terrain-1M (glTF)",
            file: big,
            spp: 4,
        }),
        _ => println!(
            "terrain-1M: ABSENT: scripts/gen_big_gltf.py could not write it (needs python3 \
             with numpy: pip install numpy)"
        ),
    }
    out
}

/// Whether Mitsuba 3 can be imported (said when not, with how to install it).
fn mitsuba_present(repo: &Path) -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import mitsuba, numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        println!(
            "Mitsuba 3: ABSENT (python3 cannot import mitsuba and numpy): run `bash {}` \
             (pip install mitsuba numpy, and libLLVM for its vectorised variant); only \
             Glimpse's rows follow",
            repo.join("scripts/mitsuba.sh").display()
        );
    }
    ok
}

fn read_image(path: &Path) -> Result<LinearImage, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    decode_image(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

fn mean(img: &LinearImage) -> glam::Vec3 {
    img.pixels().iter().copied().sum::<glam::Vec3>() / img.pixels().len() as f32
}

/// The renderers' last pictures side by side: mean radiance of each and FLIP between.
fn compare(ours: &Path, peer: &Path) -> Result<String, String> {
    let (a, b) = (read_image(ours)?, read_image(peer)?);
    let flip = glimpse::bench::flip::flip_with_map(&b, &a, 1.0, 28.0)
        .0
        .mean;
    let (ma, mb) = (mean(&a), mean(&b));
    Ok(format!(
        "mean radiance Glimpse {:.4} {:.4} {:.4}, Mitsuba {:.4} {:.4} {:.4} (ratio {:.3}); FLIP between them {flip:.4}",
        ma.x, ma.y, ma.z, mb.x, mb.y, mb.z,
        ma.element_sum() / mb.element_sum()
    ))
}

struct Tools<'a> {
    repo: &'a Path,
    bin: &'a str,
    work: &'a Path,
}

impl Tools<'_> {
    fn glimpse(&self, c: &Case, exr: &Path) -> Result<Run, String> {
        let stats = self.work.join("stats.json");
        let (w, h) = SIZE;
        run(Command::new(self.bin)
            .arg("render")
            .arg(&c.file)
            .args(["--mode", "reference", "--no-denoise", "--seed", "1"])
            .args(["--spp", &c.spp.to_string(), "--size", &format!("{w}x{h}")])
            .arg("--output")
            .arg(self.work.join("glimpse.png"))
            .arg("--exr")
            .arg(exr)
            .arg("--stats")
            .arg(&stats))?;
        let text = std::fs::read_to_string(&stats).map_err(|e| e.to_string())?;
        let v: Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
        Ok(Run::from_glimpse(&v))
    }

    fn mitsuba(&self, doc: &Path, c: &Case, exr: &Path) -> Result<Run, String> {
        let (w, h) = SIZE;
        let out = run(Command::new("python3")
            .arg(self.repo.join("scripts/peer_import.py"))
            .arg(doc)
            .arg(exr)
            .args(["--spp", &c.spp.to_string(), "--size", &format!("{w}x{h}")]))?;
        let last = out.lines().last().unwrap_or_default();
        let v: Value = serde_json::from_str(last).map_err(|e| format!("{e}: {last}"))?;
        Ok(Run::from_mitsuba(&v))
    }
}

/// Glimpse's and (when present) Mitsuba's medians for `c` over `runs` interleaved runs.
fn measure(t: &Tools, c: &Case, runs: usize, peer: bool) -> Result<(Run, Option<Run>), String> {
    let doc = t.work.join("doc.json");
    if peer {
        run(Command::new(t.bin)
            .arg("convert")
            .arg(&c.file)
            .arg("--output")
            .arg(&doc))?;
    }
    let (ours_exr, peer_exr) = (t.work.join("glimpse.exr"), t.work.join("mitsuba.exr"));
    let (mut g, mut m) = (Vec::new(), Vec::new());
    for _ in 0..runs {
        g.push(t.glimpse(c, &ours_exr)?);
        if peer {
            m.push(t.mitsuba(&doc, c, &peer_exr)?);
        }
    }
    if peer {
        match compare(&ours_exr, &peer_exr) {
            Ok(line) => println!("{}: {line}", c.name),
            Err(e) => println!("{}: pictures not compared: {e}", c.name),
        }
    }
    Ok((Run::median(&g), peer.then(|| Run::median(&m))))
}

fn env_number(name: &str, default: u32) -> u32 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(default)
}

fn main() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let work = tempfile::tempdir().expect("a temporary folder");
    let runs = env_number("SCALE_RUNS", 1) as usize;
    let spp = env_number("SCALE_SPP", 64);
    let peer = mitsuba_present(&repo);
    let t = Tools {
        repo: &repo,
        bin: env!("CARGO_BIN_EXE_glimpse"),
        work: work.path(),
    };
    let cases = cases(&repo, work.path(), spp);
    let mut rows = Vec::new();
    let mut ratios = Vec::new();
    for c in &cases {
        eprintln!(
            "{}: {} run(s) at {}x{}, {} spp …",
            c.name, runs, SIZE.0, SIZE.1, c.spp
        );
        match measure(&t, c, runs, peer) {
            Ok((g, m)) => {
                // Said at once too: a long run stopped early keeps what it measured.
                rows.push(g.row("Glimpse", c.name));
                eprintln!("{}", rows[rows.len() - 1]);
                if let Some(m) = m {
                    rows.push(m.row("Mitsuba 3", c.name));
                    ratios.push(ratio_line(c, &g, &m));
                    eprintln!("{}\n{}", rows[rows.len() - 1], ratios[ratios.len() - 1]);
                }
            }
            Err(e) => println!("{}: FAILED: {e}", c.name),
        }
    }
    println!(
        "\n{}x{}, medians of {runs} run(s); veach scenes at {spp} spp, the terrain at 4 spp; MB = MiB",
        SIZE.0, SIZE.1
    );
    println!("| scene | renderer | triangles | load s | build s | load+build s | render s | Msamples/s | peak MB | built MB | B/tri (built) |");
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    rows.iter().for_each(|r| println!("{r}"));
    if !ratios.is_empty() {
        println!("\nGlimpse / Mitsuba 3 (same run):");
        ratios.iter().for_each(|r| println!("{r}"));
    }
}

fn ratio_line(c: &Case, g: &Run, m: &Run) -> String {
    format!(
        "{}: load+build {:.2}, samples/s {:.2}, peak memory {:.2}, built memory {:.2}",
        c.name,
        (g.load_s + g.build_s) / (m.load_s + m.build_s),
        g.samples_per_s / m.samples_per_s,
        g.peak_bytes / m.peak_bytes,
        g.built_bytes / m.built_bytes,
    )
}
