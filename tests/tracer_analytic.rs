//! Scenes with known answers for the path tracer: furnace, mirror, emitter
//! seen head-on, darkness, a point light's inverse-square law, glass energy balance,
//! determinism across subsets and thread counts, extremes, and the Cornell box against
//! Tungsten's reference render.

use glam::Vec3;
use glimpse::cancel::CancelToken;
use glimpse::raster::{LinearImage, PixelCoord};
use glimpse::scene::{Camera, Light, Material, Scene, Shape, Texture, BACKGROUND_ID};
use glimpse::tracer::fixtures::{cornell_box, quad, scene};
use glimpse::tracer::{object_id_map, render_reference, trace_pixels, PathTracer, PixelOracle};

fn diffuse(c: f32) -> Material {
    Material::Diffuse {
        albedo: Texture::Constant(Vec3::splat(c)),
    }
}

fn look(from: Vec3, to: Vec3, up: Vec3, fov: f32) -> Camera {
    Camera {
        position: from,
        look_at: to,
        up,
        fov_y_deg: fov,
    }
}

fn render(t: &PathTracer) -> LinearImage {
    render_reference(t, &CancelToken::new(), &|_, _| {}).expect("not cancelled")
}

/// Mean of the pixels whose primary hit is `object` and whose four neighbours' hits are
/// too (silhouette pixels mix the object with what is behind it).
fn mean_over(t: &PathTracer, img: &LinearImage, object: u32) -> (Vec3, usize) {
    let ids = object_id_map(t);
    let (w, h) = (img.width() as i64, img.height() as i64);
    let id = |x: i64, y: i64| {
        if x < 0 || y < 0 || x >= w || y >= h {
            None
        } else {
            Some(*ids.get(x as u32, y as u32))
        }
    };
    let mut s = Vec3::ZERO;
    let mut n = 0;
    for y in 0..h {
        for x in 0..w {
            let all = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .all(|(dx, dy)| id(x + dx, y + dy).is_none_or(|i| i == object));
            if all {
                s += *img.get(x as u32, y as u32);
                n += 1;
            }
        }
    }
    (s / n.max(1) as f32, n)
}

fn rel_err(a: Vec3, b: Vec3) -> f32 {
    ((a - b).abs() / b.abs().max(Vec3::splat(1e-30))).max_element()
}

/// A sphere of radius 1 at the origin, filling most of a 24×24 image, in environment `env`.
fn sphere_in_env(m: Material, env: Vec3, spp: u32, bounces: u32) -> Scene {
    scene(
        24,
        24,
        look(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 35.0),
        vec![m],
        vec![Shape::Sphere {
            center: Vec3::ZERO,
            radius: 1.0,
            material: 0,
        }],
        vec![Light::Environment { radiance: env }],
        (spp, bounces, 7),
    )
}

#[test]
fn furnace_diffuse_sphere_returns_albedo_times_environment() {
    // A convex object sees only the environment: L = ρ·L_env exactly (pbrt-v4's
    // integrators_test "furnace"). NEE + MIS must stay unbiased.
    let env = Vec3::new(0.5, 0.8, 1.0);
    let t = PathTracer::new(&sphere_in_env(diffuse(0.6), env, 64, 8));
    let img = render(&t);
    let (m, n) = mean_over(&t, &img, 0);
    assert!(n > 200, "sphere covers {n} pixels");
    assert!(
        rel_err(m, 0.6 * env) < 0.01,
        "furnace mean {m}, expected {}",
        0.6 * env
    );
    let (bg, _) = mean_over(&t, &img, BACKGROUND_ID);
    assert!(rel_err(bg, env) < 1e-5, "background {bg}");
    assert!(!img.has_non_finite());
}

#[test]
fn furnace_glossy_sphere_never_exceeds_albedo() {
    let env = Vec3::ONE;
    // Lower bounds: GGX + Smith loses energy to multiple scattering it does not model,
    // about 60% at alpha = 1 (E(mu=1) = 0.31 by quadrature) averaged over the sphere's view angles.
    for (rough, min_kept) in [(0.1f32, 0.95), (0.5, 0.8), (1.0, 0.33)] {
        let m = Material::Glossy {
            albedo: Vec3::splat(0.8),
            roughness: rough,
        };
        let t = PathTracer::new(&sphere_in_env(m, env, 32, 8));
        let (mean, _) = mean_over(&t, &render(&t), 0);
        // Energy ≤ albedo (material.rs); rough GGX with Smith G keeps most of it.
        assert!(
            mean.max_element() <= 0.8 * 1.01,
            "roughness {rough}: {mean}"
        );
        assert!(
            mean.min_element() >= 0.8 * min_kept,
            "roughness {rough}: lost too much: {mean}"
        );
    }
}

#[test]
fn mirror_sphere_reflects_reflectance_times_environment() {
    let env = Vec3::new(0.3, 0.6, 0.9);
    let r = Vec3::new(0.95, 0.5, 0.25);
    let t = PathTracer::new(&sphere_in_env(
        Material::Mirror { reflectance: r },
        env,
        4,
        8,
    ));
    let img = render(&t);
    let ids = object_id_map(&t);
    let mut n = 0;
    for (p, id) in img.pixels().iter().zip(ids.pixels()) {
        // Pixels straddling the silhouette mix sphere and background; skip them by
        // requiring a value that is a blend of at most the two.
        if *id == 0 && rel_err(*p, r * env) > 1e-5 {
            let in_between = (p.x - r.x * env.x) * (p.x - env.x) <= 0.0;
            assert!(in_between, "mirror pixel {p}");
        } else if *id == 0 {
            n += 1;
        }
    }
    assert!(n > 200, "only {n} interior mirror pixels are exact");
}

#[test]
fn glass_sphere_neither_gains_nor_loses_energy() {
    let env = Vec3::splat(2.0);
    let t = PathTracer::new(&sphere_in_env(
        Material::Dielectric {
            ior: 1.5,
            tint: Vec3::ONE,
        },
        env,
        32,
        64,
    ));
    let (m, _) = mean_over(&t, &render(&t), 0);
    assert!(rel_err(m, env) < 0.02, "glass in a furnace: {m}");
}

#[test]
fn emissive_quad_seen_head_on_shows_its_radiance() {
    let le = Vec3::new(17.0, 12.0, 4.0);
    for two_sided in [false, true] {
        // The quad faces +z (u × v = x × y), toward the camera.
        let s = scene(
            8,
            8,
            look(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, Vec3::Y, 20.0),
            vec![Material::Emissive {
                radiance: le,
                two_sided,
            }],
            vec![quad(
                Vec3::new(-5.0, -5.0, 0.0),
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(0.0, 10.0, 0.0),
                0,
            )],
            vec![],
            (4, 5, 1),
        );
        let t = PathTracer::new(&s);
        for p in render(&t).pixels() {
            assert_eq!(*p, le);
        }
        // Seen from behind: black unless two-sided.
        let mut back = s.clone();
        back.camera.position = Vec3::new(0.0, 0.0, -5.0);
        let tb = PathTracer::new(&back);
        let v = tb.radiance(PixelCoord::new(4, 4));
        assert_eq!(v, if two_sided { le } else { Vec3::ZERO });
    }
}

#[test]
fn scene_without_light_is_exactly_black() {
    let s = scene(
        6,
        5,
        look(Vec3::new(0.0, 1.0, 5.0), Vec3::ZERO, Vec3::Y, 50.0),
        vec![
            diffuse(0.9),
            Material::Glossy {
                albedo: Vec3::ONE,
                roughness: 0.3,
            },
            Material::Mirror {
                reflectance: Vec3::ONE,
            },
            Material::Dielectric {
                ior: 1.5,
                tint: Vec3::ONE,
            },
            Material::Emissive {
                radiance: Vec3::ZERO,
                two_sided: true,
            },
        ],
        vec![
            quad(
                Vec3::new(-5.0, 0.0, 5.0),
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(0.0, 0.0, -10.0),
                0,
            ),
            Shape::Sphere {
                center: Vec3::new(-1.0, 0.5, 0.0),
                radius: 0.5,
                material: 1,
            },
            Shape::Sphere {
                center: Vec3::new(0.0, 0.5, 0.0),
                radius: 0.5,
                material: 2,
            },
            Shape::Sphere {
                center: Vec3::new(1.0, 0.5, 0.0),
                radius: 0.5,
                material: 3,
            },
            Shape::Sphere {
                center: Vec3::new(0.0, 1.5, 0.0),
                radius: 0.3,
                material: 4,
            },
        ],
        vec![],
        (8, 8, 3),
    );
    let t = PathTracer::new(&s);
    assert!(!t.features().has_lights);
    assert!(render(&t).pixels().iter().all(|p| *p == Vec3::ZERO));
}

/// A point light of intensity I at height h over a diffuse plane of albedo ρ: the plane's
/// radiance at q is ρ·I·cos θ / (π·d²) (no other light: a single plane sees nothing else).
#[test]
fn point_light_follows_inverse_square_and_cosine() {
    let (rho, i, lp) = (0.5f32, 10.0f32, Vec3::new(0.7, 2.0, -0.4));
    let cam = look(Vec3::new(0.0, 10.0, 0.0), Vec3::ZERO, Vec3::Z, 4.0);
    let s = scene(
        9,
        9,
        cam,
        vec![diffuse(rho)],
        vec![quad(
            Vec3::new(-10.0, 0.0, 10.0),
            Vec3::new(20.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -20.0),
            0,
        )],
        vec![Light::Point {
            position: lp,
            intensity: Vec3::splat(i),
        }],
        (64, 4, 5),
    );
    let t = PathTracer::new(&s);
    let cam_p = glimpse::tracer::camera::Pinhole::new(&s.camera, 9, 9);
    for (x, y) in [(4, 4), (0, 0), (8, 3), (2, 7)] {
        let d = cam_p.direction(x, y, glam::Vec2::splat(0.5));
        let q = s.camera.position + d * (s.camera.position.y / -d.y);
        let to_l = lp - q;
        let dist2 = to_l.length_squared();
        let cos = to_l.y / dist2.sqrt();
        let expected = rho * i * cos / (std::f32::consts::PI * dist2);
        let got = t.radiance(PixelCoord::new(x, y));
        assert!(
            rel_err(got, Vec3::splat(expected)) < 0.005,
            "pixel ({x},{y}): {got} vs {expected}"
        );
    }
}

#[test]
fn directional_light_gives_rho_e_cos_over_pi() {
    let (rho, e) = (0.8f32, 3.0f32);
    let dir = Vec3::new(0.0, -1.0, 1.0).normalize(); // 45° incidence
    let s = scene(
        4,
        4,
        look(Vec3::new(0.0, 10.0, 0.0), Vec3::ZERO, Vec3::Z, 10.0),
        vec![diffuse(rho)],
        vec![quad(
            Vec3::new(-10.0, 0.0, 10.0),
            Vec3::new(20.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, -20.0),
            0,
        )],
        vec![Light::Directional {
            direction: dir,
            irradiance: Vec3::splat(e),
        }],
        (4, 3, 5),
    );
    let t = PathTracer::new(&s);
    let expected = rho * e * std::f32::consts::FRAC_1_SQRT_2 / std::f32::consts::PI;
    for p in render(&t).pixels() {
        assert!(
            rel_err(*p, Vec3::splat(expected)) < 1e-5,
            "{p} vs {expected}"
        );
    }
}

#[test]
fn subset_equals_full_render_bit_for_bit_on_any_thread_count() {
    let s = cornell_box(16, 12, 4, 6, 99);
    let t = PathTracer::new(&s);
    let full = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| render(&t));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| render(&t));
    assert_eq!(full, one);
    let subset: Vec<PixelCoord> = vec![
        PixelCoord::new(15, 11),
        PixelCoord::new(0, 0),
        PixelCoord::new(7, 5),
    ];
    let vals = trace_pixels(&t, &subset, &CancelToken::new()).unwrap();
    for (p, v) in subset.iter().zip(&vals) {
        assert_eq!(
            v.to_array().map(f32::to_bits),
            full.get(p.x, p.y).to_array().map(f32::to_bits)
        );
    }
    // A different seed changes the estimate (the seed reaches the sampler).
    assert_ne!(
        t.radiance_with(PixelCoord::new(7, 5), 4, 1),
        t.radiance_with(PixelCoord::new(7, 5), 4, 2)
    );
}

#[test]
fn object_ids_name_the_primary_hit() {
    let t = PathTracer::new(&cornell_box(32, 32, 1, 1, 1));
    let ids = object_id_map(&t);
    // Centre bottom: floor (0); top centre: the light (7) or the ceiling (1); the image
    // centre looks at the back wall (2) or a box.
    assert_eq!(*ids.get(16, 31), 0);
    assert!([1, 7].contains(ids.get(16, 0)), "{}", ids.get(16, 0));
    assert_eq!(*ids.get(16, 2), 7, "light at the top centre");
    assert_eq!(*ids.get(1, 16), 4, "left wall");
    assert_eq!(*ids.get(30, 16), 3, "right wall");
    // Nothing behind the camera: a camera looking away from the box sees background.
    let mut s = cornell_box(4, 4, 1, 1, 1);
    s.camera.look_at = Vec3::new(0.0, 1.0, 20.0);
    assert_eq!(
        *object_id_map(&PathTracer::new(&s)).get(2, 2),
        BACKGROUND_ID
    );
}

#[test]
fn extreme_image_sizes() {
    for (w, h) in [(1, 1), (3, 2), (400, 1)] {
        let mut s = cornell_box(w, h, 2, 4, 1);
        s.width = w;
        s.height = h;
        let t = PathTracer::new(&s);
        let img = render(&t);
        assert_eq!((img.width(), img.height()), (w, h));
        assert!(!img.has_non_finite());
        assert!(img.mean()[0] > 0.0);
    }
}

#[test]
fn extreme_radiances_scale_linearly_and_stay_finite() {
    let base = cornell_box(8, 8, 8, 6, 4);
    let t1 = PathTracer::new(&base);
    let ref_img = render(&t1);
    for k in [1e-30f32, 1e7] {
        let mut s = base.clone();
        s.materials[3] = Material::Emissive {
            radiance: Vec3::new(17.0, 12.0, 4.0) * k,
            two_sided: false,
        };
        let t = PathTracer::new(&s);
        let img = render(&t);
        assert!(!img.has_non_finite());
        assert_eq!(t.dropped_samples(), 0);
        // Same paths, radiance scaled: linear up to float rounding (and denormals at 1e-30
        // on the dimmest components).
        let (a, b) = (img.mean(), ref_img.mean());
        for c in 0..3 {
            let r = a[c] / (b[c] * f64::from(k));
            assert!((r - 1.0).abs() < 1e-3, "scale {k}: channel {c} ratio {r}");
        }
    }
}

#[test]
fn far_from_origin_and_scaled_scene_matches_the_unit_scene() {
    // Self-intersection offsets scale with the hit position (sampling.rs): the Cornell box
    // scaled ×1000 and moved 1e5 units away renders like the original.
    let base = cornell_box(16, 16, 32, 8, 2);
    let off = Vec3::new(1e5, -1e5, 1e5);
    let mut far = base.clone();
    for sh in &mut far.shapes {
        if let Shape::Triangles { triangles, .. } = sh {
            for tri in triangles {
                for p in &mut tri.p {
                    *p = *p * 1000.0 + off;
                }
            }
        }
    }
    far.camera.position = far.camera.position * 1000.0 + off;
    far.camera.look_at = far.camera.look_at * 1000.0 + off;
    let a = render(&PathTracer::new(&base)).mean();
    let img = render(&PathTracer::new(&far));
    assert!(!img.has_non_finite());
    let b = img.mean();
    for c in 0..3 {
        assert!(
            (a[c] - b[c]).abs() / a[c] < 0.05,
            "channel {c}: unit {} vs far {}",
            a[c],
            b[c]
        );
    }
}

#[test]
fn forty_coplanar_overlapping_quads_do_not_shadow_each_other() {
    let (rho, i, lp) = (0.5f32, 10.0f32, Vec3::new(0.0, 2.0, 0.0));
    let shapes: Vec<Shape> = (0..40)
        .map(|k| {
            let o = k as f32 * 0.01;
            quad(
                Vec3::new(-3.0 + o, 0.0, 3.0 - o),
                Vec3::new(6.0, 0.0, 0.0),
                Vec3::new(0.0, 0.0, -6.0),
                0,
            )
        })
        .collect();
    let s = scene(
        8,
        8,
        look(Vec3::new(0.0, 10.0, 0.0), Vec3::ZERO, Vec3::Z, 2.0),
        vec![diffuse(rho)],
        shapes,
        vec![Light::Point {
            position: lp,
            intensity: Vec3::splat(i),
        }],
        (4, 4, 5),
    );
    let t = PathTracer::new(&s);
    let img = render(&t);
    let cam = glimpse::tracer::camera::Pinhole::new(&s.camera, 8, 8);
    for y in 0..8 {
        for x in 0..8 {
            let d = cam.direction(x, y, glam::Vec2::splat(0.5));
            let q = s.camera.position + d * (s.camera.position.y / -d.y);
            let to_l = lp - q;
            let expected =
                rho * i * (to_l.y / to_l.length()) / (std::f32::consts::PI * to_l.length_squared());
            let p = *img.get(x, y);
            assert!(
                rel_err(p, Vec3::splat(expected)) < 0.002,
                "({x},{y}): {p} vs {expected}"
            );
        }
    }
}

#[test]
fn textured_and_mixed_scene_has_no_nan() {
    let s = scene(
        12,
        10,
        look(
            Vec3::new(0.0, 2.0, 6.0),
            Vec3::new(0.0, 0.5, 0.0),
            Vec3::Y,
            45.0,
        ),
        vec![
            Material::Diffuse {
                albedo: Texture::Checker {
                    scale: 0.5,
                    a: Vec3::splat(0.8),
                    b: Vec3::splat(0.1),
                },
            },
            Material::Diffuse {
                albedo: Texture::Noise {
                    scale: 0.3,
                    a: Vec3::splat(0.2),
                    b: Vec3::splat(0.9),
                },
            },
            Material::Glossy {
                albedo: Vec3::splat(0.9),
                roughness: 0.0,
            },
            Material::Dielectric {
                ior: 1.33,
                tint: Vec3::new(0.9, 1.0, 0.9),
            },
            Material::Emissive {
                radiance: Vec3::splat(5.0),
                two_sided: true,
            },
        ],
        vec![
            quad(
                Vec3::new(-5.0, 0.0, 5.0),
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(0.0, 0.0, -10.0),
                0,
            ),
            Shape::Sphere {
                center: Vec3::new(-1.2, 0.5, 0.0),
                radius: 0.5,
                material: 1,
            },
            Shape::Sphere {
                center: Vec3::new(0.0, 0.5, 0.0),
                radius: 0.5,
                material: 2,
            },
            Shape::Sphere {
                center: Vec3::new(1.2, 0.5, 0.0),
                radius: 0.5,
                material: 3,
            },
            Shape::Sphere {
                center: Vec3::new(0.0, 2.5, 0.0),
                radius: 0.3,
                material: 4,
            },
        ],
        vec![
            Light::Environment {
                radiance: Vec3::splat(0.1),
            },
            Light::Point {
                position: Vec3::new(2.0, 3.0, 2.0),
                intensity: Vec3::splat(5.0),
            },
            Light::Directional {
                direction: Vec3::new(-1.0, -1.0, 0.0),
                irradiance: Vec3::splat(0.5),
            },
        ],
        (16, 16, 9),
    );
    let t = PathTracer::new(&s);
    let f = t.features();
    assert!(
        f.has_texture && f.has_dielectric && f.has_glossy && f.has_environment && f.has_emitters
    );
    let img = render(&t);
    assert!(!img.has_non_finite());
    assert!(img.pixels().iter().all(|p| p.min_element() >= 0.0));
    assert!(img.mean()[0] > 0.05);
}

/// Mean linear RGB of Bitterli's Cornell box against Tungsten's converged reference
/// (scenes-public/cornell-box-bitterli/TungstenRender.exr, mean (0.1963, 0.1275, 0.0361)).
#[test]
fn cornell_box_mean_matches_tungsten_within_3_percent() {
    let reference = reference_mean();
    let t = PathTracer::new(&cornell_box(96, 96, 64, 64, 2024));
    let img = render(&t);
    assert!(!img.has_non_finite());
    assert_mean_within(img.mean(), reference, 0.03);
}

/// Every channel of `m` within the relative tolerance `tol` of Tungsten's `reference`.
fn assert_mean_within(m: [f64; 3], reference: [f64; 3], tol: f64) {
    for c in 0..3 {
        let rel = (m[c] - reference[c]).abs() / reference[c];
        assert!(
            rel < tol,
            "channel {c}: ours {:.4} vs Tungsten {:.4} ({:.2}%, limit {:.0}%)",
            m[c],
            reference[c],
            rel * 100.0,
            tol * 100.0
        );
    }
}

/// The reference image's mean, from the repository's copy of Tungsten's render
/// (tests/public-scenes: box-averaged to 256², the same mean as the 1024² original).
fn reference_mean() -> [f64; 3] {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/public-scenes/cornell-box-bitterli/TungstenRender-256x256.exr");
    let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    glimpse::raster::decode_image(&bytes)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .mean()
}

/// The same comparison through the JSON contract, at 256×256: scenes/cornell-box.json
/// parsed by `scene::parse_scene`, 64 bounces like Tungsten, 16 spp (the mean of 1 M paths
/// is far steadier than the tolerance). The target is 3 %; measured 0.05–0.08 %
/// (64 spp, `scripts/mitsuba_bitterli.py`, where Mitsuba 3 lands within 0.03 %), so the
/// test holds 1 %, which a real energy bias would break.
#[test]
fn cornell_box_json_mean_matches_tungsten_within_1_percent_at_256() {
    use glimpse::scene::{parse_scene, Limits, SceneOrigin};
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let json = std::fs::read_to_string(root.join("scenes/cornell-box.json"))
        .expect("scenes/cornell-box.json");
    let origin = SceneOrigin::File {
        dir: root.join("scenes"),
    };
    let mut s =
        parse_scene(&json, &origin, &Limits::command_line()).expect("cornell-box.json parses");
    s.width = 256;
    s.height = 256;
    s.render.samples_per_pixel = 16;
    s.render.max_bounces = 64;
    let reference = reference_mean();
    assert_mean_within(render(&PathTracer::new(&s)).mean(), reference, 0.01);
}

/// The scene validator accepts world coordinates up to ±1e9 (`scene::MAX_COORDINATE`):
/// at that edge the tracer must give the same picture as at unit scale (its ray offsets
/// are relative to the hit's magnitude, and nothing it squares overflows). Radiance does
/// not depend on the unit of length, so the same scene scaled by `s` renders the same.
#[test]
fn scenes_at_the_edge_of_the_coordinate_range_render_as_at_unit_scale() {
    let env = Vec3::new(0.5, 0.8, 1.0);
    // Furnace: a diffuse sphere of radius 2.5e8 seen from 1e9.
    let s = glimpse::scene::MAX_COORDINATE / 4.0;
    let sc = scene(
        24,
        24,
        look(Vec3::new(0.0, 0.0, 4.0 * s), Vec3::ZERO, Vec3::Y, 35.0),
        vec![diffuse(0.6)],
        vec![Shape::Sphere {
            center: Vec3::ZERO,
            radius: s,
            material: 0,
        }],
        vec![Light::Environment { radiance: env }],
        (64, 8, 7),
    );
    let t = PathTracer::new(&sc);
    let img = render(&t);
    let (m, n) = mean_over(&t, &img, 0);
    assert!(n > 200, "sphere covers {n} pixels");
    assert!(
        rel_err(m, 0.6 * env) < 0.01,
        "furnace mean {m} at scale {s:e}"
    );
    assert!(!img.has_non_finite());

    // The Cornell box (triangles, an area light sampled by NEE) scaled so that its far
    // corner sits near 1e9: the same picture as the unit box (same paths, scaled; measured
    // 2e-7 apart in the mean, so 1e-3 catches any loss of precision that moves a path).
    let unit = cornell_box(16, 16, 16, 5, 3);
    let extent = unit
        .shapes
        .iter()
        .flat_map(|sh| match sh {
            Shape::Triangles { triangles, .. } => triangles.iter().flat_map(|t| t.p).collect(),
            Shape::Sphere { .. } => Vec::new(),
        })
        .chain([unit.camera.position])
        .fold(0f32, |m, p| m.max(p.abs().max_element()));
    let k = 0.9 * glimpse::scene::MAX_COORDINATE / extent;
    let mut big = unit.clone();
    big.camera.position *= k;
    big.camera.look_at *= k;
    for sh in &mut big.shapes {
        if let Shape::Triangles { triangles, .. } = sh {
            for t in triangles {
                for p in &mut t.p {
                    *p *= k;
                }
            }
        }
    }
    let a = render(&PathTracer::new(&unit));
    let b = render(&PathTracer::new(&big));
    assert!(!b.has_non_finite());
    let mean = |img: &LinearImage| img.pixels().iter().fold(Vec3::ZERO, |s, &p| s + p);
    assert!(
        rel_err(mean(&b), mean(&a)) < 1e-3,
        "scaled by {k:e}: {} vs {}",
        mean(&b),
        mean(&a)
    );
}
