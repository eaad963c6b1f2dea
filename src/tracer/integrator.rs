//! Unidirectional path tracing with next-event estimation and multiple importance
//! sampling (Veach 1997, ch. 9; power heuristic β = 2), Russian roulette after a few
//! bounces, `max_bounces` scattering events at most (pbrt's `maxdepth` convention:
//! 0 = only directly visible emitters, 1 = direct lighting).

// `!(x > 0.0)` is used on purpose: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::bvh::NONE;
use super::material::Bsdf;
use super::rng::Rng;
use super::sampling::{offset_ray_origin, power_heuristic, Frame};
use super::PathTracer;
use glam::Vec3;
use std::f32::consts::PI;

/// Bounces before Russian roulette may end a path (its variance cost is low only once
/// the throughput has dropped).
pub const RR_START: u32 = 3;
/// Shadow rays stop this fraction short of the sampled light point, so the light's own
/// surface (and rounding in t) never counts as an occluder.
const SHADOW_SHRINK: f32 = 1.0 - 1e-4;

impl PathTracer {
    /// One path through pixel (x, y); its random numbers come from `rng` only. Adds the
    /// rays it casts (camera, bounce and shadow rays) to `rays`: what a path costs.
    #[inline]
    pub(crate) fn trace_path(&self, x: u32, y: u32, rng: &mut Rng, rays: &mut u32) -> Vec3 {
        self.trace_path_impl::<false>(x, y, rng, &mut None, rays)
    }

    /// [`PathTracer::trace_path`], also reporting in `albedo` the texture albedo of the
    /// camera ray's hit when it is a textured Lambertian surface (`None` otherwise: another
    /// material, an emitter, a miss). Read off the BSDF the path builds anyway, so it costs
    /// nothing; the path and its random numbers are exactly `trace_path`'s.
    #[inline]
    pub(crate) fn trace_path_albedo(
        &self,
        x: u32,
        y: u32,
        rng: &mut Rng,
        albedo: &mut Option<Vec3>,
        rays: &mut u32,
    ) -> Vec3 {
        *albedo = None;
        self.trace_path_impl::<true>(x, y, rng, albedo, rays)
    }

    #[inline(always)]
    fn trace_path_impl<const ALBEDO: bool>(
        &self,
        x: u32,
        y: u32,
        rng: &mut Rng,
        albedo: &mut Option<Vec3>,
        rays: &mut u32,
    ) -> Vec3 {
        let mut dir = self.camera.direction(x, y, rng.next_2d());
        let mut o = self.camera.origin;
        let mut throughput = Vec3::ONE;
        let mut l = Vec3::ZERO;
        // Pdf of the BSDF sample that produced `dir`, and whether it was a delta lobe
        // (the camera ray counts as one: emitters it sees get full weight).
        let mut prev_pdf = 0.0f32;
        let mut prev_delta = true;
        let mut prev_p = o;
        let mut skip = NONE;
        let max_bounces = self.max_bounces;
        let lights = &self.lights;
        let mut depth = 0u32;
        loop {
            *rays += 1;
            // The camera ray goes through the screen-tile lists (primary.rs), same hit.
            let hit = if depth == 0 {
                self.camera_hit(x, y, dir)
            } else {
                self.geo.intersect(o, dir, f32::INFINITY, skip)
            };
            let Some(hit) = hit else {
                if let Some(env) = lights.env_radiance {
                    let w = if prev_delta || lights.env_pmf == 0.0 {
                        1.0
                    } else {
                        power_heuristic(prev_pdf, lights.env_pmf / (4.0 * PI))
                    };
                    l += throughput * env * w;
                }
                break;
            };
            let s = self.geo.surface(o, dir, &hit);
            if s.info.emitter != NONE {
                let le = lights.emitted(s.info.emitter, dir, s.ng);
                if le != Vec3::ZERO {
                    let w = if prev_delta {
                        1.0
                    } else {
                        power_heuristic(
                            prev_pdf,
                            lights.pdf(s.info.emitter, prev_p, s.p, s.ng, dir),
                        )
                    };
                    l += throughput * le * w;
                }
            }
            if depth >= max_bounces {
                break;
            }
            let bsdf = self.bsdf_at(&s);
            if ALBEDO && depth == 0 {
                if let (Some(super::ResolvedMaterial::Textured(_)), Bsdf::Diffuse { albedo: a }) =
                    (self.materials.get(s.info.material as usize), bsdf)
                {
                    *albedo = Some(a);
                }
            }
            if matches!(bsdf, Bsdf::Black) {
                break;
            }
            let wo_world = -dir;
            // Diffuse and glossy surfaces are two-sided: shade with the normals flipped
            // toward the incoming ray (Tungsten's enable_two_sided_shading). Dielectrics
            // keep the geometric orientation: it says which side is inside.
            let two_sided = !matches!(bsdf, Bsdf::Dielectric { .. });
            let (ng, ns) = if two_sided && wo_world.dot(s.ng) < 0.0 {
                (-s.ng, -s.ns)
            } else {
                (s.ng, s.ns)
            };
            let frame = Frame::new(ns);
            let wo = frame.to_local(wo_world);

            // Next-event estimation (only for non-delta lobes: a delta lobe cannot meet a
            // sampled light direction).
            if self.features.has_lights && !bsdf.is_delta() {
                let u_sel = rng.next_f32();
                let u_l = rng.next_2d();
                if let Some(ls) = lights.sample(s.p, u_sel, u_l) {
                    if ls.wi.dot(ng) > 0.0 {
                        let (fc, bsdf_pdf) = bsdf.eval(wo, frame.to_local(ls.wi));
                        if fc != Vec3::ZERO {
                            let origin = offset_ray_origin(s.p, ng);
                            // Aim from the offset origin at the sampled point itself: the
                            // offset (256 ulps, 2 units at 1e5) moves the origin sideways, and a
                            // ray parallel to `wi` would meet the light's plane before `tmax`.
                            let (shadow_dir, tmax) = if ls.dist.is_finite() {
                                let v = s.p + ls.wi * ls.dist - origin;
                                let len = v.length();
                                (v / len, len * SHADOW_SHRINK)
                            } else {
                                (ls.wi, f32::INFINITY)
                            };
                            *rays += u32::from(shadow_dir.is_finite());
                            if shadow_dir.is_finite()
                                && !self.geo.occluded(origin, shadow_dir, tmax, hit.prim)
                            {
                                let w = if ls.delta {
                                    1.0
                                } else {
                                    power_heuristic(ls.pdf, bsdf_pdf)
                                };
                                l += throughput * fc * ls.weight * w;
                            }
                        }
                    }
                }
            }

            // Continue the path by sampling the BSDF.
            let u = rng.next_2d();
            let uc = rng.next_f32();
            let Some(bs) = bsdf.sample(wo, u, uc) else {
                break;
            };
            let wi = frame.to_world(bs.wi).normalize();
            let side = wi.dot(s.ng);
            if two_sided && wi.dot(ng) <= 0.0 {
                // A shading normal can send a reflected ray below the geometric surface;
                // such a ray would leak light through it.
                break;
            }
            if side == 0.0 {
                break;
            }
            throughput *= bs.weight;
            prev_pdf = bs.pdf;
            prev_delta = bs.delta;
            prev_p = s.p;
            skip = hit.prim;
            o = offset_ray_origin(s.p, if side > 0.0 { s.ng } else { -s.ng });
            dir = wi;
            depth += 1;
            if depth >= RR_START {
                let q = throughput.max_element().min(0.95);
                if !(q > 0.0) || rng.next_f32() >= q {
                    break;
                }
                throughput /= q;
            }
        }
        l
    }

    /// The BSDF of the surface at a hit (textures looked up at its position and
    /// texture coordinates).
    #[inline]
    fn bsdf_at(&self, s: &super::bvh::Surface) -> Bsdf {
        let tex = |t| super::texture::eval(t, s.p, s.uv, &self.images);
        match self.materials.get(s.info.material as usize) {
            Some(super::ResolvedMaterial::Fixed(b)) => *b,
            Some(super::ResolvedMaterial::Textured(t)) => Bsdf::Diffuse { albedo: tex(t) },
            Some(super::ResolvedMaterial::TexturedMetalRough {
                base,
                metallic,
                alpha,
            }) => Bsdf::MetalRough {
                base: tex(base),
                metallic: *metallic,
                alpha: *alpha,
            },
            Some(super::ResolvedMaterial::TexturedCoated {
                reflectance,
                eta,
                alpha,
                fdr_int,
            }) => Bsdf::CoatedDiffuse {
                albedo: tex(reflectance),
                eta: *eta,
                alpha: *alpha,
                fdr_int: *fdr_int,
            },
            None => Bsdf::Black,
        }
    }
}
