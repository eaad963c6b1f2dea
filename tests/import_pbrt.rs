//! pbrt-v4 import against references: Bitterli's Cornell box renders like Glimpse's own
//! `scenes/cornell-box.json`, and the public scenes render like the Tungsten reference
//! EXRs that come with them (display-range means: each channel clamped to [0, 1], the
//! reference box-downsampled to the render's size). Renders run the real binary
//! (`glimpse render FILE.pbrt --exr`), as a person would.

use std::path::{Path, PathBuf};

mod common;

use glimpse::cancel::CancelToken;
use glimpse::import::load_path;
use glimpse::raster::LinearImage;
use glimpse::scene::Limits;
use glimpse::tracer::{render_reference, PathTracer};

/// A public scene's pbrt file and its Tungsten reference EXR: the repository's copies
/// (tests/public-scenes/README.md: the references box-averaged by a factor that divides
/// the sizes compared here), else the shared folder beside the repository (veach-ajar,
/// too large to keep), with a failure naming the file that is missing.
fn public(folder: &str) -> (PathBuf, PathBuf) {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let kept = repo.join("tests/public-scenes").join(folder);
    let (scene, reference) = match folder {
        "cornell-box-bitterli" => (
            kept.join("scene-v4.pbrt"),
            kept.join("TungstenRender-256x256.exr"),
        ),
        "veach-mis-bitterli" => (
            kept.join("scene-v4.pbrt"),
            kept.join("TungstenRender-256x144.exr"),
        ),
        "veach-bidir-bitterli" => (
            repo.join("scenes/imported/veach-bidir/scene-v4.pbrt"),
            kept.join("TungstenRender-256x256.exr"),
        ),
        _ => {
            let shared = repo.join("../shared/scenes-public").join(folder);
            (
                shared.join("scene-v4.pbrt"),
                shared.join("TungstenRender.exr"),
            )
        }
    };
    for f in [&scene, &reference] {
        assert!(
            f.is_file(),
            "{} is missing: {folder} is not kept in the repository (tests/public-scenes/README.md); \
             this test reads it from the shared public scenes beside the repository \
             (../shared/scenes-public/{folder}/, with its models/ and textures/)",
            f.display()
        );
    }
    (scene, reference)
}

/// Mean linear RGB of a reference render (every pixel traced) of the scene at `path`,
/// at `size`² with `spp` samples and `bounces` scattering events.
fn mean_of(path: &Path, size: u32, spp: u32, bounces: u32) -> [f64; 3] {
    let (mut scene, _) = load_path(path, &Limits::command_line()).unwrap();
    scene.width = size;
    scene.height = size;
    scene.render.samples_per_pixel = spp;
    scene.render.max_bounces = bounces;
    let img = render_reference(&PathTracer::new(&scene), &CancelToken::new(), &|_, _| {}).unwrap();
    let mut s = [0f64; 3];
    for p in img.pixels() {
        s[0] += f64::from(p.x);
        s[1] += f64::from(p.y);
        s[2] += f64::from(p.z);
    }
    s.map(|v| v / f64::from(size * size))
}

#[test]
fn bitterli_cornell_box_renders_like_the_glimpse_document() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ours = mean_of(&repo.join("scenes/cornell-box.json"), 64, 256, 8);
    let pbrt = mean_of(&public("cornell-box-bitterli").0, 64, 256, 8);
    for c in 0..3 {
        let rel = (pbrt[c] - ours[c]).abs() / ours[c];
        assert!(
            rel < 0.01,
            "channel {c}: pbrt {pbrt:?} vs document {ours:?}"
        );
    }
    eprintln!("cornell: pbrt {pbrt:?}, document {ours:?}");
}

/// The mean over pixels of each channel clamped to [0, 1], after box-averaging `img`
/// (w×h) down to `tw`×`th`; over the rows in `rows` (fractions of the height) only.
fn display_mean(
    img: &[[f32; 3]],
    (w, h): (u32, u32),
    (tw, th): (u32, u32),
    rows: std::ops::Range<f64>,
) -> [f64; 3] {
    let (fx, fy) = (w / tw, h / th);
    assert_eq!((fx * tw, fy * th), (w, h), "sizes must divide");
    let (r0, r1) = (
        (rows.start * f64::from(th)) as u32,
        (rows.end * f64::from(th)) as u32,
    );
    let mut s = [0f64; 3];
    for ty in r0..r1 {
        for tx in 0..tw {
            let mut b = [0f64; 3];
            for y in ty * fy..(ty + 1) * fy {
                for x in tx * fx..(tx + 1) * fx {
                    let p = img[(y * w + x) as usize];
                    for c in 0..3 {
                        b[c] += f64::from(p[c]);
                    }
                }
            }
            for c in 0..3 {
                s[c] += (b[c] / f64::from(fx * fy)).clamp(0.0, 1.0);
            }
        }
    }
    s.map(|v| v / f64::from(tw * (r1 - r0)))
}

/// `img` (w×h) box-averaged down to `tw`×`th`, as a linear image.
fn downsampled(img: &[[f32; 3]], (w, h): (u32, u32), (tw, th): (u32, u32)) -> LinearImage {
    let (fx, fy) = (w / tw, h / th);
    let mut out = Vec::with_capacity((tw * th) as usize);
    for ty in 0..th {
        for tx in 0..tw {
            let mut b = glam::Vec3::ZERO;
            for y in ty * fy..(ty + 1) * fy {
                for x in tx * fx..(tx + 1) * fx {
                    b += glam::Vec3::from(img[(y * w + x) as usize]);
                }
            }
            out.push(b / (fx * fy) as f32);
        }
    }
    LinearImage::from_vec(tw, th, out).unwrap()
}

/// FLIP (nv-flip, at exposure 1 and 28 pixels per degree, as `glimpse bench` judges) of
/// our render against the Tungsten reference downsampled to its size: the whole image
/// and its top, middle and bottom thirds. Printed, not bounded: the pbrt conversions
/// differ from the scenes Tungsten rendered (README), and FLIP also sees our noise.
fn flip_against_tungsten(
    folder: &str,
    ours: &[[f32; 3]],
    (w, h): (u32, u32),
    refr: (&[[f32; 3]], u32, u32),
) {
    let a = downsampled(ours, (w, h), (w, h));
    let b = downsampled(refr.0, (refr.1, refr.2), (w, h));
    let (score, map) = glimpse::bench::flip::flip_with_map(&b, &a, 1.0, 28.0);
    let third = |k: u32| {
        let rows = (k * h / 3)..((k + 1) * h / 3);
        let n = f64::from(w * (rows.end - rows.start));
        rows.flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(map.pixels()[(y * w + x) as usize]))
            .sum::<f64>()
            / n
    };
    eprintln!(
        "{folder}: FLIP against Tungsten {:.4} (top third {:.4}, middle {:.4}, bottom {:.4}), 99th percentile {:.4}",
        score.mean,
        third(0),
        third(1),
        third(2),
        score.p99
    );
}

/// The render's display-range mean against the Tungsten reference's over `rows`; the
/// worst relative channel difference. Prints FLIP beside it.
fn against_tungsten(folder: &str, w: u32, h: u32, spp: u32, rows: std::ops::Range<f64>) -> f64 {
    let (scene, reference) = public(folder);
    let (ours, ow, oh) = common::render_exr(
        &scene,
        &["--spp", &spp.to_string(), "--size", &format!("{w}x{h}")],
    );
    let (refr, rw, rh) = common::read_exr(&reference);
    if rows == (0.0..1.0) {
        flip_against_tungsten(folder, &ours, (ow, oh), (&refr, rw, rh));
    }
    let a = display_mean(&ours, (ow, oh), (w, h), rows.clone());
    let b = display_mean(&refr, (rw, rh), (w, h), rows.clone());
    let worst = (0..3)
        .map(|c| (a[c] - b[c]).abs() / b[c])
        .fold(0.0, f64::max);
    eprintln!(
        "{folder}, rows {rows:?}: Glimpse {a:.4?} vs Tungsten {b:.4?}: worst channel {:.1} %",
        worst * 100.0
    );
    worst
}

#[test]
fn cornell_box_matches_the_tungsten_reference() {
    let d = against_tungsten("cornell-box-bitterli", 64, 64, 128, 0.0..1.0);
    assert!(d < 0.05, "{d}");
}

/// The wall and the lights (the top 30 % of the image) match. Over the whole image the
/// import is 35 % brighter: its plates reflect the lit back wall, which the pbrt file
/// places where the plates see it (up to y = 19.8) and Tungsten's render shows black. An
/// independent renderer agrees with Glimpse on the imported scene (Mitsuba 3 through
/// scripts/peer_import.py: within 0.4 %, README), so the difference is in the file.
#[test]
fn veach_mis_matches_the_tungsten_reference_where_the_scenes_agree() {
    let d = against_tungsten("veach-mis-bitterli", 128, 72, 64, 0.0..0.3);
    assert!(d < 0.05, "{d}");
    let whole = against_tungsten("veach-mis-bitterli", 128, 72, 64, 0.0..1.0);
    assert!(whole.is_finite());
}

#[test]
fn veach_bidir_matches_the_tungsten_reference() {
    let d = against_tungsten("veach-bidir-bitterli", 64, 64, 256, 0.0..1.0);
    assert!(d < 0.15, "{d}");
}

/// Reported, not bounded: the pbrt conversion lacks the reference's floor texture and
/// two of its textures (scenes-public/README.md).
#[test]
fn veach_ajar_is_reported_against_the_tungsten_reference() {
    let d = against_tungsten("veach-ajar-bitterli", 128, 72, 64, 0.0..1.0);
    assert!(d.is_finite());
}
