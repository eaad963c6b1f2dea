//! Rays through small scenes: every primitive tested, triangles eight (AVX) or sixteen
//! (AVX-512) at a time.
//!
//! A scene of a few dozen primitives (the Cornell box has 36 triangles) costs the CWBVH
//! traversal ~900 instructions a ray (callgrind, 128² × 8 spp of scenes/cornell-box.json),
//! most of it node decoding and stack work. Testing all its triangles in packets of eight
//! (AVX) costs about half of that (closest hit 520, occlusion 460); in packets of four
//! (SSE2) it cost as much as the traversal, so without AVX the BVH is kept. Sixteen lanes
//! (two packets side by side) took a further 5 % off a whole render's CPU time. The
//! packets repeat bvh.rs `tri_t` lane by lane, the same IEEE operations in the same order
//! with no FMA (as primary.rs does for camera rays), so `t`, `u` and `v` are
//! bit-identical to the traversal's. (One ray in
//! ~10⁵ of the unit test's, from a point within 10⁻⁴ of where two walls meet, is hit
//! nearer than the traversal finds: its box tests skipped a hit that its own triangle
//! test accepts. Renders of the bundled scenes came out bit-identical.)
//!
//! Occlusion does not depend on the order primitives are tested in, so its answer is the
//! BVH's. The closest hit does only where two primitives tie exactly in `t` (a ray
//! through an edge they share): the traversal keeps the first it visits, so such a ray
//! is handed back to it ([`Flat::closest`] returns [`Closest::Tie`]) and every hit stays
//! the BVH's.

use super::{sphere_t, Hit, Prim, PrimShape, NONE};
use glam::Vec3A;
use obvhs::ray::Ray as BvhRay;

/// Scenes of at most this many primitives are traced by [`Flat`]: ~100 instructions a
/// packet of eight, against ~900 a traversal on 36 triangles.
pub const MAX_PRIMS: usize = 64;

/// Eight triangles, structure of arrays: v0, e1, e2, each x, y, z. Unused lanes are zero
/// (det = 0: never a hit).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(32))]
struct Packet([[f32; 8]; 9]);

/// All primitives of a small scene: triangles in packets, spheres on their own.
#[derive(Debug, Default)]
pub struct Flat {
    /// With AVX-512, padded to an even count: packets are then tested two at a time.
    packets: Vec<Packet>,
    avx512: bool,
    /// The primitive index of each packet lane ([`NONE`] in unused lanes).
    lane_prim: Vec<u32>,
    /// Per primitive, its lane (`8 · packet + lane`), or [`NONE`] for a sphere.
    prim_lane: Vec<u32>,
    /// (primitive index, centre, radius).
    spheres: Vec<(u32, Vec3A, f32)>,
}

/// The closest hit as [`Flat::closest`] finds it.
pub enum Closest {
    Hit(Hit),
    Miss,
    /// Two primitives at exactly the same nearest `t`: only the traversal knows which
    /// one it would keep.
    Tie,
}

impl Flat {
    /// The packets for `prims`; `None` above [`MAX_PRIMS`] or without AVX.
    #[must_use]
    pub fn build(prims: &[Prim]) -> Option<Self> {
        if prims.len() > MAX_PRIMS || !has_avx() {
            return None;
        }
        let mut f = Self {
            prim_lane: vec![NONE; prims.len()],
            ..Self::default()
        };
        let mut tris = Vec::new();
        for (i, p) in prims.iter().enumerate() {
            match p.shape() {
                PrimShape::Tri { v0, e1, e2 } => tris.push((i as u32, [v0, e1, e2])),
                PrimShape::Sphere { center, radius } => f.spheres.push((i as u32, center, radius)),
            }
        }
        for (k, eight) in tris.chunks(8).enumerate() {
            let mut pk = Packet::default();
            let mut ids = [NONE; 8];
            for (lane, &(i, vs)) in eight.iter().enumerate() {
                for (a, v) in vs.iter().enumerate() {
                    for j in 0..3 {
                        pk.0[3 * a + j][lane] = v[j];
                    }
                }
                ids[lane] = i;
                f.prim_lane[i as usize] = (8 * k + lane) as u32;
            }
            f.packets.push(pk);
            f.lane_prim.extend(ids);
        }
        f.avx512 = has_avx512();
        if f.avx512 && f.packets.len() % 2 == 1 {
            f.packets.push(Packet::default());
            f.lane_prim.extend([NONE; 8]);
        }
        Some(f)
    }

    /// Bytes held on the heap.
    #[must_use]
    pub fn heap_bytes(&self) -> usize {
        self.packets.capacity() * std::mem::size_of::<Packet>()
            + (self.lane_prim.capacity() + self.prim_lane.capacity()) * 4
            + self.spheres.capacity() * std::mem::size_of::<(u32, Vec3A, f32)>()
    }

    /// The lane of primitive `skip` (a triangle the ray leaves cannot be hit again), or
    /// [`NONE`].
    #[inline(always)]
    fn skip_lane(&self, skip: u32) -> u32 {
        self.prim_lane.get(skip as usize).copied().unwrap_or(NONE)
    }

    /// True if a primitive other than the triangle `skip` meets `r` at `0 < t < tmax`:
    /// [`super::Geometry::occluded`]'s answer.
    #[inline]
    pub fn occluded(&self, r: &BvhRay, skip: u32) -> bool {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a `Flat` exists only where the CPU has AVX (`build`).
        let packets = unsafe {
            if self.avx512 {
                avx512::any_hit(&self.packets, r, self.skip_lane(skip))
            } else {
                avx::any_hit(&self.packets, r, self.skip_lane(skip))
            }
        };
        #[cfg(not(target_arch = "x86_64"))]
        let packets = false;
        packets
            || self
                .spheres
                .iter()
                .any(|&(i, c, radius)| sphere_t(r, c, radius, i == skip) < r.tmax)
    }

    /// The closest hit along `r` other than on the triangle `skip`, or [`Closest::Tie`].
    #[inline]
    pub fn closest(&self, r: &BvhRay, skip: u32) -> Closest {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: a `Flat` exists only where the CPU has AVX (`build`).
        let tri = unsafe {
            if self.avx512 {
                avx512::closest(&self.packets, r, self.skip_lane(skip))
            } else {
                avx::closest(&self.packets, r, self.skip_lane(skip))
            }
        };
        #[cfg(not(target_arch = "x86_64"))]
        let tri = TriBest {
            lane: None,
            t: r.tmax,
            u: 0.0,
            v: 0.0,
            tie: false,
        };
        let mut best = tri.lane.map_or(NONE, |l| self.lane_prim[l as usize]);
        let (mut best_t, mut tie) = (tri.t, tri.tie);
        let mut sphere_hit = false;
        for &(i, c, radius) in &self.spheres {
            let t = sphere_t(r, c, radius, i == skip);
            if t == best_t && t < r.tmax {
                tie = true;
            } else if t < best_t {
                (tie, best_t, best, sphere_hit) = (false, t, i, true);
            }
        }
        if tie {
            return Closest::Tie;
        }
        if best == NONE {
            return Closest::Miss;
        }
        let (u, v) = if sphere_hit {
            (0.0, 0.0)
        } else {
            // bvh.rs `tri_uv`'s clamping of the same u and v.
            let u = tri.u.clamp(0.0, 1.0);
            (u, tri.v.clamp(0.0, 1.0 - u))
        };
        Closest::Hit(Hit {
            t: best_t,
            prim: best,
            u,
            v,
        })
    }
}

/// The nearest triangle hit of a ray over all packets: its lane, t, u, v, and whether
/// another lane has the same t. `t` is the ray's tmax where nothing is hit.
#[derive(Clone, Copy, Debug)]
struct TriBest {
    lane: Option<u32>,
    t: f32,
    u: f32,
    v: f32,
    tie: bool,
}

/// AVX-512 with the 256-bit inserts of its DQ extension: two packets at a time.
fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512dq");
    #[cfg(not(target_arch = "x86_64"))]
    false
}

fn has_avx() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx");
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// [`avx`] on sixteen lanes: packets `2m` and `2m + 1` side by side (lanes `16m..16m+16`).
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{BvhRay, Packet, TriBest, NONE};
    use std::arch::x86_64::*;

    struct Lanes {
        o: [__m512; 3],
        d: [__m512; 3],
        tmin: __m512,
        tmax: __m512,
    }

    #[target_feature(enable = "avx512f")]
    fn lanes(r: &BvhRay) -> Lanes {
        let (o, d) = (r.origin, r.direction);
        let s = _mm512_set1_ps;
        Lanes {
            o: [s(o.x), s(o.y), s(o.z)],
            d: [s(d.x), s(d.y), s(d.z)],
            tmin: s(r.tmin),
            tmax: s(r.tmax),
        }
    }

    #[target_feature(enable = "avx512f,avx512dq")]
    pub(super) fn any_hit(packets: &[Packet], r: &BvhRay, skip_lane: u32) -> bool {
        let l = lanes(r);
        packets.chunks_exact(2).enumerate().any(|(m, pair)| {
            let (mask, ..) = hits(&l, &pair[0], &pair[1]);
            mask & !skip_bit(m, skip_lane) != 0
        })
    }

    #[target_feature(enable = "avx512f,avx512dq")]
    pub(super) fn closest(packets: &[Packet], r: &BvhRay, skip_lane: u32) -> TriBest {
        let l = lanes(r);
        let mut best = TriBest {
            lane: None,
            t: r.tmax,
            u: 0.0,
            v: 0.0,
            tie: false,
        };
        for (m, pair) in packets.chunks_exact(2).enumerate() {
            let (mask, t, u, v) = hits(&l, &pair[0], &pair[1]);
            let mut bits = mask & !skip_bit(m, skip_lane);
            if bits == 0 {
                continue;
            }
            let ts = to_array(t);
            let (mut tm, mut first, mut count) = (f32::INFINITY, 0usize, 0u32);
            while bits != 0 {
                let j = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                if ts[j] < tm {
                    (tm, first, count) = (ts[j], j, 1);
                } else if ts[j] == tm {
                    count += 1;
                }
            }
            if tm < best.t {
                best = TriBest {
                    lane: Some((16 * m + first) as u32),
                    t: tm,
                    u: to_array(u)[first],
                    v: to_array(v)[first],
                    tie: count > 1,
                };
            } else if tm == best.t {
                best.tie = true;
            }
        }
        best
    }

    #[inline(always)]
    fn skip_bit(m: usize, skip_lane: u32) -> u32 {
        if skip_lane != NONE && (skip_lane / 16) as usize == m {
            1 << (skip_lane % 16)
        } else {
            0
        }
    }

    #[target_feature(enable = "avx512f")]
    fn to_array(x: __m512) -> [f32; 16] {
        let mut a = [0.0f32; 16];
        // SAFETY: `a` holds sixteen floats.
        unsafe { _mm512_storeu_ps(a.as_mut_ptr(), x) };
        a
    }

    /// `avx::hits` on the sixteen lanes of packets `a` and `b`.
    #[target_feature(enable = "avx512f,avx512dq")]
    fn hits(l: &Lanes, a: &Packet, b: &Packet) -> (u32, __m512, __m512, __m512) {
        let ld = |i: usize| {
            // SAFETY: each row of a packet holds eight floats, 32-byte aligned.
            let (lo, hi) = unsafe {
                (
                    _mm256_load_ps(a.0[i].as_ptr()),
                    _mm256_load_ps(b.0[i].as_ptr()),
                )
            };
            _mm512_insertf32x8::<1>(_mm512_castps256_ps512(lo), hi)
        };
        let (mul, add, sub) = (_mm512_mul_ps, _mm512_add_ps, _mm512_sub_ps);
        let dot = |a: [__m512; 3], b: [__m512; 3]| {
            add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))
        };
        let cross = |a: [__m512; 3], b: [__m512; 3]| {
            [
                sub(mul(a[1], b[2]), mul(a[2], b[1])),
                sub(mul(a[2], b[0]), mul(a[0], b[2])),
                sub(mul(a[0], b[1]), mul(a[1], b[0])),
            ]
        };
        let (v0, e1, e2) = (
            [ld(0), ld(1), ld(2)],
            [ld(3), ld(4), ld(5)],
            [ld(6), ld(7), ld(8)],
        );
        let pv = cross(l.d, e2);
        let det = dot(e1, pv);
        let inv = _mm512_div_ps(_mm512_set1_ps(1.0), det);
        let tv = [sub(l.o[0], v0[0]), sub(l.o[1], v0[1]), sub(l.o[2], v0[2])];
        let u = mul(dot(tv, pv), inv);
        let qv = cross(tv, e1);
        let v = mul(dot(l.d, qv), inv);
        let t = mul(dot(e2, qv), inv);
        let (zero, one) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0));
        let ok = _mm512_cmp_ps_mask::<_CMP_NEQ_UQ>(det, zero)
            & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(_mm512_abs_ps(det), _mm512_set1_ps(f32::INFINITY))
            & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(u, zero)
            & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(u, one)
            & _mm512_cmp_ps_mask::<_CMP_NLT_UQ>(v, zero)
            & _mm512_cmp_ps_mask::<_CMP_NGT_UQ>(add(u, v), one)
            & _mm512_cmp_ps_mask::<_CMP_GT_OQ>(t, l.tmin)
            & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(t, l.tmax);
        (u32::from(ok), t, u, v)
    }
}

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{BvhRay, Packet, TriBest, NONE};
    use std::arch::x86_64::*;

    /// The ray's origin, direction and range, each in all eight lanes.
    struct Lanes {
        o: [__m256; 3],
        d: [__m256; 3],
        tmin: __m256,
        tmax: __m256,
    }

    #[target_feature(enable = "avx")]
    fn lanes(r: &BvhRay) -> Lanes {
        let (o, d) = (r.origin, r.direction);
        Lanes {
            o: [
                _mm256_set1_ps(o.x),
                _mm256_set1_ps(o.y),
                _mm256_set1_ps(o.z),
            ],
            d: [
                _mm256_set1_ps(d.x),
                _mm256_set1_ps(d.y),
                _mm256_set1_ps(d.z),
            ],
            tmin: _mm256_set1_ps(r.tmin),
            tmax: _mm256_set1_ps(r.tmax),
        }
    }

    /// Whether any lane but `skip_lane` is hit at `tmin < t < tmax`.
    #[target_feature(enable = "avx")]
    pub(super) fn any_hit(packets: &[Packet], r: &BvhRay, skip_lane: u32) -> bool {
        let l = lanes(r);
        packets.iter().enumerate().any(|(k, p)| {
            let (mask, ..) = hits(&l, p);
            mask & !skip_bit(k, skip_lane) != 0
        })
    }

    /// The nearest hit over all lanes but `skip_lane`.
    #[target_feature(enable = "avx")]
    pub(super) fn closest(packets: &[Packet], r: &BvhRay, skip_lane: u32) -> TriBest {
        let l = lanes(r);
        let mut best = TriBest {
            lane: None,
            t: r.tmax,
            u: 0.0,
            v: 0.0,
            tie: false,
        };
        for (k, p) in packets.iter().enumerate() {
            let (mask, t, u, v) = hits(&l, p);
            let mut bits = mask & !skip_bit(k, skip_lane);
            if bits == 0 {
                continue;
            }
            // The smallest t over the lanes hit, its first lane, and how many share it.
            let ts = to_array(t);
            let (mut m, mut first, mut count) = (f32::INFINITY, 0usize, 0u32);
            while bits != 0 {
                let j = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                if ts[j] < m {
                    (m, first, count) = (ts[j], j, 1);
                } else if ts[j] == m {
                    count += 1;
                }
            }
            if m < best.t {
                best = TriBest {
                    lane: Some((8 * k + first) as u32),
                    t: m,
                    u: to_array(u)[first],
                    v: to_array(v)[first],
                    tie: count > 1,
                };
            } else if m == best.t {
                best.tie = true;
            }
        }
        best
    }

    /// The bit of `skip_lane` within packet `k` (none if it is in another packet).
    #[inline(always)]
    fn skip_bit(k: usize, skip_lane: u32) -> u32 {
        if skip_lane != NONE && (skip_lane / 8) as usize == k {
            1 << (skip_lane % 8)
        } else {
            0
        }
    }

    #[target_feature(enable = "avx")]
    fn to_array(x: __m256) -> [f32; 8] {
        let mut a = [0.0f32; 8];
        // SAFETY: `a` holds eight floats.
        unsafe { _mm256_storeu_ps(a.as_mut_ptr(), x) };
        a
    }

    /// bvh.rs `tri_t` on eight triangles: the lanes hit at `tmin < t < tmax` (bit mask)
    /// and their t, u, v. glam's cross and dot orders: `a × b = (ay·bz − az·by, …)`,
    /// `a·b = (ax·bx + ay·by) + az·bz`; separate multiplies and adds (no FMA).
    #[target_feature(enable = "avx")]
    fn hits(l: &Lanes, p: &Packet) -> (u32, __m256, __m256, __m256) {
        // SAFETY: each row of the packet holds eight floats.
        let ld = |i: usize| unsafe { _mm256_load_ps(p.0[i].as_ptr()) };
        let (mul, add, sub) = (_mm256_mul_ps, _mm256_add_ps, _mm256_sub_ps);
        let dot = |a: [__m256; 3], b: [__m256; 3]| {
            add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))
        };
        let cross = |a: [__m256; 3], b: [__m256; 3]| {
            [
                sub(mul(a[1], b[2]), mul(a[2], b[1])),
                sub(mul(a[2], b[0]), mul(a[0], b[2])),
                sub(mul(a[0], b[1]), mul(a[1], b[0])),
            ]
        };
        let (v0, e1, e2) = (
            [ld(0), ld(1), ld(2)],
            [ld(3), ld(4), ld(5)],
            [ld(6), ld(7), ld(8)],
        );
        let pv = cross(l.d, e2);
        let det = dot(e1, pv);
        let inv = _mm256_div_ps(_mm256_set1_ps(1.0), det);
        let tv = [sub(l.o[0], v0[0]), sub(l.o[1], v0[1]), sub(l.o[2], v0[2])];
        let u = mul(dot(tv, pv), inv);
        let qv = cross(tv, e1);
        let v = mul(dot(l.d, qv), inv);
        let t = mul(dot(e2, qv), inv);
        // `tri_t`'s tests, NaN behaviour included: det ≠ 0 and finite, 0 ≤ u ≤ 1,
        // !(v < 0), !(u + v > 1) (a NaN v passes both, as there), tmin < t < tmax.
        let abs_det = _mm256_andnot_ps(_mm256_set1_ps(-0.0), det);
        let ok = [
            _mm256_cmp_ps::<_CMP_NEQ_UQ>(det, _mm256_setzero_ps()),
            _mm256_cmp_ps::<_CMP_LT_OQ>(abs_det, _mm256_set1_ps(f32::INFINITY)),
            _mm256_cmp_ps::<_CMP_GE_OQ>(u, _mm256_setzero_ps()),
            _mm256_cmp_ps::<_CMP_LE_OQ>(u, _mm256_set1_ps(1.0)),
            _mm256_cmp_ps::<_CMP_NLT_UQ>(v, _mm256_setzero_ps()),
            _mm256_cmp_ps::<_CMP_NGT_UQ>(add(u, v), _mm256_set1_ps(1.0)),
            _mm256_cmp_ps::<_CMP_GT_OQ>(t, l.tmin),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, l.tmax),
        ]
        .into_iter()
        .reduce(|a, b| _mm256_and_ps(a, b))
        .unwrap_or_else(|| _mm256_setzero_ps());
        (_mm256_movemask_ps(ok) as u32, t, u, v)
    }
}

#[cfg(test)]
mod tests {
    use super::super::Geometry;
    use crate::scene::Shape;
    use crate::tracer::fixtures::cornell_box;
    use glam::Vec3;

    /// Uniform floats in [0, 1) from a fixed sequence (splitmix64).
    fn uniforms(seed: u64) -> impl FnMut() -> f32 {
        let mut s = seed;
        move || {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// Rays from inside Bitterli's Cornell box (with a sphere added), from its surfaces
    /// (leaving a primitive, as bounce rays do) and through shared edges: the packets'
    /// closest hit and occlusion are the traversal's bit for bit, or a tie handed to it.
    #[test]
    fn packets_answer_as_the_traversal_does() {
        let mut scene = cornell_box(8, 8, 1, 6, 1);
        scene.shapes.push(Shape::Sphere {
            center: Vec3::new(0.3, 1.2, 0.2),
            radius: 0.25,
            material: 0,
        });
        let mut geo = Geometry::build(&scene);
        assert!(geo.flat.is_some(), "a small scene is traced by packets");
        // The AVX-512 build here, and AVX on the same (even-padded) packets.
        for wide in [true, false] {
            if let Some(f) = geo.flat.as_mut() {
                f.avx512 &= wide;
            }
            compare_with_traversal(&geo);
        }
    }

    fn compare_with_traversal(geo: &Geometry) {
        let mut rand = uniforms(7);
        let (mut hits, mut ties, mut blocked, mut culled) = (0, 0, 0, 0);
        for k in 0..200_000 {
            let o = Vec3::new(2.0 * rand() - 1.0, 2.0 * rand(), 2.0 * rand() - 1.0);
            let d = (Vec3::new(rand(), rand(), rand()) * 2.0 - 1.0).normalize_or(Vec3::Y);
            // A third of the rays leave the primitive the previous one hit, from its
            // surface offset as the integrator offsets it (integrator.rs).
            let (o, skip) = match geo.intersect(o, d, f32::INFINITY, super::NONE) {
                Some(h) if k % 3 == 0 => {
                    let s = geo.surface(o, d, &h);
                    let n = if d.dot(s.ng) > 0.0 { s.ng } else { -s.ng };
                    (crate::tracer::sampling::offset_ray_origin(s.p, n), h.prim)
                }
                _ => (o, super::NONE),
            };
            let tmax = if k % 2 == 0 {
                f32::INFINITY
            } else {
                3.0 * rand()
            };
            let flat = geo
                .flat
                .as_ref()
                .map(|f| f.closest(&super::super::flat_ray(o, d, tmax), skip));
            let bvh = geo.traverse(
                o,
                d,
                obvhs::ray::Ray::new(o.into(), d.into(), 0.0, tmax),
                skip,
            );
            match (flat, bvh) {
                (Some(super::Closest::Tie), _) => ties += 1,
                (Some(super::Closest::Hit(a)), Some(b)) if a.prim != b.prim => {
                    // The traversal's box tests can skip a hit within a hair of the
                    // origin (seen at t ~ 6e-5 where two walls meet): the packets' hit
                    // must then be one the traversal's own primitive test accepts, and
                    // nearer.
                    let ray = obvhs::ray::Ray::new(o.into(), d.into(), 0.0, tmax);
                    assert_eq!(geo.prim_t(&ray, a.prim, skip), a.t, "ray {k}");
                    assert!(a.t < b.t && a.t < 1e-3, "ray {k}: {a:?} {b:?}");
                    culled += 1;
                }
                (Some(super::Closest::Hit(a)), Some(b)) => {
                    hits += 1;
                    assert_eq!(
                        (a.prim, a.t.to_bits(), a.u.to_bits(), a.v.to_bits()),
                        (b.prim, b.t.to_bits(), b.u.to_bits(), b.v.to_bits()),
                        "ray {k}"
                    );
                }
                (Some(super::Closest::Miss), None) => {}
                (a, b) => panic!(
                    "ray {k}: packets {:?}, traversal {b:?}",
                    a.map(|c| matches!(c, super::Closest::Miss))
                ),
            }
            let ray = obvhs::ray::Ray::new(o.into(), d.into(), 0.0, tmax);
            let by_bvh = geo
                .bvh
                .as_ref()
                .is_some_and(|b| !b.ray_traverse_miss(ray, |r, id| geo.prim_t(r, id as u32, skip)));
            assert_eq!(geo.occluded(o, d, tmax, skip), by_bvh, "ray {k}");
            blocked += u32::from(by_bvh);
        }
        // Rays along the diagonal the floor's two triangles share: equal t on both.
        for k in 0..100 {
            let s = k as f32 / 100.0 * 2.0 - 1.0;
            let target = Vec3::new(s, 0.0, -s);
            let o = Vec3::new(0.1, 1.0, 0.3);
            let d = (target - o).normalize();
            if let Some(super::Closest::Tie) = geo
                .flat
                .as_ref()
                .map(|f| f.closest(&super::super::flat_ray(o, d, f32::INFINITY), super::NONE))
            {
                ties += 1;
            }
        }
        eprintln!("{hits} hits compared, {ties} ties, {blocked} blocked, {culled} culled by the traversal");
        assert!(hits > 100_000 && blocked > 10_000 && culled < 10);
    }
}
