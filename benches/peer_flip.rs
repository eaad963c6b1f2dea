//! Mitsuba 3's FLIP beside Glimpse's against the Tungsten references of the imported pbrt
//! scenes, in one run: each scene is imported once (`glimpse convert`), rendered by Glimpse
//! (`glimpse render --mode reference`) and by Mitsuba 3 from that same document
//! (`scripts/peer_import.py`) at the size and samples `tests/import_pbrt.rs` uses, and both
//! are judged as that test judges ours: nv-flip at exposure 1 and 28 pixels per degree, the
//! reference box-averaged to the render's size (the repository's small references,
//! tests/public-scenes). veach-ajar is left out: it is not among those small copies (9.4 MB);
//! `cargo bench --bench scenes_at_scale` renders it beside Mitsuba at full size.
//!
//! `cargo bench --bench peer_flip` (needs `pip install mitsuba numpy`).

use std::path::{Path, PathBuf};
use std::process::Command;

use glimpse::raster::{decode_image, LinearImage};

struct Case {
    name: &'static str,
    scene: &'static str,
    reference: &'static str,
    size: (u32, u32),
    spp: u32,
}

const CASES: [Case; 3] = [
    Case {
        name: "Cornell",
        scene: "tests/public-scenes/cornell-box-bitterli/scene-v4.pbrt",
        reference: "tests/public-scenes/cornell-box-bitterli/TungstenRender-256x256.exr",
        size: (64, 64),
        spp: 128,
    },
    Case {
        name: "veach-mis",
        scene: "tests/public-scenes/veach-mis-bitterli/scene-v4.pbrt",
        reference: "tests/public-scenes/veach-mis-bitterli/TungstenRender-256x144.exr",
        size: (128, 72),
        spp: 64,
    },
    Case {
        name: "veach-bidir",
        scene: "scenes/imported/veach-bidir/scene-v4.pbrt",
        reference: "tests/public-scenes/veach-bidir-bitterli/TungstenRender-256x256.exr",
        size: (64, 64),
        spp: 256,
    },
];

fn run(cmd: &mut Command) {
    let out = cmd.output().expect("cannot start");
    assert!(
        out.status.success(),
        "{cmd:?}:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn read(path: &Path) -> LinearImage {
    decode_image(&std::fs::read(path).unwrap()).unwrap()
}

/// `img` box-averaged down to `tw`×`th` (each factor must divide).
fn downsampled(img: &LinearImage, (tw, th): (u32, u32)) -> LinearImage {
    let (w, h) = (img.width(), img.height());
    let (fx, fy) = (w / tw, h / th);
    assert_eq!((fx * tw, fy * th), (w, h), "sizes must divide");
    let mut out = Vec::with_capacity((tw * th) as usize);
    for ty in 0..th {
        for tx in 0..tw {
            let mut b = glam::Vec3::ZERO;
            for y in ty * fy..(ty + 1) * fy {
                for x in tx * fx..(tx + 1) * fx {
                    b += img.pixels()[(y * w + x) as usize];
                }
            }
            out.push(b / (fx * fy) as f32);
        }
    }
    LinearImage::from_vec(tw, th, out).unwrap()
}

fn main() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let bin = env!("CARGO_BIN_EXE_glimpse");
    let tmp = tempfile::tempdir().unwrap();
    println!("| scene | size, spp | Glimpse FLIP | Mitsuba 3 FLIP |");
    println!("|---|---|---:|---:|");
    for c in CASES {
        let (w, h) = c.size;
        let size = format!("{w}x{h}");
        let doc = tmp.path().join(format!("{}.json", c.name));
        run(Command::new(bin)
            .arg("convert")
            .arg(repo.join(c.scene))
            .arg("--output")
            .arg(&doc));
        let ours = tmp.path().join(format!("{}-glimpse.exr", c.name));
        run(Command::new(bin)
            .arg("render")
            .arg(&doc)
            .args(["--mode", "reference", "--spp", &c.spp.to_string()])
            .args(["--size", &size, "--output"])
            .arg(tmp.path().join("out.png"))
            .arg("--exr")
            .arg(&ours));
        let peer = tmp.path().join(format!("{}-mitsuba.exr", c.name));
        run(Command::new("python3")
            .arg(repo.join("scripts/peer_import.py"))
            .arg(&doc)
            .arg(&peer)
            .args(["--spp", &c.spp.to_string(), "--size", &size]));
        let reference = downsampled(&read(&repo.join(c.reference)), (w, h));
        let flip =
            |img: &Path| glimpse::bench::flip::flip_with_map(&reference, &read(img), 1.0, 28.0).0;
        let (a, b) = (flip(&ours), flip(&peer));
        println!(
            "| {} | {w}×{h}, {} spp | {:.4} | {:.4} |",
            c.name, c.spp, a.mean, b.mean
        );
    }
}
