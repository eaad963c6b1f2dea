//! What a denoise costs: Intel Open Image Denoise's `RT` filter through
//! `glimpse::denoise` at 256×256 and 1024×768, for each quality, without auxiliary
//! images, with noisy ones and with clean ones (`cleanAux`, which at `High` switches
//! OIDN to its larger network). A 32×32 image measures the fixed cost of a call
//! (filter creation and commit, padding, copies) next to the network's.
//!
//! Needs the library: `bash scripts/oidn.sh` first. Run: `cargo bench --bench denoise`
//! (about 4 minutes on 2 cores).

use criterion::{criterion_group, BenchmarkId, Criterion};
use glimpse::denoise::{Aux, Denoiser, Quality, Run};
use glimpse::raster::{LinearImage, Rgb};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;
use std::hint::black_box;
use std::time::Duration;

/// A checkerboard under constant light with ±0.25 noise, and its albedo and normal.
fn scene(w: u32, h: u32) -> (LinearImage, LinearImage, LinearImage) {
    let albedo = LinearImage::from_fn(w, h, |x, y| {
        if (x / 16 + y / 16) % 2 == 0 {
            Rgb::splat(0.8)
        } else {
            Rgb::new(0.1, 0.2, 0.15)
        }
    });
    let mut rng = Pcg32::seed_from_u64(1);
    let color = albedo.map(|&a| a * 0.5 + Rgb::splat(rng.random_range(-0.25..0.25)));
    (color, albedo, LinearImage::filled(w, h, Rgb::Z))
}

fn denoise(c: &mut Criterion) {
    let denoiser = Denoiser::shared().unwrap_or_else(|e| panic!("{e}"));
    println!(
        "OIDN {} from {} on {} threads",
        denoiser.version(),
        denoiser.library_path().display(),
        rayon::current_num_threads()
    );
    let mut group = c.benchmark_group("denoise");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    for (w, h) in [(32, 32), (256, 256), (1024, 768)] {
        let (color, albedo, normal) = scene(w, h);
        for quality in [Quality::Fast, Quality::Balanced, Quality::High] {
            for (name, clean) in [("none", None), ("aux", Some(false)), ("clean", Some(true))] {
                let aux = clean.map(|clean| Aux {
                    albedo: &albedo,
                    normal: &normal,
                    clean,
                });
                let id = BenchmarkId::new(format!("{w}x{h}/{quality:?}"), name);
                group.bench_with_input(id, &aux, |b, aux| {
                    b.iter(|| {
                        denoiser
                            .denoise(black_box(&color), aux.as_ref(), &Run::new(quality))
                            .expect("denoised")
                    });
                });
            }
        }
    }
    group.finish();
}

criterion_group!(benches, denoise);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
}
