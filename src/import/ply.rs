//! A PLY reader for the meshes pbrt scenes name (`plymesh`): ASCII and binary (both byte
//! orders), a `vertex` element with `x y z` and optional normals and texture coordinates,
//! a `face` element with a vertex-index list (triangles, quads and larger polygons, the
//! latter as fans). Other elements and properties are skipped.
//!
//! Every count in the header is checked against what the bytes can hold and against the
//! triangle limit *before* anything is allocated: a 40-byte header claiming 2^31 vertices
//! is refused, not reserved.

/// A triangle mesh in the file's coordinates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlyMesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    pub uvs: Option<Vec<[f32; 2]>>,
    pub indices: Vec<[u32; 3]>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    Little,
    Big,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Clone, Debug)]
enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
}

/// Reads values one at a time from the body, in the file's format.
struct Body<'a> {
    bytes: &'a [u8],
    at: usize,
    format: Format,
}

impl Body<'_> {
    fn value(&mut self, t: Scalar) -> Result<f64, String> {
        if self.format == Format::Ascii {
            return self.ascii_value();
        }
        let n = t.size();
        let b = self
            .bytes
            .get(self.at..self.at + n)
            .ok_or_else(|| format!("ends early at byte {} (truncated file)", self.at))?;
        self.at += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.format == Format::Big {
            a[..n].reverse();
        }
        Ok(match t {
            Scalar::I8 => f64::from(a[0] as i8),
            Scalar::U8 => f64::from(a[0]),
            Scalar::I16 => f64::from(i16::from_le_bytes([a[0], a[1]])),
            Scalar::U16 => f64::from(u16::from_le_bytes([a[0], a[1]])),
            Scalar::I32 => f64::from(i32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            Scalar::U32 => f64::from(u32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            Scalar::F32 => f64::from(f32::from_le_bytes([a[0], a[1], a[2], a[3]])),
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }

    fn ascii_value(&mut self) -> Result<f64, String> {
        let rest = &self.bytes[self.at..];
        let start = rest
            .iter()
            .position(|c| !c.is_ascii_whitespace())
            .ok_or("ends early (truncated file)")?;
        let len = rest[start..]
            .iter()
            .position(u8::is_ascii_whitespace)
            .unwrap_or(rest.len() - start);
        let word = &rest[start..start + len];
        self.at += start + len;
        std::str::from_utf8(word)
            .ok()
            .and_then(|w| w.parse::<f64>().ok())
            .ok_or_else(|| format!("`{}` is not a number", String::from_utf8_lossy(word)))
    }
}

/// Parses a PLY file. `max_triangles` bounds the faces (after fan triangulation).
pub fn parse(bytes: &[u8], max_triangles: usize) -> Result<PlyMesh, String> {
    let (format, elements, body_start) = header(bytes)?;
    let body_len = (bytes.len() - body_start) as u64;
    // Smallest possible size of each element: a binary vertex is its fixed stride, a face
    // at least its list counts; ASCII needs at least 2 bytes per value ("0 ").
    let mut need = 0u64;
    for e in &elements {
        let min: u64 = e
            .props
            .iter()
            .map(|p| match (p, format) {
                (_, Format::Ascii) => 2,
                (Property::Scalar(_, t), _) => t.size() as u64,
                (Property::List(_, c, _), _) => c.size() as u64,
            })
            .sum();
        need = need.saturating_add(e.count.saturating_mul(min.max(1)));
    }
    if need > body_len {
        return Err(format!(
            "the header declares more data ({need} bytes at least) than the file holds ({body_len} bytes)"
        ));
    }
    // A mesh uses at most three vertices per triangle: more are unused, and reading them
    // would cost memory for nothing (the importer drops unused points).
    let max_vertices = (max_triangles as u64)
        .saturating_mul(3)
        .saturating_add(4096);
    if let Some(v) = elements
        .iter()
        .find(|e| e.name == "vertex" && e.count > max_vertices)
    {
        return Err(format!(
            "{} vertices are more than the limit of {max_vertices} (three per triangle of the limit of {max_triangles} triangles left, 4096 spare)",
            v.count
        ));
    }
    let mut body = Body {
        bytes,
        at: body_start,
        format,
    };
    let mut mesh = PlyMesh::default();
    for e in &elements {
        match e.name.as_str() {
            "vertex" => read_vertices(&mut body, e, &mut mesh)?,
            "face" => read_faces(&mut body, e, &mut mesh, max_triangles)?,
            _ => skip(&mut body, e)?,
        }
    }
    let n = mesh.positions.len() as u64;
    if let Some(bad) = mesh.indices.iter().flatten().find(|&&i| u64::from(i) >= n) {
        return Err(format!(
            "face index {bad} is out of range: the file has {n} vertices"
        ));
    }
    Ok(mesh)
}

fn header(bytes: &[u8]) -> Result<(Format, Vec<Element>, usize), String> {
    const END: &[u8] = b"end_header";
    // A header is a few hundred bytes; 64 KiB is far beyond any real one.
    let window = &bytes[..bytes.len().min(65536)];
    let end = window
        .windows(END.len())
        .position(|w| w == END)
        .ok_or("no `end_header` in the first 64 KiB: not a PLY file")?;
    let mut body_start = end + END.len();
    // The header line ends with \n or \r\n.
    if bytes.get(body_start) == Some(&b'\r') {
        body_start += 1;
    }
    if bytes.get(body_start) == Some(&b'\n') {
        body_start += 1;
    }
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| "the header is not text")?;
    let mut lines = text.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err("does not start with `ply`".into());
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (k, line) in lines.enumerate() {
        let w: Vec<&str> = line.split_whitespace().collect();
        let bad = || format!("header line {}: cannot read `{line}`", k + 2);
        match w.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    _ => return Err(format!("unknown PLY format `{f}`")),
                });
            }
            ["element", name, count] => elements.push(Element {
                name: (*name).to_string(),
                count: count.parse().map_err(|_| bad())?,
                props: Vec::new(),
            }),
            ["property", "list", c, t, name] => {
                let (c, t) = (
                    Scalar::parse(c).ok_or_else(bad)?,
                    Scalar::parse(t).ok_or_else(bad)?,
                );
                if matches!(c, Scalar::F32 | Scalar::F64) {
                    return Err(format!(
                        "header line {}: a list count must be an integer",
                        k + 2
                    ));
                }
                elements
                    .last_mut()
                    .ok_or_else(bad)?
                    .props
                    .push(Property::List((*name).to_string(), c, t));
            }
            ["property", t, name] => {
                elements
                    .last_mut()
                    .ok_or_else(bad)?
                    .props
                    .push(Property::Scalar(
                        (*name).to_string(),
                        Scalar::parse(t).ok_or_else(bad)?,
                    ))
            }
            _ => return Err(bad()),
        }
    }
    let format = format.ok_or("the header has no `format` line")?;
    Ok((format, elements, body_start))
}

fn read_vertices(body: &mut Body, e: &Element, mesh: &mut PlyMesh) -> Result<(), String> {
    let find = |names: &[&str]| {
        e.props.iter().position(|p| match p {
            Property::Scalar(n, _) => names.contains(&n.as_str()),
            Property::List(..) => false,
        })
    };
    let xyz = [find(&["x"]), find(&["y"]), find(&["z"])];
    let [Some(x), Some(y), Some(z)] = xyz else {
        return Err("the vertex element lacks x, y or z".into());
    };
    let nrm = [find(&["nx"]), find(&["ny"]), find(&["nz"])];
    let uv = [
        find(&["u", "s", "texture_u", "texture_s"]),
        find(&["v", "t", "texture_v", "texture_t"]),
    ];
    // The count was checked against the file size, so this reservation is bounded.
    let n = usize::try_from(e.count).map_err(|_| "too many vertices")?;
    mesh.positions.reserve_exact(n);
    let mut normals = nrm
        .iter()
        .all(Option::is_some)
        .then(|| Vec::with_capacity(n));
    let mut uvs = uv
        .iter()
        .all(Option::is_some)
        .then(|| Vec::with_capacity(n));
    let mut vals = vec![0f64; e.props.len()];
    for _ in 0..n {
        for (v, p) in vals.iter_mut().zip(&e.props) {
            *v = match p {
                Property::Scalar(_, t) => body.value(*t)?,
                Property::List(_, c, t) => {
                    skip_list(body, *c, *t)?;
                    0.0
                }
            };
        }
        let p = [vals[x] as f32, vals[y] as f32, vals[z] as f32];
        if !p.iter().all(|c| c.is_finite()) {
            return Err(format!("vertex {} is not finite", mesh.positions.len()));
        }
        mesh.positions.push(p);
        if let (Some(ns), [Some(a), Some(b), Some(c)]) = (normals.as_mut(), nrm) {
            ns.push([vals[a] as f32, vals[b] as f32, vals[c] as f32]);
        }
        if let (Some(us), [Some(a), Some(b)]) = (uvs.as_mut(), uv) {
            us.push([vals[a] as f32, vals[b] as f32]);
        }
    }
    mesh.normals = normals;
    mesh.uvs = uvs;
    Ok(())
}

fn read_faces(
    body: &mut Body,
    e: &Element,
    mesh: &mut PlyMesh,
    max_triangles: usize,
) -> Result<(), String> {
    if e.count > max_triangles as u64 {
        return Err(format!(
            "{} faces exceed the limit of {max_triangles} triangles",
            e.count
        ));
    }
    let list = e
        .props
        .iter()
        .position(
            |p| matches!(p, Property::List(n, ..) if n == "vertex_indices" || n == "vertex_index"),
        )
        .ok_or("the face element has no vertex_indices list")?;
    mesh.indices.reserve(e.count as usize);
    let mut poly: Vec<u32> = Vec::new();
    for f in 0..e.count {
        for (k, p) in e.props.iter().enumerate() {
            match p {
                Property::Scalar(_, t) => {
                    body.value(*t)?;
                }
                Property::List(_, c, t) if k == list => {
                    let n = body.value(*c)?;
                    if !(3.0..=256.0).contains(&n) {
                        return Err(format!("face {f} has {n} vertices (3 to 256 allowed)"));
                    }
                    poly.clear();
                    for _ in 0..n as usize {
                        let i = body.value(*t)?;
                        if !(0.0..=f64::from(u32::MAX)).contains(&i) {
                            return Err(format!("face {f} has the vertex index {i}"));
                        }
                        poly.push(i as u32);
                    }
                    for j in 1..poly.len() - 1 {
                        if mesh.indices.len() >= max_triangles {
                            return Err(format!(
                                "more than the limit of {max_triangles} triangles"
                            ));
                        }
                        mesh.indices.push([poly[0], poly[j], poly[j + 1]]);
                    }
                }
                Property::List(_, c, t) => skip_list(body, *c, *t)?,
            }
        }
    }
    Ok(())
}

fn skip_list(body: &mut Body, c: Scalar, t: Scalar) -> Result<(), String> {
    let n = body.value(c)?;
    if !(0.0..=1e6).contains(&n) {
        return Err(format!("a list of {n} entries"));
    }
    for _ in 0..n as usize {
        body.value(t)?;
    }
    Ok(())
}

fn skip(body: &mut Body, e: &Element) -> Result<(), String> {
    for _ in 0..e.count {
        for p in &e.props {
            match p {
                Property::Scalar(_, t) => {
                    body.value(*t)?;
                }
                Property::List(_, c, t) => skip_list(body, *c, *t)?,
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn binary_quad(big: bool) -> Vec<u8> {
        let order = if big { "big" } else { "little" };
        let mut b = format!(
            "ply\nformat binary_{order}_endian 1.0\ncomment x\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float u\nproperty float v\nelement face 1\nproperty list uint8 int vertex_indices\nend_header\n"
        )
        .into_bytes();
        let f = |b: &mut Vec<u8>, v: f32| {
            b.extend(if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            });
        };
        for (x, y) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            for v in [x, y, 2.0, x, y] {
                f(&mut b, v);
            }
        }
        b.push(4);
        for i in [0i32, 1, 2, 3] {
            b.extend(if big {
                i.to_be_bytes()
            } else {
                i.to_le_bytes()
            });
        }
        b
    }

    #[test]
    fn binary_quads_become_two_triangles_in_both_byte_orders() {
        for big in [false, true] {
            let m = parse(&binary_quad(big), 10).unwrap();
            assert_eq!(m.positions[2], [1.0, 1.0, 2.0]);
            assert_eq!(m.uvs.as_ref().unwrap()[3], [0.0, 1.0]);
            assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3]]);
            assert!(m.normals.is_none());
        }
    }

    #[test]
    fn ascii_with_normals_and_extra_elements() {
        let text = "ply\r\nformat ascii 1.0\r\nelement vertex 3\r\nproperty double x\r\nproperty double y\r\nproperty double z\r\nproperty float nx\r\nproperty float ny\r\nproperty float nz\r\nelement face 1\r\nproperty uchar flags\r\nproperty list uchar uint vertex_index\r\nelement edge 1\r\nproperty list uchar int pair\r\nend_header\r\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n7 3 0 1 2\n2 0 1\n";
        let m = parse(text.as_bytes(), 10).unwrap();
        assert_eq!(m.indices, vec![[0, 1, 2]]);
        assert_eq!(m.normals.unwrap()[1], [0.0, 0.0, 1.0]);
    }

    #[test]
    fn lying_headers_are_refused_before_allocation() {
        let huge = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        let e = parse(huge.as_bytes(), 10).unwrap_err();
        assert!(e.contains("more data"), "{e}");
        let mut q = binary_quad(false);
        q.truncate(q.len() - 3);
        assert!(parse(&q, 10).unwrap_err().contains("truncated"));
        assert!(parse(&binary_quad(false), 1)
            .unwrap_err()
            .contains("limit of 1"));
        let mut q = binary_quad(false);
        let n = q.len();
        q[n - 4..].copy_from_slice(&9i32.to_le_bytes());
        assert!(parse(&q, 10).unwrap_err().contains("out of range"));
        assert!(parse(b"solid x", 10).unwrap_err().contains("end_header"));
        // More vertices than the triangles left can use (3 each, 4096 spare): refused
        // from the header, before they are read.
        let many = format!(
            "ply\nformat ascii 1.0\nelement vertex 5000\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n{}3 0 1 2\n",
            "0 0 0\n".repeat(5000)
        );
        let e = parse(many.as_bytes(), 1).unwrap_err();
        assert!(
            e.contains("5000 vertices are more than the limit of 4099"),
            "{e}"
        );
        assert!(parse(many.as_bytes(), 400).is_ok());
        assert!(parse(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1 2",
            10
        )
        .unwrap_err()
        .contains("lacks x, y or z"));
    }
}
