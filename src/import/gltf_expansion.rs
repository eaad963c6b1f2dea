//! What a glTF scene expands to, counted without expanding it. A node placed under
//! several parents (or a root listed several times) is instanced once per path to it, so
//! a few kilobytes of nodes, each the parent of both nodes of the level below, describe
//! 2^40 instances. Each node's subtree is counted once, memoised over the node graph,
//! with saturating arithmetic; the scene's total is checked against the limits before
//! any node is walked, so such a scene is refused in the time it takes to read its nodes.

use super::{ImportError, ImportLimits};

/// What a subtree expands to, every instance counted.
#[derive(Clone, Copy, Default, Debug, PartialEq, Eq)]
pub struct Expansion {
    /// Node instances (lights and cameras are placed once per instance).
    pub nodes: u64,
    /// Mesh primitives: one object each (or one warning, when not triangles).
    pub objects: u64,
    pub triangles: u64,
    /// Vertices read: each instance reads its POSITION accessor again.
    pub vertices: u64,
    /// Edges on the longest path down from the subtree's root.
    height: usize,
}

impl Expansion {
    fn add(&mut self, o: &Expansion) {
        self.nodes = self.nodes.saturating_add(o.nodes);
        self.objects = self.objects.saturating_add(o.objects);
        self.triangles = self.triangles.saturating_add(o.triangles);
        self.vertices = self.vertices.saturating_add(o.vertices);
    }
}

/// Each node's count once known; `Visiting` while its subtree is being counted.
#[derive(Clone, Copy)]
enum Seen {
    Visiting,
    Done(Expansion),
}

/// Counts `scene` and refuses it, pointing at the root where the running total passes a
/// limit, when it expands past `limits`.
pub fn check(
    name: &str,
    doc: &gltf::Document,
    scene: &gltf::Scene,
    limits: &ImportLimits,
    max_depth: usize,
) -> Result<Expansion, ImportError> {
    let mut counter = Counter {
        name,
        max_depth,
        seen: vec![None; doc.nodes().len()],
    };
    let mut total = Expansion::default();
    for (k, root) in scene.nodes().enumerate() {
        total.add(&counter.node(&root, 0)?);
        let p = format!("{name}: /scenes/{}/nodes/{k}", scene.index());
        over_limits(&total, limits).map_err(|m| ImportError::limit(p, m))?;
    }
    Ok(total)
}

/// Why `e` is past `limits`, if it is. Node instances are bounded by the arrays and
/// objects the JSON may hold: as many as the file could describe as a plain tree.
fn over_limits(e: &Expansion, limits: &ImportLimits) -> Result<(), String> {
    let max_nodes = super::gltf::max_containers(limits);
    let max_objects = limits.max_objects as u64;
    let max_triangles = limits.max_triangles as u64;
    let max_vertices = max_triangles.saturating_mul(3);
    let what = if e.objects > max_objects {
        format!(
            "{} objects exceed this server's limit of {max_objects}",
            e.objects
        )
    } else if e.triangles > max_triangles {
        format!(
            "{} triangles, more than the limit of {max_triangles}",
            e.triangles
        )
    } else if e.vertices > max_vertices {
        format!(
            "{} vertices, more than {max_vertices} (three per triangle of the limit of {max_triangles} triangles)",
            e.vertices
        )
    } else if e.nodes > max_nodes {
        format!("{} node instances, more than {max_nodes} (what the limit of {max_objects} objects lets the file hold)", e.nodes)
    } else {
        return Ok(());
    };
    Err(format!(
        "{what}: the scene's nodes, each instance counted (before any is placed: {} node instances, {} mesh primitives, {} triangles, {} vertices so far)",
        e.nodes, e.objects, e.triangles, e.vertices
    ))
}

struct Counter<'a> {
    name: &'a str,
    max_depth: usize,
    seen: Vec<Option<Seen>>,
}

impl Counter<'_> {
    fn at(&self, node: &gltf::Node, msg: impl Into<String>) -> ImportError {
        ImportError::invalid(format!("{}: /nodes/{}", self.name, node.index()), msg)
    }

    fn too_deep(&self, node: &gltf::Node) -> ImportError {
        self.at(
            node,
            format!("the node tree is deeper than {} (a cycle?)", self.max_depth),
        )
    }

    /// The expansion of `node`'s subtree, `node` being reached at `depth`.
    fn node(&mut self, node: &gltf::Node, depth: usize) -> Result<Expansion, ImportError> {
        if depth > self.max_depth {
            return Err(self.too_deep(node));
        }
        let done = match self.seen[node.index()] {
            Some(Seen::Done(e)) => e,
            // glTF 2.0 §3.5.3: the node hierarchy must not contain cycles.
            Some(Seen::Visiting) => {
                return Err(self.at(node, "is its own ancestor (glTF node trees have no cycles)"))
            }
            None => self.subtree(node, depth)?,
        };
        if depth + done.height > self.max_depth {
            return Err(self.too_deep(node));
        }
        Ok(done)
    }

    /// Counts `node`'s subtree for the first time and remembers it.
    fn subtree(&mut self, node: &gltf::Node, depth: usize) -> Result<Expansion, ImportError> {
        self.seen[node.index()] = Some(Seen::Visiting);
        let mut e = node.mesh().map_or(Expansion::default(), |m| mesh(&m));
        e.nodes = 1;
        for child in node.children() {
            let c = self.node(&child, depth + 1)?;
            e.add(&c);
            e.height = e.height.max(c.height + 1);
        }
        self.seen[node.index()] = Some(Seen::Done(e));
        Ok(e)
    }
}

/// One instance of `mesh`: its primitives, and the triangles and vertices their
/// accessors declare (checked against their buffers only when read).
fn mesh(mesh: &gltf::Mesh) -> Expansion {
    let mut e = Expansion::default();
    for prim in mesh.primitives() {
        e.objects += 1;
        if prim.mode() != gltf::mesh::Mode::Triangles {
            continue;
        }
        let vertices = prim
            .get(&gltf::Semantic::Positions)
            .map_or(0, |a| declared(&a));
        let corners = prim.indices().map_or(vertices, |a| declared(&a));
        e.vertices = e.vertices.saturating_add(vertices);
        e.triangles = e.triangles.saturating_add(corners / 3);
    }
    e
}

/// The elements accessor `a` declares, or 0 when they cannot fit in its buffer view: the
/// walk refuses such an accessor with its pointer when it reads it, as invalid rather than
/// as too large.
fn declared(a: &gltf::Accessor) -> u64 {
    let Some(view) = a.view() else { return 0 };
    let size = a.size() as u64;
    let stride = view.stride().map_or(size, |s| s as u64);
    let count = a.count() as u64;
    let need = (a.offset() as u64)
        .saturating_add(stride.saturating_mul(count.saturating_sub(1)))
        .saturating_add(size);
    if need > view.length() as u64 {
        return 0;
    }
    count
}
