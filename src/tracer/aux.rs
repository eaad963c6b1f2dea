//! The denoiser's auxiliary images (OIDN `RT` filter: `albedo`, `normal`), one
//! [`PixelOracle::aux_features`] per pixel.
//!
//! The path tracer's features ([`PathTracer::aux_at`]) follow OIDN's doc/api.md ("Albedos",
//! "Normals", research/adaptive-sampling-denoising.md §1):
//!
//! - Features of the first surface that is not a perfect specular one. Mirrors, and lobes
//!   narrower than [`MIRROR_ALPHA`], are followed along their reflection (at most
//!   [`MAX_DELTA`] of them) and report `weight × ` what they reflect; smooth glass reports
//!   the Fresnel blend F·reflected + (1 − F)·tint·transmitted at the first glass surface of
//!   a path and the likelier branch alone at the next ones (deterministic: no random
//!   choice, so the maps are noise-free and may be declared `cleanAux`).
//! - Albedo per material: diffuse and coated diffuse (the clear coat ignored, as OIDN
//!   allows), the base colour (textures looked up at the hit); glossy, its tint; rough
//!   metal, its reflectance at normal incidence; metallic-roughness, its base colour;
//!   an emitter, its emitted radiance toward the ray clamped to [0, 1]; a miss, the
//!   environment's radiance clamped to [0, 1] (black without one), normal zero.
//! - Normal: the shading normal, turned to face the ray that meets it (world space).
//! - The beauty image is a box-filtered mean over jittered camera rays, so each feature is
//!   the mean over a 4×4 grid of sub-pixel positions, of which the 4 corners are cast
//!   first: where their features agree (a pixel inside one surface, features linear
//!   across it) their mean is the pixel's, else all 16 are averaged (edges).

use super::bvh::{Hit, Surface, NONE};
use super::material::{fresnel_conductor, fresnel_dielectric, Bsdf};
use super::sampling::{offset_ray_origin, Frame};
use super::{per_pixel, AuxFeatures, PathTracer, PixelOracle};
use crate::cancel::{CancelToken, Cancelled};
use crate::raster::{Image, LinearImage, PixelCoord};
use glam::{Vec2, Vec3};

/// GGX α at or below which a glossy or metallic lobe counts as a mirror and is followed
/// (roughness 0.05). Cycles follows lobes up to α = 0.075 but along *sampled* directions,
/// so its features blur as the reflection does; ours follow the one mirror direction, so
/// only a lobe whose reflection is sharp to a few pixels (a spread of ~2α = 0.3°) may be.
pub const MIRROR_ALPHA: f32 = 0.0025;

/// Perfect-specular vertices followed at most (two facing mirrors stop here).
pub const MAX_DELTA: u32 = 8;

/// Side of the sub-pixel grid the features are averaged over.
const GRID: usize = 4;
/// Indices (row-major in the grid) of its 4 corners, cast first.
const CORNERS: [usize; 4] = [0, GRID - 1, GRID * (GRID - 1), GRID * GRID - 1];
/// The corners agree when every albedo channel is within this of the first corner's
/// (about 5/255)...
const ALBEDO_TOL: f32 = 0.02;
/// ... and every normal component within this (about 3°).
const NORMAL_TOL: f32 = 0.05;

/// The albedo and normal images of a whole frame.
#[derive(Clone, Debug)]
pub struct AuxMaps {
    pub albedo: LinearImage,
    pub normal: LinearImage,
}

/// Every pixel's [`PixelOracle::aux_features`], in parallel batches, cancellable.
pub fn aux_maps(oracle: &impl PixelOracle, cancel: &CancelToken) -> Result<AuxMaps, Cancelled> {
    let (w, h) = oracle.size();
    let pixels: Vec<PixelCoord> = (0..h)
        .flat_map(|y| (0..w).map(move |x| PixelCoord { x, y }))
        .collect();
    let features = per_pixel(&pixels, cancel, |p| oracle.aux_features(p))?;
    let image = |f: fn(&AuxFeatures) -> glam::Vec3| {
        Image::from_vec(w, h, features.iter().map(f).collect()).expect("one feature per pixel")
    };
    Ok(AuxMaps {
        albedo: image(|a| a.albedo),
        normal: image(|a| a.normal),
    })
}

/// Sub-pixel position `i` (row-major) of the [`GRID`]×[`GRID`] pattern: cell centres.
fn grid_tap(i: usize) -> Vec2 {
    let cell = |k: usize| (k as f32 + 0.5) / GRID as f32;
    Vec2::new(cell(i % GRID), cell(i / GRID))
}

/// How a surface's features are made ([`lobe`]).
enum Lobe {
    /// Its own albedo, and its normal.
    Own(Vec3),
    /// A mirror reflection followed: `rest + weight × ` the reflected albedo, and the
    /// normals blended `1 − share` (its own) to `share` (the reflected one).
    Mirror {
        rest: Vec3,
        weight: Vec3,
        share: f32,
    },
    /// A smooth dielectric interface ([`PathTracer::aux_glass`]).
    Glass { ior: f32, tint: Vec3 },
}

/// The rule for `bsdf`, met by a ray at `cos_o` (|cos| to the shading normal).
fn lobe(bsdf: Bsdf, cos_o: f32) -> Lobe {
    let mirror = |weight| Lobe::Mirror {
        rest: Vec3::ZERO,
        weight,
        share: 1.0,
    };
    match bsdf {
        Bsdf::Diffuse { albedo } | Bsdf::CoatedDiffuse { albedo, .. } => Lobe::Own(albedo),
        Bsdf::Glossy { albedo, alpha } if alpha <= MIRROR_ALPHA => mirror(albedo),
        Bsdf::Glossy { albedo, .. } => Lobe::Own(albedo),
        // A smooth metal tints what it reflects by its Fresnel term at that angle; a rough
        // one reports its reflectance at normal incidence (OIDN "Albedos").
        Bsdf::Conductor { eta, k, alpha } if alpha <= MIRROR_ALPHA => {
            mirror(fresnel_conductor(cos_o, eta, k))
        }
        Bsdf::Conductor { eta, k, .. } => Lobe::Own(fresnel_conductor(1.0, eta, k)),
        // glTF's metal part is a mirror when smooth (Schlick's Fresnel from F0 = base, as
        // material.rs evaluates it); its dielectric part keeps the base colour here.
        Bsdf::MetalRough {
            base,
            metallic,
            alpha,
        } if alpha <= MIRROR_ALPHA && metallic > 0.0 => {
            let f = base + (Vec3::ONE - base) * (1.0 - cos_o.clamp(0.0, 1.0)).powi(5);
            Lobe::Mirror {
                rest: base * (1.0 - metallic),
                weight: f * metallic,
                share: metallic,
            }
        }
        Bsdf::MetalRough { base, .. } => Lobe::Own(base),
        Bsdf::Mirror { reflectance } => mirror(reflectance),
        Bsdf::Dielectric { ior, tint } => Lobe::Glass { ior, tint },
        Bsdf::Black => Lobe::Own(Vec3::ZERO),
    }
}

/// `v` with NaN as 0, clamped to [lo, hi].
fn clamp_finite(v: Vec3, lo: f32, hi: f32) -> Vec3 {
    Vec3::from_array(
        v.to_array()
            .map(|c| if c.is_nan() { 0.0 } else { c.clamp(lo, hi) }),
    )
}

/// Whether two taps' features agree within [`ALBEDO_TOL`] and [`NORMAL_TOL`].
fn agree(a: &AuxFeatures, b: &AuxFeatures) -> bool {
    (a.albedo - b.albedo).abs().max_element() <= ALBEDO_TOL
        && (a.normal - b.normal).abs().max_element() <= NORMAL_TOL
}

impl PathTracer {
    /// [`PixelOracle::aux_features`] of pixel `p`: the mean of the features its sub-pixel
    /// grid's camera rays see ([`grid_tap`]), the 4 corners alone where they agree.
    pub(crate) fn aux_at(&self, p: PixelCoord) -> AuxFeatures {
        let corners = CORNERS.map(|i| self.aux_tap(p, grid_tap(i)));
        let (mut albedo, mut normal) = (Vec3::ZERO, Vec3::ZERO);
        let n = if corners.iter().all(|c| agree(c, &corners[0])) {
            for c in &corners {
                albedo += c.albedo;
                normal += c.normal;
            }
            CORNERS.len()
        } else {
            for i in 0..GRID * GRID {
                let f = match CORNERS.iter().position(|&c| c == i) {
                    Some(k) => corners[k],
                    None => self.aux_tap(p, grid_tap(i)),
                };
                albedo += f.albedo;
                normal += f.normal;
            }
            GRID * GRID
        };
        let k = 1.0 / n as f32;
        AuxFeatures {
            albedo: clamp_finite(albedo * k, 0.0, 1.0),
            normal: clamp_finite(normal * k, -1.0, 1.0),
        }
    }

    /// The features the camera ray through `jitter` of pixel `p` meets, each in range.
    fn aux_tap(&self, p: PixelCoord, jitter: Vec2) -> AuxFeatures {
        let d = self.camera.direction(p.x, p.y, jitter);
        let hit = self.camera_hit(p.x, p.y, d);
        let f = self.aux_of(self.camera.origin, d, hit, 0, 1);
        AuxFeatures {
            albedo: clamp_finite(f.albedo, 0.0, 1.0),
            normal: clamp_finite(f.normal, -1.0, 1.0),
        }
    }

    /// The features a ray from `o` along `d` meets at `hit`, after `depth` perfect-specular
    /// vertices; `splits` glass surfaces may still send both branches ([`Self::aux_glass`]).
    fn aux_of(&self, o: Vec3, d: Vec3, hit: Option<Hit>, depth: u32, splits: u32) -> AuxFeatures {
        let Some(hit) = hit else {
            return AuxFeatures {
                albedo: self
                    .lights
                    .env_radiance
                    .map_or(Vec3::ZERO, |e| clamp_finite(e, 0.0, 1.0)),
                normal: Vec3::ZERO,
            };
        };
        let s = self.geo.surface(o, d, &hit);
        let normal = if s.ns.dot(d) > 0.0 { -s.ns } else { s.ns };
        if s.info.emitter != NONE {
            let le = self.lights.emitted(s.info.emitter, d, s.ng);
            return AuxFeatures {
                albedo: clamp_finite(le, 0.0, 1.0),
                normal,
            };
        }
        let own = |albedo| AuxFeatures { albedo, normal };
        match lobe(self.bsdf_at(&s), s.ns.dot(d).abs()) {
            Lobe::Own(albedo) => own(albedo),
            Lobe::Mirror {
                rest,
                weight,
                share,
            } => match self.mirror_ray(&s, d).filter(|_| depth < MAX_DELTA) {
                Some((o2, d2)) => {
                    let f = self.aux_follow(o2, d2, hit.prim, depth + 1, splits);
                    AuxFeatures {
                        albedo: rest + weight * f.albedo,
                        normal: normal * (1.0 - share) + f.normal * share,
                    }
                }
                // Not followed: the mirror as a surface of its reflectance.
                None => own(rest + weight),
            },
            Lobe::Glass { ior, tint } if depth < MAX_DELTA => self
                .aux_glass(&s, d, hit.prim, (ior, tint), depth, splits)
                .unwrap_or(own(Vec3::ONE)),
            // Glass not followed: albedo 1 (OIDN "Albedos").
            Lobe::Glass { .. } => own(Vec3::ONE),
        }
    }

    /// [`Self::aux_of`] of the ray from `o` along `d` leaving primitive `skip`.
    fn aux_follow(&self, o: Vec3, d: Vec3, skip: u32, depth: u32, splits: u32) -> AuxFeatures {
        let hit = self.geo.intersect(o, d, f32::INFINITY, skip);
        self.aux_of(o, d, hit, depth, splits)
    }

    /// The mirror reflection of the ray along `d` at two-sided surface `s`, shaded as the
    /// integrator shades it (normals turned toward the ray by the geometric normal): the
    /// offset origin and the direction, or `None` where the reflection goes below the
    /// surface (the path would end there).
    fn mirror_ray(&self, s: &Surface, d: Vec3) -> Option<(Vec3, Vec3)> {
        let wo = -d;
        let (ng, ns) = if wo.dot(s.ng) < 0.0 {
            (-s.ng, -s.ns)
        } else {
            (s.ng, s.ns)
        };
        let wi = (2.0 * wo.dot(ns) * ns - wo).normalize_or_zero();
        (wi.dot(ng) > 0.0).then(|| (offset_ray_origin(s.p, ng), wi))
    }

    /// A smooth dielectric at `s` met along `d` (material.rs `sample_dielectric`: the
    /// geometric normal's side is outside): with `splits` left and both branches possible,
    /// the Fresnel blend of the reflected and transmitted features (OIDN's better glass
    /// albedo), each branch with one split fewer; else the likelier branch alone (the
    /// reflection from F = ½, total internal reflection included), at full weight.
    /// `None` where a branch's direction degenerates.
    fn aux_glass(
        &self,
        s: &Surface,
        d: Vec3,
        prim: u32,
        (ior, tint): (f32, Vec3),
        depth: u32,
        splits: u32,
    ) -> Option<AuxFeatures> {
        let frame = Frame::new(s.ns);
        let wo = frame.to_local(-d);
        let entering = wo.z > 0.0;
        let eta = if entering { 1.0 / ior } else { ior };
        let f = fresnel_dielectric(wo.z.abs(), eta);
        let branch = |local: Vec3, splits: u32| {
            let wi = frame.to_world(local).normalize_or_zero();
            let side = wi.dot(s.ng);
            if side == 0.0 || !side.is_finite() {
                return None;
            }
            let o = offset_ray_origin(s.p, if side > 0.0 { s.ng } else { -s.ng });
            Some(self.aux_follow(o, wi, prim, depth + 1, splits))
        };
        let reflected = Vec3::new(-wo.x, -wo.y, wo.z);
        let sin2_t = eta * eta * (1.0 - wo.z * wo.z).max(0.0);
        let transmitted = (sin2_t < 1.0).then(|| {
            let cos_t = (1.0 - sin2_t).sqrt();
            Vec3::new(
                -wo.x * eta,
                -wo.y * eta,
                if entering { -cos_t } else { cos_t },
            )
        });
        match transmitted {
            Some(t) if splits > 0 && f > 0.0 && f < 1.0 => {
                let r = branch(reflected, splits - 1)?;
                let t = branch(t, splits - 1)?;
                Some(AuxFeatures {
                    albedo: f * r.albedo + (1.0 - f) * tint * t.albedo,
                    normal: f * r.normal + (1.0 - f) * t.normal,
                })
            }
            Some(t) if f < 0.5 => branch(t, splits).map(|t| AuxFeatures {
                albedo: tint * t.albedo,
                ..t
            }),
            _ => branch(reflected, splits),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Camera, Light, Material, Scene, Shape, Texture};
    use crate::tracer::fixtures;

    /// A camera at the origin looking down −z (narrow field: every ray within 3° of the
    /// axis) at a `w`×`h` image of `shapes`.
    fn view(
        w: u32,
        h: u32,
        materials: Vec<Material>,
        shapes: Vec<Shape>,
        lights: Vec<Light>,
    ) -> Scene {
        let camera = Camera {
            position: Vec3::ZERO,
            look_at: Vec3::NEG_Z,
            up: Vec3::Y,
            fov_y_deg: 5.0,
        };
        fixtures::scene(w, h, camera, materials, shapes, lights, (1, 4, 1))
    }

    fn diffuse(c: Vec3) -> Material {
        Material::Diffuse {
            albedo: Texture::Constant(c),
        }
    }

    /// A 20×20 square at depth `z` across the whole view, its normal `+z` or `−z` (`toward`
    /// the camera or away).
    fn wall(z: f32, toward: bool, material: u32) -> Shape {
        let (u, v) = (Vec3::new(20.0, 0.0, 0.0), Vec3::new(0.0, 20.0, 0.0));
        let corner = Vec3::new(-10.0, -10.0, z);
        if toward {
            fixtures::quad(corner, u, v, material)
        } else {
            fixtures::quad(corner, v, u, material)
        }
    }

    fn features(s: &Scene, x: u32, y: u32) -> AuxFeatures {
        PathTracer::new(s).aux_features(PixelCoord::new(x, y))
    }

    fn near(a: Vec3, b: Vec3, tol: f32) -> bool {
        (a - b).abs().max_element() <= tol
    }

    #[test]
    fn a_diffuse_wall_reports_its_reflectance_and_a_normal_facing_the_camera() {
        let red = Vec3::new(0.6, 0.4, 0.2);
        for toward in [true, false] {
            let s = view(
                8,
                8,
                vec![diffuse(red)],
                vec![wall(-3.0, toward, 0)],
                vec![],
            );
            let t = PathTracer::new(&s);
            for (x, y) in [(0, 0), (3, 4), (7, 7)] {
                let f = t.aux_features(PixelCoord::new(x, y));
                assert!(near(f.albedo, red, 1e-6), "{f:?}");
                // The normal is the wall's, turned toward the camera (+z) either way.
                assert!(near(f.normal, Vec3::Z, 1e-6), "{toward} {f:?}");
            }
        }
    }

    #[test]
    fn materials_map_to_their_albedo() {
        let cases = [
            (
                Material::Glossy {
                    albedo: Vec3::new(0.9, 0.5, 0.1),
                    roughness: 0.4,
                },
                Vec3::new(0.9, 0.5, 0.1),
            ),
            (
                Material::Conductor {
                    eta: Vec3::splat(0.2),
                    k: Vec3::splat(3.9),
                    roughness: 0.3,
                },
                fresnel_conductor(1.0, Vec3::splat(0.2), Vec3::splat(3.9)),
            ),
            (
                Material::CoatedDiffuse {
                    reflectance: Texture::Constant(Vec3::new(0.2, 0.7, 0.3)),
                    roughness: 0.0,
                    ior: 1.5,
                },
                Vec3::new(0.2, 0.7, 0.3),
            ),
            (
                Material::MetallicRoughness {
                    base_color: Texture::Constant(Vec3::new(0.3, 0.3, 0.8)),
                    metallic: 1.0,
                    roughness: 0.5,
                },
                Vec3::new(0.3, 0.3, 0.8),
            ),
            // An emitter seen directly: its radiance clamped to [0, 1].
            (
                Material::Emissive {
                    radiance: Vec3::new(5.0, 0.3, 0.0),
                    two_sided: false,
                },
                Vec3::new(1.0, 0.3, 0.0),
            ),
        ];
        for (m, want) in cases {
            let s = view(4, 4, vec![m], vec![wall(-3.0, true, 0)], vec![]);
            let f = features(&s, 1, 2);
            assert!(near(f.albedo, want, 1e-5), "{m:?}: {f:?}");
            assert!(near(f.normal, Vec3::Z, 1e-6), "{m:?}: {f:?}");
        }
        // A checkered wall: each pixel inside one square reports that square's colour.
        let (a, b) = (Vec3::new(0.8, 0.1, 0.1), Vec3::new(0.1, 0.1, 0.8));
        let checker = Material::Diffuse {
            albedo: Texture::Checker { scale: 0.05, a, b },
        };
        let s = view(32, 32, vec![checker], vec![wall(-3.0, true, 0)], vec![]);
        let t = PathTracer::new(&s);
        let (mut pure, mut blend) = (0, 0);
        for y in 0..32 {
            for x in 0..32 {
                let f = t.aux_features(PixelCoord::new(x, y));
                if near(f.albedo, a, 1e-6) || near(f.albedo, b, 1e-6) {
                    pure += 1;
                } else {
                    // Across a checker edge: a mean of 16 taps of a and b.
                    let k = (f.albedo.x - b.x) / (a.x - b.x) * 16.0;
                    assert!(
                        (k - k.round()).abs() < 1e-3 && (f.albedo.y - 0.1).abs() < 1e-6,
                        "{f:?}"
                    );
                    blend += 1;
                }
            }
        }
        assert!(pure > 300 && blend > 100, "{pure} {blend}");
    }

    #[test]
    fn a_mirror_reports_what_it_reflects() {
        // A mirror ahead, a red wall behind the camera facing it: the camera sees the wall
        // in the mirror.
        let red = Vec3::new(0.8, 0.1, 0.1);
        for (reflectance, roughness) in [
            (Vec3::ONE, None),
            (Vec3::splat(0.5), None),
            (Vec3::splat(0.7), Some(0.0)),
        ] {
            let mirror = match roughness {
                None => Material::Mirror { reflectance },
                Some(roughness) => Material::Glossy {
                    albedo: reflectance,
                    roughness,
                },
            };
            let s = view(
                8,
                8,
                vec![mirror, diffuse(red)],
                vec![wall(-3.0, true, 0), wall(3.0, false, 1)],
                vec![],
            );
            let f = features(&s, 4, 3);
            assert!(near(f.albedo, reflectance * red, 1e-5), "{f:?}");
            // The red wall's normal, facing the reflected ray (which travels along +z).
            assert!(near(f.normal, Vec3::NEG_Z, 1e-4), "{f:?}");
        }
        // Two facing mirrors: followed MAX_DELTA times, then reported as a mirror.
        let s = view(
            4,
            4,
            vec![Material::Mirror {
                reflectance: Vec3::splat(0.9),
            }],
            vec![wall(-3.0, true, 0), wall(3.0, false, 0)],
            vec![],
        );
        let f = features(&s, 2, 2);
        let want = 0.9f32.powi(MAX_DELTA as i32 + 1);
        assert!(near(f.albedo, Vec3::splat(want), 1e-5), "{f:?} vs {want}");
        assert!(f.normal.z.abs() > 0.99, "{f:?}");
    }

    #[test]
    fn glass_reports_the_fresnel_blend_of_what_it_reflects_and_transmits() {
        // A glass pane ahead of a blue wall, a grey environment behind the camera: the
        // reflection sees the environment (0.5, normal zero), the transmission the wall.
        let blue = Vec3::new(0.1, 0.2, 0.9);
        let tint = Vec3::new(1.0, 0.9, 0.8);
        let env = Vec3::splat(0.5);
        let s = view(
            8,
            8,
            vec![Material::Dielectric { ior: 1.5, tint }, diffuse(blue)],
            vec![wall(-2.0, true, 0), wall(-4.0, true, 1)],
            vec![Light::Environment { radiance: env }],
        );
        // Within 2.5° of normal incidence: F = 0.04 (to 1e-4).
        let f = features(&s, 4, 4);
        let want = 0.04 * env + 0.96 * tint * blue;
        assert!(near(f.albedo, want, 1e-3), "{f:?} vs {want}");
        assert!(near(f.normal, 0.96 * Vec3::Z, 1e-3), "{f:?}");
    }

    #[test]
    fn a_pixel_across_two_objects_blends_them_and_a_miss_has_no_normal() {
        // Left half red, right half green, meeting at x = 0: the middle of a 5-pixel-wide
        // image, so pixel 2's grid has 8 taps on each side.
        let (red, green) = (Vec3::new(0.9, 0.1, 0.1), Vec3::new(0.1, 0.7, 0.1));
        let half = |x0: f32, m| {
            fixtures::quad(
                Vec3::new(x0, -10.0, -3.0),
                Vec3::new(10.0, 0.0, 0.0),
                Vec3::new(0.0, 20.0, 0.0),
                m,
            )
        };
        let s = view(
            5,
            3,
            vec![diffuse(red), diffuse(green)],
            vec![half(-10.0, 0), half(0.0, 1)],
            vec![],
        );
        let t = PathTracer::new(&s);
        let f = |x| t.aux_features(PixelCoord::new(x, 1));
        assert!(near(f(1).albedo, red, 1e-6) && near(f(3).albedo, green, 1e-6));
        assert!(near(f(2).albedo, (red + green) * 0.5, 1e-6), "{:?}", f(2));
        assert!(near(f(2).normal, Vec3::Z, 1e-6));
        // A small sphere before a bright environment: a miss reports the environment
        // (clamped) with no normal; the silhouette a blend whose normal is shorter.
        let env = Vec3::new(2.0, 0.5, 0.0);
        let s = view(
            16,
            16,
            vec![diffuse(red)],
            vec![Shape::Sphere {
                center: Vec3::new(0.0, 0.0, -10.0),
                radius: 0.2,
                material: 0,
            }],
            vec![Light::Environment { radiance: env }],
        );
        let t = PathTracer::new(&s);
        let miss = t.aux_features(PixelCoord::new(0, 0));
        assert_eq!(miss.normal, Vec3::ZERO);
        assert!(near(miss.albedo, Vec3::new(1.0, 0.5, 0.0), 0.0), "{miss:?}");
        let centre = t.aux_features(PixelCoord::new(8, 8));
        assert!(near(centre.albedo, red, 1e-6), "{centre:?}");
        let mut edges = 0;
        for y in 0..16 {
            for x in 0..16 {
                let f = t.aux_features(PixelCoord::new(x, y));
                let len = f.normal.length();
                if len > 0.0 && len < 0.95 {
                    edges += 1;
                    // Between the sphere's red and the environment's (1, 0.5, 0).
                    let (lo, hi) = (red.min(miss.albedo), red.max(miss.albedo));
                    assert!(f.albedo.cmpge(lo - 1e-6).all() && f.albedo.cmple(hi + 1e-6).all());
                }
            }
        }
        assert!(edges >= 8, "{edges} silhouette pixels");
    }

    /// Each bundled scene, shrunk to 64×48.
    fn bundled() -> Vec<(String, Scene)> {
        use crate::scene::{parse_scene, Limits, SceneOrigin};
        let mut names: Vec<_> = std::fs::read_dir("scenes")
            .expect("scenes/")
            .filter_map(|e| {
                let p = e.ok()?.path();
                (p.extension()? == "json").then_some(p)
            })
            .collect();
        names.sort();
        assert!(names.len() >= 5, "{names:?}");
        names
            .into_iter()
            .map(|p| {
                let json = std::fs::read_to_string(&p).expect("bundled scene");
                let origin = SceneOrigin::File {
                    dir: "scenes".into(),
                };
                let mut s = parse_scene(&json, &origin, &Limits::command_line()).expect("valid");
                (s.width, s.height) = (64, 48);
                (p.display().to_string(), s)
            })
            .collect()
    }

    #[test]
    fn every_bundled_scene_has_features_in_range() {
        for (name, s) in bundled() {
            let maps = aux_maps(&PathTracer::new(&s), &CancelToken::new()).expect("not cancelled");
            for (a, n) in maps.albedo.pixels().iter().zip(maps.normal.pixels()) {
                assert!(
                    a.is_finite() && a.min_element() >= 0.0 && a.max_element() <= 1.0,
                    "{name}: {a}"
                );
                assert!(n.is_finite() && n.abs().max_element() <= 1.0, "{name}: {n}");
            }
            // Something is seen, and not everything is one colour.
            let first = maps.albedo.pixels()[0];
            assert!(maps.albedo.pixels().iter().any(|a| *a != first), "{name}");
            assert!(
                maps.normal.pixels().iter().any(|n| *n != Vec3::ZERO),
                "{name}"
            );
        }
    }

    #[test]
    fn aux_maps_are_the_same_on_every_call_and_thread_count() {
        let bits = |m: &AuxMaps| -> Vec<[u32; 6]> {
            m.albedo
                .pixels()
                .iter()
                .zip(m.normal.pixels())
                .map(|(a, n)| {
                    let (a, n) = (a.to_array(), n.to_array());
                    [a[0], a[1], a[2], n[0], n[1], n[2]].map(f32::to_bits)
                })
                .collect()
        };
        for (name, s) in bundled() {
            let t = PathTracer::new(&s);
            let run = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("pool");
                pool.install(|| bits(&aux_maps(&t, &CancelToken::new()).expect("not cancelled")))
            };
            let one = run(1);
            assert_eq!(one, run(1), "{name}");
            assert_eq!(one, run(3), "{name}");
        }
    }
}

/// Cost and edge quality of the sub-pixel patterns (release build, by hand; numbers in the
/// notes): `cargo test --release --lib tracer::aux::measure -- --ignored --nocapture`.
#[cfg(test)]
mod measure {
    use super::*;
    use crate::scene::{parse_scene, Limits, SceneOrigin};
    use std::time::Instant;

    fn load(name: &str, w: u32, h: u32) -> crate::scene::Scene {
        let json = std::fs::read_to_string(format!("scenes/{name}.json")).expect("scene");
        let origin = SceneOrigin::File {
            dir: "scenes".into(),
        };
        let mut s = parse_scene(&json, &origin, &Limits::command_line()).expect("valid");
        (s.width, s.height) = (w, h);
        s
    }

    /// The mean features over `taps` (no adaptivity).
    fn mean_over(t: &PathTracer, p: PixelCoord, taps: &[Vec2]) -> AuxFeatures {
        let (mut a, mut n) = (Vec3::ZERO, Vec3::ZERO);
        for &j in taps {
            let f = t.aux_tap(p, j);
            a += f.albedo;
            n += f.normal;
        }
        AuxFeatures {
            albedo: a / taps.len() as f32,
            normal: n / taps.len() as f32,
        }
    }

    fn grid(k: usize) -> Vec<Vec2> {
        (0..k * k)
            .map(|i| {
                Vec2::new(
                    ((i % k) as f32 + 0.5) / k as f32,
                    ((i / k) as f32 + 0.5) / k as f32,
                )
            })
            .collect()
    }

    fn best_of(n: usize, f: &dyn Fn()) -> f64 {
        (0..n)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    #[ignore = "a measurement, run by hand in release"]
    fn cost_and_edge_quality() {
        let cancel = CancelToken::new();
        for name in ["cornell-box", "door", "spheres-smooth", "cellar"] {
            let t = PathTracer::new(&load(name, 1024, 768));
            let render = best_of(3, &|| {
                let _ = crate::tracer::render_reference_with(&t, Some((1, 7)), &cancel, &|_, _| {});
            });
            let aux = best_of(3, &|| {
                let _ = aux_maps(&t, &cancel);
            });
            eprintln!(
                "{name} 1024x768: 1-spp render {render:.3} s, aux_maps {aux:.3} s ({:.0} %)",
                100.0 * aux / render
            );
            // Edge quality at 256x192 against a 16x16 grid per pixel.
            let t = PathTracer::new(&load(name, 256, 192));
            let reference = grid(16);
            let mut centre_taps = crate::tracer::ALBEDO_TAPS.to_vec();
            centre_taps.push(Vec2::splat(0.5));
            let patterns: [(&str, Vec<Vec2>); 4] = [
                ("centre", vec![Vec2::splat(0.5)]),
                ("2x2", crate::tracer::ALBEDO_TAPS.to_vec()),
                ("2x2+centre", centre_taps),
                ("4x4", grid(4)),
            ];
            let pixels: Vec<PixelCoord> = (0..192)
                .flat_map(|y| (0..256).map(move |x| PixelCoord::new(x, y)))
                .collect();
            let r: Vec<AuxFeatures> = pixels
                .iter()
                .map(|&p| mean_over(&t, p, &reference))
                .collect();
            let report = |label: &str, f: &dyn Fn(PixelCoord) -> AuxFeatures| {
                let (mut ea, mut en, mut worst, mut bad) = (0.0f64, 0.0f64, 0.0f32, 0usize);
                for (p, want) in pixels.iter().zip(&r) {
                    let got = f(*p);
                    let da = (got.albedo - want.albedo).abs().max_element();
                    let dn = (got.normal - want.normal).abs().max_element();
                    ea += f64::from(da);
                    en += f64::from(dn);
                    worst = worst.max(da.max(dn));
                    bad += usize::from(da.max(dn) > 0.05);
                }
                let k = pixels.len() as f64;
                eprintln!(
                    "  {label:>11}: mean |albedo err| {:.5}, mean |normal err| {:.5}, worst {worst:.3}, pixels off by > 0.05: {bad}",
                    ea / k,
                    en / k
                );
            };
            for (label, taps) in &patterns {
                report(label, &|p| mean_over(&t, p, taps));
            }
            report("adaptive", &|p| t.aux_at(p));
            let refined = pixels
                .iter()
                .filter(|&&p| {
                    let c = CORNERS.map(|i| t.aux_tap(p, grid_tap(i)));
                    !c.iter().all(|f| agree(f, &c[0]))
                })
                .count();
            eprintln!(
                "  adaptive refines {refined} of {} pixels ({:.1} %)",
                pixels.len(),
                100.0 * refined as f64 / pixels.len() as f64
            );
        }
    }
}
