//! Lights: emissive triangles and spheres, point, directional and environment lights,
//! chosen for next-event estimation with probability proportional to an estimate of
//! their power (pbrt-v4 `PowerLightSampler`).

// `!(x > 0.0)` is used on purpose: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::bvh::{Geometry, Prim, PrimShape, NONE};
use super::sampling::{average, uniform_cone, uniform_sphere, uniform_triangle, Frame};
use crate::scene::{Light, Material, Scene};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

#[derive(Clone, Copy, Debug)]
pub enum Emitter {
    Tri {
        prim: u32,
        v0: Vec3,
        e1: Vec3,
        e2: Vec3,
        n: Vec3,
        area: f32,
        radiance: Vec3,
        two_sided: bool,
    },
    Sphere {
        prim: u32,
        center: Vec3,
        radius: f32,
        radiance: Vec3,
        two_sided: bool,
    },
    Point {
        position: Vec3,
        intensity: Vec3,
    },
    /// A point light limited to a cone ([`crate::scene::Light::Spot`]).
    Spot {
        position: Vec3,
        direction: Vec3,
        intensity: Vec3,
        cos_inner: f32,
        cos_outer: f32,
        falloff: crate::scene::SpotFalloff,
    },
    /// `direction`: where the light travels (unit).
    Directional {
        direction: Vec3,
        irradiance: Vec3,
    },
    Environment {
        radiance: Vec3,
    },
}

/// One light sample as seen from a shading point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point toward the light.
    pub wi: Vec3,
    /// Distance to the sampled point (INFINITY for directional and environment).
    pub dist: f32,
    /// Incident radiance (area, environment) or irradiance-like value (point,
    /// directional), already divided by the selection probability and the pdf.
    pub weight: Vec3,
    /// Solid-angle pdf including selection probability (0 for delta lights).
    pub pdf: f32,
    pub delta: bool,
    /// The emitting primitive (skipped by the shadow ray), or NONE.
    pub prim: u32,
}

pub struct Lights {
    pub emitters: Vec<Emitter>,
    /// Selection probabilities and their running sum (the last entry is 1).
    pub pmf: Vec<f32>,
    cdf: Vec<f32>,
    /// Sum of every environment light's radiance (they are all constant).
    pub env_radiance: Option<Vec3>,
    /// Selection probability of the environment (0 when absent or black).
    pub env_pmf: f32,
}

impl Lights {
    /// Collects the lights of `scene` and tags emissive primitives in `geo.info`.
    #[must_use]
    pub fn build(scene: &Scene, geo: &mut Geometry) -> Self {
        let mut emitters = Vec::new();
        // pbrt-v4 `PowerLightSampler`: each light's power Φ, estimated once here.
        let mut power: Vec<f64> = Vec::new();
        let r_scene = f64::from(geo.bounds_radius);
        for (i, prim) in geo.prims.iter().enumerate() {
            let info = &mut geo.info[i];
            let material = geo.object_material.get(info.object as usize);
            let Some(Material::Emissive {
                radiance,
                two_sided,
            }) = material
                .and_then(|&m| scene.materials.get(m as usize))
                .copied()
            else {
                continue;
            };
            let avg = f64::from(average(radiance));
            if !(avg > 0.0) || !radiance.is_finite() {
                continue;
            }
            let sides = if two_sided { 2.0 } else { 1.0 };
            let (e, area) = area_emitter(prim, i as u32, radiance, two_sided);
            info.emitter = emitters.len() as u32;
            emitters.push(e);
            // Φ = sides · π · A · L for a diffuse emitter.
            power.push(sides * std::f64::consts::PI * area * avg);
        }
        let mut env = Vec3::ZERO;
        let mut has_env = false;
        for l in &scene.lights {
            if let Light::Environment { radiance } = *l {
                env += radiance;
                has_env = true;
            } else if let Some((e, p)) = local_light(l, r_scene) {
                emitters.push(e);
                power.push(p);
            }
        }
        let mut env_pmf_index = None;
        if has_env && average(env) > 0.0 && env.is_finite() {
            env_pmf_index = Some(emitters.len());
            emitters.push(Emitter::Environment { radiance: env });
            // Φ = π² r² L: the environment's radiance through the scene's bounding disc.
            power.push(
                std::f64::consts::PI
                    * std::f64::consts::PI
                    * r_scene
                    * r_scene
                    * f64::from(average(env)),
            );
        }
        let (pmf, cdf) = selection(&power);
        let env_pmf = env_pmf_index.map_or(0.0, |i| pmf[i]);
        Self {
            emitters,
            pmf,
            cdf,
            env_radiance: has_env.then_some(env),
            env_pmf,
        }
    }

    #[inline]
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// Samples one light for shading point `p`.
    #[inline]
    pub fn sample(&self, p: Vec3, u_sel: f32, u: Vec2) -> Option<LightSample> {
        if self.emitters.is_empty() {
            return None;
        }
        let i = self
            .cdf
            .partition_point(|&c| c <= u_sel)
            .min(self.emitters.len() - 1);
        let sel = self.pmf[i];
        if sel <= 0.0 {
            return None;
        }
        match self.emitters[i] {
            Emitter::Tri {
                prim,
                v0,
                e1,
                e2,
                n,
                area,
                radiance,
                two_sided,
            } => {
                let (b1, b2) = uniform_triangle(u);
                let emitter = AreaPoint {
                    q: v0 + e1 * b1 + e2 * b2,
                    n,
                    area,
                    radiance,
                    two_sided,
                    prim,
                };
                emitter.sample_from(p, sel)
            }
            Emitter::Sphere {
                prim,
                center,
                radius,
                radiance,
                two_sided,
            } => {
                let to_c = center - p;
                let r2 = radius * radius;
                if to_c.length_squared() > r2 * 1.000_01 {
                    // From outside the visible cap faces the point (outward side emits),
                    // so `two_sided` does not matter.
                    Some(sphere_cone(to_c, r2, radiance, prim, sel, u))
                } else {
                    // Inside (or on): uniform area sampling.
                    let nq = uniform_sphere(u);
                    let emitter = AreaPoint {
                        q: center + nq * radius,
                        n: nq,
                        area: 4.0 * PI * r2,
                        radiance,
                        two_sided,
                        prim,
                    };
                    emitter.sample_from(p, sel)
                }
            }
            // Point, spot, directional and environment lights: no surface.
            e => sample_surfaceless(&e, p, sel, u),
        }
    }

    /// Radiance leaving emitter `e` toward direction `-d` at a hit with geometric
    /// normal `ng` (one-sided emitters emit on the `ng` side only).
    #[inline]
    #[must_use]
    pub fn emitted(&self, e: u32, d: Vec3, ng: Vec3) -> Vec3 {
        match self.emitters[e as usize] {
            Emitter::Tri {
                radiance,
                two_sided,
                ..
            }
            | Emitter::Sphere {
                radiance,
                two_sided,
                ..
            } => {
                if two_sided || ng.dot(d) < 0.0 {
                    radiance
                } else {
                    Vec3::ZERO
                }
            }
            _ => Vec3::ZERO,
        }
    }

    /// Solid-angle pdf (with selection probability) that [`Lights::sample`] from `p`
    /// produces the point `q` (normal `ng`) on emitter `e`, reached along unit `d`.
    #[inline]
    #[must_use]
    pub fn pdf(&self, e: u32, p: Vec3, q: Vec3, ng: Vec3, d: Vec3) -> f32 {
        let sel = self.pmf[e as usize];
        match self.emitters[e as usize] {
            Emitter::Tri { area, .. } => {
                let d2 = (q - p).length_squared();
                let c = ng.dot(d).abs();
                if c <= 0.0 {
                    return 0.0;
                }
                sel * d2 / (c * area)
            }
            Emitter::Sphere { center, radius, .. } => {
                let d2c = (center - p).length_squared();
                let r2 = radius * radius;
                if d2c > r2 * 1.000_01 {
                    let cos_max = (1.0 - r2 / d2c).max(0.0).sqrt();
                    sel / (2.0 * PI * (1.0 - cos_max).max(1e-12))
                } else {
                    let d2 = (q - p).length_squared();
                    let c = ng.dot(d).abs();
                    if c <= 0.0 {
                        return 0.0;
                    }
                    sel * d2 / (c * 4.0 * PI * r2)
                }
            }
            _ => 0.0,
        }
    }
}

/// A light without a surface (point, spot, directional, environment) sampled from `p`,
/// selected with probability `sel`; `u` draws the environment's direction. Emissive
/// triangles and spheres are [`Lights::sample`]'s own arms.
#[inline(always)]
fn sample_surfaceless(e: &Emitter, p: Vec3, sel: f32, u: Vec2) -> Option<LightSample> {
    match *e {
        Emitter::Point {
            position,
            intensity,
        } => {
            let (wi, dist) = dir_dist(p, position)?;
            Some(LightSample::delta(
                wi,
                dist,
                intensity / (sel * dist * dist),
            ))
        }
        Emitter::Spot {
            position,
            direction,
            intensity,
            cos_inner,
            cos_outer,
            falloff,
        } => {
            let (wi, dist) = dir_dist(p, position)?;
            let f = falloff.weight(direction.dot(-wi), cos_inner, cos_outer);
            if f <= 0.0 {
                return None;
            }
            let w = intensity * (f / (sel * dist * dist));
            Some(LightSample::delta(wi, dist, w))
        }
        Emitter::Directional {
            direction,
            irradiance,
        } => Some(LightSample::delta(
            -direction,
            f32::INFINITY,
            irradiance / sel,
        )),
        Emitter::Environment { radiance } => {
            let wi = uniform_sphere(u);
            let pdf = sel / (4.0 * PI);
            Some(LightSample {
                wi,
                dist: f32::INFINITY,
                weight: radiance / pdf,
                pdf,
                delta: false,
                prim: NONE,
            })
        }
        Emitter::Tri { .. } | Emitter::Sphere { .. } => None,
    }
}

impl LightSample {
    /// A sample of a delta light (point, spot, directional): no pdf, no primitive.
    #[inline(always)]
    fn delta(wi: Vec3, dist: f32, weight: Vec3) -> Self {
        Self {
            wi,
            dist,
            weight,
            pdf: 0.0,
            delta: true,
            prim: NONE,
        }
    }
}

/// A sphere of squared radius `r2` seen from outside at offset `to_c` (centre minus
/// shading point): a direction drawn uniformly in the cone that sees it (pbrt-v4
/// `Sphere::Sample` with a reference point), the distance to its near side.
#[inline(always)]
fn sphere_cone(to_c: Vec3, r2: f32, radiance: Vec3, prim: u32, sel: f32, u: Vec2) -> LightSample {
    let d2 = to_c.length_squared();
    let dc = d2.sqrt();
    let sin2 = r2 / d2;
    let cos_max = (1.0 - sin2).max(0.0).sqrt();
    let frame = Frame::new(to_c / dc);
    let wi = frame.to_world(uniform_cone(u, cos_max));
    // Near root of the ray against the sphere; tangent if rounding misses.
    let b = wi.dot(to_c);
    let disc = (r2 - (d2 - b * b)).max(0.0);
    let dist = (b - disc.sqrt()).max(0.0);
    let pdf = sel / (2.0 * PI * (1.0 - cos_max).max(1e-12));
    LightSample {
        wi,
        dist,
        weight: radiance / pdf,
        pdf,
        delta: false,
        prim,
    }
}

/// The emitter of the emissive primitive `prim` (index `i`) and its surface area.
fn area_emitter(prim: &Prim, i: u32, radiance: Vec3, two_sided: bool) -> (Emitter, f64) {
    match prim.shape() {
        PrimShape::Tri { v0, e1, e2 } => {
            let c = Vec3::from(e1).cross(Vec3::from(e2));
            let area = 0.5 * c.length();
            (
                Emitter::Tri {
                    prim: i,
                    v0: v0.into(),
                    e1: e1.into(),
                    e2: e2.into(),
                    n: c.normalize(),
                    area,
                    radiance,
                    two_sided,
                },
                f64::from(area),
            )
        }
        PrimShape::Sphere { center, radius } => (
            Emitter::Sphere {
                prim: i,
                center: center.into(),
                radius,
                radiance,
                two_sided,
            },
            4.0 * std::f64::consts::PI * f64::from(radius) * f64::from(radius),
        ),
    }
}

/// A point, spot or directional light with its power Φ (a directional light's through
/// the scene's bounding disc of radius `r_scene`); `None` for a black or degenerate one,
/// and for the environment (summed apart: [`Lights::build`]).
fn local_light(l: &Light, r_scene: f64) -> Option<(Emitter, f64)> {
    let (e, p, ok) = match *l {
        Light::Point {
            position,
            intensity,
        } => {
            let p = 4.0 * std::f64::consts::PI * f64::from(average(intensity));
            let e = Emitter::Point {
                position,
                intensity,
            };
            (e, p, intensity.is_finite())
        }
        Light::Directional {
            direction,
            irradiance,
        } => {
            let p = std::f64::consts::PI * r_scene * r_scene * f64::from(average(irradiance));
            let d = direction.normalize_or_zero();
            let e = Emitter::Directional {
                direction: d,
                irradiance,
            };
            (e, p, irradiance.is_finite() && d != Vec3::ZERO)
        }
        Light::Spot {
            position,
            direction,
            intensity,
            cos_inner,
            cos_outer,
            falloff,
        } => {
            // pbrt-v4 SpotLight::Phi: the full cone, and half the falloff band
            // (exact for a linear ramp in cos θ, close for the others).
            let solid = 2.0
                * std::f64::consts::PI
                * ((1.0 - f64::from(cos_inner)) + 0.5 * f64::from(cos_inner - cos_outer).max(0.0));
            let p = solid * f64::from(average(intensity));
            let e = Emitter::Spot {
                position,
                direction,
                intensity,
                cos_inner,
                cos_outer,
                falloff,
            };
            (e, p, intensity.is_finite() && direction != Vec3::ZERO)
        }
        Light::Environment { .. } => return None,
    };
    (p > 0.0 && ok).then_some((e, p))
}

/// Selection probabilities proportional to `power`, and their running sum (the last
/// entry forced to 1 so that every `u < 1` selects a light).
fn selection(power: &[f64]) -> (Vec<f32>, Vec<f32>) {
    let total: f64 = power.iter().sum();
    let pmf: Vec<f32> = if total > 0.0 && total.is_finite() {
        power.iter().map(|p| (p / total) as f32).collect()
    } else {
        // Overflowing power estimates (radiance near f32::MAX): fall back to uniform.
        vec![1.0 / power.len().max(1) as f32; power.len()]
    };
    let mut cdf = Vec::with_capacity(pmf.len());
    let mut acc = 0.0f64;
    for p in &pmf {
        acc += f64::from(*p);
        cdf.push(acc as f32);
    }
    if let Some(last) = cdf.last_mut() {
        *last = 1.0;
    }
    (pmf, cdf)
}

/// A point drawn uniformly by area on an emitter of total `area`, with normal `n`.
struct AreaPoint {
    q: Vec3,
    n: Vec3,
    area: f32,
    radiance: Vec3,
    two_sided: bool,
    prim: u32,
}

impl AreaPoint {
    /// The sample seen from `p`: the area pdf converted to solid angle
    /// (pdf_ω = dist² / (|cos θ_l| · area)), times the emitter's selection probability.
    /// `None` for the back of a one-sided emitter or a degenerate configuration.
    fn sample_from(&self, p: Vec3, sel: f32) -> Option<LightSample> {
        let (wi, dist) = dir_dist(p, self.q)?;
        let cos_l = -self.n.dot(wi);
        if !self.two_sided && cos_l <= 0.0 {
            return None;
        }
        let pdf = sel * dist * dist / (cos_l.abs() * self.area);
        if !(pdf > 0.0) || !pdf.is_finite() {
            return None;
        }
        Some(LightSample {
            wi,
            dist,
            weight: self.radiance / pdf,
            pdf,
            delta: false,
            prim: self.prim,
        })
    }
}

#[inline]
fn dir_dist(p: Vec3, q: Vec3) -> Option<(Vec3, f32)> {
    let v = q - p;
    let d = v.length();
    if !(d > 0.0) || !d.is_finite() {
        return None;
    }
    Some((v / d, d))
}
