//! The pixel oracle: a Monte Carlo path tracer that computes the colour of any single pixel.
//!
//! A pixel's value is a pure function of (scene, seed, pixel): tracing a scattered subset
//! gives bit-identical values to the same pixels of a full render, whatever the thread
//! count (the progressive renderer relies on it).

use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage, PixelCoord, Rgb};
use crate::scene::{Material, ObjectId, Scene, Shape, Texture, BACKGROUND_ID};
use glam::Vec3;
use material::Bsdf;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

pub mod bvh;
pub mod camera;
pub mod fixtures;
mod integrator;
pub mod light;
pub mod material;
pub mod primary;
pub mod rng;
pub mod sampling;
pub mod texture;

/// Anything that can compute the true colour of one pixel. The progressive loop, the
/// benches and the tests see only this trait; tests pass analytic oracles.
pub trait PixelOracle: Sync {
    /// Image size in pixels.
    fn size(&self) -> (u32, u32);
    /// The pixel's estimate with the scene's `samples_per_pixel` and `seed`.
    fn radiance(&self, p: PixelCoord) -> Rgb;
    /// The same estimator with an explicit sample count and seed (equal-time baselines,
    /// independent references).
    fn radiance_with(&self, p: PixelCoord, samples: u32, seed: u64) -> Rgb;
    /// Id of the object hit by the ray through the pixel centre ([`crate::scene::BACKGROUND_ID`]
    /// on a miss): one ray per pixel, for the contour map of §4.1.
    fn object_id(&self, p: PixelCoord) -> ObjectId;
}

/// Pixels are traced in batches of this many; cancellation is checked between batches.
pub const BATCH: usize = 256;

/// Traces `pixels` in parallel (rayon), checking `cancel` between batches.
/// The result is in the order of `pixels` and independent of the thread count.
pub fn trace_pixels(
    oracle: &impl PixelOracle,
    pixels: &[PixelCoord],
    cancel: &CancelToken,
) -> Result<Vec<Rgb>, Cancelled> {
    let mut out = vec![Rgb::ZERO; pixels.len()];
    out.par_chunks_mut(BATCH)
        .zip(pixels.par_chunks(BATCH))
        .try_for_each(|(o, p)| {
            if cancel.is_cancelled() {
                return Err(Cancelled);
            }
            for (dst, &px) in o.iter_mut().zip(p) {
                *dst = oracle.radiance(px);
            }
            Ok(())
        })?;
    Ok(out)
}

/// Every pixel traced (`render.mode = "reference"`). `progress(done, total)` is called
/// after each batch from worker threads.
pub fn render_reference(
    oracle: &impl PixelOracle,
    cancel: &CancelToken,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<LinearImage, Cancelled> {
    render_reference_with(oracle, None, cancel, progress)
}

/// Like [`render_reference`], with an explicit (samples, seed) instead of the scene's.
pub fn render_reference_with(
    oracle: &impl PixelOracle,
    samples_seed: Option<(u32, u64)>,
    cancel: &CancelToken,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<LinearImage, Cancelled> {
    let (w, h) = oracle.size();
    let total = w as usize * h as usize;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let mut data = vec![Rgb::ZERO; total];
    data.par_chunks_mut(BATCH)
        .enumerate()
        .try_for_each(|(c, chunk)| {
            if cancel.is_cancelled() {
                return Err(Cancelled);
            }
            for (k, dst) in chunk.iter_mut().enumerate() {
                let i = c * BATCH + k;
                let p = PixelCoord::new((i % w as usize) as u32, (i / w as usize) as u32);
                *dst = match samples_seed {
                    None => oracle.radiance(p),
                    Some((s, seed)) => oracle.radiance_with(p, s, seed),
                };
            }
            let d = done.fetch_add(chunk.len(), std::sync::atomic::Ordering::Relaxed) + chunk.len();
            progress(d, total);
            Ok(())
        })?;
    Ok(Image::from_vec(w, h, data).expect("size matches by construction"))
}

/// The object-id map (§4.1): one primary ray per pixel.
#[must_use]
pub fn object_id_map(oracle: &impl PixelOracle) -> Image<ObjectId> {
    let (w, h) = oracle.size();
    let data: Vec<ObjectId> = (0..w as usize * h as usize)
        .into_par_iter()
        .map(|i| {
            oracle.object_id(PixelCoord::new(
                (i % w as usize) as u32,
                (i / w as usize) as u32,
            ))
        })
        .collect();
    Image::from_vec(w, h, data).expect("size matches by construction")
}

/// What a prepared scene contains, decided once in [`PathTracer::new`] so that a scene
/// pays nothing for what it lacks (STYLE.md "branch on scene features when the scene is
/// prepared").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Features {
    /// Any light that next-event estimation can sample (emitters, point, directional,
    /// non-black environment).
    pub has_lights: bool,
    pub has_emitters: bool,
    pub has_environment: bool,
    pub has_dielectric: bool,
    pub has_glossy: bool,
    pub has_mirror: bool,
    pub has_texture: bool,
    pub has_spheres: bool,
}

/// A scene material resolved for shading.
#[derive(Clone, Copy, Debug)]
pub(crate) enum ResolvedMaterial {
    /// The BSDF is the same everywhere on the surface.
    Fixed(Bsdf),
    /// Diffuse with a procedural albedo.
    Textured(crate::scene::Texture),
}

/// The path tracer over a prepared scene (BVH, emitter list, feature flags). Immutable
/// once built and shared by every thread (Tungsten's `TraceableScene`).
pub struct PathTracer {
    width: u32,
    height: u32,
    pub(crate) camera: camera::Pinhole,
    pub(crate) geo: bvh::Geometry,
    /// Screen-tile candidate lists for camera rays (small scenes only, tracer/primary.rs).
    pub(crate) primary: Option<primary::CameraRays>,
    pub(crate) lights: light::Lights,
    pub(crate) materials: Vec<ResolvedMaterial>,
    pub(crate) max_bounces: u32,
    samples_per_pixel: u32,
    seed: u64,
    pub(crate) features: Features,
    /// Samples dropped because they were NaN or infinite (diagnostics only).
    dropped: AtomicU64,
}

impl PathTracer {
    /// Prepares `scene` for tracing: builds the BVH and decides which code paths it needs.
    #[must_use]
    pub fn new(scene: &Scene) -> Self {
        let mut geo = bvh::Geometry::build(scene);
        let lights = light::Lights::build(scene, &mut geo);
        let materials: Vec<ResolvedMaterial> = scene
            .materials
            .iter()
            .map(|m| match *m {
                Material::Diffuse {
                    albedo: Texture::Constant(c),
                } => ResolvedMaterial::Fixed(Bsdf::Diffuse { albedo: c }),
                Material::Diffuse { albedo } => ResolvedMaterial::Textured(albedo),
                Material::Glossy { albedo, roughness } => ResolvedMaterial::Fixed(Bsdf::Glossy {
                    albedo,
                    alpha: (roughness * roughness).max(material::MIN_ALPHA),
                }),
                Material::Mirror { reflectance } => {
                    ResolvedMaterial::Fixed(Bsdf::Mirror { reflectance })
                }
                Material::Dielectric { ior, tint } => {
                    ResolvedMaterial::Fixed(Bsdf::Dielectric { ior, tint })
                }
                Material::Emissive { .. } => ResolvedMaterial::Fixed(Bsdf::Black),
            })
            .collect();
        let used = |f: &dyn Fn(&Material) -> bool| {
            scene
                .shapes
                .iter()
                .any(|s| scene.materials.get(s.material() as usize).is_some_and(f))
        };
        let features = Features {
            has_lights: !lights.is_empty(),
            has_emitters: lights.emitters.iter().any(|e| {
                matches!(
                    e,
                    light::Emitter::Tri { .. } | light::Emitter::Sphere { .. }
                )
            }),
            has_environment: lights.env_radiance.is_some(),
            has_dielectric: used(&|m| matches!(m, Material::Dielectric { .. })),
            has_glossy: used(&|m| matches!(m, Material::Glossy { .. })),
            has_mirror: used(&|m| matches!(m, Material::Mirror { .. })),
            has_texture: used(&|m| {
                matches!(
                    m,
                    Material::Diffuse {
                        albedo: Texture::Checker { .. } | Texture::Noise { .. }
                    }
                )
            }),
            has_spheres: scene
                .shapes
                .iter()
                .any(|s| matches!(s, Shape::Sphere { .. })),
        };
        let camera = camera::Pinhole::new(&scene.camera, scene.width, scene.height);
        let primary = primary::CameraRays::build(&geo, &camera, scene.width, scene.height);
        Self {
            width: scene.width,
            height: scene.height,
            camera,
            geo,
            primary,
            lights,
            materials,
            max_bounces: scene.render.max_bounces,
            samples_per_pixel: scene.render.samples_per_pixel,
            seed: scene.render.seed,
            features,
            dropped: AtomicU64::new(0),
        }
    }

    /// The flags decided at preparation.
    #[must_use]
    pub fn features(&self) -> Features {
        self.features
    }

    /// How many samples were dropped as NaN/Inf since this tracer was built.
    #[must_use]
    pub fn dropped_samples(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Number of primitives in the BVH (triangles + spheres).
    #[must_use]
    pub fn primitive_count(&self) -> usize {
        self.geo.prims.len()
    }

    /// Whether camera rays use the screen-tile lists of tracer/primary.rs (decided at
    /// preparation by scene size) rather than the BVH.
    #[must_use]
    pub fn has_camera_tiles(&self) -> bool {
        self.primary.is_some()
    }

    /// Closest hit of the camera ray `d` through pixel (x, y) (jitter inside the pixel):
    /// the tile lists when the scene has them, else the BVH. Both give the same hit.
    #[inline]
    pub(crate) fn camera_hit(&self, x: u32, y: u32, d: Vec3) -> Option<bvh::Hit> {
        match &self.primary {
            Some(p) => p.intersect(&self.geo, x, y, d),
            None => self
                .geo
                .intersect(self.camera.origin, d, f32::INFINITY, bvh::NONE),
        }
    }

    /// Traces one camera ray through a jittered position of pixel `p` and returns whether
    /// it hit anything: the primary-ray throughput benchmark (benches/tracer.rs). The
    /// same ray generation and first hit as [`PixelOracle::radiance`]'s paths.
    #[must_use]
    pub fn primary_ray_hits(&self, p: PixelCoord, sample: u32, seed: u64) -> bool {
        let mut rng = rng::Rng::for_sample(seed, p.x, p.y, sample);
        let d = self.camera.direction(p.x, p.y, rng.next_2d());
        self.camera_hit(p.x, p.y, d).is_some()
    }

    /// [`PathTracer::primary_ray_hits`] through the BVH only, for comparing the two
    /// camera-ray paths (benches/tracer.rs, tests).
    #[must_use]
    pub fn primary_ray_hits_bvh(&self, p: PixelCoord, sample: u32, seed: u64) -> bool {
        let mut rng = rng::Rng::for_sample(seed, p.x, p.y, sample);
        let d = self.camera.direction(p.x, p.y, rng.next_2d());
        self.geo
            .intersect(self.camera.origin, d, f32::INFINITY, bvh::NONE)
            .is_some()
    }
}

impl PixelOracle for PathTracer {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn radiance(&self, p: PixelCoord) -> Rgb {
        self.radiance_with(p, self.samples_per_pixel, self.seed)
    }

    /// The box-filtered mean of `samples` paths, each seeded by hashing (seed, x, y,
    /// sample index): a pure function of its arguments. Samples that come out NaN or
    /// infinite are dropped and the mean is taken over the others (never returned).
    fn radiance_with(&self, p: PixelCoord, samples: u32, seed: u64) -> Rgb {
        let mut sum = Vec3::ZERO;
        let mut kept = 0u32;
        for i in 0..samples {
            let mut rng = rng::Rng::for_sample(seed, p.x, p.y, i);
            let v = self.trace_path(p.x, p.y, &mut rng);
            if v.is_finite() {
                sum += v;
                kept += 1;
            }
        }
        if kept < samples {
            self.dropped
                .fetch_add(u64::from(samples - kept), Ordering::Relaxed);
        }
        if kept == 0 {
            return Rgb::ZERO;
        }
        let mean = sum / kept as f32;
        // The sum of finite samples can still overflow f32 (radiance near f32::MAX).
        if mean.is_finite() {
            mean
        } else {
            Rgb::ZERO
        }
    }

    fn object_id(&self, p: PixelCoord) -> ObjectId {
        let d = self.camera.direction(p.x, p.y, glam::Vec2::splat(0.5));
        self.camera_hit(p.x, p.y, d)
            .and_then(|h| self.geo.info.get(h.prim as usize))
            .map_or(BACKGROUND_ID, |i| i.object)
    }
}
