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

pub mod aux;
pub mod bvh;
pub mod camera;
pub mod fixtures;
mod integrator;
pub mod light;
pub mod material;
pub mod primary;
pub mod rng;
pub mod sampler;
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
    /// The shading normal, facing the camera, where the ray through the pixel centre meets
    /// a surface; zero on a miss or where the oracle cannot tell. The reconstruction keeps
    /// the faces of one object apart with it (a box's faces share its id).
    fn surface_normal(&self, _p: PixelCoord) -> glam::Vec3 {
        glam::Vec3::ZERO
    }
    /// [`Self::object_id`] and [`Self::surface_normal`] together: an oracle that traces
    /// rays answers both from the one ray through the pixel centre.
    fn centre_hit(&self, p: PixelCoord) -> (ObjectId, glam::Vec3) {
        (self.object_id(p), self.surface_normal(p))
    }
    /// The albedo of the textured Lambertian surface the pixel sees, averaged over its
    /// footprint (up to the 4 [`ALBEDO_TAPS`] camera rays), or `None` where any of them sees
    /// something else (another material, the background). Radiance leaving a Lambertian
    /// surface is its albedo times irradiance/π, so the progressive renderer interpolates
    /// radiance ÷ albedo and multiplies each pixel's own albedo back: a texture's detail
    /// comes from these few primary rays instead of from tracing every pixel of it.
    fn texture_albedo(&self, _p: PixelCoord) -> Option<Rgb> {
        None
    }
    /// [`PixelOracle::radiance_with`], and the mean albedo the estimate's own camera rays
    /// (same sub-pixel positions) hit, `None` unless every one sees a textured Lambertian
    /// surface. A traced pixel is a vertex of the interpolation: dividing its radiance by
    /// exactly the albedo it averaged (not the [`ALBEDO_TAPS`] approximation of its
    /// footprint) keeps pixels across a texture edge from spreading a wrong irradiance.
    fn radiance_albedo_with(&self, p: PixelCoord, samples: u32, seed: u64) -> (Rgb, Option<Rgb>) {
        (self.radiance_with(p, samples, seed), None)
    }
    /// [`PixelOracle::radiance_albedo_with`] with the scene's samples and seed.
    fn radiance_and_albedo(&self, p: PixelCoord) -> (Rgb, Option<Rgb>) {
        (self.radiance(p), None)
    }
    /// [`PixelOracle::radiance_albedo_with`] and the variance of the estimate: what the
    /// progressive loop needs to know how far to trust a vertex. An oracle that cannot
    /// tell reports a variance of 0 (exact values).
    fn estimate_with(&self, p: PixelCoord, samples: u32, seed: u64) -> Estimate {
        let (radiance, albedo) = self.radiance_albedo_with(p, samples, seed);
        Estimate {
            radiance,
            variance: Rgb::ZERO,
            albedo,
            rays: 0,
        }
    }
    /// [`PixelOracle::estimate_with`] with the scene's samples and seed.
    fn estimate(&self, p: PixelCoord) -> Estimate {
        let (radiance, albedo) = self.radiance_and_albedo(p);
        Estimate {
            radiance,
            variance: Rgb::ZERO,
            albedo,
            rays: 0,
        }
    }
    /// Whether any pixel can have a [`PixelOracle::texture_albedo`] (a scene without
    /// textures builds no map and pays nothing).
    fn has_textures(&self) -> bool {
        false
    }
    /// Whether the pixel's footprint (the box its estimate integrates) spans more than one
    /// object: the camera rays through its four [`ALBEDO_TAPS`] do not all see `centre`,
    /// the object its centre sees ([`PixelOracle::object_id`]). Such a pixel's value is a
    /// blend that no object's vertices can interpolate (an antialiased silhouette, a
    /// horizon, a wire thinner than a pixel). An oracle that cannot tell answers `false`.
    fn footprint_mixed(&self, _p: PixelCoord, _centre: ObjectId) -> bool {
        false
    }
    /// The denoiser's auxiliary features of pixel `p` ([`aux`]): the albedo and normal of
    /// what its camera rays first meet that is not a perfect mirror. An oracle that cannot
    /// tell answers a white albedo and no normal.
    fn aux_features(&self, _p: PixelCoord) -> AuxFeatures {
        AuxFeatures {
            albedo: Rgb::ONE,
            normal: glam::Vec3::ZERO,
        }
    }
    /// `acc` with the next `count` paths of pixel `p`'s sequence under `seed` added (paths
    /// `acc.next ..`): a pure function of its arguments, so passes that add paths to a
    /// pixel add up to [`PixelOracle::estimate_with`] of the whole count, on any thread.
    /// The default, for oracles that do not trace paths (exact and test oracles), adds
    /// the whole-count estimate's mean `count` times.
    fn sample_sum(&self, p: PixelCoord, count: u32, seed: u64, mut acc: SampleSum) -> SampleSum {
        let mean = self.estimate_with(p, acc.next + count, seed).radiance;
        for _ in 0..count {
            acc.add(mean);
        }
        acc
    }
    /// [`PixelOracle::footprint_mixed`] and [`PixelOracle::texture_albedo`] together: an
    /// oracle that casts camera rays through the [`ALBEDO_TAPS`] for both casts them once.
    fn footprint(&self, p: PixelCoord, centre: ObjectId) -> Footprint {
        Footprint {
            mixed: self.footprint_mixed(p, centre),
            albedo: if self.has_textures() {
                self.texture_albedo(p)
            } else {
                None
            },
        }
    }
}

/// A pixel's auxiliary features for the denoiser ([`PixelOracle::aux_features`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AuxFeatures {
    /// Each channel in [0, 1].
    pub albedo: Rgb,
    /// Each component in [-1, 1]; zero on a miss.
    pub normal: glam::Vec3,
}

/// One pixel's paths summed so far ([`PixelOracle::sample_sum`]). The sum is kept in the
/// same f32 arithmetic, in the same order, as [`PixelOracle::estimate_with`], so a pixel
/// summed over runs `0..a`, `a..n` has the mean of `estimate_with(p, n)` bit for bit.
/// Even-numbered paths are also summed apart: with independent paths, the even and odd
/// halves are two independent estimates of the pixel (an error estimate needs two).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SampleSum {
    /// Sum of the finite paths' radiance.
    pub sum: Rgb,
    /// Sum of their squares.
    pub sum_sq: glam::DVec3,
    /// Paths kept (non-finite ones are dropped, as in [`PixelOracle::estimate_with`]).
    pub kept: u32,
    /// Sum and count of the kept paths of even index.
    pub even_sum: Rgb,
    pub even_kept: u32,
    /// Paths asked for so far, kept or not: the index of the next one.
    pub next: u32,
    /// Rays cast for them (0 from an oracle that does not count).
    pub rays: u64,
}

impl SampleSum {
    /// The mean of the kept paths, as [`PixelOracle::estimate_with`] computes it (zero when
    /// none was kept or the mean overflows).
    #[must_use]
    pub fn mean(&self) -> Rgb {
        if self.kept == 0 {
            return Rgb::ZERO;
        }
        let m = self.sum / self.kept as f32;
        if m.is_finite() {
            m
        } else {
            Rgb::ZERO
        }
    }

    /// The means of the even and of the odd paths: two independent half estimates.
    #[must_use]
    pub fn halves(&self) -> (Rgb, Rgb) {
        let odd_kept = self.kept - self.even_kept;
        let mean = |s: Rgb, k: u32| {
            let m = if k == 0 { Rgb::ZERO } else { s / k as f32 };
            if m.is_finite() {
                m
            } else {
                Rgb::ZERO
            }
        };
        (
            mean(self.even_sum, self.even_kept),
            mean(self.sum - self.even_sum, odd_kept),
        )
    }

    /// Adds one path's radiance `v` (index `self.next`); non-finite paths are counted
    /// as asked for, not kept.
    #[inline]
    pub fn add(&mut self, v: Rgb) {
        if v.is_finite() {
            self.sum += v;
            let d = v.as_dvec3();
            self.sum_sq += d * d;
            if self.next.is_multiple_of(2) {
                self.even_sum += v;
                self.even_kept += 1;
            }
            self.kept += 1;
        }
        self.next += 1;
    }
}

/// What a pixel's footprint holds ([`PixelOracle::footprint`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    /// [`PixelOracle::footprint_mixed`].
    pub mixed: bool,
    /// [`PixelOracle::texture_albedo`] (always `None` without textures).
    pub albedo: Option<Rgb>,
}

/// One pixel's estimate (a mean of paths) and how far to trust it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Estimate {
    pub radiance: Rgb,
    /// Variance of the mean, per channel: the paths' sample variance over their count.
    /// `f32::INFINITY` when fewer than two paths were kept (unknown); 0 from an exact oracle.
    pub variance: Rgb,
    /// [`PixelOracle::radiance_albedo_with`]'s albedo (textured scenes only).
    pub albedo: Option<Rgb>,
    /// Rays cast for it (camera, bounce and shadow rays): what the estimate cost, counted
    /// rather than timed so that decisions taken on it do not depend on the machine or
    /// its load. 0 from an oracle that does not count (its cost is unknown).
    pub rays: u32,
}

/// Sub-pixel positions of [`PixelOracle::texture_albedo`]: a 2×2 stratified pattern over
/// the pixel, the support of the radiance estimate's box filter.
pub const ALBEDO_TAPS: [glam::Vec2; 4] = [
    glam::Vec2::new(0.25, 0.25),
    glam::Vec2::new(0.75, 0.25),
    glam::Vec2::new(0.25, 0.75),
    glam::Vec2::new(0.75, 0.75),
];

/// The mean albedo over a footprint from the albedos its [`ALBEDO_TAPS`] see (`tap(k)`,
/// `None` off a textured Lambertian surface): two opposite corners first; where they
/// agree within 1 % (a checker's interior, a texture smooth at the pixel's scale) their
/// mean is the footprint's and the other two taps are not asked for.
fn footprint_albedo(tap: impl Fn(usize) -> Option<Vec3>) -> Option<Rgb> {
    let a = tap(0)?;
    let d = tap(3)?;
    if (a - d).abs().max_element() <= 0.01 * a.max(d).max_element() {
        return Some((a + d) * 0.5);
    }
    let (b, c) = (tap(1)?, tap(2)?);
    Some((a + b + c + d) / 4.0)
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
    per_pixel(pixels, cancel, |p| oracle.radiance(p))
}

/// [`trace_pixels`] with [`PixelOracle::radiance_and_albedo`].
pub fn trace_pixels_albedo(
    oracle: &impl PixelOracle,
    pixels: &[PixelCoord],
    cancel: &CancelToken,
) -> Result<Vec<(Rgb, Option<Rgb>)>, Cancelled> {
    per_pixel(pixels, cancel, |p| oracle.radiance_and_albedo(p))
}

/// [`trace_pixels`] with [`PixelOracle::estimate`].
pub fn trace_estimates(
    oracle: &impl PixelOracle,
    pixels: &[PixelCoord],
    cancel: &CancelToken,
) -> Result<Vec<Estimate>, Cancelled> {
    per_pixel(pixels, cancel, |p| oracle.estimate(p))
}

/// `f` over `pixels` in parallel batches of at most [`BATCH`], checking `cancel` before
/// every pixel (one relaxed load; a batch of costly pixels, such as rays through a mesh
/// of near-duplicate triangles, took over a second to notice a cancel). A short list (the
/// progressive loop's first sample set and late iterations: a few hundred pixels) is cut
/// into at least 8 batches per thread, so no thread idles while another finishes a whole
/// 256-pixel batch.
fn per_pixel<T: Send + Clone + Default>(
    pixels: &[PixelCoord],
    cancel: &CancelToken,
    f: impl Fn(PixelCoord) -> T + Sync,
) -> Result<Vec<T>, Cancelled> {
    let mut out = vec![T::default(); pixels.len()];
    let batch = (pixels.len() / (8 * rayon::current_num_threads())).clamp(8, BATCH);
    out.par_chunks_mut(batch)
        .zip(pixels.par_chunks(batch))
        .try_for_each(|(o, p)| {
            for (dst, &px) in o.iter_mut().zip(p) {
                if cancel.is_cancelled() {
                    return Err(Cancelled);
                }
                *dst = f(px);
            }
            Ok(())
        })?;
    Ok(out)
}

/// Every pixel traced (`render.mode = "reference"`). `progress(done, total)` is called
/// after each batch from worker threads.
///
/// The batches (runs of [`BATCH`] pixels of a row) are traced in a scattered order, so
/// that the pixels done at any moment sample the whole image: a sky costs a fraction of
/// a floor, and in raster order the share done ran ahead of the time spent by up to 2×
/// (a 451² corpus scene: a quarter of its pixels in 8 % of the pass), which the time
/// left, extrapolated from that share, believed. Each pixel's value is its own (seeded by
/// its coordinates), whatever the order.
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
    let mut batches: Vec<(usize, &mut [Rgb])> = data.chunks_mut(BATCH).enumerate().collect();
    // Fibonacci hashing of the batch index: a fixed order that spreads neighbours apart.
    batches.sort_unstable_by_key(|(c, _)| (*c as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    batches
        .into_par_iter()
        .with_max_len(1)
        .try_for_each(|(c, chunk)| {
            for (k, dst) in chunk.iter_mut().enumerate() {
                // Per pixel, as in `per_pixel`: a cancel is seen within one pixel's time.
                if cancel.is_cancelled() {
                    return Err(Cancelled);
                }
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
    let data = every_pixel(oracle, |p| oracle.object_id(p));
    Image::from_vec(w, h, data).expect("size matches by construction")
}

/// What the progressive loop knows of every pixel before tracing any (§4.1 and our
/// extensions): the object-id map, the normals, the mixed footprints and the texture
/// albedos.
pub struct PixelAnalysis {
    pub ids: Image<ObjectId>,
    /// [`PixelOracle::surface_normal`], row-major.
    pub normals: Vec<Vec3>,
    /// [`PixelOracle::footprint_mixed`] against the pixel's own id, row-major.
    pub mixed: Vec<bool>,
    /// [`PixelOracle::texture_albedo`] per pixel, row-major: `None` when the oracle has no
    /// texture.
    pub albedo: Option<Vec<Option<Rgb>>>,
}

/// [`PixelAnalysis`] in one parallel pass: per pixel the centre ray ([`PixelOracle::centre_hit`])
/// and the footprint's taps ([`PixelOracle::footprint`]), five camera rays in all.
#[must_use]
pub fn analysis_maps(oracle: &impl PixelOracle) -> PixelAnalysis {
    let (w, h) = oracle.size();
    let per_pixel = every_pixel(oracle, |p| {
        let (id, normal) = oracle.centre_hit(p);
        (id, normal, oracle.footprint(p, id))
    });
    let n = per_pixel.len();
    let mut ids = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    let mut mixed = Vec::with_capacity(n);
    let mut albedo = oracle.has_textures().then(|| Vec::with_capacity(n));
    for (id, normal, f) in per_pixel {
        ids.push(id);
        normals.push(normal);
        mixed.push(f.mixed);
        if let Some(a) = albedo.as_mut() {
            a.push(f.albedo);
        }
    }
    PixelAnalysis {
        ids: Image::from_vec(w, h, ids).expect("size matches by construction"),
        normals,
        mixed,
        albedo,
    }
}

/// `f` at every pixel of the oracle's image, row-major, in parallel.
fn every_pixel<T: Send>(
    oracle: &impl PixelOracle,
    f: impl Fn(PixelCoord) -> T + Sync + Send,
) -> Vec<T> {
    let (w, h) = oracle.size();
    let (w, n) = (w as usize, w as usize * h as usize);
    (0..n)
        .into_par_iter()
        .map(|i| f(PixelCoord::new((i % w) as u32, (i / w) as u32)))
        .collect()
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
    /// Diffuse with a procedural or image albedo.
    Textured(crate::scene::Texture),
    /// glTF metallic-roughness with a textured base colour.
    TexturedMetalRough {
        base: crate::scene::Texture,
        metallic: f32,
        alpha: f32,
    },
    /// A coated diffuse surface with a textured base: [`Bsdf::CoatedDiffuse`]'s other
    /// fields.
    TexturedCoated {
        reflectance: crate::scene::Texture,
        eta: f32,
        alpha: f32,
        fdr_int: f32,
    },
}

impl Features {
    /// The flags of `scene`, whose lights are `lights`: a feature counts only where a
    /// shape uses it (an unused material costs nothing).
    fn of(scene: &Scene, lights: &light::Lights) -> Self {
        let used = |f: &dyn Fn(&Material) -> bool| {
            scene
                .shapes
                .iter()
                .any(|s| scene.materials.get(s.material() as usize).is_some_and(f))
        };
        Features {
            has_lights: !lights.is_empty(),
            has_emitters: lights.emitters.iter().any(|e| {
                matches!(
                    e,
                    light::Emitter::Tri { .. } | light::Emitter::Sphere { .. }
                )
            }),
            has_environment: lights.env_radiance.is_some(),
            has_dielectric: used(&|m| matches!(m, Material::Dielectric { .. })),
            has_glossy: used(&|m| {
                matches!(
                    m,
                    Material::Glossy { .. }
                        | Material::Conductor { .. }
                        | Material::MetallicRoughness { .. }
                        | Material::CoatedDiffuse { .. }
                )
            }),
            has_mirror: used(&|m| matches!(m, Material::Mirror { .. })),
            // Only a textured Lambertian surface gives the progressive loop an albedo to
            // divide by (`PixelOracle::texture_albedo`).
            has_texture: used(&|m| {
                matches!(
                    m,
                    Material::Diffuse {
                        albedo: Texture::Checker { .. } | Texture::Noise { .. } | Texture::Image(_)
                    }
                )
            }),
            has_spheres: scene
                .shapes
                .iter()
                .any(|s| matches!(s, Shape::Sphere { .. })),
        }
    }
}

impl ResolvedMaterial {
    /// `m` resolved for shading: constant textures fold into a fixed BSDF, roughness
    /// becomes the microfacet α = roughness² (clamped at [`material::MIN_ALPHA`]).
    fn of(m: &Material) -> Self {
        match *m {
            Material::Diffuse {
                albedo: Texture::Constant(c),
            } => ResolvedMaterial::Fixed(Bsdf::Diffuse { albedo: c }),
            Material::Diffuse { albedo } => ResolvedMaterial::Textured(albedo),
            Material::Glossy { albedo, roughness } => ResolvedMaterial::Fixed(Bsdf::Glossy {
                albedo,
                alpha: (roughness * roughness).max(material::MIN_ALPHA),
            }),
            Material::Conductor { eta, k, roughness } => ResolvedMaterial::Fixed(Bsdf::Conductor {
                eta,
                k,
                alpha: (roughness * roughness).max(material::MIN_ALPHA),
            }),
            Material::MetallicRoughness {
                base_color: Texture::Constant(base),
                metallic,
                roughness,
            } => ResolvedMaterial::Fixed(Bsdf::MetalRough {
                base,
                metallic,
                alpha: (roughness * roughness).max(material::MIN_ALPHA),
            }),
            Material::MetallicRoughness {
                base_color,
                metallic,
                roughness,
            } => ResolvedMaterial::TexturedMetalRough {
                base: base_color,
                metallic,
                alpha: (roughness * roughness).max(material::MIN_ALPHA),
            },
            Material::CoatedDiffuse {
                reflectance,
                roughness,
                ior,
            } => {
                let (eta, alpha) = (ior, (roughness * roughness).max(material::MIN_ALPHA));
                let fdr_int = material::internal_diffuse_reflectance(ior);
                match reflectance {
                    Texture::Constant(albedo) => ResolvedMaterial::Fixed(Bsdf::CoatedDiffuse {
                        albedo,
                        eta,
                        alpha,
                        fdr_int,
                    }),
                    reflectance => ResolvedMaterial::TexturedCoated {
                        reflectance,
                        eta,
                        alpha,
                        fdr_int,
                    },
                }
            }
            Material::Mirror { reflectance } => {
                ResolvedMaterial::Fixed(Bsdf::Mirror { reflectance })
            }
            Material::Dielectric { ior, tint } => {
                ResolvedMaterial::Fixed(Bsdf::Dielectric { ior, tint })
            }
            Material::Emissive { .. } => ResolvedMaterial::Fixed(Bsdf::Black),
        }
    }
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
    /// The scene's decoded image textures (shared with it).
    pub(crate) images: Vec<std::sync::Arc<crate::scene::TextureImage>>,
    pub(crate) max_bounces: u32,
    samples_per_pixel: u32,
    seed: u64,
    /// Which numbers the paths draw (`render.sampler`).
    sampler: crate::scene::SamplerKind,
    /// Where pixels and samples lie along the z-ordered sampler's sequence.
    z_order: sampler::ZOrder,
    pub(crate) features: Features,
    /// Samples dropped because they were NaN or infinite (diagnostics only).
    dropped: AtomicU64,
}

impl PathTracer {
    /// Prepares `scene` for tracing: builds the BVH and decides which code paths it needs.
    #[must_use]
    pub fn new(scene: &Scene) -> Self {
        match Self::prepare(scene, &CancelToken::new()) {
            Ok(t) => t,
            Err(Cancelled) => unreachable!("a fresh token is never cancelled"),
        }
    }

    /// [`Self::new`], ending with `Err(Cancelled)` soon after `cancel` is (the BVH build
    /// of a large mesh takes seconds: [`bvh::Geometry::prepare`]).
    pub fn prepare(scene: &Scene, cancel: &CancelToken) -> Result<Self, Cancelled> {
        let mut geo = bvh::Geometry::prepare(scene, cancel)?;
        cancel.check()?;
        let lights = light::Lights::build(scene, &mut geo);
        cancel.check()?;
        let materials: Vec<ResolvedMaterial> =
            scene.materials.iter().map(ResolvedMaterial::of).collect();
        let features = Features::of(scene, &lights);
        let camera = camera::Pinhole::new(&scene.camera, scene.width, scene.height);
        let primary = primary::CameraRays::build(&geo, &camera, scene.width, scene.height);
        Ok(Self {
            width: scene.width,
            height: scene.height,
            camera,
            geo,
            primary,
            lights,
            materials,
            images: scene.images.clone(),
            max_bounces: scene.render.max_bounces,
            samples_per_pixel: scene.render.samples_per_pixel,
            seed: scene.render.seed,
            sampler: scene.render.sampler,
            z_order: sampler::ZOrder::new(
                scene.width,
                scene.height,
                scene.render.samples_per_pixel,
            ),
            features,
            dropped: AtomicU64::new(0),
        })
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
        let d = self
            .camera
            .direction(p.x, p.y, self.camera_jitter(p, sample, seed));
        self.camera_hit(p.x, p.y, d).is_some()
    }

    /// [`PathTracer::primary_ray_hits`] through the BVH only, for comparing the two
    /// camera-ray paths (benches/tracer.rs, tests).
    #[must_use]
    pub fn primary_ray_hits_bvh(&self, p: PixelCoord, sample: u32, seed: u64) -> bool {
        let d = self
            .camera
            .direction(p.x, p.y, self.camera_jitter(p, sample, seed));
        self.geo
            .intersect(self.camera.origin, d, f32::INFINITY, bvh::NONE)
            .is_some()
    }

    /// The position inside pixel `p` of its sample `sample` under `seed`: the first 2-D
    /// value of the path's numbers, as the paths draw it.
    #[must_use]
    pub fn camera_jitter(&self, p: PixelCoord, sample: u32, seed: u64) -> glam::Vec2 {
        use sampler::{Dim, PathSampler};
        match self.sampler {
            crate::scene::SamplerKind::Sobol => {
                sampler::SobolSample::for_sample(seed, p.x, p.y, sample).get_2d(Dim::Camera)
            }
            crate::scene::SamplerKind::ZSobol => {
                sampler::SobolSample::z_ordered(seed, p.x, p.y, sample, self.z_order)
                    .get_2d(Dim::Camera)
            }
            crate::scene::SamplerKind::Independent => {
                rng::Rng::for_sample(seed, p.x, p.y, sample).get_2d(Dim::Camera)
            }
        }
    }
}

impl PathTracer {
    /// [`PixelOracle::estimate_with`]; the albedo (the mean first-hit texture albedo over
    /// the same kept samples, `None` unless every one hit a textured Lambertian surface,
    /// [`PixelOracle::radiance_albedo_with`]) only with `ALBEDO`. The radiance is the same
    /// bit for bit either way, and the variance is summed beside it without touching it.
    fn sample_mean<const ALBEDO: bool>(&self, p: PixelCoord, samples: u32, seed: u64) -> Estimate {
        // Without ALBEDO it stays `None` (nothing summed).
        let mut albedo = ALBEDO.then_some(Vec3::ZERO);
        let acc = self.add_paths::<ALBEDO>(p, samples, seed, SampleSum::default(), &mut albedo);
        let (kept, rays) = (acc.kept, u32::try_from(acc.rays).unwrap_or(u32::MAX));
        if kept == 0 {
            return Estimate {
                radiance: Rgb::ZERO,
                variance: Rgb::INFINITY,
                albedo: None,
                rays,
            };
        }
        let k = f64::from(kept);
        let s1 = acc.sum.as_dvec3();
        let variance = if kept < 2 {
            Rgb::INFINITY
        } else {
            ((acc.sum_sq - s1 * s1 / k).max(glam::DVec3::ZERO) / (k * (k - 1.0))).as_vec3()
        };
        let albedo = albedo.map(|s| s / kept as f32);
        // The sum of finite samples can still overflow f32 (radiance near f32::MAX).
        Estimate {
            radiance: acc.mean(),
            variance: if variance.is_finite() {
                variance
            } else {
                Rgb::INFINITY
            },
            albedo,
            rays,
        }
    }

    /// `acc` with the next `count` paths of pixel `p` added, and (with `ALBEDO`) their
    /// first-hit texture albedos summed into `albedo` (`None` once any kept path missed a
    /// textured Lambertian surface). Paths that come out NaN or infinite are dropped.
    fn add_paths<const ALBEDO: bool>(
        &self,
        p: PixelCoord,
        count: u32,
        seed: u64,
        acc: SampleSum,
        albedo: &mut Option<Vec3>,
    ) -> SampleSum {
        match self.sampler {
            crate::scene::SamplerKind::Sobol => {
                self.add_paths_of::<ALBEDO, _>(p, count, acc, albedo, |i| {
                    sampler::SobolSample::for_sample(seed, p.x, p.y, i)
                })
            }
            crate::scene::SamplerKind::ZSobol => {
                self.add_paths_of::<ALBEDO, _>(p, count, acc, albedo, |i| {
                    sampler::SobolSample::z_ordered(seed, p.x, p.y, i, self.z_order)
                })
            }
            crate::scene::SamplerKind::Independent => {
                self.add_paths_of::<ALBEDO, _>(p, count, acc, albedo, |i| {
                    rng::Rng::for_sample(seed, p.x, p.y, i)
                })
            }
        }
    }

    /// [`PathTracer::add_paths`] with path `i`'s numbers drawn by `sampler_of(i)`.
    #[inline(always)]
    fn add_paths_of<const ALBEDO: bool, S: sampler::PathSampler>(
        &self,
        p: PixelCoord,
        count: u32,
        mut acc: SampleSum,
        albedo: &mut Option<Vec3>,
        sampler_of: impl Fn(u32) -> S,
    ) -> SampleSum {
        let mut rays = 0u32;
        let kept_before = acc.kept;
        let end = acc.next.saturating_add(count);
        for i in acc.next..end {
            let mut rng = sampler_of(i);
            let (v, a) = if ALBEDO {
                let mut a = None;
                (
                    self.trace_path_albedo(p.x, p.y, &mut rng, &mut a, &mut rays),
                    a,
                )
            } else {
                (self.trace_path(p.x, p.y, &mut rng, &mut rays), None)
            };
            if v.is_finite() {
                *albedo = albedo.zip(a).map(|(s, a)| s + a);
            }
            acc.add(v);
        }
        let kept = acc.kept - kept_before;
        if kept < count {
            self.dropped
                .fetch_add(u64::from(count - kept), Ordering::Relaxed);
        }
        acc.rays += u64::from(rays);
        acc
    }

    /// The object the camera ray through `jitter` of pixel `p` hits.
    fn object_at(&self, p: PixelCoord, jitter: glam::Vec2) -> ObjectId {
        let d = self.camera.direction(p.x, p.y, jitter);
        self.camera_hit(p.x, p.y, d)
            .map_or(BACKGROUND_ID, |h| self.object_of(&h))
    }

    /// The object a camera ray's hit belongs to.
    fn object_of(&self, h: &bvh::Hit) -> ObjectId {
        self.geo
            .info
            .get(h.prim as usize)
            .map_or(BACKGROUND_ID, |i| i.object)
    }

    /// The albedo of the textured Lambertian surface the camera ray through `jitter` of
    /// pixel `p` hits; `None` for any other material or a miss.
    fn albedo_at(&self, p: PixelCoord, jitter: glam::Vec2) -> Option<Vec3> {
        let d = self.camera.direction(p.x, p.y, jitter);
        self.albedo_of(d, self.camera_hit(p.x, p.y, d)?)
    }

    /// [`Self::albedo_at`] of a camera ray along `d` that hit `hit`.
    fn albedo_of(&self, d: Vec3, hit: bvh::Hit) -> Option<Vec3> {
        let s = self.geo.surface(self.camera.origin, d, &hit);
        match self.materials.get(s.info.material as usize)? {
            ResolvedMaterial::Textured(t) => Some(texture::eval(t, s.p, s.uv, &self.images)),
            ResolvedMaterial::Fixed(_)
            | ResolvedMaterial::TexturedMetalRough { .. }
            | ResolvedMaterial::TexturedCoated { .. } => None,
        }
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
        self.sample_mean::<false>(p, samples, seed).radiance
    }

    fn has_textures(&self) -> bool {
        self.features.has_texture
    }

    fn texture_albedo(&self, p: PixelCoord) -> Option<Rgb> {
        if !self.features.has_texture {
            return None;
        }
        footprint_albedo(|k| self.albedo_at(p, ALBEDO_TAPS[k]))
    }

    fn radiance_albedo_with(&self, p: PixelCoord, samples: u32, seed: u64) -> (Rgb, Option<Rgb>) {
        if !self.features.has_texture {
            return (self.radiance_with(p, samples, seed), None);
        }
        let e = self.sample_mean::<true>(p, samples, seed);
        (e.radiance, e.albedo)
    }

    fn radiance_and_albedo(&self, p: PixelCoord) -> (Rgb, Option<Rgb>) {
        self.radiance_albedo_with(p, self.samples_per_pixel, self.seed)
    }

    fn estimate_with(&self, p: PixelCoord, samples: u32, seed: u64) -> Estimate {
        if self.features.has_texture {
            self.sample_mean::<true>(p, samples, seed)
        } else {
            self.sample_mean::<false>(p, samples, seed)
        }
    }

    fn estimate(&self, p: PixelCoord) -> Estimate {
        self.estimate_with(p, self.samples_per_pixel, self.seed)
    }

    fn sample_sum(&self, p: PixelCoord, count: u32, seed: u64, acc: SampleSum) -> SampleSum {
        self.add_paths::<false>(p, count, seed, acc, &mut None)
    }

    fn object_id(&self, p: PixelCoord) -> ObjectId {
        self.object_at(p, glam::Vec2::splat(0.5))
    }

    fn footprint_mixed(&self, p: PixelCoord, centre: ObjectId) -> bool {
        ALBEDO_TAPS.iter().any(|&t| self.object_at(p, t) != centre)
    }

    /// Each tap's camera ray cast once, for its object and (textured scenes) its albedo.
    fn footprint(&self, p: PixelCoord, centre: ObjectId) -> Footprint {
        let taps = ALBEDO_TAPS.map(|t| {
            let d = self.camera.direction(p.x, p.y, t);
            (d, self.camera_hit(p.x, p.y, d))
        });
        let mixed = taps
            .iter()
            .any(|(_, h)| h.as_ref().map_or(BACKGROUND_ID, |h| self.object_of(h)) != centre);
        let albedo = if self.features.has_texture {
            footprint_albedo(|k| taps[k].1.and_then(|h| self.albedo_of(taps[k].0, h)))
        } else {
            None
        };
        Footprint { mixed, albedo }
    }

    fn surface_normal(&self, p: PixelCoord) -> Vec3 {
        self.centre_hit(p).1
    }

    fn aux_features(&self, p: PixelCoord) -> AuxFeatures {
        self.aux_at(p)
    }

    fn centre_hit(&self, p: PixelCoord) -> (ObjectId, Vec3) {
        let d = self.camera.direction(p.x, p.y, glam::Vec2::splat(0.5));
        self.camera_hit(p.x, p.y, d)
            .map_or((BACKGROUND_ID, Vec3::ZERO), |h| {
                let id = self.object_of(&h);
                let n = self.geo.surface(self.camera.origin, d, &h).ns;
                (id, if n.dot(d) > 0.0 { -n } else { n })
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Camera, Light};

    /// [`PixelOracle::texture_albedo`] of every pixel (row-major, in parallel), or `None` when
    /// the oracle has no texture.
    fn texture_albedo_map(oracle: &impl PixelOracle) -> Option<Vec<Option<Rgb>>> {
        if !oracle.has_textures() {
            return None;
        }
        Some(every_pixel(oracle, |p| oracle.texture_albedo(p)))
    }

    /// A checkered floor (squares of 0.6, albedo 0.8 / 0.2) seen from straight above, lit by
    /// a vertical directional light, with a plain diffuse sphere on it; direct light only,
    /// so every estimate is exact.
    fn checker_floor(textured: bool) -> Scene {
        let (a, b) = (Vec3::splat(0.8), Vec3::splat(0.2));
        let floor = if textured {
            Texture::Checker { scale: 0.6, a, b }
        } else {
            Texture::Constant(a)
        };
        fixtures::scene(
            32,
            32,
            Camera {
                position: Vec3::new(0.0, 3.0, 0.0),
                look_at: Vec3::ZERO,
                up: Vec3::NEG_Z,
                fov_y_deg: 60.0,
            },
            vec![
                Material::Diffuse { albedo: floor },
                Material::Diffuse {
                    albedo: Texture::Constant(Vec3::splat(0.5)),
                },
            ],
            vec![
                fixtures::quad(
                    Vec3::new(-4.0, 0.0, 4.0),
                    Vec3::new(8.0, 0.0, 0.0),
                    Vec3::new(0.0, 0.0, -8.0),
                    0,
                ),
                Shape::Sphere {
                    center: Vec3::new(1.2, 0.3, 1.2),
                    radius: 0.3,
                    material: 1,
                },
            ],
            vec![Light::Directional {
                direction: Vec3::NEG_Y,
                irradiance: Vec3::ONE,
            }],
            (2, 1, 5),
        )
    }

    #[test]
    fn an_estimate_counts_the_rays_its_paths_cast() {
        // 2 paths of one bounce on the lit floor: each a camera ray, a shadow ray towards
        // the directional light and the bounce ray (which ends the path, hit or miss).
        let t = PathTracer::new(&checker_floor(false));
        assert_eq!(t.estimate(PixelCoord::new(5, 5)).rays, 2 * 3);
    }

    #[test]
    fn a_footprint_is_mixed_exactly_where_its_taps_see_two_objects() {
        let t = PathTracer::new(&checker_floor(false));
        let PixelAnalysis {
            ids,
            normals,
            mixed,
            albedo,
        } = analysis_maps(&t);
        assert!(albedo.is_none(), "no texture, no albedo map");
        assert_eq!(ids, object_id_map(&t), "the centre ray is the id map's ray");
        for (i, n) in normals.iter().enumerate() {
            let p = PixelCoord::new((i % 32) as u32, (i / 32) as u32);
            assert_eq!(*n, t.surface_normal(p), "{p:?}");
            assert_eq!(ids.pixels()[i], t.object_id(p), "{p:?}");
        }
        let floor = *ids.get(0, 0);
        let sphere = ids.pixels().iter().position(|&id| id != floor);
        let inside = sphere.map(|i| i + 1).expect("the sphere is in view");
        let mut n = 0;
        for (i, &m) in mixed.iter().enumerate() {
            let p = PixelCoord::new((i % 32) as u32, (i / 32) as u32);
            let seen: Vec<ObjectId> = ALBEDO_TAPS.iter().map(|&j| t.object_at(p, j)).collect();
            assert_eq!(m, seen.iter().any(|&id| id != ids.pixels()[i]), "{p:?}");
            n += usize::from(m);
        }
        // The sphere's silhouette: a ring of pixels, none inside it or on the open floor.
        assert!((8..60).contains(&n), "{n} mixed pixels");
        let row = 32 * (inside / 32 + 2);
        let centre = (row..row + 32).find(|&i| ids.pixels()[i] != floor && !mixed[i]);
        assert!(
            centre.is_some() && !mixed[5 * 32 + 5],
            "inside the sphere, on the floor"
        );
    }

    #[test]
    fn texture_albedo_is_the_footprint_mean_on_textured_lambertian_surfaces_only() {
        let t = PathTracer::new(&checker_floor(true));
        assert!(t.has_textures());
        let map = texture_albedo_map(&t).expect("a textured scene has a map");
        assert_eq!(map.len(), 32 * 32);
        let analysis = analysis_maps(&t);
        assert_eq!(
            analysis.albedo.as_ref(),
            Some(&map),
            "the analysis casts each tap once for its object and its albedo, same albedos"
        );
        assert_eq!(
            analysis.mixed,
            analysis_maps(&PathTracer::new(&checker_floor(false))).mixed
        );
        let floor_id = t.object_id(PixelCoord::new(0, 0));
        let (mut inside, mut edge, mut none) = (0, 0, 0);
        for (i, a) in map.iter().enumerate() {
            let p = PixelCoord::new((i % 32) as u32, (i / 32) as u32);
            // The plain sphere is not textured (nor is a pixel partly on it).
            if t.object_id(p) != floor_id {
                assert_eq!(*a, None, "{p:?}");
            }
            match a {
                None => none += 1,
                Some(a) => {
                    let v = a.x;
                    assert!(a.y == v && a.z == v, "grey texture: {a:?}");
                    if v == 0.8 || v == 0.2 {
                        inside += 1;
                    } else {
                        // A pixel across a checker edge: a mean of the 4 taps.
                        let taps = (v - 0.2) / 0.6 * 4.0;
                        assert!((taps - taps.round()).abs() < 1e-4, "{v}");
                        edge += 1;
                    }
                }
            }
        }
        assert!(
            inside > 600 && edge > 50 && none > 10,
            "{inside} {edge} {none}"
        );
        // L = albedo × E/π: radiance ÷ albedo is the same on both colours of the checker
        // (away from edges, where the radiance's jittered samples can cross to the other
        // colour; left half, away from the sphere's shadow).
        let e = |i: usize| {
            let p = PixelCoord::new((i % 32) as u32, (i / 32) as u32);
            t.radiance(p).x / map[i].unwrap().x
        };
        let whole: Vec<usize> = (32..map.len() - 32)
            .filter(|&i| (1..15).contains(&(i % 32)))
            .filter(|&i| {
                let a = map[i];
                a.is_some_and(|a| a.x == 0.8 || a.x == 0.2)
                    && [i - 33, i - 32, i - 31, i - 1, i + 1, i + 31, i + 32, i + 33]
                        .iter()
                        .all(|&j| map[j] == a)
            })
            .collect();
        assert!(
            whole.iter().any(|&i| map[i].unwrap().x == 0.8)
                && whole.iter().any(|&i| map[i].unwrap().x == 0.2)
        );
        let e0 = e(whole[0]);
        assert!(e0 > 0.0);
        for &i in &whole {
            assert!(
                (e(i) - e0).abs() <= 1e-4 * e0,
                "pixel {i}: {} vs {e0}",
                e(i)
            );
        }
        // A traced pixel's albedo is read off its own paths: the mean over exactly the
        // camera rays the radiance averaged, and the radiance is unchanged bit for bit.
        for i in (0..map.len()).step_by(7) {
            let p = PixelCoord::new((i % 32) as u32, (i / 32) as u32);
            let (v, a) = t.radiance_albedo_with(p, 5, 9);
            assert_eq!(v.to_array(), t.radiance_with(p, 5, 9).to_array());
            let taps: Option<Vec<Vec3>> = (0..5)
                .map(|k| t.albedo_at(p, t.camera_jitter(p, k, 9)))
                .collect();
            let want = taps.map(|v| v.iter().fold(Vec3::ZERO, |s, &a| s + a) / 5.0);
            assert_eq!(a, want, "{p:?}");
        }
        // A scene without texture builds no map.
        let plain = PathTracer::new(&checker_floor(false));
        assert!(!plain.has_textures());
        assert!(texture_albedo_map(&plain).is_none());
        assert_eq!(plain.texture_albedo(PixelCoord::new(3, 3)), None);
    }
}
