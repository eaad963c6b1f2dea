//! Delaunay triangulation of the traced samples (F&P04 §4.2) and Gouraud shading.
//!
//! Vertices sit at pixel centres, i.e. at integer coordinates, so spade's exact predicates
//! see only integers and barycentric numerators are exact in f64. Every traced pixel is a
//! vertex: the triangulation is the Delaunay of everything traced so far, so a complex
//! triangle whose contour was traced is subdivided along that contour in the next
//! iteration ("a complex triangle is of course subdivided during the next iteration").

use crate::raster::{morton, PixelCoord, Rgb};
use crate::scene::ObjectId;
use rayon::prelude::*;
use spade::{DelaunayTriangulation, HasPosition, Point2, Triangulation};

/// A triangulation vertex: one traced pixel.
#[derive(Clone, Copy, Debug)]
pub struct Vertex {
    pub x: u32,
    pub y: u32,
}

impl HasPosition for Vertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        Point2::new(f64::from(self.x), f64::from(self.y))
    }
}

/// One triangle, vertices counter-clockwise in (x, y) with y as stored (spade's order).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tri {
    pub v: [PixelCoord; 3],
}

impl Tri {
    /// Longest edge in pixels: the "largest dimension" of F&P04 §4.2 (spec §4.4 guard).
    #[must_use]
    pub fn longest_edge(&self) -> f64 {
        let mut m: f64 = 0.0;
        for i in 0..3 {
            let (a, b) = (self.v[i], self.v[(i + 1) % 3]);
            let dx = f64::from(a.x) - f64::from(b.x);
            let dy = f64::from(a.y) - f64::from(b.y);
            m = m.max((dx * dx + dy * dy).sqrt());
        }
        m
    }

    #[must_use]
    pub fn centroid(&self) -> (f64, f64) {
        let x = self.v.iter().map(|p| f64::from(p.x)).sum::<f64>() / 3.0;
        let y = self.v.iter().map(|p| f64::from(p.y)).sum::<f64>() / 3.0;
        (x, y)
    }

    /// Twice the signed area (positive for the counter-clockwise order of spade).
    #[must_use]
    pub fn area2(&self) -> f64 {
        let [a, b, c] = self.v.map(|p| (f64::from(p.x), f64::from(p.y)));
        (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)
    }

    /// Barycentric weights of pixel centre (x, y), or `None` if it lies outside.
    /// Integer inputs make the numerators exact, so shared edges are decided consistently.
    #[must_use]
    pub fn barycentric(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        let area = self.area2();
        if area == 0.0 {
            return None;
        }
        let [a, b, c] = self.v.map(|p| (f64::from(p.x), f64::from(p.y)));
        let edge = |p: (f64, f64), q: (f64, f64)| (q.0 - p.0) * (y - p.1) - (q.1 - p.1) * (x - p.0);
        let w0 = edge(b, c) / area;
        let w1 = edge(c, a) / area;
        let w2 = edge(a, b) / area;
        (w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0).then_some([w0, w1, w2])
    }
}

/// A triangle's three edge functions in exact integer arithmetic, signed so that "inside"
/// is all three ≥ 0: exactly [`Tri::barycentric`]'s test (its weights are e / area, and
/// e / area ≥ 0 ⟺ e = 0 or e has the sign of the area), without its three divisions per
/// pixel. Late in a render the triangles average ~3 pixels: one evaluation per row, one add
/// per pixel.
struct EdgeFunctions {
    /// Per edge (p, q): (s·dx, s·dy, px, py), e(x, y) = s·dx·(y − py) − s·dy·(x − px).
    e: [(i64, i64, i64, i64); 3],
}

impl EdgeFunctions {
    fn new(tr: &Tri) -> Option<Self> {
        let [a, b, c] = tr.v.map(|p| (i64::from(p.x), i64::from(p.y)));
        let area = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        if area == 0 {
            return None;
        }
        let s = area.signum();
        Some(Self {
            e: [(b, c), (c, a), (a, b)].map(|(p, q)| (s * (q.0 - p.0), s * (q.1 - p.1), p.0, p.1)),
        })
    }

    fn at(&self, x: i64, y: i64) -> [i64; 3] {
        self.e.map(|(dx, dy, px, py)| dx * (y - py) - dy * (x - px))
    }

    /// From x to x + 1.
    fn step(&self, e: &mut [i64; 3]) {
        for (v, &(_, dy, _, _)) in e.iter_mut().zip(&self.e) {
            *v -= dy;
        }
    }
}

/// The incremental Delaunay triangulation of the traced pixels.
pub struct Triangulator {
    dt: DelaunayTriangulation<Vertex>,
}

impl Default for Triangulator {
    fn default() -> Self {
        Self::new()
    }
}

impl Triangulator {
    #[must_use]
    pub fn new() -> Self {
        Self {
            dt: DelaunayTriangulation::new(),
        }
    }

    /// Inserts traced pixels. Duplicates are harmless (spade keeps one vertex); an
    /// insertion error (impossible for in-range integer coordinates) skips the point: the
    /// pixel is traced anyway and keeps its traced value.
    pub fn insert(&mut self, pixels: &[PixelCoord]) -> usize {
        // Insert in Morton (Z) order: spade locates each new point by walking from the
        // last inserted one, so spatially coherent order keeps the walks short (a random
        // order made insertion the largest non-tracing cost of an iteration).
        let mut sorted = pixels.to_vec();
        sorted.sort_unstable_by_key(|p| morton(p.x, p.y));
        let mut failed = 0;
        for p in &sorted {
            if self.dt.insert(Vertex { x: p.x, y: p.y }).is_err() {
                failed += 1;
            }
        }
        failed
    }

    #[must_use]
    pub fn num_vertices(&self) -> usize {
        self.dt.num_vertices()
    }

    /// The inner triangles (none when every vertex is collinear).
    #[must_use]
    pub fn triangles(&self) -> Vec<Tri> {
        self.dt
            .inner_faces()
            .map(|f| {
                let v = f.vertices().map(|h| {
                    let d = h.data();
                    PixelCoord::new(d.x, d.y)
                });
                Tri { v }
            })
            .collect()
    }

    /// Nearest vertex to a pixel (fallback fill of pixels no triangle covers).
    #[must_use]
    pub fn nearest(&self, x: u32, y: u32) -> Option<PixelCoord> {
        self.dt
            .nearest_neighbor(Point2::new(f64::from(x), f64::from(y)))
            .map(|h| PixelCoord::new(h.data().x, h.data().y))
    }
}

/// Which triangle owns each pixel, and each triangle's pixels grouped (counting sort).
pub struct Raster {
    pub width: u32,
    pub height: u32,
    /// Owner triangle per pixel, `u32::MAX` if none covers it.
    pub owner: Vec<u32>,
    /// Pixel indices grouped by triangle: triangle t owns `order[start[t]..start[t+1]]`.
    pub order: Vec<u32>,
    pub start: Vec<u32>,
}

impl Raster {
    /// The pixel indices owned by triangle `t`.
    #[must_use]
    pub fn pixels_of(&self, t: usize) -> &[u32] {
        &self.order[self.start[t] as usize..self.start[t + 1] as usize]
    }

    /// Per triangle, the mean of `value(map[pixel])` over its pixels (f64 accumulation);
    /// 0 for a triangle that owns no pixel. The per-triangle distances of F&P04 §4.2 and
    /// the noise distances of super::noise are both such means.
    #[must_use]
    pub fn triangle_means(&self, map: &[f32], value: impl Fn(f32) -> f64 + Sync) -> Vec<f64> {
        let nt = self.start.len().saturating_sub(1);
        // In parallel over triangles; each mean is summed in pixel order, as before.
        (0..nt)
            .into_par_iter()
            .map(|t| {
                let px = self.pixels_of(t);
                if px.is_empty() {
                    return 0.0;
                }
                px.iter().map(|&i| value(map[i as usize])).sum::<f64>() / px.len() as f64
            })
            .collect()
    }
}

/// Rasterises by bounding box: O(Σ bounding-box areas) ≈ O(pixels), never pixels × triangles.
/// A pixel centre on a shared edge goes to the lowest-numbered triangle that covers it, so
/// every covered pixel has exactly one owner, whatever the thread count.
///
/// Parallel over horizontal bands (this runs every iteration over the whole image, on
/// the critical path between two tracing batches): each triangle is listed in the bands
/// its bounding box meets, and each band visits its triangles in increasing order, which
/// keeps "lowest-numbered wins".
#[must_use]
pub fn rasterise(tris: &[Tri], width: u32, height: u32) -> Raster {
    let (w, n) = (width as usize, width as usize * height as usize);
    let mut owner = vec![u32::MAX; n];
    if n > 0 && !tris.is_empty() {
        let band_rows = (height as usize)
            .div_ceil(4 * rayon::current_num_threads())
            .max(8);
        let bands = (height as usize).div_ceil(band_rows);
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); bands];
        for (t, tri) in tris.iter().enumerate() {
            let y0 = tri.v.iter().map(|p| p.y).min().unwrap_or(0) as usize;
            let y1 =
                (tri.v.iter().map(|p| p.y).max().unwrap_or(0) as usize).min(height as usize - 1);
            if y0 > y1 {
                continue;
            }
            for m in &mut members[y0 / band_rows..=y1 / band_rows] {
                m.push(t as u32);
            }
        }
        owner
            .par_chunks_mut(band_rows * w)
            .zip(members.par_iter())
            .enumerate()
            .for_each(|(b, (rows, list))| {
                let (b0, b1) = (b * band_rows, b * band_rows + rows.len() / w);
                for &t in list {
                    let tri = &tris[t as usize];
                    let Some(edges) = EdgeFunctions::new(tri) else {
                        continue; // degenerate: covers nothing (barycentric is None)
                    };
                    let x0 = tri.v.iter().map(|p| p.x).min().unwrap_or(0);
                    let x1 = tri.v.iter().map(|p| p.x).max().unwrap_or(0).min(width - 1);
                    let y0 = (tri.v.iter().map(|p| p.y).min().unwrap_or(0) as usize).max(b0);
                    let y1 = (tri.v.iter().map(|p| p.y).max().unwrap_or(0) as usize).min(b1 - 1);
                    for y in y0..=y1 {
                        let row = &mut rows[(y - b0) * w..(y - b0 + 1) * w];
                        let mut e = edges.at(i64::from(x0), y as i64);
                        for o in &mut row[x0 as usize..=x1 as usize] {
                            if *o == u32::MAX && e.iter().all(|&v| v >= 0) {
                                *o = t;
                            }
                            edges.step(&mut e);
                        }
                    }
                }
            });
    }
    let mut count = vec![0u32; tris.len() + 1];
    for &o in &owner {
        if o != u32::MAX {
            count[o as usize] += 1;
        }
    }
    let mut start = vec![0u32; tris.len() + 1];
    for t in 0..tris.len() {
        start[t + 1] = start[t] + count[t];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; start[tris.len()] as usize];
    for (i, &o) in owner.iter().enumerate() {
        if o != u32::MAX {
            order[fill[o as usize] as usize] = i as u32;
            fill[o as usize] += 1;
        }
    }
    Raster {
        width,
        height,
        owner,
        order,
        start,
    }
}

/// Below this an albedo channel cannot divide a radiance (a black texel carries no
/// irradiance information).
pub const MIN_ALBEDO: f32 = 1e-4;

/// Texture-modulated interpolation at one pixel: the vertices' radiance ÷ albedo (their
/// irradiance/π, smooth where the texture is not) is interpolated with weights `b` and
/// multiplied by the pixel's own albedo `a`. Per channel, only vertices whose albedo can
/// divide take part (weights renormalised); a channel where none can falls back to plain
/// Gouraud.
fn modulated(c: [Rgb; 3], va: [Rgb; 3], b: [f64; 3], a: Rgb) -> Rgb {
    let mut out = [0f32; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let (mut e, mut wsum) = (0f64, 0f64);
        for j in 0..3 {
            if va[j][k] >= MIN_ALBEDO {
                e += b[j] * f64::from(c[j][k] / va[j][k]);
                wsum += b[j];
            }
        }
        *o = if wsum > 1e-9 {
            (e / wsum) as f32 * a[k]
        } else {
            (0..3).map(|j| c[j][k] * b[j] as f32).sum()
        };
    }
    Rgb::from_array(out)
}

/// Vertex radiances as they would be under a uniform texture of the vertices' mean albedo:
/// `c[j] ÷ va[j] × mean(va)`, per channel. What a contrast test between vertices should
/// see, since the texture itself is reproduced from the albedo map ([`gouraud`]). `None`
/// if a channel's albedo is too small to divide by.
#[must_use]
pub fn untextured(c: [Rgb; 3], va: [Rgb; 3]) -> Option<[Rgb; 3]> {
    if va.iter().any(|a| a.min_element() < MIN_ALBEDO) {
        return None;
    }
    let mean = (va[0] + va[1] + va[2]) / 3.0;
    Some([0, 1, 2].map(|j| c[j] / va[j] * mean))
}

/// What the shading reads, per pixel of the image (row-major).
#[derive(Clone, Copy)]
pub struct ShadeInput<'a> {
    /// Traced estimates.
    pub radiance: &'a [Rgb],
    /// What each vertex (traced pixel) shows and contributes to the interpolation
    /// (`reconstruct::vertex_values`); `radiance` where `None`.
    pub vertex: Option<&'a [Rgb]>,
    pub traced: &'a [bool],
    /// [`crate::tracer::PixelOracle::texture_albedo`] per pixel (textured scenes only).
    pub albedo: Option<&'a [Option<Rgb>]>,
    /// The object-id map (§4.1): a pixel is interpolated only from the vertices of its
    /// triangle that lie on its own object, when it has any.
    pub ids: Option<&'a [ObjectId]>,
}

/// Gouraud shading (F&P04 §4.2): barycentric interpolation of the vertex values over
/// each triangle's untraced pixels; traced pixels show their vertex value. Pixels no
/// triangle covers take their nearest vertex's value. Parallel over rows: every pixel is
/// computed from its owner triangle alone, so the result does not depend on threads.
///
/// Where the object-id map is given, a pixel takes only the vertices on its own object,
/// their barycentric weights renormalised ([`same_object`]): one object's radiance is never
/// interpolated onto another, and a contour inside a triangle stays as sharp as the exact
/// id map. A pixel whose triangle has no vertex on its object (an *orphan*: the loop traces
/// such pixels, [`orphan_of`]) keeps plain Gouraud meanwhile.
///
/// With `albedo`: where a pixel and its triangle's vertices see textured Lambertian
/// surfaces, the interpolation is texture-modulated ([`modulated`]): the texture's detail
/// is reproduced exactly instead of being averaged away between samples. Elsewhere, and
/// without a map, plain Gouraud.
pub fn gouraud(
    tris: &[Tri],
    raster: &Raster,
    tri: &Triangulator,
    input: &ShadeInput,
    out: &mut [Rgb],
) {
    let w = raster.width as usize;
    if w == 0 {
        return;
    }
    let vertex = input.vertex.unwrap_or(input.radiance);
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let t = raster.owner[i];
            if input.traced[i] {
                *o = vertex[i];
                continue;
            }
            let Some(tr) = tris.get(t as usize) else {
                continue; // uncovered: filled below
            };
            let vi = tr.v.map(|p| p.y as usize * w + p.x as usize);
            let c = vi.map(|j| vertex[j]);
            *o = match tr.barycentric(x as f64, y as f64) {
                Some(b) => {
                    let b = input
                        .ids
                        .map_or(b, |ids| same_object(b, vi.map(|j| ids[j]), ids[i]));
                    let tex = input
                        .albedo
                        .and_then(|a| Some((a[i]?, [a[vi[0]]?, a[vi[1]]?, a[vi[2]]?])));
                    match tex {
                        Some((a, va)) => modulated(c, va, b, a),
                        None => c[0] * b[0] as f32 + c[1] * b[1] as f32 + c[2] * b[2] as f32,
                    }
                }
                None => c[0],
            };
        }
    });
    for (i, o) in raster.owner.iter().enumerate() {
        if *o != u32::MAX || input.traced[i] {
            continue;
        }
        out[i] = match tri.nearest((i % w) as u32, (i / w) as u32) {
            Some(p) => vertex[p.y as usize * w + p.x as usize],
            None => Rgb::ZERO,
        };
    }
}

/// Barycentric weights restricted to the vertices on object `id` and renormalised; equal
/// weights over them where the pixel lies on the edge opposite them all; `b` unchanged when
/// no vertex (an orphan) or every vertex is on `id`.
#[must_use]
pub fn same_object(b: [f64; 3], vid: [ObjectId; 3], id: ObjectId) -> [f64; 3] {
    let on = vid.map(|v| v == id);
    if on.iter().all(|&o| o) || !on.iter().any(|&o| o) {
        return b;
    }
    let kept = [0, 1, 2].map(|k| if on[k] { b[k] } else { 0.0 });
    let sum: f64 = kept.iter().sum();
    if sum > 0.0 {
        return kept.map(|v| v / sum);
    }
    let n = on.iter().filter(|&&o| o).count() as f64;
    on.map(|o| if o { 1.0 / n } else { 0.0 })
}

/// An untraced pixel of triangle `t` whose object none of the triangle's vertices lies on
/// (nearest the triangle's centroid), if any: interpolation cannot give it its own
/// object's colour, so the loop traces it.
#[must_use]
pub fn orphan_of(
    tr: &Tri,
    raster: &Raster,
    t: usize,
    traced: &[bool],
    ids: &[ObjectId],
) -> Option<usize> {
    let w = raster.width as usize;
    let vid = tr.v.map(|p| ids[p.y as usize * w + p.x as usize]);
    let (cx, cy) = tr.centroid();
    raster
        .pixels_of(t)
        .iter()
        .map(|&i| i as usize)
        .filter(|&i| !traced[i] && !vid.contains(&ids[i]))
        .min_by(|&a, &b| {
            let d = |i: usize| ((i % w) as f64 - cx).powi(2) + ((i / w) as f64 - cy).powi(2);
            d(a).total_cmp(&d(b))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plain_input<'a>(
        radiance: &'a [Rgb],
        traced: &'a [bool],
        albedo: Option<&'a [Option<Rgb>]>,
    ) -> ShadeInput<'a> {
        ShadeInput {
            radiance,
            vertex: None,
            traced,
            albedo,
            ids: None,
        }
    }

    #[test]
    fn a_pixel_takes_only_the_vertices_on_its_own_object() {
        let b = [0.5, 0.25, 0.25];
        assert_eq!(same_object(b, [1, 1, 1], 1), b);
        assert_eq!(
            same_object(b, [2, 2, 2], 1),
            b,
            "an orphan keeps plain weights"
        );
        assert_eq!(same_object(b, [1, 2, 1], 1), [0.5 / 0.75, 0.0, 0.25 / 0.75]);
        assert_eq!(same_object([0.0, 1.0, 0.0], [1, 2, 1], 1), [0.5, 0.0, 0.5]);
    }

    fn corners(w: u32, h: u32) -> Vec<PixelCoord> {
        vec![
            PixelCoord::new(0, 0),
            PixelCoord::new(w - 1, 0),
            PixelCoord::new(0, h - 1),
            PixelCoord::new(w - 1, h - 1),
        ]
    }

    #[test]
    fn corners_cover_every_pixel_exactly_once() {
        let (w, h) = (7u32, 5u32);
        let mut t = Triangulator::new();
        t.insert(&corners(w, h));
        t.insert(&[PixelCoord::new(3, 2)]);
        let tris = t.triangles();
        assert_eq!(tris.len(), 4);
        let r = rasterise(&tris, w, h);
        assert!(r.owner.iter().all(|&o| o != u32::MAX));
        assert_eq!(r.order.len(), (w * h) as usize);
        for tr in &tris {
            assert!(tr.area2() > 0.0, "spade faces are counter-clockwise");
        }
    }

    #[test]
    fn gouraud_reproduces_a_linear_field_exactly() {
        let (w, h) = (9u32, 6u32);
        let f = |x: u32, y: u32| Rgb::new(x as f32, y as f32, (2 * x + 3 * y) as f32);
        let mut t = Triangulator::new();
        let pts = corners(w, h);
        t.insert(&pts);
        let tris = t.triangles();
        let r = rasterise(&tris, w, h);
        let n = (w * h) as usize;
        let mut rad = vec![Rgb::ZERO; n];
        let mut traced = vec![false; n];
        for p in &pts {
            let i = (p.y * w + p.x) as usize;
            rad[i] = f(p.x, p.y);
            traced[i] = true;
        }
        let mut out = vec![Rgb::splat(-1.0); n];
        gouraud(&tris, &r, &t, &plain_input(&rad, &traced, None), &mut out);
        for y in 0..h {
            for x in 0..w {
                let d = out[(y * w + x) as usize] - f(x, y);
                assert!(d.abs().max_element() < 1e-4, "({x},{y}) {d:?}");
            }
        }
    }

    #[test]
    fn edge_functions_are_exactly_the_barycentric_inside_test() {
        // Counter-clockwise, clockwise, slivers, horizontal and vertical edges, degenerate
        // (collinear and repeated) triangles, and triangles reaching past the row's end.
        let mut tris: Vec<Tri> = [
            [(0, 0), (12, 0), (0, 9)],
            [(0, 0), (0, 9), (12, 0)],
            [(1, 1), (30, 2), (2, 3)],
            [(3, 0), (4, 25), (3, 24)],
            [(5, 5), (5, 5), (9, 9)],
            [(0, 0), (4, 4), (8, 8)],
            [(20, 3), (29, 17), (11, 17)],
            [(29, 0), (0, 19), (29, 19)],
        ]
        .iter()
        .map(|v| Tri {
            v: v.map(|(x, y)| PixelCoord::new(x, y)),
        })
        .collect();
        // And a deterministic scatter of small and large ones.
        for k in 0..200u32 {
            let p = |j: u32| {
                PixelCoord::new((k * 7 + j * 13 + k * j) % 30, (k * 11 + j * 5 + k / 3) % 20)
            };
            tris.push(Tri {
                v: [p(1), p(2), p(3)],
            });
        }
        for tr in &tris {
            let ef = EdgeFunctions::new(tr);
            assert_eq!(ef.is_none(), tr.area2() == 0.0);
            for y in 0..22i64 {
                let want: Vec<i64> = (0..32)
                    .filter(|&x| tr.barycentric(x as f64, y as f64).is_some())
                    .collect();
                let mut got = vec![];
                if let Some(ef) = &ef {
                    let mut e = ef.at(0, y);
                    for x in 0..32 {
                        if e.iter().all(|&v| v >= 0) {
                            got.push(x);
                        }
                        ef.step(&mut e);
                    }
                }
                assert_eq!(got, want, "{:?} row {y}", tr.v);
            }
        }
    }

    #[test]
    fn rasterise_gives_each_pixel_its_lowest_covering_triangle_on_any_thread_count() {
        let (w, h) = (61u32, 47u32);
        let mut t = Triangulator::new();
        t.insert(&corners(w, h));
        // A scattered, deterministic point set (many shared edges through pixel centres).
        let pts: Vec<PixelCoord> = (0..150u32)
            .map(|k| PixelCoord::new((k * 37 + 11) % w, (k * 53 + 7) % h))
            .collect();
        t.insert(&pts);
        let tris = t.triangles();
        let brute: Vec<u32> = (0..w * h)
            .map(|i| {
                let (x, y) = (f64::from(i % w), f64::from(i / w));
                tris.iter()
                    .position(|tr| tr.barycentric(x, y).is_some())
                    .map_or(u32::MAX, |p| p as u32)
            })
            .collect();
        for threads in [1, 2, 5] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let r = pool.install(|| rasterise(&tris, w, h));
            assert_eq!(r.owner, brute, "{threads} threads");
            assert_eq!(r.order.len(), (w * h) as usize);
        }
    }

    #[test]
    fn gouraud_with_albedo_reproduces_a_textured_field() {
        // Radiance = albedo × a smooth irradiance; the albedo is a checker of 3-px cells
        // (0.9 / 0.1, and a black blue channel on one colour). Plain Gouraud from a few
        // vertices blurs the checker; modulated Gouraud reproduces it exactly wherever the
        // irradiance is linear.
        let (w, h) = (24u32, 18u32);
        let alb = |x: u32, y: u32| {
            if (x / 3 + y / 3).is_multiple_of(2) {
                Rgb::new(0.9, 0.9, 0.9)
            } else {
                Rgb::new(0.1, 0.1, 0.0)
            }
        };
        let e = |x: u32, y: u32| Rgb::new(1.0 + 0.05 * x as f32, 2.0 + 0.1 * y as f32, 1.5);
        let n = (w * h) as usize;
        let mut pts = corners(w, h);
        pts.extend([PixelCoord::new(10, 8), PixelCoord::new(17, 4)]);
        let mut t = Triangulator::new();
        t.insert(&pts);
        let tris = t.triangles();
        let r = rasterise(&tris, w, h);
        let mut rad = vec![Rgb::ZERO; n];
        let mut traced = vec![false; n];
        let mut albedo = vec![None; n];
        for y in 0..h {
            for x in 0..w {
                albedo[(y * w + x) as usize] = Some(alb(x, y));
            }
        }
        for p in &pts {
            let i = (p.y * w + p.x) as usize;
            rad[i] = alb(p.x, p.y) * e(p.x, p.y);
            traced[i] = true;
        }
        let truth = |x: u32, y: u32| alb(x, y) * e(x, y);
        let err = |out: &[Rgb], k: usize| {
            (0..n)
                .map(|i| (out[i][k] - truth(i as u32 % w, i as u32 / w)[k]).abs())
                .fold(0f32, f32::max)
        };
        let mut plain = vec![Rgb::ZERO; n];
        gouraud(&tris, &r, &t, &plain_input(&rad, &traced, None), &mut plain);
        let mut modu = vec![Rgb::ZERO; n];
        gouraud(
            &tris,
            &r,
            &t,
            &plain_input(&rad, &traced, Some(&albedo)),
            &mut modu,
        );
        assert!(err(&plain, 0) > 0.3, "plain Gouraud blurs the checker");
        assert!(
            err(&modu, 0) < 1e-4 && err(&modu, 1) < 1e-4,
            "{}",
            err(&modu, 0)
        );
        // Blue: vertices on the black colour cannot divide; the others carry the
        // irradiance, and a black pixel stays black. Never NaN.
        assert!(modu.iter().all(|v| v.is_finite()));
        for (i, v) in modu.iter().enumerate() {
            if alb(i as u32 % w, i as u32 / w).z == 0.0 {
                assert_eq!(v.z, 0.0);
            }
        }
        // A pixel without albedo (another material) gets plain Gouraud.
        let mut partial = albedo.clone();
        partial[5 * w as usize + 7] = None;
        let mut out = vec![Rgb::ZERO; n];
        gouraud(
            &tris,
            &r,
            &t,
            &plain_input(&rad, &traced, Some(&partial)),
            &mut out,
        );
        assert_eq!(out[5 * w as usize + 7], plain[5 * w as usize + 7]);
        assert_eq!(out[5 * w as usize + 8], modu[5 * w as usize + 8]);
    }

    #[test]
    fn untextured_divides_out_the_albedo() {
        let c = [Rgb::splat(0.8), Rgb::splat(0.2), Rgb::splat(0.4)];
        let va = [Rgb::splat(0.8), Rgb::splat(0.2), Rgb::splat(0.4)];
        let u = untextured(c, va).unwrap();
        let mean = 1.4 / 3.0;
        for v in u {
            assert!((v.x - mean).abs() < 1e-6);
        }
        assert!(untextured(c, [va[0], Rgb::new(0.5, 0.0, 0.5), va[2]]).is_none());
    }

    #[test]
    fn collinear_points_give_no_triangles() {
        let mut t = Triangulator::new();
        t.insert(&(0..10).map(|x| PixelCoord::new(x, 0)).collect::<Vec<_>>());
        assert!(t.triangles().is_empty());
        assert_eq!(t.nearest(4, 0), Some(PixelCoord::new(4, 0)));
    }
}
