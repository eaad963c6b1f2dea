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
//! vertices, 1 (no averaging) where vertices are a pixel apart. [`target_count`] asks for
//! [`VISIBILITY_MARGIN`] times that.
//!
//! The average is a bilateral one over rings of the Delaunay graph (Tomasi & Manduchi's
//! weights with the range scale set by the estimates' own variance, as SVGF does): only
//! vertices on the same object (the exact object-id map of §4.1) and whose values differ
//! by no more than their noise explains are averaged, so contours, shadows and highlights
//! keep their vertices' own values, and a region's vertices share their noise instead of
//! each drawing its own blotch. Textured surfaces are averaged in radiance ÷ albedo (the
//! same demodulation as `mesh::gouraud`). An exact oracle (variance 0) gets F&P04's
//! interpolation unchanged: no neighbour is similar enough to be averaged.

use super::mesh::{Tri, MIN_ALBEDO};
use crate::raster::Rgb;
use crate::scene::ObjectId;
use rayon::prelude::*;

/// Ask for this many times the averaging that makes interpolated noise exactly as visible
/// as the reference's grain: the blotches must not be *more* visible, and an average is
/// also slightly biased where the signal curves.
pub const VISIBILITY_MARGIN: f64 = 4.0;

/// Range scale of the bilateral weight, in standard deviations of the difference of two
/// estimates: a neighbour that agrees within its noise keeps most of its weight
/// (E[exp(−z²/2κ²)] ≈ 0.89 for z ~ N(0, 1)), a real step of a few σ loses it.
const RANGE_SIGMAS: f32 = 2.0;

/// Rings of the Delaunay graph searched at most (a vertex has ~6 neighbours per ring).
const MAX_RINGS: usize = 6;

/// Effective number of vertices to average at a vertex whose surroundings hold one vertex
/// per `area` pixels, shown at `ppd` pixels per degree (the module's derivation).
#[must_use]
pub fn target_count(ppd: f32, area: f64) -> f64 {
    let s = 0.0154 * f64::from(ppd);
    let csf = 4.0 * std::f64::consts::PI * s * s;
    VISIBILITY_MARGIN * (1.0 + csf) / (2.0 + csf / area.max(1.0))
}

/// What a vertex contributes: its pixel, object, value (demodulated where textured) and
/// that value's variance.
#[derive(Clone, Copy, Debug)]
struct Node {
    pixel: usize,
    id: ObjectId,
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

/// The value each vertex of `tris` contributes to the shading, written at its pixel index
/// into `out` (other entries untouched). `radiance`, `variance`, `ids`, `albedo` are
/// per-pixel buffers of a `w`-wide image.
#[allow(clippy::too_many_arguments)]
pub fn vertex_values(
    tris: &[Tri],
    w: usize,
    radiance: &[Rgb],
    variance: &[Rgb],
    ids: &[ObjectId],
    albedo: Option<&[Option<Rgb>]>,
    ppd: f32,
    out: &mut [Rgb],
) {
    let (mut nodes, adjacency) = graph(tris, w, radiance, variance, ids, albedo);
    guide(&mut nodes, &adjacency);
    let smoothed: Vec<Rgb> = (0..nodes.len())
        .into_par_iter()
        .with_min_len(2048)
        .map_init(
            || Visited::new(nodes.len()),
            |visited, k| smooth(k, &nodes, &adjacency, ppd, visited),
        )
        .collect();
    for (node, v) in nodes.iter().zip(smoothed) {
        out[node.pixel] = v;
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

fn graph(
    tris: &[Tri],
    w: usize,
    radiance: &[Rgb],
    variance: &[Rgb],
    ids: &[ObjectId],
    albedo: Option<&[Option<Rgb>]>,
) -> (Vec<Node>, Adjacency) {
    let at = |p: crate::raster::PixelCoord| p.y as usize * w + p.x as usize;
    let mut pixels: Vec<usize> = tris.iter().flat_map(|t| t.v.map(at)).collect();
    pixels.par_sort_unstable();
    pixels.dedup();
    let number = |p: usize| pixels.binary_search(&p).map_or(u32::MAX, |k| k as u32);
    let mut area = vec![0f64; pixels.len()];
    let mut count = vec![0u32; pixels.len()];
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(tris.len() * 6);
    for t in tris {
        let k = t.v.map(|p| number(at(p)));
        let a = t.area2().abs() * 0.5;
        for j in 0..3 {
            let (u, v) = (k[j], k[(j + 1) % 3]);
            area[u as usize] += a;
            count[u as usize] += 1;
            edges.push((u, v));
            edges.push((v, u));
        }
    }
    edges.par_sort_unstable();
    edges.dedup();
    let mut start = vec![0u32; pixels.len() + 1];
    for &(u, _) in &edges {
        start[u as usize + 1] += 1;
    }
    for k in 0..pixels.len() {
        start[k + 1] += start[k];
    }
    let list = edges.into_iter().map(|(_, v)| v).collect();
    let nodes = pixels
        .iter()
        .enumerate()
        .map(|(k, &i)| {
            let own = albedo
                .and_then(|a| a[i])
                .filter(|a| a.min_element() >= MIN_ALBEDO);
            let value = own.map_or(radiance[i], |a| radiance[i] / a);
            Node {
                pixel: i,
                id: ids[i],
                value,
                variance: own.map_or(variance[i], |a| variance[i] / (a * a)),
                guide: Rgb::ZERO,
                guide_variance: Rgb::ZERO,
                albedo: own,
                area: 2.0 * area[k] / f64::from(count[k].max(1)),
            }
        })
        .collect();
    (nodes, Adjacency { start, list })
}

/// The range weight's guide: each vertex's luminance averaged with its same-object
/// neighbours (a cross-bilateral filter's prefiltered guide), and the variance of that
/// mean from the neighbourhood's pooled variance. Comparing raw estimates would be biased:
/// path-traced noise is heavy-tailed, and a weight that drops whichever neighbour caught a
/// bright path darkens every average (measured: objects 8–19 % too dark on the door
/// scene). A pooled variance also stops a pixel whose few paths all missed the light from
/// claiming a tiny noise beside one that caught it: both are draws of one distribution.
fn guide(nodes: &mut [Node], adj: &Adjacency) {
    let guides: Vec<(Rgb, Rgb)> = (0..nodes.len())
        .into_par_iter()
        .map(|k| {
            let me = &nodes[k];
            let (mut g, mut v, mut n) = (me.value, me.variance, 1.0f32);
            for &u in adj.of(k) {
                let o = &nodes[u as usize];
                if o.id == me.id {
                    g += o.value;
                    v += o.variance;
                    n += 1.0;
                }
            }
            (g / n, v / (n * n))
        })
        .collect();
    for (node, (g, gv)) in nodes.iter_mut().zip(guides) {
        node.guide = g;
        node.guide_variance = gv;
    }
}

/// The bilateral mean around vertex `k`, ring by ring until the effective number of
/// vertices averaged, (Σw)² / Σw², reaches [`target_count`].
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

fn smooth(k: usize, nodes: &[Node], adj: &Adjacency, ppd: f32, visited: &mut Visited) -> Rgb {
    let me = nodes[k];
    let own = |v: Rgb| me.albedo.map_or(v, |a| v * a);
    let target = target_count(ppd, me.area);
    if target <= 1.0 || me.variance == Rgb::ZERO {
        return own(me.value);
    }
    let (mut sum, mut sw, mut sw2) = (me.value, 1f64, 1f64);
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
                if nodes[v as usize].id != me.id || !visited.insert(v) {
                    continue;
                }
                next.push(v);
                let o = nodes[v as usize];
                let wgt = range_weight(me.guide - o.guide, me.guide_variance + o.guide_variance);
                sum += o.value * wgt as f32;
                sw += wgt;
                sw2 += wgt * wgt;
            }
        }
        if next.is_empty() || sw * sw / sw2 >= target {
            break;
        }
        std::mem::swap(&mut ring, &mut next);
    }
    visited.ring = ring;
    visited.next = next;
    own(sum / sw as f32)
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
    (-(chi2 / 3.0) / (2.0 * k * k)).exp()
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
        assert!(target_count(28.0, 1.0) <= VISIBILITY_MARGIN * 1.0);
        assert!(target_count(60.0, 50.0) > target_count(28.0, 50.0));
        assert!(target_count(60.0, 50.0) > target_count(60.0, 4.0));
        // Widely spaced vertices at 60 ppd: (1 + 4π·0.924²) / 2 ≈ 5.9 before the margin.
        let far = target_count(60.0, 1e9) / VISIBILITY_MARGIN;
        assert!((far - 5.86).abs() < 0.05, "{far}");
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
        vertex_values(&tris, w, &rad, &var, &ids, None, 90.0, &mut out);
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
        vertex_values(&tris, w, &rad, &exact, &ids, None, 90.0, &mut out);
        assert_eq!(out[4 * w + 4].x, rad[4 * w + 4].x);
    }
}
