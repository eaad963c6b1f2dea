//! Spot lights end to end: a pbrt-v4 `spot` light (coneangle 30°, conedelta 10°) shining
//! straight down on a diffuse floor from the camera's own position, rendered by the real
//! binary with direct light only (`maxdepth` 1). The camera ray at angle θ from the axis
//! meets the floor where the light arrives at the same θ, so a pixel shows
//! L(θ) = ρ/π · I · smoothstep(θ) · cos³θ / h² (distance h / cos θ, incidence cos θ):
//! full inside 20°, pbrt-v4's smoothstep in cos θ between 20° and 30°, black beyond. Each
//! pixel's expectation is averaged over its area (the render's box filter).

mod common;

const SIZE: u32 = 64;
const H: f64 = 2.0;
const I: f64 = 4.0;
const RHO: f64 = 0.5;

fn expected(theta_cos: f64) -> f64 {
    let (ci, co) = (20f64.to_radians().cos(), 30f64.to_radians().cos());
    let f = if theta_cos >= ci {
        1.0
    } else if theta_cos <= co {
        0.0
    } else {
        let t = (theta_cos - co) / (ci - co);
        t * t * (3.0 - 2.0 * t)
    };
    RHO / std::f64::consts::PI * I * f * theta_cos.powi(3) / (H * H)
}

/// The mean of [`expected`] over pixel (x, y) of a 90° square pinhole image.
fn pixel_expected(x: u32, y: u32) -> f64 {
    let n = 16;
    let mut sum = 0.0;
    for j in 0..n {
        for i in 0..n {
            let sx = (f64::from(x) + (f64::from(i) + 0.5) / f64::from(n)) / f64::from(SIZE);
            let sy = (f64::from(y) + (f64::from(j) + 0.5) / f64::from(n)) / f64::from(SIZE);
            let (u, v) = (2.0 * sx - 1.0, 2.0 * sy - 1.0);
            sum += expected(1.0 / (1.0 + u * u + v * v).sqrt());
        }
    }
    sum / f64::from(n * n)
}

#[test]
fn pbrt_spot_light_falls_off_as_pbrt_defines_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("spot.pbrt");
    std::fs::write(
        &scene,
        format!(
            r#"LookAt 0 0 {H}  0 0 0  0 1 0
Camera "perspective" "float fov" [90]
Film "rgb" "integer xresolution" [{SIZE}] "integer yresolution" [{SIZE}]
Integrator "path" "integer maxdepth" [1]
WorldBegin
LightSource "spot" "point3 from" [0 0 {H}] "point3 to" [0 0 0] "rgb I" [{I} {I} {I}]
  "float coneangle" [30] "float conedelta" [10]
Material "diffuse" "rgb reflectance" [{RHO} {RHO} {RHO}]
Shape "trianglemesh" "point3 P" [-10 -10 0  10 -10 0  10 10 0  -10 10 0]
  "integer indices" [0 1 2  0 2 3]
"#
        ),
    )
    .unwrap();
    let (img, w, h) = common::render_exr(&scene, &["--spp", "64"]);
    assert_eq!((w, h), (SIZE, SIZE));
    let (mut band, mut dark) = (0, 0);
    let mut worst: f64 = 0.0;
    // Inside the inner cone the picture is smooth: the mean there is exact.
    let (mut flat_got, mut flat_want) = (0.0, 0.0);
    for y in 0..SIZE {
        for x in 0..SIZE {
            let got = f64::from(img[(y * SIZE + x) as usize][0]);
            let want = pixel_expected(x, y);
            let peak = expected(1.0);
            worst = worst.max((got - want).abs() / peak);
            if want > 0.99 * peak * 0.85 && (x as i32 - 32).abs() < 10 && (y as i32 - 32).abs() < 10
            {
                flat_got += got;
                flat_want += want;
            }
            if want > 0.05 * peak && want < 0.95 * peak {
                band += 1;
            }
            if want == 0.0 {
                // A jittered sample may still graze the cone's edge: nothing to see.
                assert!(
                    got < 1e-4 * peak,
                    "pixel ({x}, {y}) lies outside the cone: {got}"
                );
                dark += 1;
            }
        }
    }
    let flat = flat_got / flat_want - 1.0;
    eprintln!(
        "inner cone: mean {:+.3} % off; worst pixel off by {:.3} % of the peak; {band} pixels in the falloff band, {dark} outside the cone",
        flat * 100.0,
        worst * 100.0
    );
    assert!(flat.abs() < 0.003, "inner cone {:.3} % off", flat * 100.0);
    // In the band one pixel's value varies by up to ~10 % of the peak across it, which
    // 64 jittered samples average with a few per cent of noise.
    assert!(
        worst < 0.04,
        "worst pixel off by {:.2} % of the peak",
        worst * 100.0
    );
    assert!(band > 300 && dark > 1000, "{band} {dark}");
}
