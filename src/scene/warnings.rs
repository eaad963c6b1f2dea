//! Scenes that are valid but almost surely not what their author meant: checked once a
//! document is accepted, reported beside the soft problems of validation
//! ([`Scene::warnings`]: the job's `warnings`, the command line's stderr, the viewer).
//!
//! Pure geometry, no path tracing, and conservative: each check warns only when the scene
//! cannot look as intended, never on a mere suspicion.
//! - An emitter facing away from all geometry: a one-sided emitter (scene-format.md
//!   `emissive`, emitting on the side of its geometric normal) none of whose triangles
//!   has any other object in front of it lights nothing; the picture is black but for the
//!   emitter's own edges.
//! - An emitter whose light almost all escapes into the void (a lamp facing out of an
//!   open room, a point light outside the scene): under [`super::reach::LIMIT`] of a few
//!   hundred rays cast from it reach any other object (`reach`, the one check that casts
//!   rays; bounded).
//! - Almost no light reaching the camera: an upper bound of the brightest radiance any
//!   pixel can show (an emitter seen directly, a white Lambertian surface facing a light at
//!   its nearest object: `I/(π d²)` for a point light, `E/π` for a directional one) times
//!   the display exposure is below [`DARK_LIMIT`] of display white.
//! - The camera inside a closed object: inside a sphere, or inside a closed triangle mesh
//!   (every edge shared by exactly two triangles, an odd number of crossings on a ray from
//!   the camera) whose normals point outwards (positive signed volume), i.e. a solid seen
//!   from within; a room modelled with inward normals is not one.

use super::{Light, Material, Problem, Scene, Shape, Triangle};
use glam::Vec3;
use std::collections::HashMap;

/// Display white share below which a picture is "almost black": the bound of the
/// brightest pixel shows at level ~16 of 255 in sRGB.
pub const DARK_LIMIT: f32 = 0.005;

/// Triangles of one emitter checked for facing geometry; a larger emitter is not judged
/// (the check is quadratic in the worst case, and a big emissive mesh rarely faces away
/// whole).
const MAX_EMITTER_TRIANGLES: usize = 4096;

/// Triangles of one mesh tested for enclosing the camera (edges hashed, one ray).
const MAX_ENCLOSING_TRIANGLES: usize = 1 << 20;

/// What is valid in `scene` but almost surely wrong, each with the JSON path at fault.
#[must_use]
pub fn check(scene: &Scene) -> Vec<Problem> {
    let mut out = Vec::new();
    let mut facing_away = Vec::new();
    let bounds: Vec<Aabb> = scene.shapes.iter().map(Aabb::of).collect();
    for (k, shape) in scene.shapes.iter().enumerate() {
        if let Shape::Triangles {
            triangles,
            material,
        } = shape
        {
            if let Some(Material::Emissive {
                two_sided: false, ..
            }) = scene.materials.get(*material as usize)
            {
                if faces_nothing(triangles, k, &bounds) {
                    facing_away.push(k);
                    out.push(Problem {
                        path: format!("objects[{k}]"),
                        message: "this one-sided emitter faces away from every other object, so it lights nothing (the picture will be dark); turn it around (reverse its winding or flip its quad's edges) or make it two_sided".into(),
                    });
                }
            }
        }
    }
    // Then every emitter whose light (nearly) all escapes: rays cast, `reach`.
    out.extend(super::reach::check(scene, &facing_away));
    let brightest = brightest_radiance(scene, &bounds) * scene.display.exposure;
    if brightest < DARK_LIMIT {
        out.push(Problem {
            path: "display.exposure".into(),
            message: format!(
                "almost no light reaches the camera: even the brightest surface would show at {:.2} % of display white (exposure {}); raise the lights or display.exposure",
                f64::from(brightest) * 100.0,
                scene.display.exposure
            ),
        });
    }
    let eye = scene.camera.position;
    for (k, shape) in scene.shapes.iter().enumerate() {
        if encloses(shape, eye) {
            out.push(Problem {
                path: "camera.position".into(),
                message: format!(
                    "the camera is inside objects[{k}], a closed object seen from within: the picture will show its inside only; move the camera out of it"
                ),
            });
        }
    }
    out
}

/// Axis-aligned bounds of a shape.
#[derive(Clone, Copy, Debug)]
struct Aabb {
    min: Vec3,
    max: Vec3,
}

impl Aabb {
    fn of(shape: &Shape) -> Self {
        match shape {
            Shape::Sphere { center, radius, .. } => Self {
                min: *center - Vec3::splat(*radius),
                max: *center + Vec3::splat(*radius),
            },
            Shape::Triangles { triangles, .. } => {
                let mut b = Self {
                    min: Vec3::splat(f32::INFINITY),
                    max: Vec3::splat(f32::NEG_INFINITY),
                };
                for p in triangles.iter().flat_map(|t| t.p) {
                    b.min = b.min.min(p);
                    b.max = b.max.max(p);
                }
                b
            }
        }
    }

    fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }

    /// The largest signed distance of the box from the plane through `c` with unit
    /// normal `n`: positive when some of the box lies in front.
    fn reach_in_front(&self, c: Vec3, n: Vec3) -> f32 {
        let far = Vec3::new(
            if n.x >= 0.0 { self.max.x } else { self.min.x },
            if n.y >= 0.0 { self.max.y } else { self.min.y },
            if n.z >= 0.0 { self.max.z } else { self.min.z },
        );
        (far - c).dot(n)
    }

    /// Distance from `p` to the box (0 inside).
    fn distance(&self, p: Vec3) -> f32 {
        (self.min - p).max(p - self.max).max(Vec3::ZERO).length()
    }
}

/// True when no triangle of the emitter `own` has any other object's bounds in front of
/// it (beyond a relative tolerance, so geometry in its own plane does not count).
fn faces_nothing(triangles: &[Triangle], own: usize, bounds: &[Aabb]) -> bool {
    if triangles.is_empty() || triangles.len() > MAX_EMITTER_TRIANGLES {
        return false;
    }
    let scale = bounds
        .iter()
        .filter(|b| !b.is_empty())
        .map(|b| (b.max - b.min).max_element())
        .fold(0.0f32, f32::max)
        .max(1e-6);
    let tolerance = 1e-4 * scale;
    !triangles.iter().any(|t| {
        let n = (t.p[1] - t.p[0]).cross(t.p[2] - t.p[0]).normalize_or_zero();
        let c = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
        n != Vec3::ZERO
            && bounds
                .iter()
                .enumerate()
                .any(|(k, b)| k != own && !b.is_empty() && b.reach_in_front(c, n) > tolerance)
    })
}

/// An upper bound of the linear radiance (largest channel) any pixel can show before
/// exposure: emitters and the environment seen directly, white Lambertian surfaces facing
/// a point or spot light at its nearest object or a directional light.
fn brightest_radiance(scene: &Scene, bounds: &[Aabb]) -> f32 {
    let mut best = 0.0f32;
    for m in &scene.materials {
        if let Material::Emissive { radiance, .. } = m {
            best = best.max(radiance.max_element());
        }
    }
    for l in &scene.lights {
        let b = match l {
            // A spot is a point light whose intensity is at most `intensity`.
            Light::Point {
                position,
                intensity,
            }
            | Light::Spot {
                position,
                intensity,
                ..
            } => {
                let d = bounds
                    .iter()
                    .filter(|b| !b.is_empty())
                    .map(|b| b.distance(*position))
                    .fold(f32::INFINITY, f32::min);
                if d <= 0.0 {
                    f32::INFINITY
                } else {
                    intensity.max_element() / (std::f32::consts::PI * d * d)
                }
            }
            Light::Directional { irradiance, .. } => {
                irradiance.max_element() / std::f32::consts::PI
            }
            Light::Environment { radiance } => radiance.max_element(),
        };
        best = best.max(b);
    }
    best
}

/// True when `eye` is inside `shape` and the shape is a solid (see the module's notes).
fn encloses(shape: &Shape, eye: Vec3) -> bool {
    match shape {
        Shape::Sphere { center, radius, .. } => eye.distance(*center) < *radius,
        Shape::Triangles { triangles, .. } => {
            triangles.len() >= 4
                && triangles.len() <= MAX_ENCLOSING_TRIANGLES
                && signed_volume(triangles) > 0.0
                && crossings(triangles, eye) % 2 == 1
                && is_closed(triangles)
        }
    }
}

/// The signed volume (divergence theorem), positive when the geometric normals point
/// outwards.
fn signed_volume(triangles: &[Triangle]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.p.map(|p| p.as_dvec3());
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

/// Every edge (by its end points' exact coordinates) belongs to exactly two triangles.
fn is_closed(triangles: &[Triangle]) -> bool {
    let key = |p: Vec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    let mut edges: HashMap<([u32; 3], [u32; 3]), u32> = HashMap::new();
    for t in triangles {
        for (a, b) in [(0, 1), (1, 2), (2, 0)] {
            let (ka, kb) = (key(t.p[a]), key(t.p[b]));
            let e = if ka <= kb { (ka, kb) } else { (kb, ka) };
            *edges.entry(e).or_insert(0) += 1;
        }
    }
    edges.values().all(|&n| n == 2)
}

/// Crossings of the ray from `eye` in a fixed direction (chosen off every axis and
/// diagonal, so it does not graze the edges of axis-aligned boxes) with the triangles.
fn crossings(triangles: &[Triangle], eye: Vec3) -> usize {
    let dir = Vec3::new(0.371_390_7, 0.557_086, 0.742_781_4);
    triangles.iter().filter(|t| ray_hits(eye, dir, t)).count()
}

/// Möller–Trumbore, hits at t > 0 only.
fn ray_hits(o: Vec3, d: Vec3, t: &Triangle) -> bool {
    let (e1, e2) = (t.p[1] - t.p[0], t.p[2] - t.p[0]);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return false;
    }
    let inv = 1.0 / det;
    let s = o - t.p[0];
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return false;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    e2.dot(q) * inv > 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{parse_scene, Limits, SceneOrigin};

    /// A closed room (five walls and a floor of quads facing inwards), a lamp under the
    /// ceiling, the camera in the room; `lamp_v` is the lamp quad's second edge, so its
    /// sign decides which way the one-sided lamp faces.
    fn room(lamp_y: f32, lamp_v: &str, extra: &str, exposure: f32) -> Scene {
        let doc = format!(
            r#"{{
  "version": 1, "image": {{ "width": 32, "height": 24 }},
  "camera": {{ "position": [0, 1, 3.5], "look_at": [0, 1, 0], "fov_y": 50 }},
  "display": {{ "exposure": {exposure} }},
  "materials": {{ "white": {{ "type": "diffuse", "albedo": [0.7, 0.7, 0.7] }},
                 "lamp": {{ "type": "emissive", "radiance": [10, 10, 10] }} }},
  "objects": [
    {{ "type": "quad", "material": "white", "corner": [-2, 0, -2], "edge_u": [0, 0, 4], "edge_v": [4, 0, 0] }},
    {{ "type": "quad", "material": "white", "corner": [-2, 2, -2], "edge_u": [4, 0, 0], "edge_v": [0, 0, 4] }},
    {{ "type": "quad", "material": "lamp", "corner": [-0.5, {lamp_y}, -0.5], "edge_u": [1, 0, 0], "edge_v": {lamp_v} }}
    {extra}
  ]
}}"#
        );
        parse_scene(&doc, &SceneOrigin::Request, &Limits::command_line())
            .unwrap_or_else(|e| panic!("{e}\n{doc}"))
    }

    fn messages(s: &Scene) -> Vec<String> {
        check(s).iter().map(ToString::to_string).collect()
    }

    #[test]
    fn a_lamp_facing_the_room_is_fine_and_one_facing_away_is_named() {
        // edge_u × edge_v: x × z = −y (down, into the room) for [0,0,1]; up for [0,0,-1].
        let down = room(1.99, "[0, 0, 1]", "", 1.0);
        assert!(messages(&down).is_empty(), "{:?}", messages(&down));
        // Facing up at the ceiling 1 cm above: it lights the ceiling, still fine.
        let at_ceiling = room(1.99, "[0, 0, -1]", "", 1.0);
        assert!(
            messages(&at_ceiling).is_empty(),
            "{:?}",
            messages(&at_ceiling)
        );
        // In the ceiling's plane facing out: nothing in front of it.
        let away = room(2.0, "[0, 0, -1]", "", 1.0);
        let w = check(&away);
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].path, "objects[2]");
        assert!(w[0].message.contains("faces away from every other object"));
    }

    #[test]
    fn almost_no_light_reaching_the_camera_is_named_with_the_level() {
        let dim = room(1.99, "[0, 0, 1]", "", 1e-4);
        let w = check(&dim);
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].path, "display.exposure");
        assert!(
            w[0].message.contains("0.10 % of display white"),
            "{}",
            w[0].message
        );
        // Just above the limit: no warning.
        assert!(check(&room(1.99, "[0, 0, 1]", "", 6e-4)).is_empty());
    }

    #[test]
    fn the_camera_inside_a_solid_is_named_but_not_inside_a_room() {
        let sphere =
            r#", { "type": "sphere", "material": "white", "center": [0, 1, 3.4], "radius": 0.5 }"#;
        let w = check(&room(1.99, "[0, 0, 1]", sphere, 1.0));
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].path, "camera.position");
        assert!(w[0].message.contains("objects[3]"), "{}", w[0].message);
        // A box (outward normals) around the camera: inside a solid.
        let boxed = r#", { "type": "box", "material": "white", "min": [-0.3, 0.7, 3.2], "max": [0.3, 1.3, 3.8] }"#;
        let w = check(&room(1.99, "[0, 0, 1]", boxed, 1.0));
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].message.contains("objects[3]"));
        // The same box beside the camera, and the open room around it: nothing.
        let beside = r#", { "type": "box", "material": "white", "min": [0.3, 0.7, 3.2], "max": [0.9, 1.3, 3.8] }"#;
        assert!(check(&room(1.99, "[0, 0, 1]", beside, 1.0)).is_empty());
    }

    #[test]
    fn no_bundled_example_warns() {
        for (name, text) in crate::scene::examples::EXAMPLES {
            let s = parse_scene(text, &SceneOrigin::Request, &Limits::command_line()).unwrap();
            assert!(check(&s).is_empty(), "{name}: {:?}", check(&s));
        }
    }
}
