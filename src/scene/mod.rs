//! The scene: the JSON contract (`doc`), its validation (`validate`), and the validated,
//! units-resolved [`Scene`] that the tracer and the progressive renderer consume.
//!
//! Only [`Scene`] crosses into the tracer; `doc` types never leave this module's parse step.

pub mod doc;
pub mod duplicates;
pub mod examples;
pub mod image;
pub mod obj;
pub mod reach;
pub mod transform;
pub mod validate;
pub mod warnings;

pub use validate::{
    parse_scene, validate_doc, Limits, Problem, SceneError, SceneErrorKind, SceneOrigin,
    MAX_COORDINATE, MAX_EMISSION,
};

use glam::{Vec2, Vec3};
use std::sync::Arc;

/// Index of a material in [`Scene::materials`].
pub type MaterialId = u32;
/// Index of an object in the document's `objects` list: the primary-hit id of §4.1.
pub type ObjectId = u32;
/// The object id of a ray that escapes (background).
pub const BACKGROUND_ID: ObjectId = u32::MAX;

/// A validated scene, ready to be prepared for tracing. Immutable once built, but for
/// [`Scene::release_geometry`].
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    pub display: Display,
    pub materials: Vec<Material>,
    /// `material_names[i]` is the document name of `materials[i]`.
    pub material_names: Vec<String>,
    /// One entry per document object, in document order (index = [`ObjectId`]).
    pub shapes: Vec<Shape>,
    pub lights: Vec<Light>,
    /// Decoded image textures, addressed by [`ImageMap::image`] (shared, not copied, by
    /// every tracer built from this scene).
    pub images: Vec<Arc<TextureImage>>,
    pub render: RenderSettings,
    pub progressive: ProgressiveSettings,
    /// Soft problems (ignored degenerate triangles, ...), with their JSON paths.
    pub warnings: Vec<Problem>,
}

/// Pinhole camera (scene-format.md `camera`).
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub position: Vec3,
    pub look_at: Vec3,
    pub up: Vec3,
    /// Full vertical field of view, degrees.
    pub fov_y_deg: f32,
}

/// How the finished image is shown to a person; calibrates the vision model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Display {
    pub peak_luminance: f32,
    pub black_luminance: f32,
    pub exposure: f32,
    pub pixels_per_degree: f32,
}

impl Default for Display {
    fn default() -> Self {
        Self {
            peak_luminance: 100.0,
            black_luminance: 0.5,
            exposure: 1.0,
            pixels_per_degree: 28.0,
        }
    }
}

/// A surface's reflectance, constant, procedural or an image.
#[derive(Clone, Copy, Debug)]
pub enum Texture {
    Constant(Vec3),
    /// 3-D checker of period `scale` between `a` and `b`.
    Checker {
        scale: f32,
        a: Vec3,
        b: Vec3,
    },
    /// Band-limited noise of feature size `scale`, blending `a` to `b`.
    Noise {
        scale: f32,
        a: Vec3,
        b: Vec3,
    },
    /// An image looked up at the surface's texture coordinates.
    Image(ImageMap),
}

impl Texture {
    /// Whether looking it up needs the surface's texture coordinates.
    #[must_use]
    pub fn uses_uv(&self) -> bool {
        matches!(self, Texture::Image(_))
    }
}

/// How an image is mapped: texel (s, t) = uv × `scale` + `offset`, in units of the whole
/// image, (0, 0) its top-left corner and t growing downwards (glTF's convention).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageMap {
    /// Index into [`Scene::images`].
    pub image: u32,
    /// Multiplies every texel (glTF `baseColorFactor`, pbrt `scale`).
    pub factor: Vec3,
    pub wrap: Wrap,
    pub scale: Vec2,
    pub offset: Vec2,
}

/// What a lookup outside [0, 1) of the image returns (glTF samplers, pbrt `wrap`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wrap {
    Repeat,
    Clamp,
    /// Mirrored repeat: every other copy flipped.
    Mirror,
    /// Black outside the image.
    Black,
}

/// A decoded image: linear RGB texels, row 0 at the top of the picture.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureImage {
    pub width: u32,
    pub height: u32,
    /// `width × height` texels, row-major.
    pub texels: Vec<Vec3>,
}

#[derive(Clone, Copy, Debug)]
pub enum Material {
    Diffuse {
        albedo: Texture,
    },
    Glossy {
        albedo: Vec3,
        roughness: f32,
    },
    /// A metal: complex index `eta + i·k` per channel, GGX `roughness` (alpha = roughness²).
    Conductor {
        eta: Vec3,
        k: Vec3,
        roughness: f32,
    },
    /// glTF 2.0 metallic-roughness (glTF spec Appendix B).
    MetallicRoughness {
        base_color: Texture,
        metallic: f32,
        roughness: f32,
    },
    /// A Lambertian base of albedo `reflectance` under a dielectric coat of index `ior`
    /// with GGX `roughness` (pbrt-v4 `coateddiffuse`; alpha = roughness²).
    CoatedDiffuse {
        reflectance: Texture,
        roughness: f32,
        ior: f32,
    },
    Mirror {
        reflectance: Vec3,
    },
    Dielectric {
        ior: f32,
        tint: Vec3,
    },
    Emissive {
        radiance: Vec3,
        two_sided: bool,
    },
}

impl Material {
    /// Whether shading it needs the surface's texture coordinates (an image texture).
    #[must_use]
    pub fn uses_uv(&self) -> bool {
        match self {
            Material::Diffuse { albedo: t }
            | Material::MetallicRoughness { base_color: t, .. }
            | Material::CoatedDiffuse { reflectance: t, .. } => t.uses_uv(),
            _ => false,
        }
    }
}

/// One triangle in world space. Shading normals are optional (mesh `normals`), and so
/// are texture coordinates (mesh `uvs`; a quad's own parametrisation).
///
/// Winding (set by `validate`): the geometric normal is `(p[1] − p[0]) × (p[2] − p[0])`.
/// For a quad it is `edge_u × edge_v`, for a box it points outwards, for a mesh it follows
/// the index order, and a mirroring transform re-winds the triangle so this stays true.
/// One-sided emitters emit on this side.
#[derive(Clone, Copy, Debug)]
pub struct Triangle {
    pub p: [Vec3; 3],
    pub n: Option<[Vec3; 3]>,
    pub uv: Option<[Vec2; 3]>,
}

/// A document object after its transform has been applied (world space).
#[derive(Clone, Debug)]
pub enum Shape {
    Sphere {
        center: Vec3,
        radius: f32,
        material: MaterialId,
    },
    /// Quads, boxes, meshes and OBJ files all become triangles. Degenerate triangles
    /// were dropped (and counted in [`Scene::warnings`]).
    Triangles {
        triangles: Vec<Triangle>,
        material: MaterialId,
    },
}

impl Shape {
    #[must_use]
    pub fn material(&self) -> MaterialId {
        match self {
            Shape::Sphere { material, .. } | Shape::Triangles { material, .. } => *material,
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub enum Light {
    Point {
        position: Vec3,
        intensity: Vec3,
    },
    /// `direction` is the (unit) direction the light travels.
    Directional {
        direction: Vec3,
        irradiance: Vec3,
    },
    Environment {
        radiance: Vec3,
    },
    /// A point light limited to a cone: intensity `intensity` (W/sr) inside `cos_inner`
    /// of the axis `direction` (unit, where the light points), falling to zero at
    /// `cos_outer` as `falloff` says.
    Spot {
        position: Vec3,
        direction: Vec3,
        intensity: Vec3,
        cos_inner: f32,
        cos_outer: f32,
        falloff: SpotFalloff,
    },
}

/// How a spot light's intensity falls from its inner to its outer cone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpotFalloff {
    /// pbrt-v4 `SpotLight::I`: smoothstep(cos θ) from cos_outer (0) to cos_inner (1).
    Smoothstep,
    /// glTF `KHR_lights_punctual`'s recommended attenuation: the square of the linear
    /// ramp in cos θ from cos_outer (0) to cos_inner (1).
    SquaredLinear,
}

impl SpotFalloff {
    /// The fraction of the intensity sent at cos θ from the axis (1 inside the inner
    /// cone, 0 outside the outer one).
    #[must_use]
    pub fn weight(self, cos_theta: f32, cos_inner: f32, cos_outer: f32) -> f32 {
        if cos_theta >= cos_inner {
            return 1.0;
        }
        if cos_theta <= cos_outer {
            return 0.0;
        }
        // cos_outer < cos θ < cos_inner here, so the span is positive.
        let t = ((cos_theta - cos_outer) / (cos_inner - cos_outer)).clamp(0.0, 1.0);
        match self {
            SpotFalloff::Smoothstep => t * t * (3.0 - 2.0 * t),
            SpotFalloff::SquaredLinear => t * t,
        }
    }
}

/// Which sampler draws a render's numbers (`render.sampler`; the numbers themselves are
/// tracer/sampler.rs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SamplerKind {
    /// Padded Owen-scrambled Sobol (`tracer::sampler::SobolSample`).
    Sobol,
    /// The same points in Z order across the image, its error spread as blue noise
    /// (`tracer::sampler::SobolSample::z_ordered`).
    ZSobol,
    /// An independent PCG32 stream per path (`tracer::rng::Rng`). The default: Sobol's
    /// gain at equal time is small and the loops' interpolated or denoised pixels do not
    /// share it (docs/design.md, "Samples").
    #[default]
    Independent,
}

impl SamplerKind {
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            SamplerKind::Sobol => "sobol",
            SamplerKind::ZSobol => "zsobol",
            SamplerKind::Independent => "independent",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RenderMode {
    Progressive,
    Guo,
    Reference,
    /// Passes of samples over the whole image, each spent where the vision model sees the
    /// most error left in the denoised picture (`progressive::adaptive`).
    Adaptive,
}

impl RenderMode {
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            RenderMode::Progressive => "progressive",
            RenderMode::Guo => "guo",
            RenderMode::Reference => "reference",
            RenderMode::Adaptive => "adaptive",
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub struct RenderSettings {
    pub mode: RenderMode,
    pub samples_per_pixel: u32,
    pub max_bounces: u32,
    pub seed: u64,
    /// Which numbers the paths draw (tracer/sampler.rs).
    pub sampler: crate::scene::SamplerKind,
    /// Whether the final picture (and, in adaptive mode, every pass's) goes through the
    /// denoiser: `render.denoise`; `None` = on in adaptive mode only (decided with the
    /// mode a render actually runs, which the command line and the API can override).
    pub denoise: Option<bool>,
}

/// The `progressive` block: thresholds of §4.2 and the metric's subdivision test (§3.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProgressiveSettings {
    pub t0: f32,
    /// `None`: the mean distance of the first iteration (F&P04 §5).
    pub t1: Option<f32>,
    pub initial_rate: f32,
    pub homogeneity: f32,
    pub epsilon: f32,
    pub max_iterations: u32,
    /// Run the perceptual loop even where the first sample set shows that tracing every
    /// pixel costs less (`progressive::driver::plan::loop_pays`): to watch the method on a
    /// cheap scene. Off by default.
    pub force_loop: bool,
}

impl Default for ProgressiveSettings {
    fn default() -> Self {
        Self {
            t0: 1.0,
            t1: None,
            initial_rate: 0.01,
            homogeneity: 0.8,
            epsilon: 1.0,
            max_iterations: 64,
            force_loop: false,
        }
    }
}

impl Scene {
    /// Frees every triangle list, keeping one shape per object with its material: a
    /// prepared tracer holds its own copy of the primitives, and the render loops read
    /// only the scene's settings, camera, materials and object count. At 10^6 triangles
    /// the lists are ~100 MB (104 bytes per [`Triangle`] with normals and uvs), as much
    /// as the tracer's whole geometry. A scene released so cannot prepare a tracer again.
    pub fn release_geometry(&mut self) {
        for s in &mut self.shapes {
            if let Shape::Triangles { triangles, .. } = s {
                *triangles = Vec::new();
            }
        }
    }

    /// Number of triangles after tessellation (spheres count 0).
    #[must_use]
    pub fn triangle_count(&self) -> usize {
        self.shapes
            .iter()
            .map(|s| match s {
                Shape::Triangles { triangles, .. } => triangles.len(),
                Shape::Sphere { .. } => 0,
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::{Shape, SpotFalloff};

    #[test]
    fn released_geometry_keeps_every_object_and_its_material() {
        let (_, doc) = super::examples::EXAMPLES[0];
        let mut scene = super::parse_scene(
            doc,
            &super::SceneOrigin::Request,
            &super::Limits::command_line(),
        )
        .unwrap();
        assert!(scene.triangle_count() > 0);
        let materials: Vec<_> = scene.shapes.iter().map(Shape::material).collect();
        scene.release_geometry();
        assert_eq!(scene.triangle_count(), 0);
        let kept: Vec<_> = scene.shapes.iter().map(Shape::material).collect();
        assert_eq!(kept, materials);
    }

    #[test]
    fn spot_falloff_at_the_cone_angles() {
        // pbrt-v4's defaults: coneangle 30°, conedelta 5°: full intensity within 25°,
        // none beyond 30°.
        let (ci, co) = (25f32.to_radians().cos(), 30f32.to_radians().cos());
        for f in [SpotFalloff::Smoothstep, SpotFalloff::SquaredLinear] {
            assert_eq!(f.weight(1.0, ci, co), 1.0);
            assert_eq!(f.weight(ci, ci, co), 1.0);
            assert_eq!(f.weight(co, ci, co), 0.0);
            assert_eq!(f.weight(31f32.to_radians().cos(), ci, co), 0.0);
            assert_eq!(f.weight(-1.0, ci, co), 0.0);
        }
        // Half-way in cos θ: smoothstep 0.5, the squared ramp 0.25.
        let mid = 0.5 * (ci + co);
        assert!((SpotFalloff::Smoothstep.weight(mid, ci, co) - 0.5).abs() < 1e-6);
        assert!((SpotFalloff::SquaredLinear.weight(mid, ci, co) - 0.25).abs() < 1e-6);
        // At 27.5°: t = (cos 27.5° − cos 30°) / (cos 25° − cos 30°) = 0.5210;
        // smoothstep 3t² − 2t³ = 0.5314, squared 0.2714.
        let c = 27.5f32.to_radians().cos();
        assert!((SpotFalloff::Smoothstep.weight(c, ci, co) - 0.5314).abs() < 2e-4);
        assert!((SpotFalloff::SquaredLinear.weight(c, ci, co) - 0.2714).abs() < 2e-4);
        // A hard-edged cone (inner = outer): all or nothing, never a division by zero.
        assert_eq!(SpotFalloff::Smoothstep.weight(co + 1e-6, co, co), 1.0);
        assert_eq!(SpotFalloff::Smoothstep.weight(co - 1e-6, co, co), 0.0);
    }
}
