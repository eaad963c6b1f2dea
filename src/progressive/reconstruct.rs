//! Which values the shading interpolates between traced pixels: each vertex's estimate,
//! averaged with its similar neighbours on the same object until the noise it carries
//! is no more visible than the reference's own grain at the declared viewing condition.
//!
//! Why (our extension of F&P04 §4.2, whose oracle was exact): a traced pixel is a Monte
//! Carlo mean with variance σ². Shown alone it is grain, one pixel wide, which the eye's
//! contrast sensitivity largely filters out at high pixels per degree. Gouraud shading
//! spreads the same error over every triangle around the vertex: a blotch a few to twenty
//! pixels wide, at the spatial frequencies the eye sees best. With the achromatic CSF
//! modelled as a Gaussian of standard deviation s pixels (FLIP's, Andersson et al. 2020:
//! σ = √(0.0047 / 2π²) ≈ 0.0154°, so s = 0.0154 · ppd), white per-pixel noise keeps
//! about 1 / (1 + 4πs²) of its variance after the filter, while noise interpolated
//! between vertices L pixels apart keeps about 1 / (2 + 4πs²/L²) of the vertex variance
//! (½ is the mean of Σ bᵢ² over a triangle; a filter wider than L averages ~4πs²/L²
//! vertices). Averaging m independent vertices divides their variance by m, so the
//! interpolated noise is no more visible than the reference's grain when
//! m ≥ (1 + 4πs²) / (2 + 4πs²/L²) — about 1.6 at 28 ppd and 6 at 60 ppd for widely spaced
//! vertices, 1 (no averaging) where vertices are a pixel apart. [`Averaging::target_count`]
//! asks for a margin times that: [`VISIBILITY_MARGIN`] at t0 = 1 JND, more for a lower t0.
//!
//! The average is a bilateral one over rings of the Delaunay graph (Tomasi & Manduchi's
//! weights with the range scale set by the estimates' own variance, as SVGF does): only
//! vertices on the same surface (the exact object-id map of §4.1, and normals within a
//! crease angle, so a box's faces stay apart) and whose values differ by no more than
//! their noise explains are averaged, so contours, shadows and highlights keep their
//! vertices' own values, and a region's vertices share their noise instead of each
//! drawing its own blotch. The average is a weighted plane fit, not a mean, so a gradient
//! is not flattened; and the rings stop where successive fits disagree beyond their noise
//! (ICI, [`smooth`]), so a wide average does not trade grain for a blotch of bias. A
//! vertex that cannot reach its target within that radius is *unresolved*, and the loop
//! refines around it (`driver`). Textured surfaces are averaged in radiance ÷ albedo
//! (the same demodulation as `mesh::gouraud`). An exact oracle (variance 0) gets F&P04's
//! interpolation unchanged.
//!
//! Measured (bundled scenes, declared 60 / 90 ppd, Q = FLIP(progressive, truth) ÷
//! FLIP(reference, truth)): a plain bilateral mean left Q at 1.07 / 1.36–1.39 on
//! cornell-box and spheres-rough; fed the truth's own values at the vertices it still
//! scored 1.30–1.36 at 90 ppd, so the mean's bias, not the noise left, was the error.

use super::mesh::{Tri, MIN_ALBEDO};
use crate::raster::Rgb;
use crate::scene::ObjectId;
use glam::Vec3;
use rayon::prelude::*;

/// Ask for this many times the averaging that makes interpolated noise exactly as visible
/// as the reference's grain, at F&P04's t0 of 1 JND: the blotches must not be *more*
/// visible, and an average is also slightly biased where the signal curves.
pub const VISIBILITY_MARGIN: f64 = 4.0;

/// The t0 range over which the margin follows t0 ([`Averaging::for_render`]): the margins
/// measured, 2 to 16.
const MARGIN_T0: (f32, f32) = (0.25, 2.0);

/// Range scale of the bilateral weight, in standard deviations of the difference of two
/// estimates: a neighbour that agrees within its noise keeps most of its weight
/// (E[exp(−z²/2κ²)] ≈ 0.83 for z ~ N(0, 1)), a real step of a few σ loses it. With ICI at
/// ±1, 1.5 kept objects' colours better than 2 (and 3) on a generated corpus and the
/// bundled scenes, Q unchanged or lower (README, "Where we departed").
const RANGE_SIGMAS: f32 = 1.5;

/// Rings of the Delaunay graph searched at most (a vertex has ~6 neighbours per ring).
const MAX_RINGS: usize = 6;

/// How much averaging a render asks of the reconstruction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Averaging {
    /// The declared viewing condition.
    pub pixels_per_degree: f32,
    /// Times the averaging that makes interpolated noise as visible as the reference's
    /// grain.
    pub margin: f64,
}

impl Averaging {
    /// For a render at `pixels_per_degree` whose triangles are final below `t0` JND: the
    /// margin is [`VISIBILITY_MARGIN`] at t0 = 1 and grows as t0 falls (4 / t0 within
    /// t0 = 0.25–2). t0 is the user's accuracy knob, and what it asks for must reach the
    /// noise the interpolation keeps, not only the frame-to-frame distance: measured on a
    /// 40-scene corpus at each scene's declared condition, t0 = 2, 1, 0.5 and 0.25 now give
    /// a median Q of 1.10, 0.99, 0.90 and 0.83 at 0.56×, 0.64×, 0.76× and 1.04× the
    /// reference's time; with the margin fixed at 4 they gave 0.98–0.99 at every t0
    /// (README, "Where we departed").
    ///
    /// t0 = 0 traces every pixel, so the last frame is the reference whatever the margin:
    /// it keeps the default one (a wider average there only cost time, 1.08–1.26× on the
    /// Cornell box and a 451² corpus scene).
    #[must_use]
    pub fn for_render(pixels_per_degree: f32, t0: f32) -> Self {
        let t0 = if t0.is_nan() || t0 <= 0.0 { 1.0 } else { t0 };
        Self {
            pixels_per_degree,
            margin: VISIBILITY_MARGIN / f64::from(t0.clamp(MARGIN_T0.0, MARGIN_T0.1)),
        }
    }

    /// Effective number of vertices to average at a vertex whose surroundings hold one
    /// vertex per `area` pixels (the module's derivation).
    #[must_use]
    pub fn target_count(&self, area: f64) -> f64 {
        let s = 0.0154 * f64::from(self.pixels_per_degree);
        let csf = 4.0 * std::f64::consts::PI * s * s;
        self.margin * (1.0 + csf) / (2.0 + csf / area.max(1.0))
    }
}

/// What a vertex contributes: its pixel, object, value (demodulated where textured) and
/// that value's variance.
#[derive(Clone, Copy, Debug)]
struct Node {
    pixel: usize,
    /// The pixel's column and row (read at every visit of every search: no division).
    x: f64,
    y: f64,
    id: ObjectId,
    /// Facing the camera; zero where unknown.
    normal: Vec3,
    value: Rgb,
    variance: Rgb,
    /// The value averaged over the vertex and its same-object neighbours, and that mean's
    /// variance: what the range weight compares ([`guide`]).
    guide: Rgb,
    guide_variance: Rgb,
    /// Own albedo to multiply back (textured vertices only).
    albedo: Option<Rgb>,
    /// Pixels per vertex around it: twice the mean area of its triangles.
    area: f64,
}

impl Node {
    /// Whether two vertices lie on one smooth surface: the same object, and normals within
    /// [`CREASE`] of each other (a box's faces, a room's walls meeting in a corner, are lit
    /// differently however alike their noisy values look).
    fn same_surface(&self, o: &Node) -> bool {
        self.id == o.id
            && (self.normal == Vec3::ZERO
                || o.normal == Vec3::ZERO
                || self.normal.dot(o.normal) >= CREASE)
    }
}

/// Cosine of the largest angle between the normals of two vertices averaged together (30°):
/// a tessellated sphere's neighbouring facets stay well inside it at the vertex spacings
/// the loop produces, a box's faces (90°) are far outside.
const CREASE: f32 = 0.866;

/// What the reconstruction knows per pixel of a `w`-wide image (only the vertices' entries
/// are read).
pub struct Samples<'a> {
    pub w: usize,
    pub radiance: &'a [Rgb],
    pub variance: &'a [Rgb],
    pub ids: &'a [ObjectId],
    /// [`crate::tracer::PixelOracle::surface_normal`] per pixel; empty if unknown.
    pub normals: &'a [Vec3],
    pub albedo: Option<&'a [Option<Rgb>]>,
    pub averaging: Averaging,
    /// Paths each estimate averages (the scene's samples per pixel).
    pub paths: u32,
}

/// The value each vertex of `tris` contributes to the shading, written at its pixel index
/// into `out`, and whether it reached its [`Averaging::target_count`] into `resolved` (other entries
/// of both untouched).
pub fn vertex_values(tris: &[Tri], samples: &Samples<'_>, out: &mut [Rgb], resolved: &mut [bool]) {
    let (mut nodes, adjacency) = graph(tris, samples);
    guide(&mut nodes, &adjacency, samples.paths);
    let averaging = samples.averaging;
    // A fit costs 1-4 µs (rings of up to a hundred vertices), so a few hundred make a job
    // worth sharing: small images have only a few thousand vertices, and jobs of 2048 left
    // one core idle (measured: 0.78-0.92× the render's time on corpus scenes of 5-14 k
    // pixels). Each job's `Visited` is one u32 per vertex, so rayon's few dozen jobs cost
    // little even with millions of vertices.
    let smoothed: Vec<(Rgb, bool)> = (0..nodes.len())
        .into_par_iter()
        .with_min_len(256)
        .map_init(
            || Visited::new(nodes.len()),
            |visited, k| smooth(k, &nodes, &adjacency, averaging, visited),
        )
        .collect();
    for (node, (v, ok)) in nodes.iter().zip(smoothed) {
        out[node.pixel] = v;
        resolved[node.pixel] = ok;
    }
}

/// Vertices and their Delaunay neighbours (compressed rows).
struct Adjacency {
    start: Vec<u32>,
    list: Vec<u32>,
}

impl Adjacency {
    fn of(&self, k: usize) -> &[u32] {
        &self.list[self.start[k] as usize..self.start[k + 1] as usize]
    }
}

/// The triangulation as a graph: its vertices as [`Node`]s (in pixel order) and each
/// one's Delaunay neighbours.
fn graph(tris: &[Tri], samples: &Samples<'_>) -> (Vec<Node>, Adjacency) {
    let w = samples.w;
    let (node_of, pixels) = number_vertices(tris, w, samples.radiance.len());
    let (area, count) = vertex_areas(tris, w, &node_of, pixels.len());
    let adjacency = Adjacency::build(tris, w, &node_of, &count);
    let nodes = pixels
        .iter()
        .enumerate()
        .map(|(k, &i)| node(samples, i, 2.0 * area[k] / f64::from(count[k].max(1))))
        .collect();
    (nodes, adjacency)
}

/// Pixel index of `p` in an image `w` wide.
fn pixel_at(p: crate::raster::PixelCoord, w: usize) -> usize {
    p.y as usize * w + p.x as usize
}

/// The vertices of `tris` numbered in pixel order: per pixel of an image `w` wide with
/// `len` pixels, its vertex number (`u32::MAX` for none), and per vertex its pixel. A scan
/// of the image instead of a sort of the vertices: the result is the same.
fn number_vertices(tris: &[Tri], w: usize, len: usize) -> (Vec<u32>, Vec<usize>) {
    let mut node_of = vec![u32::MAX; len];
    for t in tris {
        for p in t.v {
            node_of[pixel_at(p, w)] = 0;
        }
    }
    let mut pixels = Vec::new();
    for (i, k) in node_of.iter_mut().enumerate() {
        if *k == 0 {
            *k = pixels.len() as u32;
            pixels.push(i);
        }
    }
    (node_of, pixels)
}

/// Per vertex, the summed area of the triangles around it and how many there are.
fn vertex_areas(tris: &[Tri], w: usize, node_of: &[u32], n: usize) -> (Vec<f64>, Vec<u32>) {
    let mut area = vec![0f64; n];
    let mut count = vec![0u32; n];
    for t in tris {
        let a = t.area2().abs() * 0.5;
        for p in t.v {
            let u = node_of[pixel_at(p, w)] as usize;
            area[u] += a;
            count[u] += 1;
        }
    }
    (area, count)
}

impl Adjacency {
    /// Each vertex's neighbours in ascending order, from a bucket per vertex (`count[k]`
    /// triangles around vertex k) instead of sorting every edge (the sorts were a sixth of
    /// a render on a 451² corpus scene; the result is the same).
    fn build(tris: &[Tri], w: usize, node_of: &[u32], count: &[u32]) -> Self {
        let n = count.len();
        // Each triangle gives each of its vertices two directed edges, to its other two.
        let mut start = vec![0u32; n + 1];
        for (k, c) in count.iter().enumerate() {
            start[k + 1] = start[k] + 2 * c;
        }
        let mut end = start.clone();
        let mut list = vec![0u32; start[n] as usize];
        for t in tris {
            let k = t.v.map(|p| node_of[pixel_at(p, w)]);
            for j in 0..3 {
                let u = k[j] as usize;
                for v in [k[(j + 1) % 3], k[(j + 2) % 3]] {
                    list[end[u] as usize] = v;
                    end[u] += 1;
                }
            }
        }
        // Sort and deduplicate each vertex's bucket, compacting the list in place.
        let mut kept = 0usize;
        for k in 0..n {
            let bucket = &mut list[start[k] as usize..end[k] as usize];
            bucket.sort_unstable();
            let from = start[k] as usize;
            start[k] = kept as u32;
            let mut last = None;
            for j in from..end[k] as usize {
                let v = list[j];
                if last != Some(v) {
                    list[kept] = v;
                    kept += 1;
                    last = Some(v);
                }
            }
        }
        start[n] = kept as u32;
        list.truncate(kept);
        Self { start, list }
    }
}

/// The vertex at pixel `i`, whose triangles have mean area `area`. A textured surface's
/// estimate is divided by its albedo (where that is not too dark to divide by), so the
/// fit smooths the lighting, not the texture.
fn node(samples: &Samples<'_>, i: usize, area: f64) -> Node {
    let w = samples.w;
    let (radiance, variance) = (samples.radiance, samples.variance);
    let own = samples
        .albedo
        .and_then(|a| a[i])
        .filter(|a| a.min_element() >= MIN_ALBEDO);
    let value = own.map_or(radiance[i], |a| radiance[i] / a);
    Node {
        pixel: i,
        x: (i % w) as f64,
        y: (i / w) as f64,
        id: samples.ids[i],
        normal: samples.normals.get(i).copied().unwrap_or(Vec3::ZERO),
        value,
        variance: own.map_or(variance[i], |a| variance[i] / (a * a)),
        guide: Rgb::ZERO,
        guide_variance: Rgb::ZERO,
        albedo: own,
        area,
    }
}

/// The range weight's guide: each vertex's luminance averaged with its same-object
/// neighbours (a cross-bilateral filter's prefiltered guide), and the variance of that
/// mean from the neighbourhood's pooled variance. Comparing raw estimates would be biased:
/// path-traced noise is heavy-tailed, and a weight that drops whichever neighbour caught a
/// bright path darkens every average (measured: objects 8–19 % too dark on the door
/// scene). A pooled variance also stops a pixel whose few paths all missed the light from
/// claiming a tiny noise beside one that caught it: both are draws of one distribution.
///
/// Such a pixel's own estimate is black with a sample variance of 0, which the fit would
/// take for an exact value: kept as it is while its bright neighbours are averaged with
/// it, a dark scene lit by rare paths loses most of its light (measured: objects 60–80 %
/// too dark on two corpus scenes). Where its neighbours' spread makes an all-black
/// estimate likely by chance ([`black_by_chance`]), it takes their variance instead; a
/// black vertex among steady neighbours (the dark side of a refraction) stays exact.
fn guide(nodes: &mut [Node], adj: &Adjacency, paths: u32) {
    let guides: Vec<(Rgb, Rgb, Option<Rgb>)> = (0..nodes.len())
        .into_par_iter()
        .map(|k| {
            let me = &nodes[k];
            let (mut g, mut v, mut n) = (me.value, me.variance, 1.0f32);
            for &u in adj.of(k) {
                let o = &nodes[u as usize];
                if me.same_surface(o) {
                    g += o.value;
                    v += o.variance;
                    n += 1.0;
                }
            }
            // Black with no variance, the vertex adds nothing: g and v are its neighbours'.
            let others = n - 1.0;
            let unseen = (me.value == Rgb::ZERO && me.variance == Rgb::ZERO && others > 0.0)
                .then(|| v / others)
                .filter(|nv| {
                    let mean = g.element_sum() / (3.0 * others);
                    black_by_chance(mean, nv.element_sum() / 3.0, paths)
                });
            (g / n, v / (n * n), unseen)
        })
        .collect();
    for (node, (g, gv, unseen)) in nodes.iter_mut().zip(guides) {
        node.guide = g;
        node.guide_variance = gv;
        if let Some(v) = unseen {
            node.variance = v;
        }
    }
}

/// Whether `paths` paths all returning black is likely (≥ [`BLACK_BY_CHANCE`]) for a
/// pixel drawn from a neighbourhood whose estimates have mean `mean` and variance
/// `variance` (means over the channels). If a path is either black or carries about the
/// same radiance, it is not black with probability q = 1 / (1 + `paths`·variance / mean²)
/// (its per-path variance over its squared mean is (1 − q) / q), and all are black with
/// probability (1 − q)^`paths`. Set on the seed-1 corpus: at 0.05 the dark side of a glass
/// sphere was averaged with its lit rim (+15 % on the sphere), at 0.9 the dark rooms kept
/// their black vertices; 0.5, "as likely as not", keeps both right.
fn black_by_chance(mean: f32, variance: f32, paths: u32) -> bool {
    if !(mean > 0.0 && variance > 0.0) {
        return false;
    }
    let n = f64::from(paths.max(1));
    let q = 1.0 / (1.0 + n * f64::from(variance) / f64::from(mean).powi(2));
    (1.0 - q).powf(n) >= BLACK_BY_CHANCE
}

/// How likely an all-black estimate must be by chance to be treated as noise
/// ([`black_by_chance`]).
const BLACK_BY_CHANCE: f64 = 0.5;

/// Which vertices one search has already met: a stamp per vertex, so a search costs
/// what it visits, not a scan of its list per neighbour (rings of 100 vertices).
struct Visited {
    stamp: Vec<u32>,
    current: u32,
    /// The ring being expanded and the next one (kept to reuse their allocations).
    ring: Vec<u32>,
    next: Vec<u32>,
}

impl Visited {
    fn new(n: usize) -> Self {
        Self {
            stamp: vec![0; n],
            current: 0,
            ring: Vec::new(),
            next: Vec::new(),
        }
    }

    /// Starts a new search (forgets every vertex met).
    fn clear(&mut self) {
        self.current = self.current.wrapping_add(1);
        if self.current == 0 {
            self.stamp.fill(0);
            self.current = 1;
        }
    }

    /// Marks `k`; false if it was already met in this search.
    fn insert(&mut self, k: u32) -> bool {
        let s = &mut self.stamp[k as usize];
        if *s == self.current {
            return false;
        }
        *s = self.current;
        true
    }
}

/// The reconstructed value of vertex `k`, and whether it reached its [`Averaging::target_count`]
/// (an effective number of vertices averaged, (Σw)² / Σw²).
///
/// Rings of same-surface neighbours are added while the plane fits them: the intercepts of
/// successive rings must keep a common interval of ±[`ICI_SIGMAS`] standard deviations
/// (Goldenshluger & Nemirovski's intersection of confidence intervals, as Katkovnik's
/// LPA-ICI uses it). Past that radius the signal curves more than the noise explains, and
/// a wider average trades noise for a blotch of bias. A vertex that stops short of its
/// target is *unresolved*: its triangles are refined (`driver`) until vertices are dense
/// enough to reach the target within the radius where the plane holds.
fn smooth(
    k: usize,
    nodes: &[Node],
    adj: &Adjacency,
    averaging: Averaging,
    visited: &mut Visited,
) -> (Rgb, bool) {
    let me = nodes[k];
    let own = |v: Rgb| me.albedo.map_or(v, |a| v * a);
    let target = averaging.target_count(me.area);
    if target <= 1.0 || me.variance == Rgb::ZERO {
        return (own(me.value), true);
    }

    let mut fit = PlaneFit::new();
    fit.add(0.0, 0.0, me.value, me.variance, 1.0);
    let mut kept = (me.value, 1.0);
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    visited.clear();
    visited.insert(k as u32);
    let mut ring = std::mem::take(&mut visited.ring);
    let mut next = std::mem::take(&mut visited.next);
    ring.clear();
    ring.push(k as u32);
    for _ in 0..MAX_RINGS {
        next.clear();
        for &u in &ring {
            for &v in adj.of(u as usize) {
                if !visited.insert(v) || !me.same_surface(&nodes[v as usize]) {
                    continue;
                }
                next.push(v);
                let o = nodes[v as usize];
                let wgt = range_weight(me.guide - o.guide, me.guide_variance + o.guide_variance);
                if wgt > 0.0 {
                    fit.add(o.x - me.x, o.y - me.y, o.value, o.variance, wgt);
                }
            }
        }
        if next.is_empty() {
            break;
        }
        let (value, sd, count) = fit.solve();
        let mean = f64::from(value.element_sum()) / 3.0;
        lo = lo.max(mean - ICI_SIGMAS * sd);
        hi = hi.min(mean + ICI_SIGMAS * sd);
        if lo > hi {
            break;
        }
        kept = (value, count);
        if kept.1 >= target {
            break;
        }
        std::mem::swap(&mut ring, &mut next);
    }
    visited.ring = ring;
    visited.next = next;
    (own(kept.0), kept.1 >= target)
}

/// Half-width of ICI's confidence intervals, in standard deviations of an intercept. A
/// narrower interval stops a fit sooner where the signal curves (less bias, more vertices
/// unresolved and refined around). Against the truth, ±1 brought more pictures at least
/// as close as the reference's than ±2 on two generated corpora and the bundled scenes at
/// 28–90 ppd; ±0.75 and ±1.5 did no better than ±2 (README, "Where we departed").
const ICI_SIGMAS: f64 = 1.0;

/// A weighted least-squares plane v ≈ a + b·x + c·y through a vertex's neighbours, whose
/// intercept a is the value at the vertex: a mean would also average the signal's slope
/// across a gradient and shift it (a local-linear smoother has no first-order bias,
/// Cleveland 1979). Falls back to the weighted mean while the neighbours do not span a
/// plane.
struct PlaneFit {
    /// Σ w·u uᵀ, Σ w²·u uᵀ and Σ w²·σ²·u uᵀ with u = (1, x, y), σ² the channels' mean
    /// variance.
    m: Moments,
    m2: Moments,
    mv: Moments,
    /// Σ w·u·v per channel.
    r: [glam::DVec3; 3],
}

/// The six distinct entries of a weighted sum of u uᵀ with u = (1, x, y): the matrix is
/// symmetric, so a vertex adds 6 products instead of 9 (the fits are most of the
/// reconstruction's time, which is most of the loop's own work on small images).
#[derive(Clone, Copy, Default)]
struct Moments {
    w: f64,
    x: f64,
    y: f64,
    xx: f64,
    xy: f64,
    yy: f64,
}

impl Moments {
    fn add(&mut self, x: f64, y: f64, w: f64) {
        let (wx, wy) = (w * x, w * y);
        self.w += w;
        self.x += wx;
        self.y += wy;
        self.xx += wx * x;
        self.xy += wx * y;
        self.yy += wy * y;
    }

    fn matrix(&self) -> glam::DMat3 {
        glam::DMat3::from_cols_array(&[
            self.w, self.x, self.y, self.x, self.xx, self.xy, self.y, self.xy, self.yy,
        ])
    }

    /// lᵀ M l.
    fn quadratic(&self, l: glam::DVec3) -> f64 {
        l.x * l.x * self.w
            + l.y * l.y * self.xx
            + l.z * l.z * self.yy
            + 2.0 * (l.x * l.y * self.x + l.x * l.z * self.y + l.y * l.z * self.xy)
    }
}

impl PlaneFit {
    fn new() -> Self {
        Self {
            m: Moments::default(),
            m2: Moments::default(),
            mv: Moments::default(),
            r: [glam::DVec3::ZERO; 3],
        }
    }

    fn add(&mut self, x: f64, y: f64, v: Rgb, variance: Rgb, w: f64) {
        self.m.add(x, y, w);
        self.m2.add(x, y, w * w);
        self.mv
            .add(x, y, w * w * f64::from(variance.element_sum()) / 3.0);
        let u = glam::DVec3::new(1.0, x, y);
        for c in 0..3 {
            self.r[c] += u * (w * f64::from(v[c]));
        }
    }

    /// The intercept's weights ℓ = M⁻¹ e₁, or the mean's (1/Σw, 0, 0) while the
    /// neighbours do not span a plane.
    fn row(&self) -> glam::DVec3 {
        let m = self.m.matrix();
        let det = m.determinant();
        let scale = self.m.w.powi(3).max(1e-300);
        if det > 1e-6 * scale {
            m.inverse().x_axis
        } else {
            glam::DVec3::new(1.0 / self.m.w, 0.0, 0.0)
        }
    }

    /// The intercept, its standard deviation (channels' mean variance) and 1 / Σℓᵢ²: how
    /// many equally noisy vertices the intercept is worth.
    fn solve(&self) -> (Rgb, f64, f64) {
        let l = self.row();
        let v = Rgb::new(
            l.dot(self.r[0]) as f32,
            l.dot(self.r[1]) as f32,
            l.dot(self.r[2]) as f32,
        );
        let sd = self.mv.quadratic(l).max(0.0).sqrt();
        (v, sd, 1.0 / self.m2.quadratic(l).max(1e-300))
    }
}

/// The bilateral range weight of a difference `d` between two guides whose difference has
/// variance `var`, per channel: exp(−χ²/2κ²) with χ² the mean of d²/var over the channels
/// (colour counts, not only luminance: a red face beside a white one of equal luminance is
/// a contour). A channel without noise (var 0) that differs rules the pair out; unknown
/// noise (var ∞) rules nothing out.
fn range_weight(d: Rgb, var: Rgb) -> f64 {
    let mut chi2 = 0f64;
    for c in 0..3 {
        let (d, v) = (f64::from(d[c]), f64::from(var[c]));
        chi2 += match (d == 0.0, v == 0.0) {
            (true, _) => 0.0,
            (false, true) => return 0.0,
            (false, false) => d * d / v,
        };
    }
    let k = f64::from(RANGE_SIGMAS);
    let exponent = (chi2 / 3.0) / (2.0 * k * k);
    // Past e⁻³⁰ a neighbour's share of any fit is below f32's precision: skip the exp.
    if exponent > 30.0 {
        0.0
    } else {
        (-exponent).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::PixelCoord;

    fn grid(n: u32) -> Vec<Tri> {
        let mut t = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let p = |dx, dy| PixelCoord::new((x + dx) * 4, (y + dy) * 4);
                t.push(Tri {
                    v: [p(0, 0), p(1, 0), p(1, 1)],
                });
                t.push(Tri {
                    v: [p(0, 0), p(1, 1), p(0, 1)],
                });
            }
        }
        t
    }

    #[test]
    fn the_target_grows_with_the_viewing_distance_and_the_vertex_spacing() {
        let target = |ppd, area| Averaging::for_render(ppd, 1.0).target_count(area);
        assert!(target(28.0, 1.0) <= VISIBILITY_MARGIN * 1.0);
        assert!(target(60.0, 50.0) > target(28.0, 50.0));
        assert!(target(60.0, 50.0) > target(60.0, 4.0));
        // Widely spaced vertices at 60 ppd: (1 + 4π·0.924²) / 2 ≈ 5.9 before the margin.
        let far = target(60.0, 1e9) / VISIBILITY_MARGIN;
        assert!((far - 5.86).abs() < 0.05, "{far}");
    }

    #[test]
    fn the_margin_grows_as_t0_falls_within_the_measured_range() {
        let margin = |t0| Averaging::for_render(60.0, t0).margin;
        assert_eq!(margin(1.0), VISIBILITY_MARGIN);
        assert_eq!((margin(0.5), margin(2.0)), (8.0, 2.0));
        // Values beyond the range stay within the margins measured.
        assert_eq!((margin(0.01), margin(100.0)), (16.0, 2.0));
        // t0 = 0 ends on the reference whatever the margin: it keeps the default one.
        assert_eq!(margin(0.0), VISIBILITY_MARGIN);
        assert_eq!(margin(f32::NAN), VISIBILITY_MARGIN);
    }

    #[test]
    fn noise_is_averaged_on_one_object_and_steps_and_other_objects_are_kept() {
        let n = 9;
        let w = 40usize;
        let tris = grid(n);
        let len = w * w;
        let mut rad = vec![Rgb::ZERO; len];
        let ids: Vec<ObjectId> = (0..len).map(|i| u32::from(i % w >= 16)).collect();
        // Object 0: 1.0 ± 0.1 alternating (noise σ² = 0.01); object 1: a flat 5.0.
        for y in 0..n {
            for x in 0..n {
                let i = (y * 4) as usize * w + (x * 4) as usize;
                rad[i] = if ids[i] == 0 {
                    Rgb::splat(if (x + y) % 2 == 0 { 1.1 } else { 0.9 })
                } else {
                    Rgb::splat(5.0)
                };
            }
        }
        let var = vec![Rgb::splat(0.01); len];
        let mut out = vec![Rgb::splat(-1.0); len];
        let mut resolved = vec![false; len];
        let samples = |variance| Samples {
            w,
            radiance: &rad,
            variance,
            ids: &ids,
            normals: &[],
            albedo: None,
            averaging: Averaging::for_render(90.0, 1.0),
            paths: 16,
        };
        vertex_values(&tris, &samples(&var), &mut out, &mut resolved);
        let v = out[4 * w + 4].x;
        assert!((v - 1.0).abs() < 0.05, "averaged towards the mean: {v}");
        let edge = out[4 * w + 12].x;
        assert!(
            edge < 1.2,
            "object 1's 5.0 never leaks into object 0: {edge}"
        );
        assert_eq!(out[4 * w + 20].x, 5.0);
        // An exact oracle (variance 0) keeps every value.
        let exact = vec![Rgb::ZERO; len];
        vertex_values(&tris, &samples(&exact), &mut out, &mut resolved);
        assert_eq!(out[4 * w + 4].x, rad[4 * w + 4].x);
    }

    #[test]
    fn an_all_black_estimate_is_noise_only_where_its_neighbours_make_it_likely() {
        // 9 paths, neighbours of mean 1: a variance of the mean of 3 is a per-path
        // variance over mean² of 27, q = 1 / 28 and (27/28)^9 ≈ 0.72 ≥ ½; of 1, q = 0.1
        // and 0.9^9 ≈ 0.39.
        assert!(black_by_chance(1.0, 3.0, 9));
        assert!(!black_by_chance(1.0, 1.0, 9));
        assert!(!black_by_chance(1.0, 1e-4, 9), "steady neighbours");
        assert!(black_by_chance(1.0, f32::INFINITY, 9), "unknown spread");
        assert!(
            !black_by_chance(0.0, 1.0, 9),
            "black neighbours: nothing to borrow"
        );
        assert!(!black_by_chance(f32::NAN, 1.0, 9) && !black_by_chance(1.0, f32::NAN, 9));
    }

    /// The 9×9 grid of [`reconstruct`] with each vertex's (value, variance of the mean)
    /// from `f` (of its pixel x, y), estimates of 9 paths; the vertex values.
    fn nine_path_vertices(f: impl Fn(usize, usize) -> (f32, f32)) -> Vec<Rgb> {
        let w = 40usize;
        let len = w * w;
        let (mut rad, mut var) = (vec![Rgb::ZERO; len], vec![Rgb::ZERO; len]);
        for y in (0..36).step_by(4) {
            for x in (0..36).step_by(4) {
                let (v, s) = f(x, y);
                (rad[y * w + x], var[y * w + x]) = (Rgb::splat(v), Rgb::splat(s));
            }
        }
        let ids = vec![0; len];
        let samples = Samples {
            w,
            radiance: &rad,
            variance: &var,
            ids: &ids,
            normals: &[],
            albedo: None,
            averaging: Averaging::for_render(90.0, 1.0),
            paths: 9,
        };
        let (mut out, mut resolved) = (vec![Rgb::splat(-1.0); len], vec![false; len]);
        vertex_values(&grid(9), &samples, &mut out, &mut resolved);
        out
    }

    #[test]
    fn a_surface_lit_by_rare_paths_keeps_its_light() {
        // One vertex in five caught the light: one of its 9 paths carried 9, a mean of 1
        // with a variance of the mean of ~1; the others are black with a variance of 0.
        let bright = |x: usize, y: usize| (x / 4 + 3 * (y / 4)).is_multiple_of(5);
        let out = nine_path_vertices(|x, y| if bright(x, y) { (1.0, 1.0) } else { (0.0, 0.0) });
        let (mut raw, mut kept) = (0.0, 0.0);
        for y in (0..36).step_by(4) {
            for x in (0..36).step_by(4) {
                raw += f32::from(u8::from(bright(x, y))) / 81.0;
                kept += out[y * 40 + x].x / 81.0;
            }
        }
        assert!(
            (kept - raw).abs() < 0.25 * raw,
            "the light the rare paths found stays: {kept} vs {raw}"
        );
        let black = out[0].x;
        assert!(
            black > 0.0,
            "a black vertex there is noise, averaged: {black}"
        );
    }

    #[test]
    fn a_black_vertex_among_steady_neighbours_stays_black() {
        // The dark side of a refraction: every path of a vertex returned black, and its
        // neighbours' 9 paths agree closely (variance of the mean 1e-4 at a mean of 1).
        let out = nine_path_vertices(|x, y| {
            if (x, y) == (16, 16) {
                (0.0, 0.0)
            } else {
                (1.0, 1e-4)
            }
        });
        assert_eq!(out[16 * 40 + 16], Rgb::ZERO);
    }

    /// A 9×9 grid of vertices 4 px apart in a 40-px-wide image, every vertex valued by `f`
    /// (of its pixel x, y and grid parity), one object; reconstructed at 90 ppd.
    fn reconstruct(
        f: impl Fn(u32, u32, bool) -> f32,
        variance: f32,
        normals: &[Vec3],
    ) -> (Vec<Rgb>, Vec<bool>) {
        let w = 40usize;
        let len = w * w;
        let mut rad = vec![Rgb::ZERO; len];
        for y in 0..9u32 {
            for x in 0..9u32 {
                rad[(y * 4) as usize * w + (x * 4) as usize] =
                    Rgb::splat(f(x * 4, y * 4, (x + y) % 2 == 0));
            }
        }
        let (var, ids) = (vec![Rgb::splat(variance); len], vec![0; len]);
        let samples = Samples {
            w,
            radiance: &rad,
            variance: &var,
            ids: &ids,
            normals,
            albedo: None,
            averaging: Averaging::for_render(90.0, 1.0),
            paths: 16,
        };
        let (mut out, mut resolved) = (vec![Rgb::splat(-1.0); len], vec![false; len]);
        vertex_values(&grid(9), &samples, &mut out, &mut resolved);
        (out, resolved)
    }

    #[test]
    fn the_fit_recovers_a_plane_exactly_from_one_sided_neighbours() {
        let mut fit = PlaneFit::new();
        let plane = |x: f64, y: f64| 1.0 + 0.1 * x - 0.05 * y;
        // The vertex at a corner of its neighbourhood: a mean would read ~2.0 here.
        for (x, y) in [
            (0.0, 0.0),
            (5.0, 0.0),
            (0.0, 5.0),
            (5.0, 5.0),
            (10.0, 3.0),
            (8.0, 9.0),
        ] {
            fit.add(x, y, Rgb::splat(plane(x, y) as f32), Rgb::splat(0.01), 1.0);
        }
        let (v, sd, count) = fit.solve();
        assert!((v.x - 1.0).abs() < 1e-5, "{v}");
        // Extrapolating to a corner costs precision: worth fewer than its 6 vertices.
        assert!(count < 6.0 && sd > 0.1 / 6f64.sqrt());
    }

    #[test]
    fn a_noisy_gradient_is_averaged_without_shifting_it() {
        // 0.5 + 0.05 · x with ±0.05 of alternating "noise" (σ² = 0.0025).
        let ramp = |x: u32| 0.5 + 0.05 * x as f32;
        let (out, _) = reconstruct(
            |x, _, even| ramp(x) + if even { 0.05 } else { -0.05 },
            0.0025,
            &[],
        );
        // Near the image's corner every neighbour lies to one side: a mean over the rings
        // would read the ramp ~10 px further right (+0.5).
        for (x, y) in [(4, 4), (16, 16), (32, 8)] {
            let v = out[y * 40 + x].x;
            assert!(
                (v - ramp(x as u32)).abs() < 0.06,
                "({x}, {y}): {v} vs {}",
                ramp(x as u32)
            );
        }
    }

    #[test]
    fn the_faces_of_one_object_are_not_averaged_together() {
        // A box's two faces: same object, normals 90° apart, values 1.0 and 1.3 with a
        // noise (σ² = 0.25) that hides the step from the range weight.
        let w = 40usize;
        let normals: Vec<Vec3> = (0..w * w)
            .map(|i| if i % w < 16 { Vec3::Z } else { Vec3::X })
            .collect();
        let face = |x: u32| if x < 16 { 1.0 } else { 1.3 };
        let (out, _) = reconstruct(|x, _, _| face(x), 0.25, &normals);
        assert_eq!(out[8 * w + 4].x, 1.0);
        assert_eq!(out[8 * w + 24].x, 1.3);
        let (mixed, _) = reconstruct(|x, _, _| face(x), 0.25, &[]);
        assert!(mixed[8 * w + 12].x > 1.0, "without normals the faces mix");
    }

    #[test]
    fn a_vertex_that_cannot_reach_its_target_is_unresolved() {
        // Widely spaced vertices at 90 ppd ask for ~50 averaged; 81 vertices of a plain
        // noisy field reach it in the middle, not where the grid (the surface) ends, and
        // a sharply curved signal stops the rings early everywhere.
        let (_, plain) = reconstruct(|_, _, even| if even { 1.05 } else { 0.95 }, 0.0025, &[]);
        assert!(plain[16 * 40 + 16]);
        let (_, curved) = reconstruct(|x, y, _| (x * x + y * y) as f32 / 64.0, 0.0025, &[]);
        assert!(!curved[16 * 40 + 16]);
        // An exact oracle has nothing to resolve.
        let (_, exact) = reconstruct(|x, _, _| x as f32, 0.0, &[]);
        assert!(exact[16 * 40 + 16] && exact[0]);
    }
}
