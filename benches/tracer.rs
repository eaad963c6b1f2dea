//! Path tracer throughput on Bitterli's Cornell box.
//!
//! - `primary_rays/512x512`: one camera ray per pixel, closest hit, on one thread:
//!   primary rays per second per core = 262144 / time. Camera rays of a scene this small
//!   test the screen-tile lists of `tracer::primary` (the path tracer's first hit and the
//!   object-id map use the same); `primary_rays/512x512_bvh` traces the same rays through
//!   the CWBVH alone, as scenes too large for the lists do.
//! - `paths/64x64x4spp_depth6`: full paths (NEE + MIS + Russian roulette) on one thread:
//!   paths per second per core = 16384 / time.
//! - After criterion, a reference render of 512², 64 spp, max_bounces 6 on all cores
//!   (rayon), timed three times, interleaved with three renders of the same scene (the
//!   same triangles, materials and camera, written as OBJ files and a JSON manifest) by
//!   Mitsuba 3's `llvm_ad_rgb` path tracer on the same cores (scripts/mitsuba_time.py,
//!   which loads the scene and renders it once untimed first: scene load and Dr.Jit's
//!   kernel compilation are not in Mitsuba's time). Prints both medians and
//!   `glimpse / mitsuba = X×`. Without Mitsuba it says how to install it and times
//!   Glimpse alone.
//!
//! Run: `cargo bench --bench tracer` (`-- primary_rays` for that group alone, without the
//! reference render; `-- reference_render` for the render comparison alone).

use criterion::{criterion_group, Criterion, Throughput};
use glimpse::cancel::CancelToken;
use glimpse::raster::PixelCoord;
use glimpse::scene::{Material, Scene, Shape, Texture};
use glimpse::tracer::fixtures::cornell_box;
use glimpse::tracer::{render_reference, PathTracer, PixelOracle};
use serde_json::json;
use std::hint::black_box;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Instant;

fn primary_rays(c: &mut Criterion) {
    let t = PathTracer::new(&cornell_box(512, 512, 1, 6, 1));
    let mut g = c.benchmark_group("primary_rays");
    g.throughput(Throughput::Elements(512 * 512));
    g.sample_size(20);
    g.bench_function("512x512", |b| {
        b.iter(|| {
            let mut hits = 0u32;
            for y in 0..512 {
                for x in 0..512 {
                    hits += u32::from(t.primary_ray_hits(PixelCoord::new(x, y), 0, 1));
                }
            }
            black_box(hits)
        });
    });
    // The same rays through the BVH alone (what scenes too large for the screen-tile
    // lists of tracer/primary.rs use), for comparison in the same run.
    g.bench_function("512x512_bvh", |b| {
        b.iter(|| {
            let mut hits = 0u32;
            for y in 0..512 {
                for x in 0..512 {
                    hits += u32::from(t.primary_ray_hits_bvh(PixelCoord::new(x, y), 0, 1));
                }
            }
            black_box(hits)
        });
    });
    g.finish();
}

fn paths(c: &mut Criterion) {
    let t = PathTracer::new(&cornell_box(64, 64, 4, 6, 1));
    let mut g = c.benchmark_group("paths");
    g.throughput(Throughput::Elements(64 * 64 * 4));
    g.sample_size(20);
    g.bench_function("64x64x4spp_depth6", |b| {
        b.iter(|| {
            let mut s = glam::Vec3::ZERO;
            for y in 0..64 {
                for x in 0..64 {
                    s += t.radiance(PixelCoord::new(x, y));
                }
            }
            black_box(s)
        });
    });
    g.finish();
}

/// 512², 64 spp, depth 6 on every core, three times, each followed by one Mitsuba render of
/// the same scene when Mitsuba is available; medians and their ratio.
fn full_render() {
    let scene = cornell_box(512, 512, 64, 6, 1);
    let t = PathTracer::new(&scene);
    let dir = tempfile::tempdir().expect("a temporary folder");
    let mut peer = Mitsuba::start(&scene, dir.path());
    let (mut times, mut peer_times) = (Vec::new(), Vec::new());
    let mut mean = [0.0; 3];
    for _ in 0..3 {
        let start = Instant::now();
        let img = render_reference(&t, &CancelToken::new(), &|_, _| {}).expect("not cancelled");
        times.push(start.elapsed().as_secs_f64());
        mean = img.mean();
        if let Some(secs) = peer.as_mut().and_then(Mitsuba::render) {
            peer_times.push(secs);
        }
    }
    let paths = 512.0 * 512.0 * 64.0;
    let med = median(&mut times);
    println!(
        "reference render cornell 512x512 64spp depth6 on {} threads: median {med:.2} s (runs {:?}), {:.2} M paths/s, mean rgb {:.4} {:.4} {:.4}",
        rayon::current_num_threads(),
        rounded(&times),
        paths / med / 1e6,
        mean[0],
        mean[1],
        mean[2]
    );
    if peer_times.len() == times.len() {
        let peer_med = median(&mut peer_times);
        println!(
            "mitsuba llvm_ad_rgb same scene (load and JIT warm-up excluded): median {peer_med:.2} s (runs {:?})",
            rounded(&peer_times)
        );
        println!("glimpse / mitsuba = {:.2}×", med / peer_med);
    } else if peer.is_some() {
        println!("mitsuba stopped answering: no ratio");
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn rounded(v: &[f64]) -> Vec<f64> {
    v.iter().map(|t| (t * 100.0).round() / 100.0).collect()
}

/// Mitsuba 3 (`llvm_ad_rgb`) rendering the bench's scene in a child process
/// (scripts/mitsuba_time.py), one render per request so that its renders interleave
/// with Glimpse's.
struct Mitsuba {
    child: Child,
    answers: std::io::Lines<BufReader<ChildStdout>>,
}

impl Mitsuba {
    /// Writes `scene` into `dir` and starts the script on it; waits for its warm-up
    /// render. `None` (with how to install it) when Mitsuba or its LLVM backend is missing.
    fn start(scene: &Scene, dir: &Path) -> Option<Self> {
        let peer = Self::spawn(scene, dir);
        if peer.is_none() {
            println!(
                "Mitsuba 3 llvm_ad_rgb is not available: no comparison. Install it with \
                 `export DRJIT_LIBLLVM_PATH=$(bash scripts/mitsuba.sh)`, then run again."
            );
        }
        peer
    }

    /// [`Self::start`] without the message.
    fn spawn(scene: &Scene, dir: &Path) -> Option<Self> {
        write_scene(scene, dir).ok()?;
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/mitsuba_time.py");
        let mut child = Command::new("python3")
            .arg(script)
            .arg(dir)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .ok()?;
        let mut answers = BufReader::new(child.stdout.take()?).lines();
        match answers.next() {
            Some(Ok(line)) if line.starts_with("ready llvm_ad_rgb") => {
                Some(Self { child, answers })
            }
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                None
            }
        }
    }

    /// One timed render, in seconds.
    fn render(&mut self) -> Option<f64> {
        let stdin = self.child.stdin.as_mut()?;
        writeln!(stdin, "render").ok()?;
        stdin.flush().ok()?;
        let line = self.answers.next()?.ok()?;
        line.strip_prefix("seconds ")?
            .split(' ')
            .next()?
            .parse()
            .ok()
    }
}

impl Drop for Mitsuba {
    fn drop(&mut self) {
        drop(self.child.stdin.take()); // EOF ends the script
        let _ = self.child.wait();
    }
}

/// The scene as Mitsuba's script reads it: `scene.json` (size, spp, bounces, camera, per
/// object its OBJ and its diffuse albedo or emitted radiance) and one OBJ per object.
fn write_scene(scene: &Scene, dir: &Path) -> std::io::Result<()> {
    let mut objects = Vec::new();
    for (i, shape) in scene.shapes.iter().enumerate() {
        let Shape::Triangles {
            triangles,
            material,
        } = shape
        else {
            return Err(std::io::Error::other("only triangle meshes are written"));
        };
        let name = format!("object{i}.obj");
        let mut obj = String::new();
        for t in triangles {
            for p in t.p {
                obj += &format!("v {} {} {}\n", p.x, p.y, p.z);
            }
        }
        for k in 0..triangles.len() {
            obj += &format!("f {} {} {}\n", 3 * k + 1, 3 * k + 2, 3 * k + 3);
        }
        std::fs::write(dir.join(&name), obj)?;
        let mut object = json!({ "obj": name });
        match scene.materials.get(*material as usize) {
            Some(Material::Diffuse {
                albedo: Texture::Constant(a),
            }) => object["albedo"] = json!(a.to_array()),
            Some(Material::Emissive {
                radiance: r,
                two_sided: false,
            }) => object["radiance"] = json!(r.to_array()),
            _ => {
                return Err(std::io::Error::other(
                    "only constant diffuse and one-sided emitters",
                ))
            }
        }
        objects.push(object);
    }
    let c = &scene.camera;
    let doc = json!({
        "width": scene.width,
        "height": scene.height,
        "spp": scene.render.samples_per_pixel,
        "max_bounces": scene.render.max_bounces,
        "camera": {
            "position": c.position.to_array(),
            "look_at": c.look_at.to_array(),
            "up": c.up.to_array(),
            "fov_y_deg": c.fov_y_deg,
        },
        "objects": objects,
    });
    std::fs::write(dir.join("scene.json"), doc.to_string())
}

criterion_group!(benches, primary_rays, paths);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    // A criterion filter (`cargo bench --bench tracer -- primary_rays`) skips the
    // 20-second render unless it names it: quick A/B runs of one group.
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    if filter.is_none_or(|f| "reference_render".contains(f.as_str())) {
        full_render();
    }
}
