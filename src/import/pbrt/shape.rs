//! Shapes (pbrt-v4 file format, "Shapes") and object instancing: `Shape` reads a
//! sphere, an inline `trianglemesh`/`bilinearmesh` or a `plymesh` into world space under
//! the current transform, material and area light; `ObjectBegin`/`ObjectEnd` define a
//! named list of shapes that `ObjectInstance` places again under its own transform.

use glam::{DMat3, DMat4, DVec3};

use super::lexer::{Lexer, Pos};
use super::params::{self, Cap, Params, Values};
use super::{list_cap, Emission, ImportError, Importer, Prim};
use crate::scene::doc::{DiffuseDoc, MaterialDoc};

/// A mesh's lists as read: positions, normals, (u, v)s and triangles.
type Lists = (
    Vec<DVec3>,
    Option<Vec<DVec3>>,
    Option<Vec<[f32; 2]>>,
    Vec<[u32; 3]>,
);

impl Importer<'_> {
    /// `Shape "type" params`, its parameters capped by what the triangle limit leaves.
    pub(super) fn shape_directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        self.shapes += 1;
        let ty = Self::string(lx, pos, dir)?;
        let p = params::parse(lx, &|name, so_far| self.shape_cap(&ty, name, so_far))?;
        self.shape(&ty, &p, pos)
    }

    /// The cap of a shape's parameter, from the triangle limit: `indices` may hold the
    /// scene's remaining room, and a point list (`P`, `N`, `S`, `uv`) no more points than
    /// the indices read before it can use (4096 spare), or than three per triangle of that
    /// room when the points come first. Unused points are dropped later
    /// ([`drop_unused_points`]); these caps bound what reading them costs.
    fn shape_cap(&self, ty: &str, name: &str, so_far: &Params) -> Cap {
        let room = self.limits.max_triangles.saturating_sub(self.triangles);
        let limit = self.limits.max_triangles;
        // Numbers per triangle in `indices`: a bilinear patch is 4 indices, 2 triangles.
        let per_triangle = if ty == "bilinearmesh" { 2 } else { 3 };
        let width = match name {
            "indices" => {
                return Cap {
                    max: room.saturating_mul(per_triangle),
                    why: format!("the scene's limit of {limit} triangles"),
                }
            }
            "P" | "N" | "S" => 3,
            "uv" | "st" => 2,
            _ => return list_cap(name, so_far),
        };
        let (points, why) = match so_far.get("indices").map(|p| &p.values) {
            Some(Values::Nums(idx)) => (
                idx.len().saturating_add(4096),
                format!(
                    "one point per index read before it ({}), 4096 spare",
                    idx.len()
                ),
            ),
            _ => (
                room.saturating_mul(3).max(4),
                format!("three points per triangle of the scene's limit of {limit} triangles"),
            ),
        };
        Cap {
            max: points.saturating_mul(width),
            why,
        }
    }

    /// One shape under the graphics state: its material (pbrt's default if none), its
    /// emission (none inside an object definition), then its geometry by type.
    fn shape(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<(), ImportError> {
        if !self.world {
            return Err(pos.error("`Shape` before `WorldBegin`"));
        }
        if p.get("alpha").is_some() {
            self.warn(
                pos,
                "shape alpha (cut-outs) is not modelled: the shape is opaque",
            );
        }
        let m = self.state.ctm;
        let flip = self.state.reverse ^ (DMat3::from_mat4(m).determinant() < 0.0);
        let material = self.shape_material();
        let emission = self.shape_emission(pos);
        let lists = match ty {
            "sphere" => return self.sphere(p, pos, &m, material, emission),
            "trianglemesh" | "bilinearmesh" => self.inline_mesh(ty, p, pos)?,
            "plymesh" => self.ply_mesh(p, pos)?,
            other => {
                return Err(pos.error(format!(
                "shape \"{other}\" is not supported (trianglemesh, bilinearmesh, plymesh, sphere)"
            )))
            }
        };
        self.count_triangles(lists.3.len(), pos)?;
        let (positions, normals, uvs, indices) = drop_unused_points(lists);
        let normal_m = DMat3::from_mat4(m).inverse().transpose();
        let prim = Prim::Mesh {
            positions: positions.iter().map(|&q| m.transform_point3(q)).collect(),
            normals: normals.map(|ns: Vec<DVec3>| ns.iter().map(|&n| normal_m * n).collect()),
            uvs,
            indices,
            flip,
            material,
            emission,
        };
        self.emit_prims(vec![prim]);
        Ok(())
    }

    /// The current material's key; without one, pbrt's default material (diffuse 0.5),
    /// made the first time it is needed.
    fn shape_material(&mut self) -> String {
        let material = self.state.material.clone();
        if !material.is_empty() {
            return material;
        }
        self.materials
            .entry("default".into())
            .or_insert(MaterialDoc::Diffuse(DiffuseDoc {
                albedo: Some([0.5; 3]),
                texture: None,
            }));
        "default".into()
    }

    /// The current area light's emission; inside an object definition none, as in
    /// pbrt-v4 (with a warning).
    fn shape_emission(&mut self, pos: &Pos) -> Option<Emission> {
        let emission = self.state.area.clone();
        if emission.is_some() && self.defining.is_some() {
            self.warn(
                pos,
                "area lights inside an object instance do not emit (as in pbrt-v4)",
            );
        }
        if self.defining.is_some() {
            None
        } else {
            emission
        }
    }

    /// A whole sphere at the origin under `m`, which must scale uniformly (the document's
    /// sphere has one radius).
    fn sphere(
        &mut self,
        p: &Params,
        pos: &Pos,
        m: &DMat4,
        material: String,
        emission: Option<Emission>,
    ) -> Result<(), ImportError> {
        let r = p.float("radius", 1.0)?;
        if r.is_nan() || r <= 0.0 {
            return Err(pos.error(format!("sphere radius must be > 0, got {r}")));
        }
        if p.get("zmin").is_some() || p.get("zmax").is_some() || p.get("phimax").is_some() {
            self.warn(pos, "partial sphere (zmin/zmax/phimax): rendered whole");
        }
        let lin = DMat3::from_mat4(*m);
        let scales = [
            lin.x_axis.length(),
            lin.y_axis.length(),
            lin.z_axis.length(),
        ];
        let (lo, hi) = scales
            .iter()
            .fold((f64::MAX, 0f64), |(a, b), &s| (a.min(s), b.max(s)));
        if hi - lo > 1e-6 * hi {
            return Err(pos.error("a sphere under a non-uniform scale is not supported"));
        }
        self.emit_prims(vec![Prim::Sphere {
            center: m.transform_point3(DVec3::ZERO),
            radius: r * hi,
            material,
            emission,
        }]);
        Ok(())
    }

    /// A `plymesh`: the PLY file read within the triangles the scene has room for.
    fn ply_mesh(&mut self, p: &Params, pos: &Pos) -> Result<Lists, ImportError> {
        let (file, fpos) = p
            .string("filename")?
            .ok_or_else(|| pos.error("plymesh has no filename"))?;
        let (file, fpos) = (file.to_string(), fpos.clone());
        if p.get("displacement").is_some() {
            self.warn(
                pos,
                "displacement is not modelled: the mesh is rendered undisplaced",
            );
        }
        let bytes = self.open(&file, &fpos)?;
        let room = self.limits.max_triangles.saturating_sub(self.triangles);
        let mesh = crate::import::ply::parse(&bytes, room).map_err(|e| {
            let msg = format!("\"{file}\": {e}");
            if e.contains("limit of") {
                ImportError::limit(fpos.to_string(), msg)
            } else {
                fpos.error(msg)
            }
        })?;
        let pos3 = |v: &[f32; 3]| DVec3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
        Ok((
            mesh.positions.iter().map(pos3).collect(),
            mesh.normals.map(|ns| ns.iter().map(pos3).collect()),
            mesh.uvs,
            mesh.indices,
        ))
    }

    /// `trianglemesh` (`P`, `indices`, `N`, `uv`) or `bilinearmesh` (`P`, `indices` of
    /// quads p00 p10 p01 p11, split into two triangles).
    fn inline_mesh(&mut self, ty: &str, p: &Params, pos: &Pos) -> Result<Lists, ImportError> {
        let (pts, ppos) = p
            .nums("P")?
            .ok_or_else(|| pos.error(format!("{ty} has no \"point3 P\"")))?;
        if pts.len() % 3 != 0 || pts.is_empty() {
            return Err(ppos.error(format!(
                "\"P\" must hold a multiple of 3 numbers, got {}",
                pts.len()
            )));
        }
        let positions: Vec<DVec3> = pts
            .chunks_exact(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]))
            .collect();
        let n = positions.len();
        let indices = mesh_indices(ty, p, pos, n)?;
        let normals = mesh_normals(p, n)?;
        let uvs = mesh_uvs(p, n)?;
        Ok((positions, normals, uvs, indices))
    }

    /// `ObjectBegin`, `ObjectEnd` and `ObjectInstance` (pbrt-v4 file format, "Object
    /// instancing").
    pub(super) fn object_directive(
        &mut self,
        dir: &str,
        pos: &Pos,
        lx: &mut Lexer,
    ) -> Result<(), ImportError> {
        match dir {
            "ObjectBegin" => {
                let name = Self::string(lx, pos, dir)?;
                if self.defining.is_some() {
                    return Err(pos.error("`ObjectBegin` inside another object definition"));
                }
                self.stack.push((self.state.clone(), pos.clone()));
                self.defining = Some((name, Vec::new()));
            }
            "ObjectEnd" => {
                let (name, prims) = self
                    .defining
                    .take()
                    .ok_or_else(|| pos.error("`ObjectEnd` without `ObjectBegin`"))?;
                self.instances.insert(name, prims);
                let (s, _) = self
                    .stack
                    .pop()
                    .ok_or_else(|| pos.error("`ObjectEnd` without `ObjectBegin`"))?;
                self.state = s;
            }
            // `ObjectInstance`
            _ => self.object_instance(dir, pos, lx)?,
        }
        Ok(())
    }

    /// `ObjectInstance`: the named object's shapes placed by the current transform.
    fn object_instance(&mut self, dir: &str, pos: &Pos, lx: &mut Lexer) -> Result<(), ImportError> {
        let name = Self::string(lx, pos, dir)?;
        let prims = self
            .instances
            .get(&name)
            .ok_or_else(|| pos.error(format!("unknown object \"{name}\"")))?;
        let count: usize = prims.iter().map(prim_triangles).sum();
        if self.prims.len() + prims.len() > self.limits.max_objects {
            return Err(self.too_many(pos, "objects (shapes)"));
        }
        let m = self.state.ctm;
        let placed: Vec<Prim> = prims.iter().map(|p| transform_prim(p, &m)).collect();
        self.count_triangles(count, pos)?;
        self.emit_prims(placed);
        Ok(())
    }
}

/// A mesh's triangles from `indices` (optional when there are exactly 3 points, or 4 for
/// a bilinear patch), each checked against the `n` points.
fn mesh_indices(ty: &str, p: &Params, pos: &Pos, n: usize) -> Result<Vec<[u32; 3]>, ImportError> {
    let per = if ty == "bilinearmesh" { 4 } else { 3 };
    let idx: Vec<f64> = match p.nums("indices")? {
        Some((v, _)) => v.to_vec(),
        None if n == per => (0..per).map(|i| i as f64).collect(),
        None => {
            return Err(pos.error(format!(
                "{ty} has no \"integer indices\" (required unless there are exactly {per} points)"
            )))
        }
    };
    let ipos = p.get("indices").map_or(pos, |q| &q.pos).clone();
    if !idx.len().is_multiple_of(per) {
        return Err(ipos.error(format!(
            "\"indices\" must hold a multiple of {per} numbers, got {}",
            idx.len()
        )));
    }
    if let Some(bad) = idx.iter().find(|&&i| !(i >= 0.0 && (i as usize) < n)) {
        return Err(ipos.error(format!(
            "index {bad} is out of range: the mesh has {n} points"
        )));
    }
    let indices: Vec<[u32; 3]> = if per == 3 {
        idx.chunks_exact(3)
            .map(|c| [c[0] as u32, c[1] as u32, c[2] as u32])
            .collect()
    } else {
        idx.chunks_exact(4)
            .flat_map(|c| {
                let q = [c[0] as u32, c[1] as u32, c[2] as u32, c[3] as u32];
                [[q[0], q[1], q[3]], [q[0], q[3], q[2]]]
            })
            .collect()
    };
    Ok(indices)
}

/// A mesh's shading normals `N`, 3 numbers per point, if it has them.
fn mesh_normals(p: &Params, n: usize) -> Result<Option<Vec<DVec3>>, ImportError> {
    Ok(match p.nums("N")? {
        None => None,
        Some((v, npos)) => {
            if v.len() != 3 * n {
                return Err(npos.error(format!(
                    "\"N\" must hold 3 numbers per point ({}), got {}",
                    3 * n,
                    v.len()
                )));
            }
            Some(
                v.chunks_exact(3)
                    .map(|c| DVec3::new(c[0], c[1], c[2]))
                    .collect(),
            )
        }
    })
}

/// A mesh's (u, v)s, 2 numbers per point, if it has them.
fn mesh_uvs(p: &Params, n: usize) -> Result<Option<Vec<[f32; 2]>>, ImportError> {
    // pbrt-v4 calls them `uv` (pbrt-v3 files may still say `st`).
    let uv_param = if p.get("uv").is_some() { "uv" } else { "st" };
    Ok(match p.nums(uv_param)? {
        None => None,
        Some((v, upos)) => {
            if v.len() != 2 * n {
                return Err(upos.error(format!(
                    "\"{uv_param}\" must hold 2 numbers per point ({}), got {}",
                    2 * n,
                    v.len()
                )));
            }
            Some(
                v.chunks_exact(2)
                    .map(|c| [c[0] as f32, c[1] as f32])
                    .collect(),
            )
        }
    })
}

/// A mesh without the points no triangle uses
/// ([`crate::import::drop_unused_vertices`]).
fn drop_unused_points((positions, normals, uvs, mut indices): Lists) -> Lists {
    let (positions, normals, uvs) =
        crate::import::drop_unused_vertices(positions, normals, uvs, indices.as_flattened_mut());
    (positions, normals, uvs, indices)
}

fn prim_triangles(p: &Prim) -> usize {
    match p {
        Prim::Mesh { indices, .. } => indices.len(),
        Prim::Sphere { .. } => 0,
    }
}

/// An instance's primitive placed by `m` (pbrt: instance world = CTM at
/// `ObjectInstance` × the shape's CTM at definition).
fn transform_prim(p: &Prim, m: &DMat4) -> Prim {
    match p {
        Prim::Mesh {
            positions,
            normals,
            uvs,
            indices,
            flip,
            material,
            emission,
        } => {
            let nm = DMat3::from_mat4(*m).inverse().transpose();
            Prim::Mesh {
                positions: positions.iter().map(|&q| m.transform_point3(q)).collect(),
                normals: normals
                    .as_ref()
                    .map(|ns| ns.iter().map(|&n| nm * n).collect()),
                uvs: uvs.clone(),
                indices: indices.clone(),
                flip: *flip ^ (DMat3::from_mat4(*m).determinant() < 0.0),
                material: material.clone(),
                emission: emission.clone(),
            }
        }
        Prim::Sphere {
            center,
            radius,
            material,
            emission,
        } => {
            let lin = DMat3::from_mat4(*m);
            Prim::Sphere {
                center: m.transform_point3(*center),
                radius: radius * lin.x_axis.length(),
                material: material.clone(),
                emission: emission.clone(),
            }
        }
    }
}
