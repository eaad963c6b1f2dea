//! The truth the study judges against: the same scene traced with many more samples per
//! pixel than the reference and other seeds, as two independent halves whose mean is the
//! truth. FLIP between the halves is the truth's own error, reported beside the
//! reference's; where it is more than [`SELF_ERROR_SHARE`] of FLIP(reference, truth) at a
//! judged condition, the truth is given twice the samples, until it is not or the next
//! doubling would pass the time cap ([`TruthCheck::cap_ms`]).
//!
//! The truth is traced in *chunks*, renders of [`TRUTH_SPP_FACTOR`] / 2 × the scene's
//! samples each with its own seed: even chunks make half A, odd chunks half B, so a
//! doubling traces only the new chunks. Each chunk is cached on disk as a float EXR, so a
//! second run does not trace it again.
//!
//! The cache key is a hash of everything a chunk depends on: the scene document as
//! written, the image size, the samples per pixel and the seed (the bench may change the
//! size and samples after parsing: `--quick`, `--spp-factor`). The display (exposure,
//! pixels per degree) is not in it: it shapes what a person sees, not the radiance. OBJ
//! files a document names are not hashed: edit one and delete the cache.

use super::flip::flip;
use crate::cancel::CancelToken;
use crate::raster::{decode_image, encode_exr, LinearImage, Rgb};
use crate::scene::Scene;
use crate::tracer::{self, PathTracer};
use anyhow::Context;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// The truth's samples per pixel over the scene's before any doubling: each half then
/// has 8× the reference's samples.
pub const TRUTH_SPP_FACTOR: u32 = 16;
/// The truth's own error, FLIP(half A, half B), may be at most this share of the
/// reference's error FLIP(reference, truth): then the truth's noise is small beside the
/// error it judges. FLIP between the halves overstates the mean's own noise (the
/// difference of two halves has √2 × a half's deviation, the mean 1/√2 ×: 2× in
/// radiance), so the rule is a conservative one.
pub const SELF_ERROR_SHARE: f64 = 0.25;
/// Seed of the truth's first chunk (independent of the reference, the judge and the noise
/// twins); chunk k adds k × [`CHUNK_SEED_STEP`].
const TRUTH_SEED_OFFSET: u64 = 0x2545_F491_4F6C_DD1D;
const CHUNK_SEED_STEP: u64 = 0xD1B5_4A32_D192_ED03;

/// What the truth must be converged against, and how long it may take.
pub struct TruthCheck<'a> {
    /// A render at the scene's samples (the reference or an independent one): its FLIP to
    /// the truth is the error the truth's own must be small beside.
    pub reference: &'a LinearImage,
    /// That render's time: a chunk is estimated to cost it × the chunk's samples over its.
    pub reference_ms: f64,
    /// The viewing conditions (pixels per degree) the truth is judged at: the rule holds
    /// at every one of them.
    pub ppds: &'a [f32],
    /// The truth's whole estimated tracing time may not pass this (the first two chunks are
    /// always traced).
    pub cap_ms: f64,
}

/// The truth's convergence, as the report states it.
#[derive(Clone, Debug, Serialize)]
pub struct TruthInfo {
    pub spp: u32,
    /// `spp` over the scene's.
    pub factor: u32,
    /// The rule was not met at some condition when the next doubling would have passed the
    /// cap.
    pub capped: bool,
    pub cap_s: f64,
    /// Every chunk came from the cache.
    pub cached: bool,
}

/// The converged render, its two halves and how it was reached.
pub struct Truth {
    /// The mean of the halves.
    pub image: LinearImage,
    pub halves: (LinearImage, LinearImage),
    pub info: TruthInfo,
}

impl Truth {
    /// FLIP(half A, half B) at `ppd`: the truth's own error.
    #[must_use]
    pub fn self_flip(&self, exposure: f32, ppd: f32) -> f64 {
        flip(&self.halves.0, &self.halves.1, exposure, ppd).mean
    }
}

/// The truth's own error over the reference's; 0 when the halves agree (a black scene),
/// whatever the reference's.
#[must_use]
pub fn self_error_share(self_flip: f64, reference_flip: f64) -> f64 {
    if self_flip <= 0.0 {
        0.0
    } else if reference_flip > 0.0 {
        self_flip / reference_flip
    } else {
        f64::INFINITY
    }
}

/// The truth's chunks so far: running sums of the even (A) and odd (B) ones.
struct Halves {
    sum: [Vec<Rgb>; 2],
    count: [u32; 2],
    size: (u32, u32),
}

impl Halves {
    fn new(w: u32, h: u32) -> Self {
        let n = w as usize * h as usize;
        Self {
            sum: [vec![Rgb::ZERO; n], vec![Rgb::ZERO; n]],
            count: [0, 0],
            size: (w, h),
        }
    }

    fn add(&mut self, k: usize, chunk: &LinearImage) {
        for (s, p) in self.sum[k % 2].iter_mut().zip(chunk.pixels()) {
            *s += *p;
        }
        self.count[k % 2] += 1;
    }

    fn half(&self, i: usize) -> LinearImage {
        let inv = 1.0 / self.count[i].max(1) as f32;
        let data = self.sum[i].iter().map(|s| *s * inv).collect();
        LinearImage::from_vec(self.size.0, self.size.1, data).expect("the sums are w × h")
    }

    fn chunks(&self) -> usize {
        (self.count[0] + self.count[1]) as usize
    }
}

/// The halves and their mean, and whether the cap stopped the doubling.
struct Converged {
    a: LinearImage,
    b: LinearImage,
    mean: LinearImage,
    chunks: usize,
    capped: bool,
}

fn mean_of(a: &LinearImage, b: &LinearImage) -> LinearImage {
    let data = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(x, y)| (*x + *y) * 0.5)
        .collect();
    LinearImage::from_vec(a.width(), a.height(), data).expect("two images of one size")
}

/// The doubling rule: two chunks, then twice as many while `share(a, b, mean)` (the truth's
/// own error over the reference's, worst over the conditions) is above
/// [`SELF_ERROR_SHARE`] and twice as many chunks stay within `max_chunks`.
fn converge(
    (w, h): (u32, u32),
    mut chunk: impl FnMut(usize) -> anyhow::Result<LinearImage>,
    share: impl Fn(&LinearImage, &LinearImage, &LinearImage) -> f64,
    max_chunks: usize,
) -> anyhow::Result<Converged> {
    let mut halves = Halves::new(w, h);
    loop {
        for k in halves.chunks()..halves.chunks().max(1) * 2 {
            halves.add(k, &chunk(k)?);
        }
        let (a, b) = (halves.half(0), halves.half(1));
        let mean = mean_of(&a, &b);
        let over = share(&a, &b, &mean) > SELF_ERROR_SHARE;
        let room = halves.chunks() * 2 <= max_chunks;
        if !over || !room {
            return Ok(Converged {
                a,
                b,
                mean,
                chunks: halves.chunks(),
                capped: over,
            });
        }
    }
}

/// The truth of `scene` (whose document text is `document`), converged against `check`;
/// each chunk from `cache_dir` if there, else traced and stored there. A cache file that
/// does not decode to the right size is traced again and replaced.
pub fn converged(
    scene: &Scene,
    document: &str,
    tracer: &PathTracer,
    cache_dir: &Path,
    check: &TruthCheck,
    cancel: &CancelToken,
) -> anyhow::Result<Truth> {
    let spp = scene.render.samples_per_pixel;
    let chunk_spp = spp.saturating_mul(TRUTH_SPP_FACTOR / 2);
    let chunk_ms = check.reference_ms * f64::from(chunk_spp) / f64::from(spp.max(1));
    let max_chunks = (check.cap_ms / chunk_ms.max(1e-9)).floor().min(1e6) as usize;
    let mut all_cached = true;
    let chunk = |k: usize| {
        let seed = (scene.render.seed ^ TRUTH_SEED_OFFSET)
            .wrapping_add((k as u64).wrapping_mul(CHUNK_SEED_STEP));
        let (img, cached) = cached_render(
            scene,
            document,
            tracer,
            cache_dir,
            (chunk_spp, seed),
            cancel,
        )?;
        all_cached &= cached;
        Ok(img)
    };
    let exposure = scene.display.exposure;
    let share = |a: &LinearImage, b: &LinearImage, mean: &LinearImage| {
        check
            .ppds
            .iter()
            .map(|&ppd| {
                let own = flip(a, b, exposure, ppd).mean;
                self_error_share(own, flip(mean, check.reference, exposure, ppd).mean)
            })
            .fold(0.0, f64::max)
    };
    let c = converge((scene.width, scene.height), chunk, share, max_chunks)?;
    let total = chunk_spp.saturating_mul(c.chunks as u32);
    Ok(Truth {
        image: c.mean,
        halves: (c.a, c.b),
        info: TruthInfo {
            spp: total,
            factor: total / spp.max(1),
            capped: c.capped,
            cap_s: check.cap_ms / 1e3,
            cached: all_cached,
        },
    })
}

/// A render at (samples, seed), from the cache or traced and cached; and whether it came
/// from the cache.
pub fn cached_render(
    scene: &Scene,
    document: &str,
    tracer: &PathTracer,
    cache_dir: &Path,
    (spp, seed): (u32, u64),
    cancel: &CancelToken,
) -> anyhow::Result<(LinearImage, bool)> {
    let path = cache_path(cache_dir, document, scene.width, scene.height, spp, seed);
    if let Ok(bytes) = std::fs::read(&path) {
        match decode_image(&bytes) {
            Ok(img) if (img.width(), img.height()) == (scene.width, scene.height) => {
                return Ok((img, true))
            }
            _ => eprintln!(
                "bench: cached truth {} is unreadable or of another size: tracing it again",
                path.display()
            ),
        }
    }
    let image = tracer::render_reference_with(tracer, Some((spp, seed)), cancel, &|_, _| {})?;
    std::fs::create_dir_all(cache_dir)
        .with_context(|| format!("cannot create the cache folder {}", cache_dir.display()))?;
    // Written beside and renamed: an interrupted run never leaves a truncated truth.
    let tmp = path.with_extension("exr.part");
    std::fs::write(&tmp, encode_exr(&image)?)
        .and_then(|()| std::fs::rename(&tmp, &path))
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok((image, false))
}

/// `cache_dir/truth-<key>.exr`.
fn cache_path(dir: &Path, document: &str, w: u32, h: u32, spp: u32, seed: u64) -> PathBuf {
    let mut key = Fnv1a::default();
    key.write(document.as_bytes());
    for n in [u64::from(w), u64::from(h), u64::from(spp), seed] {
        key.write(&n.to_le_bytes());
    }
    dir.join(format!("truth-{:016x}.exr", key.0))
}

/// FNV-1a, 64 bits: a key that stays the same across Rust versions and platforms (std's
/// `DefaultHasher` promises neither), and needs no crate.
struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{parse_scene, Limits, SceneOrigin};

    #[test]
    fn fnv1a_matches_its_published_test_vectors() {
        let h = |s: &str| {
            let mut f = Fnv1a::default();
            f.write(s.as_bytes());
            f.0
        };
        assert_eq!(h(""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(h("a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(h("foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn the_key_changes_with_every_input_the_render_depends_on() {
        let d = Path::new("c");
        let base = cache_path(d, "{}", 8, 4, 16, 1);
        for other in [
            cache_path(d, "{ }", 8, 4, 16, 1),
            cache_path(d, "{}", 4, 8, 16, 1),
            cache_path(d, "{}", 8, 4, 32, 1),
            cache_path(d, "{}", 8, 4, 16, 2),
        ] {
            assert_ne!(base, other);
        }
        assert_eq!(base, cache_path(d, "{}", 8, 4, 16, 1));
    }

    const DOC: &str = r#"{"version": 1, "image": {"width": 12, "height": 8},
        "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "fov_y": 40},
        "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}],
        "lights": [{"type": "environment", "radiance": [1, 1, 1]}],
        "render": {"samples_per_pixel": 2}}"#;

    /// A check that any truth passes (a reference far off), within a generous cap.
    fn lenient(reference: &LinearImage) -> TruthCheck<'_> {
        TruthCheck {
            reference,
            reference_ms: 1.0,
            ppds: &[60.0],
            cap_ms: 1e9,
        }
    }

    #[test]
    fn a_second_call_reads_the_cache_and_a_broken_cache_file_is_traced_again() {
        let scene = parse_scene(DOC, &SceneOrigin::Request, &Limits::command_line()).unwrap();
        let tracer = PathTracer::new(&scene);
        let dir = tempfile::tempdir().unwrap();
        let cancel = CancelToken::new();
        let far = LinearImage::filled(12, 8, Rgb::splat(5.0));
        let check = lenient(&far);
        let first = converged(&scene, DOC, &tracer, dir.path(), &check, &cancel).unwrap();
        assert!(!first.info.cached && !first.info.capped);
        assert_eq!(first.info.spp, 2 * TRUTH_SPP_FACTOR);
        assert_eq!(first.info.factor, TRUTH_SPP_FACTOR);
        assert_ne!(first.halves.0, first.halves.1, "two seeds");
        let second = converged(&scene, DOC, &tracer, dir.path(), &check, &cancel).unwrap();
        assert!(second.info.cached);
        assert_eq!(first.image, second.image, "the EXR keeps f32 bit for bit");
        let file = std::fs::read_dir(dir.path())
            .unwrap()
            .next()
            .unwrap()
            .unwrap();
        std::fs::write(file.path(), b"not an exr").unwrap();
        let third = converged(&scene, DOC, &tracer, dir.path(), &check, &cancel).unwrap();
        assert!(!third.info.cached);
        assert_eq!(first.image, third.image);
    }

    /// The rule on a scripted sequence of shares: doubling while the share is above a
    /// quarter, stopping at it, and stopping at the cap with `capped` set.
    #[test]
    fn the_truth_doubles_until_its_own_error_is_a_quarter_of_the_references() {
        let run = |shares: &[f64], max_chunks: usize| {
            let calls = std::cell::Cell::new(0);
            let traced = std::cell::RefCell::new(Vec::new());
            let c = converge(
                (2, 1),
                |k| {
                    traced.borrow_mut().push(k);
                    Ok(LinearImage::filled(2, 1, Rgb::splat(k as f32)))
                },
                |_, _, _| {
                    calls.set(calls.get() + 1);
                    shares[calls.get() - 1]
                },
                max_chunks,
            )
            .unwrap();
            assert_eq!(*traced.borrow(), (0..c.chunks).collect::<Vec<_>>());
            (c.chunks, c.capped, c.a, c.b)
        };
        let (n, capped, a, b) = run(&[1.0, 0.5, 0.3, 0.2], 1000);
        assert_eq!((n, capped), (16, false));
        // Even chunks 0, 2, …, 14 make A (mean 7), odd ones B (mean 8).
        assert_eq!((a.get(0, 0).x, b.get(1, 0).x), (7.0, 8.0));
        assert_eq!(run(&[SELF_ERROR_SHARE], 1000).0, 2, "a quarter is enough");
        assert_eq!(run(&[0.26, 0.1], 1000).0, 4);
        let (n, capped, ..) = run(&[1.0, 0.5, 0.3, 0.2], 8);
        assert_eq!((n, capped), (8, true), "the cap");
        let (n, capped, ..) = run(&[1.0], 3);
        assert_eq!((n, capped), (2, true), "two chunks always");
    }

    /// On a real scene and a reference at its own samples, the truth doubles past 16×
    /// (its halves at 8× the reference's samples leave about half its FLIP) and stops
    /// where the rule holds.
    #[test]
    fn a_noisy_scene_s_truth_is_given_more_samples_until_the_rule_holds() {
        let scene = parse_scene(DOC, &SceneOrigin::Request, &Limits::command_line()).unwrap();
        let tracer = PathTracer::new(&scene);
        let dir = tempfile::tempdir().unwrap();
        let cancel = CancelToken::new();
        let reference = tracer::render_reference(&tracer, &cancel, &|_, _| {}).unwrap();
        let check = TruthCheck {
            ppds: &[28.0, 90.0],
            ..lenient(&reference)
        };
        let t = converged(&scene, DOC, &tracer, dir.path(), &check, &cancel).unwrap();
        assert!(t.info.factor > TRUTH_SPP_FACTOR, "{:?}", t.info);
        assert!(!t.info.capped, "{:?}", t.info);
        for ppd in [28.0, 90.0] {
            let own = t.self_flip(1.0, ppd);
            let r = flip(&t.image, &reference, 1.0, ppd).mean;
            assert!(
                self_error_share(own, r) <= SELF_ERROR_SHARE,
                "{own} vs {r} at {ppd}"
            );
        }
    }

    #[test]
    fn halves_that_agree_have_no_error_whatever_the_reference_s() {
        assert_eq!(self_error_share(0.0, 0.0), 0.0);
        assert_eq!(self_error_share(0.0, 0.3), 0.0);
        assert_eq!(self_error_share(0.1, 0.0), f64::INFINITY);
        assert!((self_error_share(0.1, 0.4) - 0.25).abs() < 1e-12);
    }
}
