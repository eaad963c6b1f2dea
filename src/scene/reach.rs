//! How much of each light source's power reaches anything: a few hundred rays from the
//! emitter (cosine-distributed from an emissive surface, uniform from a point light, in
//! the cone of a spot), each asking only whether it hits some other object. A lamp whose
//! light almost all escapes into the void lights nothing a camera can see: the picture is
//! nearly black, and the cause is usually the lamp's facing (a quad's `edge_u × edge_v`,
//! a mesh's winding) or its position (behind a wall, outside the room).
//!
//! Pure geometry and bounded: object bounds first, then the triangles of the objects a
//! ray's bounds test lets through, stopping at the first hit; the whole check stops at
//! [`BUDGET`] tests, and an emitter not finished by then is not judged (no warning on a
//! guess). `scene` cannot use the tracer's BVH (data flows one way, ARCHITECTURE.md).

use super::{Light, Material, Problem, Scene, Shape, Triangle};
use glam::Vec3;

/// Rays cast from each emitter: at 256 a share of 3 % is ~8 hits, so a lamp lighting the
/// room through a narrow gap still scores well above zero, and a lamp facing the void
/// scores 0-2 rays (grazing hits on a ceiling or floor).
pub const RAYS: u32 = 256;

/// Below this share of its rays reaching another object an emitter is named.
pub const LIMIT: f32 = 0.03;

/// Box and triangle tests for the whole scene: what a submit may spend before its `201`.
/// Measured (test profile, this 2-core machine): a scene whose every ray meets a 320 k
/// triangle mesh's box, the worst shape, spends 16 M tests in 223 ms, so 4 M is ~55 ms
/// at most; veach-ajar (382 k triangles) needs 1.7 ms, the bundled scenes < 0.1 ms.
pub const BUDGET: u64 = 4_000_000;

/// One light source to judge: where its rays start and which way they go.
enum Source<'a> {
    Surface {
        own: usize,
        triangles: &'a [Triangle],
        two_sided: bool,
    },
    Sphere {
        own: usize,
        center: Vec3,
        radius: f32,
    },
    Point {
        position: Vec3,
        axis: Vec3,
        cos_max: f32,
    },
}

/// Every emitter (emissive object, point or spot light) of `scene` whose rays mostly
/// reach nothing, except the objects in `skip` (already named by another check).
#[must_use]
pub fn check(scene: &Scene, skip: &[usize]) -> Vec<Problem> {
    let bounds: Vec<(Vec3, Vec3)> = scene.shapes.iter().map(bounds_of).collect();
    let scale = bounds
        .iter()
        .filter(|b| b.0.x <= b.1.x)
        .map(|b| (b.1 - b.0).max_element())
        .fold(0.0f32, f32::max)
        .max(1e-6);
    let mut cast = Caster {
        scene,
        bounds: &bounds,
        eps: 1e-4 * scale,
        tests: 0,
    };
    let mut out = Vec::new();
    for (path, source) in sources(scene, skip) {
        match cast.share(&source) {
            Some(share) if share < LIMIT => out.push(Problem {
                message: advice(&source, share),
                path,
            }),
            Some(_) => {}
            None => break,
        }
    }
    out
}

/// The light sources of `scene` with their JSON paths.
fn sources<'a>(scene: &'a Scene, skip: &[usize]) -> Vec<(String, Source<'a>)> {
    let mut out = Vec::new();
    for (k, shape) in scene.shapes.iter().enumerate() {
        let Some(Material::Emissive {
            radiance,
            two_sided,
        }) = scene.materials.get(shape.material() as usize)
        else {
            continue;
        };
        if skip.contains(&k) || radiance.max_element() <= 0.0 {
            continue;
        }
        let source = match shape {
            Shape::Triangles { triangles, .. } => Source::Surface {
                own: k,
                triangles,
                two_sided: *two_sided,
            },
            Shape::Sphere { center, radius, .. } => Source::Sphere {
                own: k,
                center: *center,
                radius: *radius,
            },
        };
        out.push((format!("objects[{k}]"), source));
    }
    for (i, l) in scene.lights.iter().enumerate() {
        let source = match l {
            Light::Point {
                position,
                intensity,
            } if intensity.max_element() > 0.0 => Source::Point {
                position: *position,
                axis: Vec3::Y,
                cos_max: -1.0,
            },
            Light::Spot {
                position,
                direction,
                intensity,
                cos_outer,
                ..
            } if intensity.max_element() > 0.0 => Source::Point {
                position: *position,
                axis: *direction,
                cos_max: *cos_outer,
            },
            _ => continue,
        };
        out.push((format!("lights[{i}]"), source));
    }
    out
}

/// What to tell the author about a source whose rays reach `share` of the time.
fn advice(source: &Source, share: f32) -> String {
    let pct = f64::from(share) * 100.0;
    match source {
        Source::Surface { .. } => format!(
            "only {pct:.1} % of this emitter's light reaches any other object ({RAYS} rays cast from its surface), so it lights almost nothing and the picture will be dark; check which way it faces: a one-sided emitter emits on the side of its normal (a quad's edge_u × edge_v, a mesh's counter-clockwise winding), so swap edge_u and edge_v, reverse its winding or make it two_sided, and check that no wall is missing in front of it"
        ),
        Source::Sphere { .. } => format!(
            "only {pct:.1} % of this emissive sphere's light reaches any other object ({RAYS} rays cast from its surface), so it lights almost nothing; check its position (is it outside the scene?)"
        ),
        Source::Point { cos_max, .. } if *cos_max > -1.0 => format!(
            "only {pct:.1} % of this spot light's rays reach any object ({RAYS} rays cast in its cone), so it lights almost nothing; check its direction and position"
        ),
        Source::Point { .. } => format!(
            "only {pct:.1} % of this point light's rays reach any object ({RAYS} rays cast from it), so it lights almost nothing; check its position (is it outside the scene, behind a wall?)"
        ),
    }
}

/// Casts rays against the scene's objects within the shared test budget.
struct Caster<'a> {
    scene: &'a Scene,
    bounds: &'a [(Vec3, Vec3)],
    /// Hits nearer than this do not count (the emitter's own plane, a lamp set flush
    /// into a ceiling).
    eps: f32,
    tests: u64,
}

impl Caster<'_> {
    /// The share of [`RAYS`] rays from `source` that hit another object; `None` when the
    /// budget ran out first.
    fn share(&mut self, source: &Source) -> Option<f32> {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let (own, cdf) = match source {
            Source::Surface { own, triangles, .. } => (Some(*own), area_cdf(triangles)),
            Source::Sphere { own, .. } => (Some(*own), Vec::new()),
            Source::Point { .. } => (None, Vec::new()),
        };
        if matches!(source, Source::Surface { .. }) && cdf.last().is_none_or(|&a| a <= 0.0) {
            return Some(1.0);
        }
        let mut hits = 0u32;
        for _ in 0..RAYS {
            let (o, d) = sample_ray(source, &cdf, &mut rng);
            if self.hits_any(o, d, own)? {
                hits += 1;
            }
        }
        Some(hits as f32 / RAYS as f32)
    }

    /// Whether the ray hits any object but `own`; `None` when the budget is spent.
    fn hits_any(&mut self, o: Vec3, d: Vec3, own: Option<usize>) -> Option<bool> {
        let inv = d.recip();
        for (k, shape) in self.scene.shapes.iter().enumerate() {
            if Some(k) == own {
                continue;
            }
            self.tests += 1;
            if !slab(self.bounds[k], o, inv) {
                continue;
            }
            let hit = match shape {
                Shape::Sphere { center, radius, .. } => {
                    sphere_hit(o, d, *center, *radius, self.eps)
                }
                Shape::Triangles { triangles, .. } => {
                    self.tests += triangles.len() as u64;
                    triangles.iter().any(|t| tri_t(o, d, t) > self.eps)
                }
            };
            if hit {
                return Some(true);
            }
            if self.tests > BUDGET {
                return None;
            }
        }
        (self.tests <= BUDGET).then_some(false)
    }
}

/// A ray from `source`: a point on it and a direction, cosine-distributed about the
/// surface's normal (the side it emits on, or either for a two-sided one).
fn sample_ray(source: &Source, cdf: &[f32], rng: &mut Rng) -> (Vec3, Vec3) {
    match source {
        Source::Surface {
            triangles,
            two_sided,
            ..
        } => {
            let total = cdf.last().copied().unwrap_or(0.0);
            let pick = rng.next() * total;
            let i = cdf.partition_point(|&a| a < pick).min(triangles.len() - 1);
            let t = &triangles[i];
            let (mut u, mut v) = (rng.next(), rng.next());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let p = t.p[0] + (t.p[1] - t.p[0]) * u + (t.p[2] - t.p[0]) * v;
            let mut n = (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]).normalize_or_zero();
            if *two_sided && rng.next() < 0.5 {
                n = -n;
            }
            (p, cosine_about(n, rng))
        }
        Source::Sphere { center, radius, .. } => {
            let n = uniform_sphere(rng);
            (*center + n * *radius, cosine_about(n, rng))
        }
        Source::Point {
            position,
            axis,
            cos_max,
        } => {
            // Uniform in the cone cos θ ≥ cos_max about `axis` (the whole sphere at −1).
            let z = 1.0 - rng.next() * (1.0 - cos_max);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = std::f32::consts::TAU * rng.next();
            let (t, b) = axis.any_orthonormal_pair();
            (*position, t * r * phi.cos() + b * r * phi.sin() + *axis * z)
        }
    }
}

/// Running sums of the triangles' areas.
fn area_cdf(triangles: &[Triangle]) -> Vec<f32> {
    let mut sum = 0.0f32;
    triangles
        .iter()
        .map(|t| {
            sum += 0.5 * (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]).length();
            sum
        })
        .collect()
}

/// A cosine-distributed direction about the unit normal `n` (Malley's method).
fn cosine_about(n: Vec3, rng: &mut Rng) -> Vec3 {
    let (r, phi) = (rng.next().sqrt(), std::f32::consts::TAU * rng.next());
    let (t, b) = n.any_orthonormal_pair();
    let z = (1.0 - r * r).max(0.0).sqrt();
    t * r * phi.cos() + b * r * phi.sin() + n * z
}

fn uniform_sphere(rng: &mut Rng) -> Vec3 {
    let z = 1.0 - 2.0 * rng.next();
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f32::consts::TAU * rng.next();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn bounds_of(shape: &Shape) -> (Vec3, Vec3) {
    match shape {
        Shape::Sphere { center, radius, .. } => (
            *center - Vec3::splat(*radius),
            *center + Vec3::splat(*radius),
        ),
        Shape::Triangles { triangles, .. } => triangles.iter().flat_map(|t| t.p).fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(p), hi.max(p)),
        ),
    }
}

/// Whether the ray meets the box at some t ≥ 0 (a flat box's zero extent included).
fn slab((lo, hi): (Vec3, Vec3), o: Vec3, inv: Vec3) -> bool {
    let (a, b) = ((lo - o) * inv, (hi - o) * inv);
    // NaN (0 × ∞ on a flat box's face) is dropped by min/max, keeping the other bound.
    let near = a.min(b).max_element().max(0.0);
    let far = a.max(b).min_element();
    near <= far * (1.0 + 1e-5)
}

/// The distance to the triangle along the ray (Möller–Trumbore), or −1.
fn tri_t(o: Vec3, d: Vec3, t: &Triangle) -> f32 {
    let (e1, e2) = (t.p[1] - t.p[0], t.p[2] - t.p[0]);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-20 {
        return -1.0;
    }
    let inv = 1.0 / det;
    let s = o - t.p[0];
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return -1.0;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return -1.0;
    }
    e2.dot(q) * inv
}

fn sphere_hit(o: Vec3, d: Vec3, c: Vec3, r: f32, eps: f32) -> bool {
    let oc = o - c;
    let b = oc.dot(d);
    let disc = b * b - (oc.length_squared() - r * r);
    if disc < 0.0 {
        return false;
    }
    let s = disc.sqrt();
    -b - s > eps || -b + s > eps
}

/// A small deterministic generator (SplitMix64): the check gives the same answer every
/// time for the same scene.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 40) as f32 / (1u64 << 24) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{parse_scene, Limits, SceneOrigin};

    /// A 4 × 2 × 4 room (floor, ceiling, left, right and front walls; no back wall at
    /// z = −2) with a 1 × 1 lamp standing 10 cm in front of where the back wall was, and
    /// `lamp_v` its quad's second edge: [0, 1, 0] faces +z (into the room), [0, −1, 0]
    /// faces −z (out through the missing wall).
    pub(crate) fn open_room(lamp_v: &str, lamp: &str) -> String {
        format!(
            r#"{{
  "version": 1, "image": {{ "width": 32, "height": 24 }},
  "camera": {{ "position": [0, 1, 1.9], "look_at": [0, 1, 0], "fov_y": 60 }},
  "materials": {{ "white": {{ "type": "diffuse", "albedo": [0.7, 0.7, 0.7] }},
                 "lamp": {{ "type": "emissive", "radiance": [10, 10, 10] }} }},
  "objects": [
    {{ "type": "quad", "material": "white", "corner": [-2, 0, -2], "edge_u": [0, 0, 4], "edge_v": [4, 0, 0] }},
    {{ "type": "quad", "material": "white", "corner": [-2, 2, -2], "edge_u": [4, 0, 0], "edge_v": [0, 0, 4] }},
    {{ "type": "quad", "material": "white", "corner": [-2, 0, -2], "edge_u": [0, 2, 0], "edge_v": [0, 0, 4] }},
    {{ "type": "quad", "material": "white", "corner": [2, 0, -2], "edge_u": [0, 0, 4], "edge_v": [0, 2, 0] }},
    {{ "type": "quad", "material": "white", "corner": [-2, 0, 2], "edge_u": [4, 0, 0], "edge_v": [0, 2, 0] }}
    {lamp}
  ]
}}"#
        )
        .replace("LAMP_V", lamp_v)
    }

    const LAMP: &str = r#", { "type": "quad", "material": "lamp", "corner": [-0.5, LAMP_Y, -1.9], "edge_u": [1, 0, 0], "edge_v": LAMP_V }"#;

    fn scene(doc: &str) -> Scene {
        parse_scene(doc, &SceneOrigin::Request, &Limits::command_line())
            .unwrap_or_else(|e| panic!("{e}\n{doc}"))
    }

    #[test]
    fn a_lamp_facing_out_of_an_open_room_is_named_and_one_facing_in_is_not() {
        // edge_u × edge_v = x × y = +z for [0, 1, 0]: into the room.
        let lamp_in = LAMP.replace("LAMP_Y", "0.5");
        let inward = scene(&open_room("[0, 1, 0]", &lamp_in));
        assert!(check(&inward, &[]).is_empty(), "{:?}", check(&inward, &[]));
        // Turned round (x × −y = −z): out through the missing wall; the ceiling and the
        // floor lie beside it at grazing angles, which the bounds-only rule accepted.
        let lamp_out = LAMP.replace("LAMP_Y", "1.5");
        let outward = scene(&open_room("[0, -1, 0]", &lamp_out));
        let w = check(&outward, &[]);
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].path, "objects[5]");
        assert!(
            w[0].message.contains("which way it faces"),
            "{}",
            w[0].message
        );
        // The whole scene check names it once (not also as facing away from everything).
        let all = crate::scene::warnings::check(&outward);
        assert_eq!(all.len(), 1, "{all:?}");
    }

    #[test]
    fn point_lights_outside_and_inside_a_room() {
        let inside = r#"], "lights": [ { "type": "point", "position": [0, 1, 0], "intensity": [5, 5, 5] } ]"#;
        let doc = open_room("", "").replace("\n  ]\n}", &format!("\n  {inside}\n}}"));
        assert!(check(&scene(&doc), &[]).is_empty());
        let outside = inside.replace("[0, 1, 0]", "[0, 1, -40]");
        let doc = open_room("", "").replace("\n  ]\n}", &format!("\n  {outside}\n}}"));
        let w = check(&scene(&doc), &[]);
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].path, "lights[0]");
    }

    #[test]
    fn no_bundled_example_is_named() {
        for (name, text) in crate::scene::examples::EXAMPLES {
            let s = parse_scene(text, &SceneOrigin::Request, &Limits::command_line()).unwrap();
            assert!(check(&s, &[]).is_empty(), "{name}: {:?}", check(&s, &[]));
        }
    }
}
