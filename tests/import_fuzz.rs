//! Fuzzing every import parser with a property-test mutator (as tests/scene_fuzz.rs does
//! for documents): the public pbrt, PLY, glTF and GLB files and a zip bundle, mutated by
//! byte flips, truncations, deleted and duplicated spans and extreme numbers. Every case
//! must come back as a scene or an explained error (no panic) within a second, and an
//! imported scene must validate or be refused without a panic. `GLIMPSE_FUZZ_CASES`
//! sets the cases per format (default 150: fast enough for CI).

use std::path::Path;
use std::time::{Duration, Instant};

use glimpse::import::{self, DirSource, Format, ImportLimits, Upload, UploadSettings};
use glimpse::scene::{validate_doc, Limits, SceneOrigin};
use rand::{Rng, SeedableRng};

fn cases() -> usize {
    std::env::var("GLIMPSE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(150)
}

/// The repository's copies of the public scenes: veach-bidir is a bench scene
/// (scenes/imported), the Khronos box a test file (tests/public-scenes).
fn public(p: &str) -> std::path::PathBuf {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    match p.split_once('/') {
        Some(("veach-bidir-bitterli", rest)) => repo.join("scenes/imported/veach-bidir").join(rest),
        None if p == "veach-bidir-bitterli" => repo.join("scenes/imported/veach-bidir"),
        _ => repo.join("tests/public-scenes").join(p),
    }
}

const EXTREMES: [&str; 8] = [
    "1e38",
    "-1e38",
    "0",
    "-0",
    "4294967296",
    "nan",
    "1e-45",
    "-1",
];

/// One random mutation of `b`.
fn mutate(rng: &mut rand_pcg::Pcg64, b: &mut Vec<u8>) {
    if b.is_empty() {
        b.push(b'[');
        return;
    }
    let i = rng.random_range(0..b.len());
    match rng.random_range(0..6) {
        0 => b[i] = rng.random(),
        1 => b.truncate(i),
        2 => {
            let j = (i + rng.random_range(1..64)).min(b.len());
            b.drain(i..j);
        }
        3 => {
            let j = (i + rng.random_range(1..64)).min(b.len());
            let span = b[i..j].to_vec();
            b.splice(i..i, span);
        }
        4 => {
            let e = EXTREMES[rng.random_range(0..EXTREMES.len())].as_bytes();
            b.splice(i..i, e.iter().copied());
        }
        _ => {
            let bytes = rng.random::<u32>().to_le_bytes();
            let j = (i + 4).min(b.len());
            b.splice(i..j, bytes);
        }
    }
}

/// Runs `f` on `cases()` mutants of `seed`, each with 1 to 4 mutations.
fn fuzz(name: &str, seed: &[u8], f: impl Fn(&[u8])) {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    for k in 0..cases() {
        let mut b = seed.to_vec();
        for _ in 0..rng.random_range(1..=4) {
            mutate(&mut rng, &mut b);
        }
        let t = Instant::now();
        f(&b);
        assert!(
            t.elapsed() < Duration::from_secs(1),
            "{name} case {k} took {:?}",
            t.elapsed()
        );
    }
}

fn limits() -> Limits {
    Limits::command_line()
}

#[test]
fn pbrt_mutants_are_imported_or_refused() {
    let dir = public("veach-bidir-bitterli");
    let text = std::fs::read(dir.join("scene-v4.pbrt")).unwrap();
    let files = DirSource { dir };
    let il = ImportLimits::from_scene(&limits());
    fuzz("pbrt", &text, |b| {
        if let Ok(im) = import::import(Format::Pbrt, "scene-v4.pbrt", b, &files, &il) {
            let _ = validate_doc(&im.doc, &SceneOrigin::Request, &limits());
        }
    });
}

#[test]
fn ply_mutants_are_read_or_refused() {
    let ply = std::fs::read(public("veach-bidir-bitterli/models/Mesh002.ply")).unwrap();
    fuzz("ply", &ply, |b| {
        let _ = import::ply::parse(b, 1 << 20);
    });
}

#[test]
fn gltf_and_glb_mutants_are_imported_or_refused() {
    let gltf = std::fs::read(public("gltf-box/Box.gltf")).unwrap();
    let files = DirSource {
        dir: public("gltf-box"),
    };
    let il = ImportLimits::from_scene(&limits());
    fuzz("gltf", &gltf, |b| {
        if let Ok(im) = import::import(Format::Gltf, "Box.gltf", b, &files, &il) {
            let _ = validate_doc(&im.doc, &SceneOrigin::Request, &limits());
        }
    });
    // The same box as a .glb: its JSON in a GLB container, the buffer still a data URI.
    let mut j = gltf.clone();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut glb = b"glTF".to_vec();
    glb.extend(2u32.to_le_bytes());
    glb.extend(((20 + j.len()) as u32).to_le_bytes());
    glb.extend((j.len() as u32).to_le_bytes());
    glb.extend(0x4E4F_534Au32.to_le_bytes());
    glb.extend(&j);
    assert!(import::import_upload(
        Upload::Glb,
        &glb,
        &UploadSettings::default(),
        &limits(),
        1 << 23
    )
    .is_ok());
    fuzz("glb", &glb, |b| {
        let _ = import::import_upload(
            Upload::Glb,
            b,
            &UploadSettings::default(),
            &limits(),
            1 << 23,
        );
    });
}

#[test]
fn zip_mutants_are_unpacked_or_refused() {
    // A stored zip of a small pbrt scene naming one PLY.
    let ply = std::fs::read(public("veach-bidir-bitterli/models/Mesh000.ply")).unwrap();
    let scene = b"Camera \"perspective\" WorldBegin LightSource \"point\" \"rgb I\" [1 1 1] Shape \"plymesh\" \"string filename\" \"m.ply\"".to_vec();
    let mut z = Vec::new();
    let mut dir = Vec::new();
    for (name, data) in [("scene.pbrt", &scene), ("m.ply", &ply)] {
        let at = z.len() as u32;
        let head = |v: &mut Vec<u8>, central: bool| {
            v.extend(if central {
                [0x50, 0x4b, 1, 2]
            } else {
                [0x50, 0x4b, 3, 4]
            });
            if central {
                v.extend([20, 3]);
            }
            v.extend([20, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
            v.extend((data.len() as u32).to_le_bytes());
            v.extend((data.len() as u32).to_le_bytes());
            v.extend((name.len() as u16).to_le_bytes());
            v.extend(0u16.to_le_bytes());
            if central {
                v.extend([0, 0, 0, 0, 0, 0]);
                v.extend((0o100_644u32 << 16).to_le_bytes());
                v.extend(at.to_le_bytes());
            }
            v.extend(name.as_bytes());
        };
        head(&mut z, false);
        z.extend(data.iter());
        head(&mut dir, true);
    }
    let dir_at = z.len() as u32;
    z.extend(&dir);
    z.extend([0x50, 0x4b, 5, 6, 0, 0, 0, 0, 2, 0, 2, 0]);
    z.extend((dir.len() as u32).to_le_bytes());
    z.extend(dir_at.to_le_bytes());
    z.extend([0, 0]);
    let s = UploadSettings::default();
    let ok = import::import_upload(Upload::Zip, &z, &s, &limits(), 1 << 23);
    assert!(ok.is_ok(), "{:?}", ok.err());
    fuzz("zip", &z, |b| {
        let _ = import::import_upload(Upload::Zip, b, &s, &limits(), 1 << 23);
    });
}
