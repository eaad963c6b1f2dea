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
//!   (rayon), timed three times; the median is printed (Mitsuba 3 comparison:
//!   scripts/mitsuba_cornell.py).
//!
//! Run: `cargo bench --bench tracer` (`-- primary_rays` for that group alone, without the
//! reference render).

use criterion::{criterion_group, Criterion, Throughput};
use glimpse::cancel::CancelToken;
use glimpse::raster::PixelCoord;
use glimpse::tracer::fixtures::cornell_box;
use glimpse::tracer::{render_reference, PathTracer, PixelOracle};
use std::hint::black_box;
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

/// 512², 64 spp, depth 6 on every core; median of three.
fn full_render() {
    let t = PathTracer::new(&cornell_box(512, 512, 64, 6, 1));
    let mut times = Vec::new();
    let mut mean = [0.0; 3];
    for _ in 0..3 {
        let start = Instant::now();
        let img = render_reference(&t, &CancelToken::new(), &|_, _| {}).expect("not cancelled");
        times.push(start.elapsed().as_secs_f64());
        mean = img.mean();
    }
    times.sort_by(f64::total_cmp);
    let paths = 512.0 * 512.0 * 64.0;
    println!(
        "reference render cornell 512x512 64spp depth6 on {} threads: median {:.2} s (runs {:?}), {:.2} M paths/s, mean rgb {:.4} {:.4} {:.4}",
        rayon::current_num_threads(),
        times[1],
        times.iter().map(|t| (t * 100.0).round() / 100.0).collect::<Vec<_>>(),
        paths / times[1] / 1e6,
        mean[0],
        mean[1],
        mean[2]
    );
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
