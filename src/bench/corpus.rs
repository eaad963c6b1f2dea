//! `glimpse bench --corpus N --seed S`: N varied scene documents, generated from the seed
//! alone, so nothing is tuned to five scenes. The documents are written into
//! the output folder, so a run can be repeated and any scene opened by a person.
//!
//! Each scene is a **room** (floor, ceiling, three walls, open towards the camera) or an
//! **open** scene (a ground plane under the sky) holding 1–5 objects (spheres, boxes, a
//! pyramid mesh, a standing panel) of diffuse, textured (checker or noise), glossy, mirror
//! and glass materials, lit by area lights (emissive quads or spheres), point,
//! directional and environment lights. Scene `i` always has the material and the light
//! `i` of the lists below, so any 6 consecutive scenes hold every material and light.
//! Lights are set so that a lit diffuse surface shows about 0.5 at exposure 1; the
//! exposure then spans 1/16 (dark) to 8 (blinding). Size, samples and viewing condition
//! are drawn as the [`Profile`] and [`PPD_RANGE`] say.
//!
//! Two profiles: [`Profile::Small`] (the default, and what `--quick` and the tests run:
//! references under a second) and [`Profile::Users`], the sizes and samples people render
//! (256–1024 px on the long side, 64 samples per pixel and up, references of about 1–20 s
//! on the 2-core machine the study runs on). The profiles draw from the same stream; a
//! seed of the small profile gives the documents it always gave.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use serde_json::{json, Value};

/// Declared pixels per degree (20 to 100).
pub const PPD_RANGE: (f32, f32) = (20.0, 100.0);
/// Long side of the image, pixels (96 to 512), log-uniform.
pub const LONG_SIDE: (u32, u32) = (96, 512);
/// Samples per pixel (8 to 128), log-uniform, within [`SAMPLE_BUDGET`].
pub const SPP: (u32, u32) = (8, 128);
/// Samples of one reference render at most (width × height × spp): 2^21, about 0.5–1 s of
/// tracing on this 2-core machine, so the truth (16×) stays under ~15 s and a 40-scene
/// corpus within ~15 minutes. 512² at 8 spp is exactly this budget.
pub const SAMPLE_BUDGET: u64 = 1 << 21;

const MATERIALS: [&str; 6] = ["diffuse", "checker", "noise", "glossy", "mirror", "glass"];
const LIGHTS: [&str; 4] = ["area", "point", "directional", "environment"];

/// One generated document.
pub struct CorpusScene {
    /// Also its file stem.
    pub name: String,
    /// The JSON document, as written to disk.
    pub document: String,
}

/// Which sizes and samples a corpus draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Profile {
    /// [`LONG_SIDE`], [`SPP`] within [`SAMPLE_BUDGET`]: references of 0.5–1 s.
    #[default]
    Small,
    /// [`USERS_LONG_SIDE`], [`USERS_SPP`], a reference of [`USERS_SAMPLES`] samples.
    Users,
}

/// Users' profile: long side of the image, pixels (256 to 1024), log-uniform below the
/// side that keeps [`USERS_SPP`]'s least within the drawn samples.
pub const USERS_LONG_SIDE: (u32, u32) = (256, 1024);
/// Users' profile: samples per pixel (64 to 1024).
pub const USERS_SPP: (u32, u32) = (64, 1024);
/// Users' profile: samples of one reference (width × height × spp), log-uniform: 2^21 to
/// 2^25. Measured here (2 cores, `glimpse render --stats`, shared machine), the generated
/// scenes trace 0.9 (rooms, 5–6 bounces) to 2.8 (open scenes under the sky) million
/// samples per second: references of about 1 to 20 s (up to ~40 s for a large room).
pub const USERS_SAMPLES: (u64, u64) = (1 << 21, 1 << 25);

/// The `n` documents of `seed` in the small profile.
#[must_use]
pub fn generate(n: usize, seed: u64) -> Vec<CorpusScene> {
    generate_in(n, seed, Profile::Small)
}

/// The `n` documents of `seed` in `profile`: the same seed and profile give the same
/// documents, byte for byte.
#[must_use]
pub fn generate_in(n: usize, seed: u64, profile: Profile) -> Vec<CorpusScene> {
    (0..n)
        .map(|i| {
            // One stream per scene: scene i does not change when n does.
            let mut rng =
                Pcg64::seed_from_u64(seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let name = format!("corpus-{seed}-{i:03}");
            let doc = scene(&mut rng, &name, i, profile);
            CorpusScene {
                name,
                document: serde_json::to_string_pretty(&doc).expect("a json! value serialises"),
            }
        })
        .collect()
}

/// Rounded to 3 decimals: documents a person can read.
fn r3(v: f32) -> f32 {
    (v * 1000.0).round() / 1000.0
}

fn log_uniform(rng: &mut Pcg64, lo: f32, hi: f32) -> f32 {
    (rng.random_range(lo.ln()..=hi.ln())).exp()
}

/// (width, height): the long side log-uniform in [`LONG_SIDE`], landscape or portrait, one
/// of four common aspect ratios.
fn draw_size(rng: &mut Pcg64) -> (u32, u32) {
    let long = log_uniform(rng, LONG_SIDE.0 as f32, LONG_SIDE.1 as f32).round() as u32;
    let aspect = [1.0, 4.0 / 3.0, 1.5, 16.0 / 9.0][rng.random_range(0..4)];
    let short = ((long as f32 / aspect).round() as u32).max(1);
    if rng.random_bool(0.75) {
        (long, short)
    } else {
        (short, long)
    }
}

/// Users' (width, height, samples per pixel): the reference's samples log-uniform in
/// [`USERS_SAMPLES`], the long side log-uniform from [`USERS_LONG_SIDE`]'s least up to the
/// side at which [`USERS_SPP`]'s least fills those samples (a large image gets few
/// samples, a small one many), then the samples per pixel that fill them.
fn draw_users(rng: &mut Pcg64) -> (u32, u32, u32) {
    let samples = log_uniform(rng, USERS_SAMPLES.0 as f32, USERS_SAMPLES.1 as f32);
    let aspect = [1.0, 4.0 / 3.0, 1.5, 16.0 / 9.0][rng.random_range(0..4)];
    let (lo, hi) = (USERS_LONG_SIDE.0 as f32, USERS_LONG_SIDE.1 as f32);
    // long × long / aspect pixels at the least samples per pixel fill `samples`.
    let fits = (samples * aspect / USERS_SPP.0 as f32).sqrt().clamp(lo, hi);
    let long = log_uniform(rng, lo, fits).round() as u32;
    let short = ((long as f32 / aspect).round() as u32).max(1);
    let pixels = long as f32 * short as f32;
    let spp = ((samples / pixels).round() as u32).clamp(USERS_SPP.0, USERS_SPP.1);
    if rng.random_bool(0.75) {
        (long, short, spp)
    } else {
        (short, long, spp)
    }
}

/// (width, height, samples per pixel) as `profile` draws them.
fn draw_image(rng: &mut Pcg64, profile: Profile) -> (u32, u32, u32) {
    match profile {
        Profile::Small => {
            let (w, h) = draw_size(rng);
            (w, h, draw_spp(rng, u64::from(w) * u64::from(h)))
        }
        Profile::Users => draw_users(rng),
    }
}

/// Samples per pixel log-uniform in [`SPP`], drawn again below the largest that keeps the
/// render within [`SAMPLE_BUDGET`] (a large image gets fewer samples).
fn draw_spp(rng: &mut Pcg64, pixels: u64) -> u32 {
    let cap = (SAMPLE_BUDGET / pixels.max(1)).clamp(u64::from(SPP.0), u64::from(SPP.1)) as f32;
    log_uniform(rng, SPP.0 as f32, cap).round() as u32
}

fn colour(rng: &mut Pcg64, lo: f32, hi: f32) -> [f32; 3] {
    [0; 3].map(|_| r3(rng.random_range(lo..=hi)))
}

/// A material of `kind` (one of [`MATERIALS`]).
fn material(rng: &mut Pcg64, kind: &str) -> Value {
    match kind {
        "diffuse" => json!({"type": "diffuse", "albedo": colour(rng, 0.05, 0.9)}),
        "checker" | "noise" => json!({"type": "diffuse", "texture": {
            "type": kind, "scale": r3(log_uniform(rng, 0.1, 1.0)),
            "a": colour(rng, 0.02, 0.4), "b": colour(rng, 0.5, 0.95)}}),
        "glossy" => json!({"type": "glossy", "albedo": colour(rng, 0.3, 0.95),
                           "roughness": r3(rng.random_range(0.05..=0.6))}),
        "mirror" => json!({"type": "mirror", "reflectance": colour(rng, 0.7, 0.98)}),
        _ => json!({"type": "dielectric", "ior": r3(rng.random_range(1.3..=1.8)),
                    "tint": colour(rng, 0.8, 1.0)}),
    }
}

/// Where objects stand and how the camera sees them.
struct Stage {
    room: bool,
    /// Half-width, height and depth of a room (x ∈ ±w, y ∈ [0, h], z ∈ [0, d]).
    w: f32,
    h: f32,
    d: f32,
}

/// An object of a random shape standing on the floor at (x, z), size about `s`.
fn object(rng: &mut Pcg64, x: f32, z: f32, s: f32, mat: &str) -> Value {
    match rng.random_range(0..4) {
        0 => json!({"type": "sphere", "center": [r3(x), r3(s), r3(z)], "radius": r3(s),
                    "material": mat}),
        1 => json!({"type": "box", "min": [r3(-s), 0.0, r3(-s)],
                    "max": [r3(s), r3(s * rng.random_range(1.0..=2.5)), r3(s)], "material": mat,
                    "transform": {"rotate_y": r3(rng.random_range(0.0..=90.0)),
                                  "translate": [r3(x), 0.0, r3(z)]}}),
        2 => json!({"type": "mesh", "positions": [[-1, 0, -1], [1, 0, -1], [1, 0, 1],
                    [-1, 0, 1], [0, 1.6, 0]],
                    "indices": [[0, 4, 1], [1, 4, 2], [2, 4, 3], [3, 4, 0], [0, 1, 2], [0, 2, 3]],
                    "material": mat, "transform": {"scale": r3(s),
                    "rotate_y": r3(rng.random_range(0.0..=90.0)),
                    "translate": [r3(x), 0.0, r3(z)]}}),
        _ => {
            json!({"type": "quad", "corner": [r3(x - s), 0.0, r3(z)], "edge_u": [r3(2.0 * s), 0.0, 0.0],
                    "edge_v": [0.0, r3(2.0 * s), r3(0.3 * s)], "material": mat})
        }
    }
}

/// The lights: `first` (one of [`LIGHTS`]) and possibly one more, each set so that a
/// diffuse surface of albedo ~0.6 it lights shows ~0.5 (radiance = albedo × E / π), the
/// total shared among them.
fn lights(
    rng: &mut Pcg64,
    st: &Stage,
    first: &str,
) -> (Vec<Value>, Vec<Value>, Vec<(String, Value)>) {
    let mut kinds = vec![first];
    if rng.random_bool(0.5) {
        let other = LIGHTS[rng.random_range(0..LIGHTS.len())];
        if other != first {
            kinds.push(other);
        }
    }
    let share = 1.0 / kinds.len() as f32;
    // Irradiance giving 0.5 on albedo 0.6: E = 0.5 π / 0.6.
    let e = 2.6 * share;
    let (mut lights, mut objects, mut materials) = (Vec::new(), Vec::new(), Vec::new());
    let top = if st.room { st.h } else { 4.0 };
    for (k, kind) in kinds.into_iter().enumerate() {
        let tint = colour(rng, 0.7, 1.0);
        let scaled = |v: f32| tint.map(|t| r3(t * v));
        match kind {
            "area" => {
                let name = format!("lamp{k}");
                let a = rng.random_range(0.5..=1.5f32);
                // E ≈ L A / d² below a small source: L = E d² / A.
                let radiance = scaled(e * top * top / (a * a));
                if st.room || rng.random_bool(0.5) {
                    // Emits downwards: edge_u × edge_v = (0, −a², 0).
                    objects.push(json!({"type": "quad", "corner": [r3(-a / 2.0), r3(top - 0.01),
                        r3(st.d * 0.5 - a / 2.0)], "edge_u": [r3(a), 0.0, 0.0],
                        "edge_v": [0.0, 0.0, r3(a)], "material": name}));
                } else {
                    objects.push(json!({"type": "sphere", "center": [r3(rng.random_range(-2.0..=2.0)),
                        r3(top), r3(rng.random_range(0.0..=2.0))], "radius": r3(a / 2.0), "material": name}));
                }
                materials.push((name, json!({"type": "emissive", "radiance": radiance})));
            }
            "point" => {
                let y = top * 0.8;
                lights.push(json!({"type": "point", "position": [r3(rng.random_range(-1.0..=1.0)),
                    r3(y), r3(st.d * rng.random_range(0.3..=0.7))], "intensity": scaled(e * y * y)}));
            }
            "directional" => lights.push(json!({"type": "directional",
                "direction": [r3(rng.random_range(-0.6..=0.6)), -1.0, r3(rng.random_range(0.1..=0.8))],
                "irradiance": scaled(e)})),
            _ => lights.push(json!({"type": "environment", "radiance": scaled(e / std::f32::consts::PI)})),
        }
    }
    (lights, objects, materials)
}

/// One document.
fn scene(rng: &mut Pcg64, name: &str, i: usize, profile: Profile) -> Value {
    let room = rng.random_bool(0.5);
    let st = Stage {
        room,
        w: rng.random_range(1.5..=3.0),
        h: rng.random_range(2.5..=4.0),
        d: rng.random_range(3.0..=6.0),
    };
    let (width, height, spp) = draw_image(rng, profile);
    let mut materials = serde_json::Map::new();
    let mut objects = Vec::new();
    // The stage: walls of a room or a ground plane (normals face the camera's side; only
    // emitters are one-sided).
    let wall_kind = ["diffuse", "diffuse", "checker", "noise"][rng.random_range(0..4)];
    materials.insert("floor".into(), material(rng, wall_kind));
    materials.insert("wall".into(), material(rng, "diffuse"));
    materials.insert("accent".into(), material(rng, "diffuse"));
    let (w, h, d) = (r3(st.w), r3(st.h), r3(st.d));
    if room {
        objects.push(json!({"type": "quad", "corner": [-w, 0.0, 0.0], "edge_u": [0.0, 0.0, d], "edge_v": [2.0 * w, 0.0, 0.0], "material": "floor"}));
        objects.push(json!({"type": "quad", "corner": [-w, h, 0.0], "edge_u": [2.0 * w, 0.0, 0.0], "edge_v": [0.0, 0.0, d], "material": "wall"}));
        objects.push(json!({"type": "quad", "corner": [-w, 0.0, d], "edge_u": [2.0 * w, 0.0, 0.0], "edge_v": [0.0, h, 0.0], "material": "wall"}));
        objects.push(json!({"type": "quad", "corner": [-w, 0.0, 0.0], "edge_u": [0.0, h, 0.0], "edge_v": [0.0, 0.0, d], "material": "accent"}));
        objects.push(json!({"type": "quad", "corner": [w, 0.0, 0.0], "edge_u": [0.0, 0.0, d], "edge_v": [0.0, h, 0.0], "material": "accent"}));
    } else {
        objects.push(json!({"type": "quad", "corner": [-40.0, 0.0, -40.0], "edge_u": [0.0, 0.0, 80.0], "edge_v": [80.0, 0.0, 0.0], "material": "floor"}));
    }
    let count = rng.random_range(1..=5);
    let spread = if room { st.w * 0.6 } else { 2.0 };
    for k in 0..count {
        let kind = if k == 0 {
            MATERIALS[i % MATERIALS.len()]
        } else {
            MATERIALS[rng.random_range(0..MATERIALS.len())]
        };
        let mat = format!("m{k}");
        materials.insert(mat.clone(), material(rng, kind));
        let x = rng.random_range(-spread..=spread);
        let z = if room {
            st.d * rng.random_range(0.45..=0.85)
        } else {
            rng.random_range(-1.0..=2.5)
        };
        let s = rng.random_range(0.25..=0.7);
        objects.push(object(rng, x, z, s, &mat));
    }
    let (lights, emitters, emissive) = lights(rng, &st, LIGHTS[i % LIGHTS.len()]);
    objects.extend(emitters);
    for (n, m) in emissive {
        materials.insert(n, m);
    }
    let camera = if room {
        json!({"position": [0.0, r3(st.h * 0.5), 0.05], "look_at": [0.0, r3(st.h * 0.2), d],
               "fov_y": r3(rng.random_range(55.0..=75.0))})
    } else {
        json!({"position": [r3(rng.random_range(-1.0..=1.0)), r3(rng.random_range(1.0..=2.5)), -5.0],
               "look_at": [0.0, 0.5, 0.5], "fov_y": r3(rng.random_range(30.0..=55.0))})
    };
    json!({
        "version": 1,
        "name": name,
        "image": {"width": width, "height": height},
        "camera": camera,
        "display": {
            "peak_luminance": r3(rng.random_range(80.0..=400.0)),
            "black_luminance": r3(rng.random_range(0.1..=1.0)),
            "exposure": r3(log_uniform(rng, 1.0 / 16.0, 8.0)),
            "pixels_per_degree": (rng.random_range(PPD_RANGE.0..=PPD_RANGE.1) * 10.0).round() / 10.0,
        },
        "materials": materials,
        "objects": objects,
        "lights": lights,
        "render": {"mode": "progressive", "samples_per_pixel": spp,
                   "max_bounces": rng.random_range(3..=6), "seed": rng.random_range(1..=1_000_000)},
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{parse_scene, Limits, SceneOrigin};

    #[test]
    fn every_generated_scene_validates_within_the_declared_ranges() {
        for seed in [0, 1, 42, u64::MAX] {
            for c in generate(60, seed) {
                let s = parse_scene(&c.document, &SceneOrigin::Request, &Limits::command_line())
                    .unwrap_or_else(|e| panic!("{}: {e}\n{}", c.name, c.document));
                assert!(s.warnings.is_empty(), "{}: {:?}", c.name, s.warnings);
                let long = s.width.max(s.height);
                assert!((LONG_SIDE.0..=LONG_SIDE.1).contains(&long), "{}", c.name);
                let spp = s.render.samples_per_pixel;
                assert!((SPP.0..=SPP.1).contains(&spp), "{}: {spp}", c.name);
                assert!(u64::from(spp) * u64::from(s.width) * u64::from(s.height) <= SAMPLE_BUDGET);
                let ppd = s.display.pixels_per_degree;
                assert!((PPD_RANGE.0..=PPD_RANGE.1).contains(&ppd), "{}", c.name);
                let e = s.display.exposure;
                assert!((1.0 / 16.0 - 1e-3..=8.0 + 1e-3).contains(&e), "{}", c.name);
            }
        }
    }

    #[test]
    fn a_seed_gives_the_same_documents_and_another_seed_others() {
        let a = generate(5, 7);
        let b = generate(8, 7);
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(
                (&x.name, &x.document),
                (&y.name, &y.document),
                "scene i does not depend on n"
            );
        }
        let c = generate(5, 8);
        assert!(a.iter().zip(&c).all(|(x, y)| x.document != y.document));
    }

    #[test]
    fn six_scenes_hold_every_material_and_light_and_both_stages() {
        let docs: Vec<Value> = generate(40, 3)
            .iter()
            .map(|c| serde_json::from_str(&c.document).unwrap())
            .collect();
        let text: String = docs.iter().take(6).map(Value::to_string).collect();
        for needle in [
            "\"diffuse\"",
            "\"checker\"",
            "\"noise\"",
            "\"glossy\"",
            "\"mirror\"",
            "\"dielectric\"",
            "\"emissive\"",
            "\"point\"",
            "\"directional\"",
            "\"environment\"",
        ] {
            assert!(
                text.contains(needle),
                "{needle} missing from the first six scenes"
            );
        }
        // An open scene's first object is its 80-unit ground plane.
        let rooms = docs
            .iter()
            .filter(|d| d["objects"][0]["corner"][0] != -40.0)
            .count();
        assert!(rooms > 5 && rooms < 35, "{rooms} rooms of 40");
        // Dark and blinding exposures both occur.
        let exposures: Vec<f64> = docs
            .iter()
            .map(|d| d["display"]["exposure"].as_f64().unwrap())
            .collect();
        assert!(exposures.iter().any(|&e| e < 0.25) && exposures.iter().any(|&e| e > 4.0));
    }

    /// FNV-1a, 64 bits, of the documents concatenated.
    fn digest(scenes: &[CorpusScene]) -> u64 {
        scenes
            .iter()
            .flat_map(|c| c.document.bytes())
            .fold(0xcbf2_9ce4_8422_2325, |h, b| {
                (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
            })
    }

    /// Seed 1's first three documents of the small profile, byte for byte as they were
    /// before the users' profile existed (written by `glimpse bench --corpus 3`).
    #[test]
    fn the_small_profile_s_seeds_give_the_documents_they_always_gave() {
        assert_eq!(digest(&generate(3, 1)), 0x2d5e_b5b5_335b_4747);
    }

    #[test]
    fn the_users_profile_draws_users_sizes_and_samples_deterministically() {
        let (mut longs, mut spps) = (Vec::new(), Vec::new());
        for seed in [0, 1, 42, u64::MAX] {
            let docs = generate_in(60, seed, Profile::Users);
            assert_eq!(
                digest(&docs),
                digest(&generate_in(60, seed, Profile::Users))
            );
            assert_ne!(digest(&docs), digest(&generate(60, seed)));
            for c in docs {
                let s = parse_scene(&c.document, &SceneOrigin::Request, &Limits::command_line())
                    .unwrap_or_else(|e| panic!("{}: {e}\n{}", c.name, c.document));
                assert!(s.warnings.is_empty(), "{}: {:?}", c.name, s.warnings);
                let long = s.width.max(s.height);
                assert!(
                    (USERS_LONG_SIDE.0..=USERS_LONG_SIDE.1).contains(&long),
                    "{}",
                    c.name
                );
                let spp = s.render.samples_per_pixel;
                assert!(
                    (USERS_SPP.0..=USERS_SPP.1).contains(&spp),
                    "{}: {spp}",
                    c.name
                );
                let samples = u64::from(spp) * u64::from(s.width) * u64::from(s.height);
                // The least samples per pixel at the least side may pass the least budget;
                // rounding the samples per pixel may pass the largest by a little.
                assert!(samples >= USERS_SAMPLES.0, "{}: {samples}", c.name);
                assert!(
                    samples <= USERS_SAMPLES.1 + USERS_SAMPLES.1 / 50,
                    "{}",
                    c.name
                );
                longs.push(long);
                spps.push(spp);
            }
        }
        // The ranges are used, not only allowed: large images and many samples both occur.
        assert!(longs.iter().any(|&l| l >= 700) && longs.iter().any(|&l| l < 320));
        assert!(spps.iter().any(|&s| s >= 400) && spps.iter().any(|&s| s < 100));
    }
}
