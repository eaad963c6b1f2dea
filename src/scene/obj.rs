//! `obj` objects (scene-format.md): a Wavefront OBJ file relative to the scene file, read
//! for the command line only. The path is confined to the scene's folder so that a scene
//! file cannot make `glimpse` read arbitrary files (`/etc/passwd`, `../../secret.obj`).

use std::path::{Component, Path, PathBuf};

/// Raw triangles of an OBJ file, in the file's own coordinates.
#[derive(Clone, Debug, Default)]
pub struct ObjMesh {
    pub positions: Vec<[f32; 3]>,
    /// Per-position normals, present only when every model of the file has them.
    pub normals: Option<Vec<[f32; 3]>>,
    pub indices: Vec<[u32; 3]>,
}

/// Resolves `rel` inside `dir`, refusing absolute paths, `..` that climbs above `dir`, and
/// (after following symbolic links with `canonicalize`) anything that ends up outside it.
/// The error is the message for the `path` field.
pub fn resolve(dir: &Path, rel: &str) -> Result<PathBuf, String> {
    if rel.is_empty() {
        return Err("must not be empty".into());
    }
    let p = Path::new(rel);
    let mut depth: i64 = 0;
    for c in p.components() {
        match c {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir => {
                depth -= 1;
                if depth < 0 {
                    return Err(format!(
                        "\"{rel}\" climbs out of the scene's folder with `..`"
                    ));
                }
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err(format!("\"{rel}\" must be relative to the scene file"));
            }
        }
    }
    let joined = dir.join(p);
    let canon_dir = dir
        .canonicalize()
        .map_err(|e| format!("cannot resolve the scene's folder: {e}"))?;
    let canon = joined
        .canonicalize()
        .map_err(|e| format!("cannot open \"{rel}\": {e}"))?;
    if !canon.starts_with(&canon_dir) {
        return Err(format!("\"{rel}\" resolves outside the scene's folder"));
    }
    Ok(canon)
}

/// Loads every model of an OBJ file into one triangle list (materials and texture
/// coordinates of the file are ignored: the document's `material` applies).
pub fn load(path: &Path) -> Result<ObjMesh, String> {
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    // The second result (the .mtl materials) is deliberately ignored: a missing .mtl
    // must not fail a scene that does not use it.
    let (models, _materials) =
        tobj::load_obj(path, &opts).map_err(|e| format!("cannot load OBJ file: {e}"))?;
    let mut out = ObjMesh::default();
    let mut normals = Vec::new();
    let mut all_normals = true;
    for m in &models {
        let mesh = &m.mesh;
        let base = out.positions.len();
        let n = mesh.positions.len() / 3;
        out.positions
            .extend(mesh.positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        if mesh.normals.len() == mesh.positions.len() {
            normals.extend(mesh.normals.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        } else {
            all_normals = false;
        }
        for t in mesh.indices.chunks_exact(3) {
            let idx = [t[0], t[1], t[2]];
            if idx.iter().any(|&i| i as usize >= n) {
                return Err(format!("model \"{}\" has an index out of range", m.name));
            }
            let b = u32::try_from(base).map_err(|_| "too many vertices".to_string())?;
            out.indices.push([idx[0] + b, idx[1] + b, idx[2] + b]);
        }
    }
    if all_normals && !out.positions.is_empty() {
        out.normals = Some(normals);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let inner = dir.path().join("scenes");
        std::fs::create_dir(&inner).unwrap();
        std::fs::write(dir.path().join("secret.obj"), "v 0 0 0\n").unwrap();
        std::fs::write(inner.join("ok.obj"), "v 0 0 0\n").unwrap();
        assert!(resolve(&inner, "../secret.obj").unwrap_err().contains(".."));
        assert!(resolve(&inner, "a/../../secret.obj").is_err());
        assert!(resolve(&inner, "/etc/passwd")
            .unwrap_err()
            .contains("relative"));
        assert!(resolve(&inner, "").is_err());
        assert!(resolve(&inner, "missing.obj").is_err());
        // `..` that stays inside is fine.
        std::fs::create_dir(inner.join("sub")).unwrap();
        assert!(resolve(&inner, "sub/../ok.obj").is_ok());
        assert!(resolve(&inner, "./ok.obj").is_ok());
    }

    #[cfg(unix)]
    #[test]
    fn symlink_out_of_the_folder_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let inner = dir.path().join("scenes");
        std::fs::create_dir(&inner).unwrap();
        std::fs::write(dir.path().join("secret.obj"), "v 0 0 0\n").unwrap();
        std::os::unix::fs::symlink(dir.path().join("secret.obj"), inner.join("link.obj")).unwrap();
        assert!(resolve(&inner, "link.obj").unwrap_err().contains("outside"));
    }

    #[test]
    fn loads_and_triangulates_a_quad() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("q.obj");
        std::fs::write(&p, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n").unwrap();
        let m = load(&p).unwrap();
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.indices.len(), 2);
        assert!(m.normals.is_none());
    }
}
