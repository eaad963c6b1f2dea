//! Camera rays of small scenes: screen tiles that list the primitives they can see.
//!
//! Every camera ray starts at the pinhole and leaves through a known pixel (its jitter
//! stays inside the pixel, camera.rs), so the primitives it can hit are known before it
//! is traced: those whose projection overlaps the pixel. For a scene of a few dozen or
//! hundred primitives, each 8×8-pixel tile keeps that list (conservatively, with a margin
//! far above rounding) and a camera ray tests only its tile's list instead of traversing
//! the BVH (the CWBVH traversal was ~70 % of a primary ray on the Cornell box).
//! Tiles with the same list share it (the inside of a wall is one list).
//!
//! Because the origin is the same for every camera ray, the origin-dependent half of
//! Möller–Trumbore is computed once per triangle, and a list's triangles are tested four
//! at a time (glam `Vec4`, SSE2 on x86-64), lane by lane the same IEEE operations in the
//! same order as bvh.rs `tri_t`, so `t`, `u` and `v` are bit-identical to
//! [`Geometry::intersect`]. An exact tie in `t` between two primitives (a ray through an
//! edge they share) would be broken by visiting order, which differs: those rays go to
//! the BVH, so the hit is always the BVH's and pixel values do not change.
//!
//! Large scenes (many primitives, or long lists) skip this: the BVH is then faster
//! (decided once in [`CameraRays::build`], STYLE.md "branch on scene features when the
//! scene is prepared").

use super::bvh::{Geometry, Hit, Prim, PrimShape, NONE};
use super::camera::Pinhole;
use glam::{Vec3, Vec3A, Vec4};
use std::collections::HashMap;

/// Scenes with more primitives than this keep the BVH for camera rays: building the
/// lists costs O(primitives × tiles covered) and long lists lose to a traversal.
pub const MAX_PRIMS: usize = 1024;
/// Mean list length (over tiles) above which the lists are dropped: beyond it the CWBVH
/// traversal (~700 instructions per ray on the Cornell box) is as cheap.
const MAX_MEAN_CANDIDATES: usize = 24;
/// At most this many tiles (the tile side doubles from 8 pixels until it fits).
const MAX_TILES: u32 = 1 << 16;
/// Safety margin in pixels around each projected bound. The projection (f64) and the
/// f32 direction of [`Pinhole::direction`] differ by ~1e-6 relative; a pixel's width is
/// orders of magnitude more.
const MARGIN_PX: f64 = 1.0;

/// Four triangles, structure of arrays, with the terms of bvh.rs `tri_t` that depend only
/// on the ray origin precomputed for the camera: `tv = o - v0`, `qv = tv × e1`,
/// `tnum = e2 · qv`. Unused lanes are zero (det = 0: never a hit) with prim [`NONE`].
#[derive(Clone, Copy, Debug)]
struct TriPacket {
    e1: [Vec4; 3],
    e2: [Vec4; 3],
    tv: [Vec4; 3],
    qv: [Vec4; 3],
    tnum: Vec4,
    prim: [u32; 4],
}

/// bvh.rs `sphere_t` with `f = o - c`, `r2 = r²` and `cc = |f|² - r²` fixed.
#[derive(Clone, Copy, Debug)]
struct CamSphere {
    prim: u32,
    f: Vec3A,
    r2: f32,
    cc: f32,
}

/// One distinct candidate list: `packets[p0..p1]` and `spheres[s0..s1]`.
#[derive(Clone, Copy, Debug, Default)]
struct List {
    p0: u32,
    p1: u32,
    s0: u32,
    s1: u32,
}

/// Screen tiles with their candidate primitives.
pub struct CameraRays {
    origin: Vec3,
    width: u32,
    height: u32,
    tile_shift: u32,
    tiles_x: u32,
    /// Per tile, index into `lists`.
    tile_list: Vec<u32>,
    lists: Vec<List>,
    packets: Vec<TriPacket>,
    spheres: Vec<CamSphere>,
    /// Sum of the list lengths over tiles (diagnostics).
    entries: usize,
}

/// The tiles a primitive may be seen in.
enum Region {
    Nowhere,
    Everywhere,
    /// Inclusive tile ranges.
    Tiles {
        x0: u32,
        x1: u32,
        y0: u32,
        y1: u32,
    },
}

impl CameraRays {
    /// The lists for `geo` seen from `cam` at `width`×`height`, or `None` when the scene
    /// is better served by the BVH (see [`MAX_PRIMS`], [`MAX_MEAN_CANDIDATES`]).
    #[must_use]
    pub fn build(geo: &Geometry, cam: &Pinhole, width: u32, height: u32) -> Option<Self> {
        let n = geo.prims.len();
        if n == 0 || n > MAX_PRIMS || width == 0 || height == 0 {
            return None;
        }
        let grid = Grid::fitting(width, height);
        let (per_tile, entries) = per_tile_lists(geo, cam, width, height, &grid)?;
        let mut packed = Packed::default();
        let mut ids: HashMap<&[u32], u32> = HashMap::new();
        let mut tile_list = Vec::with_capacity(per_tile.len());
        let o = Vec3A::from(cam.origin);
        for l in &per_tile {
            // Tiles with equal lists share one.
            let id = *ids
                .entry(l.as_slice())
                .or_insert_with(|| packed.push_list(geo, o, l));
            tile_list.push(id);
        }
        Some(Self {
            origin: cam.origin,
            width,
            height,
            tile_shift: grid.shift,
            tiles_x: grid.x,
            tile_list,
            lists: packed.lists,
            packets: packed.packets,
            spheres: packed.spheres,
            entries,
        })
    }

    /// Mean number of candidates per tile (diagnostics and tests).
    #[must_use]
    pub fn mean_candidates(&self) -> f64 {
        self.entries as f64 / self.tile_list.len().max(1) as f64
    }

    /// Number of distinct lists (tiles share equal lists).
    #[must_use]
    pub fn distinct_lists(&self) -> usize {
        self.lists.len()
    }

    /// Closest hit of the camera ray `d` (unit) through pixel (x, y): what
    /// `geo.intersect(camera.origin, d, ∞, NONE)` returns. Pixels outside the image fall
    /// back to the BVH.
    // Kept whole (~80 lines): the packet and sphere loops are the hot body of every camera
    // ray, and their best-so-far state (t, prim, u, v, tie) lives in registers across both.
    #[inline(always)]
    #[must_use]
    pub fn intersect(&self, geo: &Geometry, x: u32, y: u32, d: Vec3) -> Option<Hit> {
        let Some((packets, spheres)) = self.candidates(x, y) else {
            return geo.intersect(self.origin, d, f32::INFINITY, NONE);
        };
        let da = Vec3A::from(d);
        let (dx, dy, dz) = (Vec4::splat(d.x), Vec4::splat(d.y), Vec4::splat(d.z));
        let mut best_t = f32::INFINITY;
        let mut best = NONE;
        let (mut best_u, mut best_v) = (0.0f32, 0.0f32);
        // An exact tie in t between two primitives (a ray along an edge the two share:
        // at pixel centres of a symmetric view this is common) is broken by visiting
        // order, which differs from the BVH's. Such rays are handed to the BVH so that
        // the hit, and hence every pixel and object id, stays the BVH's exactly.
        let mut tie_t = f32::NAN;
        for p in packets {
            // bvh.rs `tri_t` lane-wise: pv = d × e2, det = e1 · pv, u = tv · pv / det,
            // v = d · qv / det, t = tnum / det (glam's cross and dot orders: a·b =
            // (ax·bx + ay·by) + az·bz).
            let [e1x, e1y, e1z] = p.e1;
            let [e2x, e2y, e2z] = p.e2;
            let pvx = dy * e2z - dz * e2y;
            let pvy = dz * e2x - dx * e2z;
            let pvz = dx * e2y - dy * e2x;
            let det = e1x * pvx + e1y * pvy + e1z * pvz;
            let inv = Vec4::ONE / det;
            let u = (p.tv[0] * pvx + p.tv[1] * pvy + p.tv[2] * pvz) * inv;
            let v = (dx * p.qv[0] + dy * p.qv[1] + dz * p.qv[2]) * inv;
            let t = p.tnum * inv;
            // The acceptance tests of `tri_t`, NaN behaviour included (`!(v < 0)` lets a
            // NaN v through exactly as `v < 0.0 || u + v > 1.0` does), except that a t
            // equal to the best so far is kept to detect ties.
            let ok = det.cmpne(Vec4::ZERO)
                & det.is_finite_mask()
                & u.cmpge(Vec4::ZERO)
                & u.cmple(Vec4::ONE)
                & !v.cmplt(Vec4::ZERO)
                & !(u + v).cmpgt(Vec4::ONE)
                & t.cmpgt(Vec4::ZERO)
                & t.cmplt(Vec4::INFINITY)
                & t.cmple(Vec4::splat(best_t));
            if ok.any() {
                let tt = Vec4::select(ok, t, Vec4::INFINITY);
                let m = tt.min_element();
                let at_min = tt.cmpeq(Vec4::splat(m)).bitmask();
                if m == best_t || at_min.count_ones() > 1 {
                    tie_t = m;
                }
                if m < best_t {
                    // The first lane with the smallest t: the one a sequential loop keeps.
                    let lane = (at_min.trailing_zeros() & 3) as usize;
                    best_t = m;
                    best = p.prim[lane];
                    best_u = u.to_array()[lane];
                    best_v = v.to_array()[lane];
                }
            }
        }
        let mut sphere_hit = false;
        for s in spheres {
            let t = sphere_t(da, s.f, s.r2, s.cc, f32::INFINITY);
            if t == best_t && t < f32::INFINITY {
                tie_t = t;
            }
            if t < best_t {
                best_t = t;
                best = s.prim;
                sphere_hit = true;
            }
        }
        if tie_t == best_t {
            return geo.intersect(self.origin, d, f32::INFINITY, NONE);
        }
        if best == NONE {
            return None;
        }
        Some(hit_of(best_t, best, sphere_hit, best_u, best_v))
    }

    /// The candidate triangles and spheres of pixel (x, y)'s tile, or `None` outside the
    /// image.
    #[inline(always)]
    fn candidates(&self, x: u32, y: u32) -> Option<(&[TriPacket], &[CamSphere])> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let tile = ((y >> self.tile_shift) * self.tiles_x + (x >> self.tile_shift)) as usize;
        let l = self.lists.get(*self.tile_list.get(tile)? as usize)?;
        Some((
            self.packets.get(l.p0 as usize..l.p1 as usize)?,
            self.spheres.get(l.s0 as usize..l.s1 as usize)?,
        ))
    }
}

/// The hit on `prim` at `t`, its barycentrics clamped as bvh.rs `tri_uv` clamps the same
/// u and v (a sphere's are zero).
#[inline(always)]
fn hit_of(t: f32, prim: u32, sphere: bool, u: f32, v: f32) -> Hit {
    let (u, v) = if sphere {
        (0.0, 0.0)
    } else {
        let u = u.clamp(0.0, 1.0);
        (u, v.clamp(0.0, 1.0 - u))
    };
    Hit { t, prim, u, v }
}

/// The screen's tiling: tiles of 2^`shift` pixels a side, `x` × `y` of them.
struct Grid {
    shift: u32,
    x: u32,
    y: u32,
}

impl Grid {
    /// The smallest tiles, from 8 pixels a side, of which there are at most [`MAX_TILES`].
    fn fitting(width: u32, height: u32) -> Self {
        let mut shift = 3u32;
        let tiles = |s: u32| (width.div_ceil(1 << s), height.div_ceil(1 << s));
        while u64::from(tiles(shift).0) * u64::from(tiles(shift).1) > u64::from(MAX_TILES) {
            shift += 1;
        }
        let (x, y) = tiles(shift);
        Grid { shift, x, y }
    }

    fn count(&self) -> usize {
        (self.x * self.y) as usize
    }
}

/// Per tile, the primitives that may be seen in it (ascending), and the sum of the list
/// lengths; `None` once that sum passes [`MAX_MEAN_CANDIDATES`] per tile (the BVH is then
/// as fast).
fn per_tile_lists(
    geo: &Geometry,
    cam: &Pinhole,
    width: u32,
    height: u32,
    grid: &Grid,
) -> Option<(Vec<Vec<u32>>, usize)> {
    let tile_count = grid.count();
    let mut per_tile: Vec<Vec<u32>> = vec![Vec::new(); tile_count];
    let mut entries = 0usize;
    for (i, p) in geo.prims.iter().enumerate() {
        match region(p, cam, width, height, grid.shift, grid.x, grid.y) {
            Region::Nowhere => {}
            Region::Everywhere => {
                per_tile.iter_mut().for_each(|l| l.push(i as u32));
                entries += tile_count;
            }
            Region::Tiles { x0, x1, y0, y1 } => {
                for ty in y0..=y1 {
                    for tx in x0..=x1 {
                        per_tile[(ty * grid.x + tx) as usize].push(i as u32);
                    }
                }
                entries += ((x1 - x0 + 1) * (y1 - y0 + 1)) as usize;
            }
        }
        if entries > MAX_MEAN_CANDIDATES * tile_count {
            return None;
        }
    }
    Some((per_tile, entries))
}

/// The distinct candidate lists, packed: triangles four to a [`TriPacket`], spheres as
/// [`CamSphere`]s, both with their origin-dependent terms precomputed.
#[derive(Default)]
struct Packed {
    lists: Vec<List>,
    packets: Vec<TriPacket>,
    spheres: Vec<CamSphere>,
}

impl Packed {
    /// Packs the primitives `l` as seen from the camera origin `o`; returns the new list's
    /// index.
    fn push_list(&mut self, geo: &Geometry, o: Vec3A, l: &[u32]) -> u32 {
        let p0 = self.packets.len() as u32;
        let s0 = self.spheres.len() as u32;
        let mut lanes = 0usize;
        for &i in l {
            match geo.prims[i as usize].shape() {
                PrimShape::Tri { v0, e1, e2 } => {
                    let k = lanes % 4;
                    if k == 0 {
                        self.packets.push(EMPTY_PACKET);
                    }
                    let Some(pk) = self.packets.last_mut() else {
                        continue;
                    };
                    // Exactly the values bvh.rs `tri_t` computes for a ray from `o`.
                    let tv = o - v0;
                    let qv = tv.cross(e1);
                    for j in 0..3 {
                        pk.e1[j][k] = e1[j];
                        pk.e2[j][k] = e2[j];
                        pk.tv[j][k] = tv[j];
                        pk.qv[j][k] = qv[j];
                    }
                    pk.tnum[k] = e2.dot(qv);
                    pk.prim[k] = i;
                    lanes += 1;
                }
                PrimShape::Sphere { center, radius } => {
                    let f = o - center;
                    let r2 = radius * radius;
                    self.spheres.push(CamSphere {
                        prim: i,
                        f,
                        r2,
                        cc: f.length_squared() - r2,
                    });
                }
            }
        }
        self.lists.push(List {
            p0,
            p1: self.packets.len() as u32,
            s0,
            s1: self.spheres.len() as u32,
        });
        (self.lists.len() - 1) as u32
    }
}

const EMPTY_PACKET: TriPacket = TriPacket {
    e1: [Vec4::ZERO; 3],
    e2: [Vec4::ZERO; 3],
    tv: [Vec4::ZERO; 3],
    qv: [Vec4::ZERO; 3],
    tnum: Vec4::ZERO,
    prim: [NONE; 4],
};

/// The tiles where primitive `p` may be hit by a camera ray: the bounding box of its
/// projected points (triangle vertices, or the corners of a sphere's box) when all lie in
/// front of the camera, every tile when some do not (the projection does not exist), no
/// tile when all lie behind it (a camera ray only goes forward).
fn region(
    p: &Prim,
    cam: &Pinhole,
    width: u32,
    height: u32,
    tile_shift: u32,
    tiles_x: u32,
    tiles_y: u32,
) -> Region {
    let mut pts = [Vec3::ZERO; 8];
    let pts: &[Vec3] = match p.shape() {
        PrimShape::Tri { v0, e1, e2 } => {
            pts[0] = v0.into();
            pts[1] = (v0 + e1).into();
            pts[2] = (v0 + e2).into();
            &pts[..3]
        }
        PrimShape::Sphere { center, radius } => {
            for (k, q) in pts.iter_mut().enumerate() {
                let s = |bit: usize| if k & bit == 0 { -radius } else { radius };
                *q = Vec3::from(center) + Vec3::new(s(1), s(2), s(4));
            }
            &pts[..]
        }
    };
    // Depth tolerance relative to the distances involved: a point this close to the
    // camera plane projects unreliably, so it counts as "not in front".
    let scale = pts
        .iter()
        .map(|&q| f64::from((q - cam.origin).abs().max_element()))
        .fold(0.0f64, f64::max);
    let eps = 1e-5 * scale + 1e-30;
    let depths = pts.iter().map(|&q| cam.depth(q));
    if depths.clone().all(|z| z < -eps) {
        return Region::Nowhere;
    }
    if !depths.clone().all(|z| z > eps) || !scale.is_finite() {
        return Region::Everywhere;
    }
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &q in pts {
        let Some((x, y, _)) = cam.project(q) else {
            return Region::Everywhere;
        };
        if !x.is_finite() || !y.is_finite() {
            return Region::Everywhere;
        }
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    let m = MARGIN_PX + 1e-4 * (x1 - x0 + y1 - y0 + x0.abs() + y0.abs());
    let (x0, x1, y0, y1) = (x0 - m, x1 + m, y0 - m, y1 + m);
    let (w, h) = (f64::from(width), f64::from(height));
    if x1 < 0.0 || y1 < 0.0 || x0 > w || y0 > h {
        return Region::Nowhere;
    }
    let tile = f64::from(1u32 << tile_shift);
    let to_tile = |v: f64, n: u32| ((v / tile).floor().max(0.0) as u32).min(n - 1);
    Region::Tiles {
        x0: to_tile(x0, tiles_x),
        x1: to_tile(x1, tiles_x),
        y0: to_tile(y0, tiles_y),
        y1: to_tile(y1, tiles_y),
    }
}

/// bvh.rs `sphere_t` (not leaving this sphere) for a ray from the camera.
#[inline(always)]
fn sphere_t(d: Vec3A, f: Vec3A, r2: f32, cc: f32, tmax: f32) -> f32 {
    let b = -f.dot(d);
    let l = f + d * b;
    let disc = r2 - l.length_squared();
    if disc < 0.0 {
        return f32::INFINITY;
    }
    let q = b + disc.sqrt().copysign(b);
    let (mut t0, mut t1) = (if q != 0.0 { cc / q } else { 0.0 }, q);
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    if t0 > 0.0 && t0 < tmax {
        t0
    } else if t1 > 0.0 && t1 < tmax {
        t1
    } else {
        f32::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::PixelCoord;
    use crate::scene::{Camera, Material, Shape, Texture, Triangle};
    use crate::tracer::fixtures::{cornell_box, scene};
    use crate::tracer::rng::Rng;
    use crate::tracer::PathTracer;
    use glam::Vec2;

    /// Every pixel of `t`, at its centre, its corners' extremes and a few random jitters:
    /// the tile path must return the BVH's hit (same primitive, bit-identical t, u, v;
    /// ties included, since tied rays are handed to the BVH).
    fn assert_matches_bvh(t: &PathTracer) -> usize {
        let p = t.primary.as_ref().expect("scene small enough for tiles");
        let (w, h) = (t.width, t.height);
        let mut hits = 0;
        for y in 0..h {
            for x in 0..w {
                let mut rng = Rng::for_sample(9, x, y, 0);
                let mut jitters = vec![
                    Vec2::splat(0.5),
                    Vec2::ZERO,
                    Vec2::splat(1.0 - f32::EPSILON),
                    Vec2::new(0.0, 1.0 - f32::EPSILON),
                ];
                jitters.extend((0..4).map(|_| rng.next_2d()));
                for j in jitters {
                    let d = t.camera.direction(x, y, j);
                    let a = p.intersect(&t.geo, x, y, d);
                    let b = t.geo.intersect(t.camera.origin, d, f32::INFINITY, NONE);
                    match (a, b) {
                        (None, None) => {}
                        (Some(a), Some(b)) => {
                            hits += 1;
                            assert_eq!(a.t.to_bits(), b.t.to_bits(), "pixel {x} {y} {j}");
                            assert_eq!(a.prim, b.prim, "pixel {x} {y} {j}");
                            assert_eq!(a.u.to_bits(), b.u.to_bits());
                            assert_eq!(a.v.to_bits(), b.v.to_bits());
                        }
                        _ => panic!("pixel {x} {y} jitter {j}: tiles {a:?}, bvh {b:?}"),
                    }
                }
            }
        }
        hits
    }

    #[test]
    fn cornell_box_tiles_give_the_bvh_hit_and_short_lists() {
        // 61×45: partial tiles on the right and bottom edges.
        let t = PathTracer::new(&cornell_box(61, 45, 1, 1, 1));
        let hits = assert_matches_bvh(&t);
        // The box fills the height of the view; the wider image shows black sides.
        assert!(hits > 61 * 45 * 8 / 2, "{hits}");
        let mean = t.primary.as_ref().map_or(0.0, CameraRays::mean_candidates);
        // 36 triangles; a tile sees a handful of them.
        assert!(mean > 1.0 && mean < 12.0, "mean candidates {mean}");
        // At the benchmark's size most of the 4096 tiles share a list (wall interiors).
        let big = PathTracer::new(&cornell_box(512, 512, 1, 1, 1));
        let lists = big.primary.as_ref().map_or(0, CameraRays::distinct_lists);
        assert!(lists > 10 && lists < 1024, "{lists} distinct lists");
    }

    /// Triangles and spheres all around the camera: in front, behind, crossing the
    /// camera plane, seen exactly edge-on (their plane contains the camera), off screen,
    /// and a sphere containing the camera; several seeds and camera positions.
    #[test]
    fn surrounding_geometry_behind_edge_on_and_across_the_camera_plane() {
        for (seed, eye) in [
            (77, Vec3::ZERO),
            (78, Vec3::new(3.0, -2.0, 5.0)),
            (79, Vec3::new(-120.0, 40.0, 310.0)),
        ] {
            let mut rng = Rng::new(seed);
            let mut r = |s: f32| (rng.next_f32() * 2.0 - 1.0) * s;
            let mut shapes = Vec::new();
            let tri = |p: [Vec3; 3]| Shape::Triangles {
                triangles: vec![Triangle {
                    p,
                    n: None,
                    uv: None,
                }],
                material: 0,
            };
            for _ in 0..40 {
                let c = eye + Vec3::new(r(6.0), r(6.0), r(6.0));
                let a = Vec3::new(r(2.0), r(2.0), r(2.0));
                let b = Vec3::new(r(2.0), r(2.0), r(2.0));
                shapes.push(tri([c, c + a, c + b]));
                // Edge-on: the third vertex on the line from the eye through c.
                shapes.push(tri([c, c + a, c + (c - eye) * 0.3]));
            }
            for _ in 0..10 {
                shapes.push(Shape::Sphere {
                    center: eye + Vec3::new(r(6.0), r(6.0), r(6.0)),
                    radius: 0.2 + r(0.5).abs(),
                    material: 0,
                });
            }
            // The eye inside this one: every ray leaves through its far side.
            shapes.push(Shape::Sphere {
                center: eye + Vec3::new(0.1, 0.0, 0.0),
                radius: 20.0,
                material: 0,
            });
            // A floor running under and behind the camera.
            shapes.push(tri([
                eye + Vec3::new(-50.0, -1.0, 50.0),
                eye + Vec3::new(50.0, -1.0, 50.0),
                eye + Vec3::new(0.0, -1.0, -50.0),
            ]));
            let cam = Camera {
                position: eye,
                look_at: eye + Vec3::new(0.3, 0.1, -1.0),
                up: Vec3::Y,
                fov_y_deg: 70.0,
            };
            let m = vec![Material::Diffuse {
                albedo: Texture::Constant(Vec3::splat(0.5)),
            }];
            let s = scene(40, 24, cam, m, shapes, Vec::new(), (1, 1, 1));
            let t = PathTracer::new(&s);
            assert_eq!(
                assert_matches_bvh(&t),
                40 * 24 * 8,
                "seed {seed}: every ray meets the big sphere"
            );
        }
    }

    #[test]
    fn one_pixel_image_and_pixels_outside_the_image() {
        let m = vec![Material::Diffuse {
            albedo: Texture::Constant(Vec3::splat(0.5)),
        }];
        let shapes = vec![crate::tracer::fixtures::quad(
            // Wider than the view (tan 30° · 3 < 3): every ray of the pixel hits it.
            Vec3::new(-3.0, -3.0, -3.0),
            Vec3::new(6.0, 0.0, 0.0),
            Vec3::new(0.0, 6.0, 0.0),
            0,
        )];
        let cam = Camera {
            position: Vec3::ZERO,
            look_at: Vec3::NEG_Z,
            up: Vec3::Y,
            fov_y_deg: 60.0,
        };
        let t = PathTracer::new(&scene(1, 1, cam, m, shapes, Vec::new(), (1, 1, 1)));
        assert_eq!(assert_matches_bvh(&t), 8);
        // Outside the image: no list, the BVH answers (no panic, same hit).
        let p = t.primary.as_ref().expect("tiles");
        for (x, y) in [(1, 0), (0, 1), (u32::MAX, u32::MAX)] {
            let d = t.camera.direction(x, y, Vec2::splat(0.5));
            let a = p.intersect(&t.geo, x, y, d).map(|h| h.prim);
            let b = t.geo.intersect(t.camera.origin, d, f32::INFINITY, NONE);
            assert_eq!(a, b.map(|h| h.prim));
        }
        assert!(t.primary_ray_hits(PixelCoord::new(0, 0), 0, 1));
        // With 36 triangles in its one tile, a 1×1 Cornell box keeps the BVH.
        assert!(!PathTracer::new(&cornell_box(1, 1, 1, 1, 1)).has_camera_tiles());
    }

    /// A 4096² image has 512² 8-pixel tiles, over the cap: the tiles grow to 16 pixels.
    #[test]
    fn large_images_use_larger_tiles() {
        let t = PathTracer::new(&cornell_box(4096, 4096, 1, 1, 1));
        let p = t.primary.as_ref().expect("tiles");
        assert_eq!(
            (p.tile_shift, p.tiles_x, p.tile_list.len()),
            (4, 256, 65536)
        );
        let mut rng = Rng::new(3);
        for _ in 0..2000 {
            let (x, y) = (rng.next_u32() % 4096, rng.next_u32() % 4096);
            let d = t.camera.direction(x, y, rng.next_2d());
            let a = p
                .intersect(&t.geo, x, y, d)
                .map(|h| (h.prim, h.t.to_bits()));
            let b = t.geo.intersect(t.camera.origin, d, f32::INFINITY, NONE);
            assert_eq!(a, b.map(|h| (h.prim, h.t.to_bits())), "pixel {x} {y}");
        }
    }

    #[test]
    fn large_scenes_keep_the_bvh() {
        let tri = |i: usize| Triangle {
            p: [
                Vec3::new(i as f32, 0.0, -5.0),
                Vec3::new(i as f32 + 0.5, 0.0, -5.0),
                Vec3::new(i as f32, 0.5, -5.0),
            ],
            n: None,
            uv: None,
        };
        let shapes = vec![Shape::Triangles {
            triangles: (0..MAX_PRIMS + 1).map(tri).collect(),
            material: 0,
        }];
        let m = vec![Material::Diffuse {
            albedo: Texture::Constant(Vec3::splat(0.5)),
        }];
        let cam = Camera {
            position: Vec3::ZERO,
            look_at: Vec3::NEG_Z,
            up: Vec3::Y,
            fov_y_deg: 60.0,
        };
        let s = scene(8, 8, cam, m, shapes, Vec::new(), (1, 1, 1));
        assert!(!PathTracer::new(&s).has_camera_tiles());
    }

    /// The bundled scenes (scenes/*.json) at the golden-frame size (64 pixels): every
    /// pixel's radiance and object id with the tile lists equals the BVH-only tracer's
    /// bit for bit (the Cornell box's pixel centres meet wall edges in exact ties).
    #[test]
    fn bundled_scenes_render_identically_with_and_without_tiles() {
        use crate::scene::{parse_scene, Limits, SceneOrigin};
        use crate::tracer::PixelOracle;
        let mut tiled = 0;
        for name in [
            "cellar",
            "cornell-box",
            "door",
            "spheres-rough",
            "spheres-smooth",
        ] {
            let path = format!("scenes/{name}.json");
            let json = std::fs::read_to_string(&path).expect("bundled scene");
            let origin = SceneOrigin::File {
                dir: "scenes".into(),
            };
            let mut s = parse_scene(&json, &origin, &Limits::command_line()).expect("valid");
            let k = 64.0 / s.width.max(s.height) as f32;
            s.width = ((s.width as f32 * k).round() as u32).max(1);
            s.height = ((s.height as f32 * k).round() as u32).max(1);
            let a = PathTracer::new(&s);
            let mut b = PathTracer::new(&s);
            tiled += usize::from(a.has_camera_tiles());
            b.primary = None;
            for y in 0..s.height {
                for x in 0..s.width {
                    let p = PixelCoord::new(x, y);
                    let (ra, rb) = (a.radiance_with(p, 2, 5), b.radiance_with(p, 2, 5));
                    assert_eq!(
                        ra.to_array().map(f32::to_bits),
                        rb.to_array().map(f32::to_bits),
                        "{name} pixel {x} {y}"
                    );
                    assert_eq!(a.object_id(p), b.object_id(p), "{name} pixel {x} {y}");
                }
            }
        }
        assert!(tiled >= 3, "only {tiled} bundled scenes use tiles");
    }
}
