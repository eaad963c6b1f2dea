//! Unidirectional path tracing with next-event estimation and multiple importance
//! sampling (Veach 1997, ch. 9; power heuristic β = 2), Russian roulette after a few
//! bounces, `max_bounces` scattering events at most (pbrt's `maxdepth` convention:
//! 0 = only directly visible emitters, 1 = direct lighting).

// `!(x > 0.0)` is used on purpose: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::bvh::NONE;
use super::material::{Bsdf, BsdfSample};
use super::sampler::{Dim, PathSampler};
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
    pub(crate) fn trace_path(
        &self,
        x: u32,
        y: u32,
        rng: &mut impl PathSampler,
        rays: &mut u32,
    ) -> Vec3 {
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
        rng: &mut impl PathSampler,
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
        rng: &mut impl PathSampler,
        albedo: &mut Option<Vec3>,
        rays: &mut u32,
    ) -> Vec3 {
        let mut dir = self.camera.direction(x, y, rng.get_2d(Dim::Camera));
        let mut o = self.camera.origin;
        let mut throughput = Vec3::ONE;
        let mut l = Vec3::ZERO;
        // The camera ray counts as a delta lobe: emitters it sees get full weight.
        let mut prev = Prev {
            pdf: 0.0,
            delta: true,
            p: o,
        };
        let mut skip = NONE;
        let max_bounces = self.max_bounces;
        let lights = &self.lights;
        let mut depth = 0u32;
        loop {
            *rays += 1;
            // The next vertex (the camera ray goes through the screen-tile lists,
            // primary.rs: same hit as the BVH's).
            let hit = if depth == 0 {
                self.camera_hit(x, y, dir)
            } else {
                self.geo.intersect(o, dir, f32::INFINITY, skip)
            };
            let Some(hit) = hit else {
                if let Some(env) = lights.env_radiance {
                    l += throughput * env * self.env_weight(&prev);
                }
                break;
            };
            let s = self.geo.surface(o, dir, &hit);
            // Emission seen there, MIS-weighted against the previous vertex's light sample.
            if s.info.emitter != NONE {
                if let Some(c) = self.emission(&s, dir, &prev, throughput) {
                    l += c;
                }
            }
            if depth >= max_bounces {
                break;
            }
            let bsdf = self.bsdf_at(&s);
            if ALBEDO && depth == 0 {
                *albedo = self.texture_albedo_of(&s, bsdf);
            }
            if matches!(bsdf, Bsdf::Black) {
                break;
            }
            let at = Shading::new(&s, &bsdf, dir, hit.prim);
            // Next-event estimation, then continue the path by sampling the BSDF.
            if self.features.has_lights && !bsdf.is_delta() {
                if let Some(c) = self.next_event(&at, &bsdf, throughput, rng, rays) {
                    l += c;
                }
            }
            let Some((bs, wi, side)) = scatter(&at, &bsdf, rng) else {
                break;
            };
            throughput *= bs.weight;
            prev = Prev {
                pdf: bs.pdf,
                delta: bs.delta,
                p: s.p,
            };
            skip = hit.prim;
            o = offset_ray_origin(s.p, if side > 0.0 { s.ng } else { -s.ng });
            dir = wi;
            depth += 1;
            if depth >= RR_START && !russian_roulette(&mut throughput, rng) {
                break;
            }
        }
        l
    }

    /// The MIS weight of the environment seen by a path that escaped after a BSDF sample of
    /// pdf `prev_pdf` (full weight after a delta lobe or the camera ray, or when next-event
    /// estimation never samples the environment): Veach 1997 §9.2, power heuristic.
    #[inline(always)]
    fn env_weight(&self, prev: &Prev) -> f32 {
        if prev.delta || self.lights.env_pmf == 0.0 {
            1.0
        } else {
            power_heuristic(prev.pdf, self.lights.env_pmf / (4.0 * PI))
        }
    }

    /// Radiance of the emitter hit at `s` by a path travelling along `dir`, MIS-weighted
    /// against the next-event estimate of the previous vertex (Veach 1997 §9.2) and
    /// multiplied by `throughput`; `None` where it emits nothing toward the path.
    #[inline(always)]
    fn emission(
        &self,
        s: &super::bvh::Surface,
        dir: Vec3,
        prev: &Prev,
        throughput: Vec3,
    ) -> Option<Vec3> {
        let le = self.lights.emitted(s.info.emitter, dir, s.ng);
        if le == Vec3::ZERO {
            return None;
        }
        let w = if prev.delta {
            1.0
        } else {
            power_heuristic(
                prev.pdf,
                self.lights.pdf(s.info.emitter, prev.p, s.p, s.ng, dir),
            )
        };
        Some(throughput * le * w)
    }

    /// The texture albedo of a camera-ray hit for [`PathTracer::trace_path_albedo`]: only a
    /// textured Lambertian surface has one.
    #[inline(always)]
    fn texture_albedo_of(&self, s: &super::bvh::Surface, bsdf: Bsdf) -> Option<Vec3> {
        match (self.materials.get(s.info.material as usize), bsdf) {
            (Some(super::ResolvedMaterial::Textured(_)), Bsdf::Diffuse { albedo: a }) => Some(a),
            _ => None,
        }
    }

    /// Next-event estimation at a non-delta vertex (a delta lobe cannot meet a sampled
    /// light direction): one light sample, its shadow ray, weighted against BSDF sampling
    /// by the power heuristic (Veach 1997 §9.2). Returns the radiance it adds, already
    /// multiplied by `throughput` (in the order the estimator has always used, so sums
    /// stay bit-identical), or `None` when it adds nothing; counts its shadow ray in
    /// `rays`.
    #[inline(always)]
    fn next_event(
        &self,
        at: &Shading,
        bsdf: &Bsdf,
        throughput: Vec3,
        rng: &mut impl PathSampler,
        rays: &mut u32,
    ) -> Option<Vec3> {
        let u_sel = rng.get_1d(Dim::LightSelect);
        let u_l = rng.get_2d(Dim::LightPoint);
        let ls = self.lights.sample(at.p, u_sel, u_l)?;
        if !(ls.wi.dot(at.ng) > 0.0) {
            return None;
        }
        let (fc, bsdf_pdf) = bsdf.eval(at.wo, at.frame.to_local(ls.wi));
        if fc == Vec3::ZERO {
            return None;
        }
        let origin = offset_ray_origin(at.p, at.ng);
        // Aim from the offset origin at the sampled point itself: the offset (256 ulps, 2
        // units at 1e5) moves the origin sideways, and a ray parallel to `wi` would meet
        // the light's plane before `tmax`.
        let (shadow_dir, tmax) = if ls.dist.is_finite() {
            let v = at.p + ls.wi * ls.dist - origin;
            let len = v.length();
            (v / len, len * SHADOW_SHRINK)
        } else {
            (ls.wi, f32::INFINITY)
        };
        *rays += u32::from(shadow_dir.is_finite());
        if !shadow_dir.is_finite() || self.geo.occluded(origin, shadow_dir, tmax, at.prim) {
            return None;
        }
        let w = if ls.delta {
            1.0
        } else {
            power_heuristic(ls.pdf, bsdf_pdf)
        };
        Some(throughput * fc * ls.weight * w)
    }

    /// The BSDF of the surface at a hit (textures looked up at its position and
    /// texture coordinates).
    #[inline]
    pub(super) fn bsdf_at(&self, s: &super::bvh::Surface) -> Bsdf {
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

/// The BSDF sample that led to the current vertex: its pdf, whether it was a delta lobe,
/// and the vertex it left (what MIS needs to weigh an emitter the path hits).
struct Prev {
    pdf: f32,
    delta: bool,
    p: Vec3,
}

/// A path vertex as shading sees it: position, geometric normal and shading frame (both
/// flipped toward the incoming ray on two-sided surfaces), outgoing direction in that
/// frame, and the primitive the next rays leave.
struct Shading {
    p: Vec3,
    /// The geometric normal as the primitive defines it (not flipped).
    ng_prim: Vec3,
    ng: Vec3,
    /// Whether the surface is shaded from either side ([`Shading::new`]).
    two_sided: bool,
    frame: Frame,
    wo: Vec3,
    prim: u32,
}

impl Shading {
    /// The vertex at `s` (primitive `prim`) reached along `dir`. Diffuse and glossy
    /// surfaces are two-sided: shade with the normals flipped toward the incoming ray
    /// (Tungsten's enable_two_sided_shading). Dielectrics keep the geometric orientation:
    /// it says which side is inside.
    #[inline(always)]
    fn new(s: &super::bvh::Surface, bsdf: &Bsdf, dir: Vec3, prim: u32) -> Self {
        let wo_world = -dir;
        let two_sided = !matches!(bsdf, Bsdf::Dielectric { .. });
        let (ng, ns) = if two_sided && wo_world.dot(s.ng) < 0.0 {
            (-s.ng, -s.ns)
        } else {
            (s.ng, s.ns)
        };
        let frame = Frame::new(ns);
        Self {
            p: s.p,
            ng_prim: s.ng,
            ng,
            two_sided,
            frame,
            wo: frame.to_local(wo_world),
            prim,
        }
    }
}

/// Samples the BSDF at `at` for the path's next direction: the sample, its world
/// direction and that direction's side of the primitive's surface (its dot with the
/// unflipped geometric normal). `None` ends the path: no sample, or a direction along the
/// surface, or one below the flipped geometric surface of a two-sided shading normal
/// (such a reflected ray would leak light through it).
#[inline(always)]
fn scatter(
    at: &Shading,
    bsdf: &Bsdf,
    rng: &mut impl PathSampler,
) -> Option<(BsdfSample, Vec3, f32)> {
    let u = rng.get_2d(Dim::Bsdf);
    let uc = rng.get_1d(Dim::Lobe);
    let bs = bsdf.sample(at.wo, u, uc)?;
    let wi = at.frame.to_world(bs.wi).normalize();
    let side = wi.dot(at.ng_prim);
    if at.two_sided && wi.dot(at.ng) <= 0.0 {
        return None;
    }
    if side == 0.0 {
        return None;
    }
    Some((bs, wi, side))
}

/// Russian roulette (pbrt-v4 §14.1.4): the path survives with probability
/// q = min(max throughput component, 0.95) and its throughput is divided by q. Returns
/// whether it survives; a NaN or zero throughput ends it.
#[inline(always)]
fn russian_roulette(throughput: &mut Vec3, rng: &mut impl PathSampler) -> bool {
    let q = throughput.max_element().min(0.95);
    if !(q > 0.0) || rng.get_1d(Dim::Roulette) >= q {
        return false;
    }
    *throughput /= q;
    true
}
