//! Scenes built directly in Rust for tests and benchmarks (no JSON involved), including
//! Bitterli's Cornell box with the geometry of `scenes-public/cornell-box-bitterli/
//! scene-v4.pbrt` (CC0), whose Tungsten reference render the tests compare against.

use crate::scene::{
    Camera, Display, Light, Material, ProgressiveSettings, RenderMode, RenderSettings, Scene,
    Shape, Triangle,
};
use glam::{Vec2, Vec3};

/// A scene with the given content and default display/progressive settings.
#[must_use]
pub fn scene(
    width: u32,
    height: u32,
    camera: Camera,
    materials: Vec<Material>,
    shapes: Vec<Shape>,
    lights: Vec<Light>,
    render: (u32, u32, u64),
) -> Scene {
    let material_names = (0..materials.len()).map(|i| format!("m{i}")).collect();
    Scene {
        name: "fixture".into(),
        width,
        height,
        camera,
        display: Display::default(),
        materials,
        material_names,
        shapes,
        lights,
        images: Vec::new(),
        render: RenderSettings {
            mode: RenderMode::Reference,
            samples_per_pixel: render.0,
            max_bounces: render.1,
            seed: render.2,
            sampler: crate::scene::SamplerKind::default(),
            denoise: None,
        },
        progressive: ProgressiveSettings::default(),
        warnings: Vec::new(),
    }
}

/// A parallelogram as two triangles; normal = `u × v` (scene-format.md `quad`), texture
/// coordinates (s, t) of `corner + s·u + t·v`.
#[must_use]
pub fn quad(corner: Vec3, u: Vec3, v: Vec3, material: u32) -> Shape {
    let (a, b, c, d) = (corner, corner + u, corner + u + v, corner + v);
    Shape::Triangles {
        triangles: vec![
            Triangle {
                p: [a, b, c],
                n: None,
                uv: Some([Vec2::ZERO, Vec2::X, Vec2::ONE]),
            },
            Triangle {
                p: [a, c, d],
                n: None,
                uv: Some([Vec2::ZERO, Vec2::ONE, Vec2::Y]),
            },
        ],
        material,
    }
}

fn mesh(p: &[[f32; 3]], idx: &[[usize; 3]], material: u32) -> Shape {
    let v = |i: usize| Vec3::from_array(p[i]);
    Shape::Triangles {
        triangles: idx
            .iter()
            .map(|t| Triangle {
                p: [v(t[0]), v(t[1]), v(t[2])],
                n: None,
                uv: None,
            })
            .collect(),
        material,
    }
}

/// Bitterli's Cornell box (camera at (0, 1, 6.8), fov 19.5°, light L = (17, 12, 4)).
/// Object order: floor, ceiling, back wall, right wall, left wall, short box, tall box, light.
#[must_use]
pub fn cornell_box(width: u32, height: u32, spp: u32, max_bounces: u32, seed: u64) -> Scene {
    let white = Vec3::new(0.725, 0.71, 0.68);
    let materials = vec![
        Material::Diffuse {
            albedo: crate::scene::Texture::Constant(white),
        },
        Material::Diffuse {
            albedo: crate::scene::Texture::Constant(Vec3::new(0.63, 0.065, 0.05)),
        },
        Material::Diffuse {
            albedo: crate::scene::Texture::Constant(Vec3::new(0.14, 0.45, 0.091)),
        },
        Material::Emissive {
            radiance: Vec3::new(17.0, 12.0, 4.0),
            two_sided: false,
        },
    ];
    let shapes = vec![
        mesh(&FLOOR_P, &FLOOR_I, 0),
        mesh(&CEILING_P, &CEILING_I, 0),
        mesh(&BACK_WALL_P, &BACK_WALL_I, 0),
        mesh(&RIGHT_WALL_P, &RIGHT_WALL_I, 2),
        mesh(&LEFT_WALL_P, &LEFT_WALL_I, 1),
        mesh(&SHORT_BOX_P, &BOX_I, 0),
        mesh(&TALL_BOX_P, &BOX_I, 0),
        mesh(&LIGHT_P, &LIGHT_I, 3),
    ];
    let camera = Camera {
        position: Vec3::new(0.0, 1.0, 6.8),
        look_at: Vec3::new(0.0, 1.0, 0.0),
        up: Vec3::Y,
        fov_y_deg: 19.5,
    };
    scene(
        width,
        height,
        camera,
        materials,
        shapes,
        Vec::new(),
        (spp, max_bounces, seed),
    )
}

const FLOOR_P: [[f32; 3]; 4] = [
    [-1.0, 0.0, -1.0],
    [-1.0, 0.0, 1.0],
    [1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
];
const FLOOR_I: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
const CEILING_P: [[f32; 3]; 4] = [
    [1.0, 2.0, 1.0],
    [-1.0, 2.0, 1.0],
    [-1.0, 2.0, -1.0],
    [1.0, 2.0, -1.0],
];
const CEILING_I: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
const BACK_WALL_P: [[f32; 3]; 4] = [
    [-1.0, 0.0, -1.0],
    [-1.0, 2.0, -1.0],
    [1.0, 2.0, -1.0],
    [1.0, 0.0, -1.0],
];
const BACK_WALL_I: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
const RIGHT_WALL_P: [[f32; 3]; 4] = [
    [1.0, 0.0, -1.0],
    [1.0, 2.0, -1.0],
    [1.0, 2.0, 1.0],
    [1.0, 0.0, 1.0],
];
const RIGHT_WALL_I: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
const LEFT_WALL_P: [[f32; 3]; 4] = [
    [-1.0, 0.0, 1.0],
    [-1.0, 2.0, 1.0],
    [-1.0, 2.0, -1.0],
    [-1.0, 0.0, -1.0],
];
const LEFT_WALL_I: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
const SHORT_BOX_P: [[f32; 3]; 24] = [
    [-0.046075, 0.6, 0.573007],
    [-0.046075, 0.0, 0.573007],
    [0.124253, 0.0, 0.003105],
    [0.124253, 0.6, 0.003105],
    [0.533009, 0.0, 0.746079],
    [0.533009, 0.6, 0.746079],
    [0.703337, 0.6, 0.176177],
    [0.703337, 0.0, 0.176177],
    [0.533009, 0.6, 0.746079],
    [-0.046075, 0.6, 0.573007],
    [0.124253, 0.6, 0.003105],
    [0.703337, 0.6, 0.176177],
    [0.703337, 0.0, 0.176177],
    [0.124253, 0.0, 0.003105],
    [-0.046075, 0.0, 0.573007],
    [0.533009, 0.0, 0.746079],
    [0.533009, 0.0, 0.746079],
    [-0.046075, 0.0, 0.573007],
    [-0.046075, 0.6, 0.573007],
    [0.533009, 0.6, 0.746079],
    [0.703337, 0.6, 0.176177],
    [0.124253, 0.6, 0.003105],
    [0.124253, 0.0, 0.003105],
    [0.703337, 0.0, 0.176177],
];
/// Triangle indices of either box (pbrt's vertex order is the same for both).
const BOX_I: [[usize; 3]; 12] = [
    [0, 2, 1],
    [0, 3, 2],
    [4, 6, 5],
    [4, 7, 6],
    [8, 10, 9],
    [8, 11, 10],
    [12, 14, 13],
    [12, 15, 14],
    [16, 18, 17],
    [16, 19, 18],
    [20, 22, 21],
    [20, 23, 22],
];
const TALL_BOX_P: [[f32; 3]; 24] = [
    [-0.720444, 1.2, -0.473882],
    [-0.720444, 0.0, -0.473882],
    [-0.146892, 0.0, -0.673479],
    [-0.146892, 1.2, -0.673479],
    [-0.523986, 0.0, 0.090649],
    [-0.523986, 1.2, 0.090649],
    [0.049566, 1.2, -0.108948],
    [0.049566, 0.0, -0.108948],
    [-0.523986, 1.2, 0.090649],
    [-0.720444, 1.2, -0.473882],
    [-0.146892, 1.2, -0.673479],
    [0.049566, 1.2, -0.108948],
    [0.049566, 0.0, -0.108948],
    [-0.146892, 0.0, -0.673479],
    [-0.720444, 0.0, -0.473882],
    [-0.523986, 0.0, 0.090649],
    [-0.523986, 0.0, 0.090649],
    [-0.720444, 0.0, -0.473882],
    [-0.720444, 1.2, -0.473882],
    [-0.523986, 1.2, 0.090649],
    [0.049566, 1.2, -0.108948],
    [-0.146892, 1.2, -0.673479],
    [-0.146892, 0.0, -0.673479],
    [0.049566, 0.0, -0.108948],
];
const LIGHT_P: [[f32; 3]; 4] = [
    [-0.24, 1.98, -0.22],
    [0.23, 1.98, -0.22],
    [0.23, 1.98, 0.16],
    [-0.24, 1.98, 0.16],
];
const LIGHT_I: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
