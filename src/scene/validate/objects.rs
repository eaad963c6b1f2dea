//! The `objects` section of scene-format.md: transforms, then each kind of object built
//! into world-space shapes.

use super::*;
use crate::scene::doc::{BoxDoc, MeshDoc, ObjDoc, QuadDoc, SphereDoc};

/// Checks a transform; `None` if it is unusable (the object is then not built).
fn check_transform(cx: &mut Ctx, p: &str, t: Option<&TransformDoc>) -> Option<Xform> {
    let Some(td) = t else {
        return Some(Xform::IDENTITY);
    };
    let before = cx.errors.len() + cx.unlisted_errors;
    if let Some(tr) = td.translate {
        cx.vec3(&format!("{p}.translate"), tr);
    }
    for (name, r) in [
        ("rotate_x", td.rotate_x),
        ("rotate_y", td.rotate_y),
        ("rotate_z", td.rotate_z),
    ] {
        if let Some(r) = r {
            cx.finite(&format!("{p}.{name}"), r);
        }
    }
    match td.scale {
        None => {}
        Some(ScaleDoc::Uniform(s)) => {
            let sp = format!("{p}.scale");
            if cx.finite(&sp, s) && s == 0.0 {
                cx.err(&sp, "must be non-zero (a zero scale flattens the object)");
            }
        }
        Some(ScaleDoc::Axes(a)) => {
            for (i, s) in a.iter().enumerate() {
                let sp = format!("{p}.scale[{i}]");
                if cx.finite(&sp, *s) && *s == 0.0 {
                    cx.err(&sp, "must be non-zero (a zero scale flattens the object)");
                }
            }
        }
    }
    (cx.errors.len() + cx.unlisted_errors == before).then(|| Xform::from_doc(Some(td)))
}

/// Appends a world-space triangle unless it is degenerate (then a warning at `path`).
/// Mirroring transforms swap two vertices so the geometric normal `(p1−p0)×(p2−p0)` is
/// still the transformed normal.
/// `path` is formatted only for a triangle that gets a warning: a mesh of 10^6 triangles
/// must not format 10^6 paths.
fn push_triangle(
    cx: &mut Ctx,
    out: &mut Vec<Triangle>,
    path: impl FnOnce() -> String,
    x: &Xform,
    mut p: [Vec3; 3],
    mut n: Option<[Vec3; 3]>,
    mut uv: Option<[Vec2; 3]>,
) {
    if x.mirrors {
        p.swap(1, 2);
        if let Some(n) = n.as_mut() {
            n.swap(1, 2);
        }
        if let Some(uv) = uv.as_mut() {
            uv.swap(1, 2);
        }
    }
    // A vertex out of range refuses the whole object (reported once by `build`), before the
    // degenerate test: a far-out corner can swallow its edges in f32 and look degenerate.
    let far = p.iter().fold(false, |far, &v| note_far(cx, v) | far);
    if far {
        return;
    }
    let (e1, e2, e3) = (p[1] - p[0], p[2] - p[0], p[2] - p[1]);
    let lmax2 = e1
        .length_squared()
        .max(e2.length_squared())
        .max(e3.length_squared());
    let area2 = e1.cross(e2).length();
    // Written so that NaN also counts as degenerate (every comparison with NaN is false);
    // vertices are finite and in range here, so this is only a guard.
    let sound = area2 > DEGENERATE_REL * lmax2 && lmax2.is_finite();
    if !sound {
        cx.warn(
            &path(),
            "degenerate triangle (collinear or coincident points): ignored".into(),
        );
        return;
    }
    out.push(Triangle { p, n, uv });
}

/// The two triangles of a quad: (c, c+u, c+u+v) and (c, c+u+v, c+v). Both have geometric
/// normal `u × v` (scene-format.md), which decides the emitting side of a one-sided light.
fn quad_corners(c: Vec3, u: Vec3, v: Vec3) -> [[Vec3; 3]; 2] {
    [[c, c + u, c + u + v], [c, c + u + v, c + v]]
}

/// A quad's texture coordinates at [`quad_corners`]: (s, t) of `corner + s·edge_u +
/// t·edge_v`, so an image texture spans the quad once.
const QUAD_UVS: [[Vec2; 3]; 2] = [
    [Vec2::ZERO, Vec2::X, Vec2::ONE],
    [Vec2::ZERO, Vec2::ONE, Vec2::Y],
];

/// The quad (corner `c`, edges `u`, `v`) of the object at JSON path `p`, transformed by
/// `x`, as two triangles with [`QUAD_UVS`] appended to `out`.
fn push_quad(cx: &mut Ctx, out: &mut Vec<Triangle>, p: &str, x: &Xform, [c, u, v]: [Vec3; 3]) {
    for (t, uv) in quad_corners(c, u, v).into_iter().zip(QUAD_UVS) {
        push_triangle(
            cx,
            out,
            || p.to_string(),
            x,
            t.map(|q| x.point(q)),
            None,
            Some(uv),
        );
    }
}

pub(super) fn check_object(
    cx: &mut Ctx,
    k: usize,
    o: &ObjectDoc,
    names: &[String],
    origin: &SceneOrigin,
) -> Option<Shape> {
    let p = format!("objects[{k}]");
    let material = match names.binary_search_by(|n| n.as_str().cmp(o.material())) {
        Ok(i) => u32::try_from(i).ok(),
        Err(_) => {
            let known = if names.is_empty() {
                "no materials are defined".to_string()
            } else {
                format!("defined: {}", names.join(", "))
            };
            cx.err(
                &format!("{p}.material"),
                format!("unknown material \"{}\"; {known}", o.material()),
            );
            None
        }
    };
    let x = check_transform(cx, &format!("{p}.transform"), o.transform());
    match o {
        ObjectDoc::Sphere(s) => sphere(cx, &p, s, x, material),
        ObjectDoc::Quad(q) => quad(cx, &p, q, x, material),
        ObjectDoc::Box(b) => box_object(cx, &p, b, x, material),
        ObjectDoc::Mesh(m) => mesh(cx, &p, m, x, material),
        ObjectDoc::Obj(ob) => obj_file(cx, &p, ob, x, material, origin),
    }
}

fn sphere(
    cx: &mut Ctx,
    p: &str,
    s: &SphereDoc,
    x: Option<Xform>,
    material: Option<u32>,
) -> Option<Shape> {
    let center = cx.vec3(&format!("{p}.center"), s.center);
    cx.positive(&format!("{p}.radius"), s.radius);
    let x = x?;
    // A sphere stays a sphere (the tracer intersects it analytically), so only a
    // uniform scale is meaningful; an ellipsoid must be sent as a mesh. A
    // negative uniform scale is a point reflection: the radius uses |s|.
    let s_abs = x.scale.abs();
    let (lo, hi) = (s_abs.min_element(), s_abs.max_element());
    if hi - lo > 1e-6 * hi {
        cx.err(
            &format!("{p}.transform.scale"),
            "must be uniform on a sphere (a sphere stays a sphere; send a mesh for an ellipsoid)",
        );
        return None;
    }
    let radius = s.radius * hi;
    Some(Shape::Sphere {
        center: x.point(center),
        radius,
        material: material?,
    })
}

fn quad(
    cx: &mut Ctx,
    p: &str,
    q: &QuadDoc,
    x: Option<Xform>,
    material: Option<u32>,
) -> Option<Shape> {
    let c = cx.vec3(&format!("{p}.corner"), q.corner);
    let u = cx.vec3(&format!("{p}.edge_u"), q.edge_u);
    let v = cx.vec3(&format!("{p}.edge_v"), q.edge_v);
    if !(c.is_finite() && u.is_finite() && v.is_finite()) {
        return None;
    }
    // Zero area: |u × v| ≤ DEGENERATE_REL·|u||v| (zero or parallel edges). Unlike a
    // mesh triangle this is an error: a quad is written by hand, one at a time.
    if u.length_squared() == 0.0 {
        cx.err(&format!("{p}.edge_u"), "quad has zero area: edge_u is zero");
        return None;
    }
    let has_area = u.cross(v).length() > DEGENERATE_REL * u.length() * v.length();
    if !has_area {
        cx.err(
            &format!("{p}.edge_v"),
            "quad has zero area: edge_v is zero or parallel to edge_u",
        );
        return None;
    }
    let x = x?;
    let mut tris = Vec::with_capacity(2);
    push_quad(cx, &mut tris, p, &x, [c, u, v]);
    Some(Shape::Triangles {
        triangles: tris,
        material: material?,
    })
}

fn box_object(
    cx: &mut Ctx,
    p: &str,
    b: &BoxDoc,
    x: Option<Xform>,
    material: Option<u32>,
) -> Option<Shape> {
    let lo = cx.vec3(&format!("{p}.min"), b.min);
    let hi = cx.vec3(&format!("{p}.max"), b.max);
    if !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    if let Some(axis) = (0..3).find(|&i| lo[i] >= hi[i]) {
        cx.err(
            &format!("{p}.max"),
            format!(
                "must exceed min on every axis; axis {} has min {} and max {}",
                ["x", "y", "z"][axis],
                lo[axis],
                hi[axis]
            ),
        );
        return None;
    }
    let x = x?;
    let d = hi - lo;
    let (dx, dy, dz) = (Vec3::X * d.x, Vec3::Y * d.y, Vec3::Z * d.z);
    // Six faces as quads whose u × v points outwards.
    let faces = [
        (lo, dz, dy),                          // −x
        (Vec3::new(hi.x, lo.y, lo.z), dy, dz), // +x
        (lo, dx, dz),                          // −y
        (Vec3::new(lo.x, hi.y, lo.z), dz, dx), // +y
        (lo, dy, dx),                          // −z
        (Vec3::new(lo.x, lo.y, hi.z), dx, dy), // +z
    ];
    let mut tris = Vec::with_capacity(12);
    for (c, u, v) in faces {
        push_quad(cx, &mut tris, p, &x, [c, u, v]);
    }
    Some(Shape::Triangles {
        triangles: tris,
        material: material?,
    })
}

fn mesh(
    cx: &mut Ctx,
    p: &str,
    m: &MeshDoc,
    x: Option<Xform>,
    material: Option<u32>,
) -> Option<Shape> {
    let idx_path = format!("{p}.indices");
    let before = cx.errors.len() + cx.unlisted_errors;
    check_mesh_arrays(cx, p, m);
    if cx.errors.len() + cx.unlisted_errors != before {
        return None;
    }
    let x = x?;
    let world: Vec<Vec3> = m
        .positions
        .iter()
        .map(|q| x.point(Vec3::from(*q)))
        .collect();
    let normals: Option<Vec<Vec3>> = m
        .normals
        .as_ref()
        .map(|ns| ns.iter().map(|n| x.normal(Vec3::from(*n))).collect());
    let mut tris = Vec::with_capacity(m.indices.len());
    for (i, t) in m.indices.iter().enumerate() {
        // In range (checked above), so the casts cannot truncate.
        let ix = t.map(|v| v as usize);
        push_triangle(
            cx,
            &mut tris,
            || format!("{idx_path}[{i}]"),
            &x,
            ix.map(|v| world[v]),
            normals.as_ref().map(|ns| ix.map(|v| ns[v])),
            m.uvs.as_ref().map(|uvs| ix.map(|v| Vec2::from(uvs[v]))),
        );
    }
    Some(Shape::Triangles {
        triangles: tris,
        material: material?,
    })
}

fn obj_file(
    cx: &mut Ctx,
    p: &str,
    ob: &ObjDoc,
    x: Option<Xform>,
    material: Option<u32>,
    origin: &SceneOrigin,
) -> Option<Shape> {
    let pp = format!("{p}.path");
    let dir = match origin {
        SceneOrigin::Request => {
            cx.err(
                &pp,
                "obj files are accepted by the command line only; send a mesh",
            );
            return None;
        }
        SceneOrigin::File { dir } => dir,
    };
    let file = match obj::resolve(dir, &ob.path) {
        Ok(f) => f,
        Err(msg) => {
            cx.err(&pp, msg);
            return None;
        }
    };
    let mesh = match obj::load(&file) {
        Ok(m) => m,
        Err(msg) => {
            cx.err(&pp, format!("\"{}\": {msg}", ob.path));
            return None;
        }
    };
    let x = x?;
    let world: Vec<Vec3> = mesh
        .positions
        .iter()
        .map(|q| x.point(Vec3::from(*q)))
        .collect();
    let normals: Option<Vec<Vec3>> = mesh
        .normals
        .as_ref()
        .map(|ns| ns.iter().map(|n| x.normal(Vec3::from(*n))).collect());
    let mut tris = Vec::with_capacity(mesh.indices.len());
    for t in &mesh.indices {
        let ix = t.map(|v| v as usize);
        // A zero normal in the file (rare) would poison shading: drop all normals
        // of that triangle rather than the triangle.
        let n = normals
            .as_ref()
            .map(|ns| ix.map(|v| ns[v]))
            .filter(|n| n.iter().all(|v| v.length_squared() > 0.0));
        push_triangle(
            cx,
            &mut tris,
            || pp.clone(),
            &x,
            ix.map(|v| world[v]),
            n,
            None,
        );
    }
    Some(Shape::Triangles {
        triangles: tris,
        material: material?,
    })
}

/// A mesh's arrays: finite positions, one non-zero normal and one finite uv per position
/// when given, indices in range.
/// Every entry of a mesh's arrays finite (normals also non-zero) and every index in
/// range; an entry's path is formatted only when it has a problem (10^6 vertices must not
/// format 4·10^6 paths).
fn check_mesh_arrays(cx: &mut Ctx, p: &str, m: &MeshDoc) {
    let finite = |v: &[f32]| v.iter().all(|c| c.is_finite());
    for (i, q) in m.positions.iter().enumerate() {
        if !finite(q) {
            cx.vec3(&format!("{p}.positions[{i}]"), *q);
        }
    }
    if let Some(ns) = &m.normals {
        if ns.len() != m.positions.len() {
            cx.err(
                &format!("{p}.normals"),
                format!(
                    "has {} entries; expected one per position ({})",
                    ns.len(),
                    m.positions.len()
                ),
            );
        } else {
            for (i, n) in ns.iter().enumerate() {
                if finite(n) && Vec3::from(*n).length_squared() != 0.0 {
                    continue;
                }
                let np = format!("{p}.normals[{i}]");
                if cx.vec3(&np, *n).length_squared() == 0.0 {
                    cx.err(&np, "must be non-zero");
                }
            }
        }
    }
    if let Some(uvs) = &m.uvs {
        if uvs.len() != m.positions.len() {
            cx.err(
                &format!("{p}.uvs"),
                format!(
                    "has {} entries; expected one per position ({})",
                    uvs.len(),
                    m.positions.len()
                ),
            );
        } else {
            for (i, uv) in uvs.iter().enumerate().filter(|(_, uv)| !finite(&uv[..])) {
                for (j, c) in uv.iter().enumerate() {
                    cx.finite(&format!("{p}.uvs[{i}][{j}]"), *c);
                }
            }
        }
    }
    let count = m.positions.len() as u64;
    for (i, t) in m.indices.iter().enumerate() {
        for (j, &ix) in t.iter().enumerate() {
            if ix >= count {
                cx.err(
                    &format!("{p}.indices[{i}][{j}]"),
                    format!("index {ix} is out of range: the mesh has {count} positions"),
                );
            }
        }
    }
}
