//! The truth the study judges against: the same scene traced with [`TRUTH_SPP_FACTOR`] ×
//! its samples per pixel and another seed, cached on disk as a float EXR so a
//! second run does not trace it again.
//!
//! The cache key is a hash of everything the render depends on: the scene document as
//! written, the image size, the samples per pixel and the seed (the bench may change the
//! size and samples after parsing: `--quick`, `--spp-factor`). The display (exposure,
//! pixels per degree) is not in it: it shapes what a person sees, not the radiance. OBJ
//! files a document names are not hashed: edit one and delete the cache.

use crate::cancel::CancelToken;
use crate::raster::{decode_image, encode_exr, LinearImage};
use crate::scene::Scene;
use crate::tracer::{self, PathTracer};
use anyhow::Context;
use std::path::{Path, PathBuf};

/// The truth's samples per pixel over the scene's: its noise is then 4× lower than the
/// reference's (√16), so the reference's own error dominates FLIP(reference, truth).
pub const TRUTH_SPP_FACTOR: u32 = 16;
/// Seed of the truth (independent of the reference, the judge and the noise twins).
const TRUTH_SEED_OFFSET: u64 = 0x2545_F491_4F6C_DD1D;

/// The converged render and whether it came from the cache.
pub struct Truth {
    pub image: LinearImage,
    pub spp: u32,
    pub cached: bool,
}

/// The truth of `scene` (whose document text is `document`), from `cache_dir` if there,
/// else traced and stored there. A cache file that does not decode to the right size is
/// traced again and replaced.
pub fn converged(
    scene: &Scene,
    document: &str,
    tracer: &PathTracer,
    cache_dir: &Path,
    cancel: &CancelToken,
) -> anyhow::Result<Truth> {
    let spp = scene
        .render
        .samples_per_pixel
        .saturating_mul(TRUTH_SPP_FACTOR);
    let seed = scene.render.seed ^ TRUTH_SEED_OFFSET;
    let path = cache_path(cache_dir, document, scene.width, scene.height, spp, seed);
    if let Ok(bytes) = std::fs::read(&path) {
        match decode_image(&bytes) {
            Ok(img) if (img.width(), img.height()) == (scene.width, scene.height) => {
                return Ok(Truth {
                    image: img,
                    spp,
                    cached: true,
                })
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
    Ok(Truth {
        image,
        spp,
        cached: false,
    })
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

    #[test]
    fn a_second_call_reads_the_cache_and_a_broken_cache_file_is_traced_again() {
        let doc = r#"{"version": 1, "image": {"width": 12, "height": 8},
            "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "fov_y": 40},
            "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
            "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}],
            "lights": [{"type": "environment", "radiance": [1, 1, 1]}],
            "render": {"samples_per_pixel": 2}}"#;
        let scene = parse_scene(doc, &SceneOrigin::Request, &Limits::command_line()).unwrap();
        let tracer = PathTracer::new(&scene);
        let dir = tempfile::tempdir().unwrap();
        let cancel = CancelToken::new();
        let first = converged(&scene, doc, &tracer, dir.path(), &cancel).unwrap();
        assert!(!first.cached);
        assert_eq!(first.spp, 2 * TRUTH_SPP_FACTOR);
        let second = converged(&scene, doc, &tracer, dir.path(), &cancel).unwrap();
        assert!(second.cached);
        assert_eq!(first.image, second.image, "the EXR keeps f32 bit for bit");
        let file = std::fs::read_dir(dir.path())
            .unwrap()
            .next()
            .unwrap()
            .unwrap();
        std::fs::write(file.path(), b"not an exr").unwrap();
        let third = converged(&scene, doc, &tracer, dir.path(), &cancel).unwrap();
        assert!(!third.cached);
        assert_eq!(first.image, third.image);
    }
}
