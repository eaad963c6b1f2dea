//! Scene geometry behind one acceleration structure (obvhs CWBVH, Ylitie et al. 2017).
//!
//! The rest of the tracer sees only [`Geometry::intersect`], [`Geometry::occluded`] and
//! [`Geometry::surface`] (STYLE.md: "keep obvhs behind `tracer::bvh`").

use crate::cancel::{CancelToken, Cancelled};
use crate::scene::{MaterialId, ObjectId, Scene, Shape};
use glam::{Vec2, Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::Ray as BvhRay;
use obvhs::BvhBuildParams;
use rayon::prelude::*;
use std::hash::BuildHasher;

mod flat;
mod traverse;

/// Marks "no such index" (no emitter, no shading normals, no primitive to skip).
pub const NONE: u32 = u32::MAX;

/// One intersectable primitive, stored in BVH leaf order so that the index the traversal
/// hands back addresses it directly (no indirection through `primitive_indices`).
///
/// Packed into three `Vec3` (36 bytes, where an enum of `Vec3A`s takes 64: the geometry
/// of a million triangles must fit ~120 B each). A triangle is `v0, e1, e2`; a sphere is
/// its centre, `(radius, 0, 0)` and a NaN marker: a triangle never holds a NaN
/// ([`Collected::push_triangle`] drops non-finite ones). [`Prim::shape`] unpacks it.
#[derive(Clone, Copy, Debug)]
pub struct Prim([Vec3; 3]);

/// A primitive unpacked for intersection and shading.
#[derive(Clone, Copy, Debug)]
pub enum PrimShape {
    /// `p = v0 + u·e1 + v·e2`.
    Tri {
        v0: Vec3A,
        e1: Vec3A,
        e2: Vec3A,
    },
    Sphere {
        center: Vec3A,
        radius: f32,
    },
}

impl Prim {
    #[must_use]
    pub fn tri(v0: Vec3, e1: Vec3, e2: Vec3) -> Self {
        Self([v0, e1, e2])
    }

    #[must_use]
    pub fn sphere(center: Vec3, radius: f32) -> Self {
        Self([center, Vec3::new(radius, 0.0, 0.0), Vec3::NAN])
    }

    #[inline(always)]
    #[must_use]
    pub fn shape(&self) -> PrimShape {
        let [a, b, c] = self.0;
        if c.x.is_nan() {
            PrimShape::Sphere {
                center: a.into(),
                radius: b.x,
            }
        } else {
            PrimShape::Tri {
                v0: a.into(),
                e1: b.into(),
                e2: c.into(),
            }
        }
    }
}

/// What a primitive belongs to, as shading sees it ([`Surface::info`]).
#[derive(Clone, Copy, Debug)]
pub struct PrimInfo {
    pub object: ObjectId,
    pub material: MaterialId,
    /// Index into the emitter list, or [`NONE`].
    pub emitter: u32,
    /// Index into [`Geometry::normals`] (three per triangle), or [`NONE`].
    pub normals: u32,
    /// Index into [`Geometry::uvs`] (three per triangle; any other value than [`NONE`] on
    /// a sphere), or [`NONE`] where the material needs no texture coordinates.
    pub uvs: u32,
}

/// What a primitive belongs to as stored, one per primitive: [`PrimInfo`] without the
/// material, which is its object's ([`Geometry::object_material`]; 16 bytes instead of
/// 20 a primitive).
#[derive(Clone, Copy, Debug)]
pub struct PrimLinks {
    pub object: ObjectId,
    /// Index into the emitter list, or [`NONE`].
    pub emitter: u32,
    /// Index into [`Geometry::normals`] (three per triangle), or [`NONE`].
    pub normals: u32,
    /// Index into [`Geometry::uvs`] (three per triangle; any other value than [`NONE`] on
    /// a sphere), or [`NONE`] where the material needs no texture coordinates.
    pub uvs: u32,
}

/// The closest hit of a ray.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub prim: u32,
    pub u: f32,
    pub v: f32,
}

/// A hit resolved into what shading needs.
#[derive(Clone, Copy, Debug)]
pub struct Surface {
    pub p: Vec3,
    /// Geometric normal as the primitive defines it (triangle winding, sphere outward).
    pub ng: Vec3,
    /// Shading normal on the same side as `ng`.
    pub ns: Vec3,
    /// Texture coordinates (zero where the material needs none).
    pub uv: Vec2,
    pub info: PrimInfo,
}

pub struct Geometry {
    bvh: Option<CwBvh>,
    /// The CPU has AVX2: the BVH is walked by bvh/traverse.rs's eight-box node test.
    avx2: bool,
    /// Every primitive in SIMD packets, for scenes small enough that testing them all
    /// beats a traversal (bvh/flat.rs).
    flat: Option<flat::Flat>,
    pub prims: Vec<Prim>,
    pub info: Vec<PrimLinks>,
    /// The material of each object (a scene shape has one).
    pub object_material: Vec<MaterialId>,
    pub normals: Vec<Vec3>,
    /// Texture coordinates, three per triangle, kept only for image-textured materials:
    /// a scene without image textures stores none.
    pub uvs: Vec<Vec2>,
    /// Bounding sphere of the whole scene (centre, radius): directional and environment
    /// light power, and where "infinitely far" starts.
    pub bounds_center: Vec3,
    pub bounds_radius: f32,
}

impl Geometry {
    /// Collects every primitive of `scene` and builds the BVH. `emitter_of(object, prim)`
    /// is filled in later by the light module through [`Geometry::info`].
    #[must_use]
    pub fn build(scene: &Scene) -> Self {
        match Self::prepare(scene, &CancelToken::new()) {
            Ok(g) => g,
            Err(Cancelled) => unreachable!("a fresh token is never cancelled"),
        }
    }

    /// [`Self::build`], stopping with `Err(Cancelled)` within a fraction of a second of a
    /// cancel: the token is polled between phases and every [`CHECK_EVERY`] triangles,
    /// and a large BVH (one call into obvhs that cannot stop: ~3 s for a million
    /// near-duplicate triangles) is built on a thread of its own that is abandoned on a
    /// cancel ([`crate::cancel::abandonable`]).
    pub fn prepare(scene: &Scene, cancel: &CancelToken) -> Result<Self, Cancelled> {
        let mut c = Collected::default();
        for (obj, shape) in scene.shapes.iter().enumerate() {
            c.push_shape(scene, obj as ObjectId, shape, cancel)?;
        }
        cancel.check()?;
        let Collected {
            prims,
            info,
            mut normals,
            mut uvs,
        } = c;
        // Grown by doubling while collected: up to half of each would be slack.
        normals.shrink_to_fit();
        uvs.shrink_to_fit();
        let (prims, info) = without_duplicates(prims, info, cancel)?;
        cancel.check()?;
        let aabbs: Vec<Aabb> = prims
            .iter()
            .enumerate()
            .map(|(i, p)| tie_broken(prim_aabb(p), i))
            .collect();
        let (bounds_center, bounds_radius) = bounding_sphere(&aabbs);
        let (bvh, prims, info) = in_leaf_order(aabbs, prims, info, cancel)?;
        Ok(Self {
            bvh,
            avx2: traverse::has_avx2(),
            flat: flat::Flat::build(&prims),
            prims,
            info,
            object_material: scene.shapes.iter().map(Shape::material).collect(),
            normals,
            uvs,
            bounds_center,
            bounds_radius,
        })
    }

    /// Closest hit along `o + t·d` (`d` unit) with `t < tmax`, ignoring a hit on `skip`
    /// (the primitive the ray leaves) unless that is the far side of a sphere.
    #[inline]
    pub fn intersect(&self, o: Vec3, d: Vec3, tmax: f32, skip: u32) -> Option<Hit> {
        if let Some(f) = &self.flat {
            match f.closest(&flat_ray(o, d, tmax), skip) {
                flat::Closest::Hit(h) => return Some(h),
                flat::Closest::Miss => return None,
                flat::Closest::Tie => {}
            }
        }
        self.traverse(o, d, BvhRay::new(o.into(), d.into(), 0.0, tmax), skip)
    }

    /// [`Self::intersect`] through the BVH.
    #[inline]
    fn traverse(&self, o: Vec3, d: Vec3, ray: BvhRay, skip: u32) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let (prim, t) = traverse::closest(bvh, ray, self.avx2, |r, id| self.prim_t(r, id, skip))?;
        let (u, v) = match self.prims[prim as usize].shape() {
            PrimShape::Tri { v0, e1, e2 } => tri_uv(r_o(o), r_o(d), v0, e1, e2),
            PrimShape::Sphere { .. } => (0.0, 0.0),
        };
        Some(Hit { t, prim, u, v })
    }

    /// True if anything blocks `o + t·d` for `t < tmax`.
    #[inline]
    pub fn occluded(&self, o: Vec3, d: Vec3, tmax: f32, skip: u32) -> bool {
        if let Some(f) = &self.flat {
            return f.occluded(&flat_ray(o, d, tmax), skip);
        }
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        let ray = BvhRay::new(o.into(), d.into(), 0.0, tmax);
        // Inlined into the walk: a call per primitive tested (and the `vzeroupper` the
        // AVX2 walk makes before it) was 1.6 % of veach-ajar's render instructions.
        traverse::any(
            bvh,
            ray,
            self.avx2,
            #[inline(always)]
            |r, id| self.prim_t(r, id, skip),
        )
    }

    #[inline(always)]
    fn prim_t(&self, r: &BvhRay, id: u32, skip: u32) -> f32 {
        match self.prims[id as usize].shape() {
            PrimShape::Tri { v0, e1, e2 } => {
                if id == skip {
                    // A ray leaving a plane cannot meet that plane again.
                    return f32::INFINITY;
                }
                tri_t(r, v0, e1, e2)
            }
            PrimShape::Sphere { center, radius } => sphere_t(r, center, radius, id == skip),
        }
    }

    /// Position and normals of a hit.
    #[inline]
    #[must_use]
    pub fn surface(&self, o: Vec3, d: Vec3, hit: &Hit) -> Surface {
        let links = self.info[hit.prim as usize];
        let info = PrimInfo {
            object: links.object,
            material: self
                .object_material
                .get(links.object as usize)
                .copied()
                .unwrap_or(NONE),
            emitter: links.emitter,
            normals: links.normals,
            uvs: links.uvs,
        };
        match self.prims[hit.prim as usize].shape() {
            PrimShape::Tri { v0, e1, e2 } => {
                // From barycentrics, not o + t·d: the error then scales with the vertex
                // magnitude only, which is what the ray offset assumes.
                let p = Vec3::from(v0 + e1 * hit.u + e2 * hit.v);
                let ng = Vec3::from(e1.cross(e2)).normalize();
                let ns = if info.normals == NONE {
                    ng
                } else {
                    let n = &self.normals[info.normals as usize..info.normals as usize + 3];
                    let s = (n[0] * (1.0 - hit.u - hit.v) + n[1] * hit.u + n[2] * hit.v)
                        .normalize_or_zero();
                    if s == Vec3::ZERO {
                        ng
                    } else if s.dot(ng) < 0.0 {
                        -s
                    } else {
                        s
                    }
                };
                let uv = if info.uvs == NONE {
                    Vec2::ZERO
                } else {
                    let t = &self.uvs[info.uvs as usize..info.uvs as usize + 3];
                    t[0] * (1.0 - hit.u - hit.v) + t[1] * hit.u + t[2] * hit.v
                };
                Surface {
                    p,
                    ng,
                    ns,
                    uv,
                    info,
                }
            }
            PrimShape::Sphere { center, radius } => {
                let c = Vec3::from(center);
                let n = (o + d * hit.t - c).normalize_or_zero();
                let n = if n == Vec3::ZERO { -d } else { n };
                // Re-projected onto the sphere to remove the error of o + t·d.
                Surface {
                    p: c + n * radius,
                    ng: n,
                    ns: n,
                    uv: if info.uvs == NONE {
                        Vec2::ZERO
                    } else {
                        sphere_uv(n)
                    },
                    info,
                }
            }
        }
    }

    /// Bytes the geometry holds on the heap: every buffer's capacity times its element
    /// size (primitives, their info, shading normals, texture coordinates, BVH nodes).
    #[must_use]
    pub fn heap_bytes(&self) -> usize {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        let bvh = self.bvh.as_ref().map_or(0, |b| {
            bytes(&b.nodes)
                + bytes(&b.primitive_indices)
                + b.exact_node_aabbs.as_ref().map_or(0, bytes)
        });
        let flat = self.flat.as_ref().map_or(0, flat::Flat::heap_bytes);
        flat + bytes(&self.prims)
            + bytes(&self.info)
            + bytes(&self.object_material)
            + bytes(&self.normals)
            + bytes(&self.uvs)
            + bvh
    }

    /// Closest primitive's object id through a ray, or `None`.
    #[must_use]
    pub fn object_at(&self, o: Vec3, d: Vec3) -> Option<ObjectId> {
        self.intersect(o, d, f32::INFINITY, NONE)
            .map(|h| self.info[h.prim as usize].object)
    }
}

/// The ray `o + t·d`, `0 < t < tmax`, for [`flat::Flat`], which never reads the inverse
/// direction a traversal needs (three divisions saved).
#[inline(always)]
fn flat_ray(o: Vec3, d: Vec3, tmax: f32) -> BvhRay {
    BvhRay {
        origin: o.into(),
        direction: d.into(),
        inv_direction: Vec3A::ZERO,
        tmin: 0.0,
        tmax,
    }
}

/// Texture coordinates on a sphere at unit normal `n`: longitude u ∈ [0, 1) around +y
/// (0 towards +x, growing towards −z: counter-clockwise seen from above), v = 0 at the
/// top pole and 1 at the bottom, so an equirectangular image wraps it upright.
#[must_use]
pub fn sphere_uv(n: Vec3) -> Vec2 {
    let u = (-n.z).atan2(n.x) * std::f32::consts::FRAC_1_PI * 0.5;
    Vec2::new(
        if u < 0.0 { u + 1.0 } else { u },
        n.y.clamp(-1.0, 1.0).acos() * std::f32::consts::FRAC_1_PI,
    )
}

#[inline(always)]
fn r_o(v: Vec3) -> Vec3A {
    v.into()
}

/// Triangles collected between two looks at the cancel token (~1 ms of work).
const CHECK_EVERY: usize = 1 << 14;

/// Boxes from which the BVH is built on a thread of its own (cancellable): below this it
/// takes well under 0.1 s, less than starting a thread would matter for but no reason to.
const BUILD_ON_ITS_OWN_THREAD: usize = 50_000;

fn build_cwbvh(aabbs: &[Aabb]) -> CwBvh {
    obvhs::cwbvh::builder::build_cwbvh(
        aabbs,
        BvhBuildParams::medium_build(),
        &mut std::time::Duration::default(),
    )
}

fn prim_aabb(p: &Prim) -> Aabb {
    match p.shape() {
        PrimShape::Tri { v0, e1, e2 } => Aabb::from_points(&[v0, v0 + e1, v0 + e2]),
        PrimShape::Sphere { center, radius } => {
            Aabb::new(center - Vec3A::splat(radius), center + Vec3A::splat(radius))
        }
    }
}

/// The primitives of a scene in scene order, before duplicates are dropped and the BVH
/// reorders them ([`Geometry::prepare`]).
#[derive(Default)]
struct Collected {
    prims: Vec<Prim>,
    info: Vec<PrimLinks>,
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
}

impl Collected {
    /// Appends the primitives of `shape` (object `object`), polling `cancel` every
    /// [`CHECK_EVERY`] triangles.
    fn push_shape(
        &mut self,
        scene: &Scene,
        object: ObjectId,
        shape: &Shape,
        cancel: &CancelToken,
    ) -> Result<(), Cancelled> {
        let needs_uv = scene
            .materials
            .get(shape.material() as usize)
            .is_some_and(crate::scene::Material::uses_uv);
        match shape {
            Shape::Sphere { center, radius, .. } => {
                self.prims.push(Prim::sphere(*center, *radius));
                self.info.push(PrimLinks {
                    object,
                    emitter: NONE,
                    normals: NONE,
                    uvs: if needs_uv { 0 } else { NONE },
                });
            }
            Shape::Triangles { triangles, .. } => {
                for (k, t) in triangles.iter().enumerate() {
                    if k % CHECK_EVERY == 0 {
                        cancel.check()?;
                    }
                    self.push_triangle(t, object, needs_uv);
                }
            }
        }
        Ok(())
    }

    /// Appends one triangle with its shading normals and texture coordinates (those only
    /// when `needs_uv`), unless it is degenerate.
    fn push_triangle(&mut self, t: &crate::scene::Triangle, object: ObjectId, needs_uv: bool) {
        let e1 = t.p[1] - t.p[0];
        let e2 = t.p[2] - t.p[0];
        // Validation drops degenerate triangles; this guards any that slip
        // through (a zero normal would poison shading with NaN).
        if !e1.cross(e2).is_finite() || e1.cross(e2).length_squared() == 0.0 {
            return;
        }
        let nidx = match t.n {
            Some(n) if n.iter().all(|v| v.is_finite() && v.length_squared() > 0.0) => {
                let i = self.normals.len() as u32;
                self.normals.extend(n.iter().map(|v| v.normalize()));
                i
            }
            _ => NONE,
        };
        let uidx = if needs_uv {
            let i = self.uvs.len() as u32;
            // pbrt's parametrisation of a triangle without its own: (0, 0),
            // (1, 0), (1, 1) at its corners.
            self.uvs
                .extend(t.uv.unwrap_or([Vec2::ZERO, Vec2::X, Vec2::ONE]));
            i
        } else {
            NONE
        };
        self.prims.push(Prim::tri(t.p[0], e1, e2));
        self.info.push(PrimLinks {
            object,
            emitter: NONE,
            normals: nidx,
            uvs: uidx,
        });
    }
}

/// Bounding sphere (centre, radius) of the boxes `aabbs`: the unit sphere at the origin
/// for an empty scene; never a zero radius.
fn bounding_sphere(aabbs: &[Aabb]) -> (Vec3, f32) {
    let mut total = Aabb::empty();
    for a in aabbs {
        total = total.union(a);
    }
    if aabbs.is_empty() {
        (Vec3::ZERO, 1.0)
    } else {
        let c: Vec3 = total.center().into();
        (c, (Vec3::from(total.diagonal()).length() * 0.5).max(1e-6))
    }
}

/// The BVH (none for an empty scene) and the primitives with their info in its leaf order.
type LeafOrdered = (Option<CwBvh>, Vec<Prim>, Vec<PrimLinks>);

/// Builds the BVH over `aabbs` (on a thread of its own for a large scene, abandoned on a
/// cancel) and reorders `prims` and `info` to its leaf order, so that the index the
/// traversal hands back addresses them directly. No BVH for an empty scene.
fn in_leaf_order(
    aabbs: Vec<Aabb>,
    prims: Vec<Prim>,
    info: Vec<PrimLinks>,
    cancel: &CancelToken,
) -> Result<LeafOrdered, Cancelled> {
    if prims.is_empty() {
        return Ok((None, prims, info));
    }
    let bvh = if aabbs.len() < BUILD_ON_ITS_OWN_THREAD {
        build_cwbvh(&aabbs)
    } else {
        crate::cancel::abandonable(cancel, move || build_cwbvh(&aabbs))?
    };
    cancel.check()?;
    // Reorder primitives to the BVH's leaf order (obvhs examples/cornell_box_cwbvh.rs).
    let mut bvh = bvh;
    // The builder sizes the node buffer for the worst case (a node per primitive, 80 B
    // each); a million triangles use an eighth of it.
    bvh.nodes.shrink_to_fit();
    let order = std::mem::take(&mut bvh.primitive_indices);
    let prims = order.iter().map(|&i| prims[i as usize]).collect();
    let info = order.iter().map(|&i| info[i as usize]).collect();
    // The traversal hands back leaf slots and `prims` is stored in leaf order, so the
    // permutation is not kept (4 B a primitive).
    Ok((Some(bvh), prims, info))
}

/// Drops every triangle that repeats an earlier one of the same object exactly (same
/// vertices bit for bit): one surface, drawn once. Without this a ray through a mesh of
/// a million copies of one triangle (an 8 MB request) tested all of them, since no
/// bounding box can separate coincident triangles: 32² pixels at one sample took 47 s.
/// Coincident emitters were also counted once per copy by light sampling. Spheres and
/// triangles that differ in any bit are kept.
fn without_duplicates(
    prims: Vec<Prim>,
    info: Vec<PrimLinks>,
    cancel: &CancelToken,
) -> Result<(Vec<Prim>, Vec<PrimLinks>), Cancelled> {
    let key = |p: &Prim, i: &PrimLinks| match p.shape() {
        PrimShape::Tri { v0, e1, e2 } => {
            let mut k = [0u32; 10];
            k[0] = i.object;
            for (j, v) in [v0, e1, e2].iter().flat_map(|v| v.to_array()).enumerate() {
                k[j + 1] = v.to_bits();
            }
            Some(k)
        }
        PrimShape::Sphere { .. } => None,
    };
    // A 64-bit fingerprint of each key (computed in parallel) is what the set holds: a
    // table of 16-byte entries instead of 40-byte keys stays in cache far longer, and
    // hashing was a fifth of a large mesh's build (perf). A fingerprint seen before is
    // confirmed against the kept triangle's key; a mere collision keeps the triangle.
    // foldhash's per-process random seed keeps collisions out of a request's reach.
    let hasher = foldhash::fast::RandomState::default();
    let prints: Vec<Option<u64>> = prims
        .par_iter()
        .zip(&info)
        .map(|(p, i)| key(p, i).map(|k| hasher.hash_one(k)))
        .collect();
    cancel.check()?;
    let mut first = std::collections::HashMap::with_capacity_and_hasher(
        prims.len(),
        foldhash::fast::RandomState::default(),
    );
    let (mut kept, mut kept_info) = (Vec::with_capacity(prims.len()), Vec::new());
    kept_info.reserve(prims.len());
    for (n, ((p, i), print)) in prims.into_iter().zip(info).zip(prints).enumerate() {
        if n % CHECK_EVERY == 0 {
            cancel.check()?;
        }
        if let Some(print) = print {
            let at = kept.len();
            let &mut earlier = first.entry(print).or_insert(at);
            if earlier != at && key(&kept[earlier], &kept_info[earlier]) == key(&p, &i) {
                continue;
            }
        }
        kept.push(p);
        kept_info.push(i);
    }
    Ok((kept, kept_info))
}

/// `aabb` grown by a tiny amount that differs from primitive to primitive: at most
/// [`TIE_BREAK`] of its largest extent (or of its distance from the origin, for a point),
/// chosen by a hash of `index`. A larger box is always correct for the BVH (it bounds its
/// primitive still), and this one is tighter than f32 can notice in a traversal.
///
/// Why: obvhs builds by PLOC, whose passes merge two neighbours (in Morton order) only if
/// each is the other's cheapest partner; the cheapest is decided by `<` on the union's
/// area, so among equal boxes every node prefers the same side and only one pair merges
/// per pass. A mesh of identical (or evenly shifted) triangles then builds in O(n²):
/// measured 25 k triangles 13.6 s, 100 k 225 s, 1 M some 6 hours, before the first
/// cancellation check. With distinct costs about a third of the nodes merge per pass.
fn tie_broken(aabb: Aabb, index: usize) -> Aabb {
    let extent = aabb.diagonal().max_element();
    let scale = if extent > 0.0 {
        extent
    } else {
        aabb.min.abs().max_element().max(1e-6)
    };
    // splitmix64 finaliser: well spread bits from consecutive indices.
    let mut h = (index as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
    h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^= h >> 31;
    let u = (h >> 40) as f32 / (1u64 << 24) as f32; // [0, 1)
    let pad = Vec3A::splat(scale * TIE_BREAK * (0.5 + u));
    Aabb::new(aabb.min - pad, aabb.max + pad)
}

/// Relative growth of a primitive's box in [`tie_broken`]: 1e-4 changes a box's area by
/// ~4e-4 (well above f32's 1.2e-7, so the costs differ) and a ray's work not measurably.
const TIE_BREAK: f32 = 1e-4;

/// Möller–Trumbore ray/triangle distance (INFINITY on a miss).
///
/// Every term is computed and the acceptance tests combined with `&`, not tested one by
/// one: a ray through a BVH leaf meets its triangles' edges in no pattern a branch
/// predictor can learn. Each test is the one a test-and-return version makes, NaN
/// behaviour included (a NaN passes `!outside` and fails the others), and the arithmetic
/// is unchanged: hits are bit-identical.
#[inline(always)]
fn tri_t(r: &BvhRay, v0: Vec3A, e1: Vec3A, e2: Vec3A) -> f32 {
    let pv = r.direction.cross(e2);
    let det = e1.dot(pv);
    let inv = 1.0 / det;
    let tv = r.origin - v0;
    let u = tv.dot(pv) * inv;
    let qv = tv.cross(e1);
    let v = r.direction.dot(qv) * inv;
    let t = e2.dot(qv) * inv;
    let outside = (v < 0.0) | (u + v > 1.0);
    let hit = (det != 0.0)
        & det.is_finite()
        & (0.0..=1.0).contains(&u)
        & !outside
        & (t > r.tmin)
        & (t < r.tmax);
    if hit {
        t
    } else {
        f32::INFINITY
    }
}

/// Barycentrics (u, v) of the hit of a ray on a triangle (same algebra as [`tri_t`]).
#[inline]
fn tri_uv(o: Vec3A, d: Vec3A, v0: Vec3A, e1: Vec3A, e2: Vec3A) -> (f32, f32) {
    let pv = d.cross(e2);
    let inv = 1.0 / e1.dot(pv);
    let tv = o - v0;
    let u = tv.dot(pv) * inv;
    let v = d.dot(tv.cross(e1)) * inv;
    (u.clamp(0.0, 1.0), v.clamp(0.0, 1.0 - u.clamp(0.0, 1.0)))
}

/// Ray/sphere distance with the precision fixes of Haines et al., "Precision Improvements
/// for Ray/Sphere Intersection" (Ray Tracing Gems, ch. 7). `from_self`: the ray starts on
/// this sphere, so only the far root of an inward ray is a real hit.
#[inline(always)]
fn sphere_t(r: &BvhRay, c: Vec3A, radius: f32, from_self: bool) -> f32 {
    let f = r.origin - c;
    let d = r.direction;
    let b = -f.dot(d);
    let l = f + d * b;
    let r2 = radius * radius;
    let disc = r2 - l.length_squared();
    if disc < 0.0 {
        return f32::INFINITY;
    }
    let cc = f.length_squared() - r2;
    let q = b + disc.sqrt().copysign(b);
    let (mut t0, mut t1) = (if q != 0.0 { cc / q } else { 0.0 }, q);
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    if from_self {
        // Leaving outward (b <= 0 means moving away from the centre): no hit at all.
        if b <= 0.0 {
            return f32::INFINITY;
        }
        return if t1 > r.tmin && t1 < r.tmax {
            t1
        } else {
            f32::INFINITY
        };
    }
    if t0 > r.tmin && t0 < r.tmax {
        t0
    } else if t1 > r.tmin && t1 < r.tmax {
        t1
    } else {
        f32::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Camera, Material, Shape, Triangle};
    use crate::tracer::fixtures;

    /// A scene of `n` copies of one triangle, each moved by `shift(k)`.
    fn copies(n: usize, shift: impl Fn(usize) -> Vec3) -> Scene {
        let base = [
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let triangles = (0..n)
            .map(|k| Triangle {
                p: base.map(|p| p + shift(k)),
                n: None,
                uv: None,
            })
            .collect();
        fixtures::scene(
            8,
            8,
            Camera {
                position: Vec3::new(0.0, 0.0, -5.0),
                look_at: Vec3::ZERO,
                up: Vec3::Y,
                fov_y_deg: 40.0,
            },
            vec![Material::Mirror {
                reflectance: Vec3::ONE,
            }],
            vec![Shape::Triangles {
                triangles,
                material: 0,
            }],
            Vec::new(),
            (1, 1, 0),
        )
    }

    /// A million identical triangles, and a million shifted evenly by a hair (each pair of
    /// neighbours the same distance apart, so all costs tie again): built within 3 times
    /// (plus 0.5 s) the time of a million distinct triangles on a grid, timed in the same run
    /// (under load 0.23 s, 4.1 s and 3.4 s), and still hit. The bound is relative so a
    /// loaded machine slows both sides alike (a fixed 5 s failed once at 5.46 s); the
    /// quadratic build it guards against took 225 s for 100 k copies.
    #[test]
    fn a_million_duplicates_build_fast_and_are_hit() {
        let grid_scene = copies(1_000_000, |k| {
            Vec3::new((k % 1000) as f32 * 3.0, (k / 1000) as f32 * 3.0, 10.0)
        });
        let t = std::time::Instant::now();
        let distinct = Geometry::build(&grid_scene);
        let grid = t.elapsed();
        drop(grid_scene);
        assert_eq!(distinct.prims.len(), 1_000_000);
        drop(distinct);
        eprintln!("distinct: built in {grid:?}");
        for (what, scene) in [
            ("identical", copies(1_000_000, |_| Vec3::ZERO)),
            (
                "near-duplicates",
                copies(1_000_000, |k| {
                    Vec3::new(k as f32 * 1e-7, 0.0, k as f32 * 1e-6)
                }),
            ),
        ] {
            let t = std::time::Instant::now();
            let geo = Geometry::build(&scene);
            let took = t.elapsed();
            eprintln!("{what}: built in {took:?}");
            assert!(
                took.as_secs_f64() < 3.0 * grid.as_secs_f64() + 0.5,
                "{what}: {took:?}, a million distinct triangles {grid:?}"
            );
            if what == "identical" {
                assert_eq!(
                    geo.prims.len(),
                    1,
                    "copies of one triangle are one triangle"
                );
            } else {
                assert_eq!(geo.prims.len(), 1_000_000);
            }
            let hit = geo
                .intersect(Vec3::new(0.0, 0.0, -5.0), Vec3::Z, f32::INFINITY, NONE)
                .unwrap_or_else(|| panic!("{what}: no hit"));
            assert!((hit.t - 5.0).abs() < 0.01, "{what}: {}", hit.t);
            assert!(geo.occluded(Vec3::new(0.2, 0.0, -5.0), Vec3::Z, 10.0, NONE));
            assert!(geo
                .intersect(Vec3::new(3.0, 0.0, -5.0), Vec3::Z, f32::INFINITY, NONE)
                .is_none());
        }
    }

    /// A mesh of `2·n²` triangles (an n×n grid of quads), with per-vertex normals and an
    /// image-textured material (texture coordinates kept) as asked.
    fn grid_mesh(n: usize, normals: bool, uvs: bool) -> Scene {
        let v = |i: usize, j: usize| Vec3::new(i as f32, (i * j % 7) as f32 * 0.1, j as f32);
        let mut triangles = Vec::with_capacity(2 * n * n);
        for i in 0..n {
            for j in 0..n {
                let (a, b, c, d) = (v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1));
                for p in [[a, b, c], [a, c, d]] {
                    triangles.push(Triangle {
                        p,
                        n: normals.then_some([Vec3::Y; 3]),
                        uv: uvs.then_some([Vec2::ZERO, Vec2::X, Vec2::ONE]),
                    });
                }
            }
        }
        let albedo = if uvs {
            crate::scene::Texture::Image(crate::scene::ImageMap {
                image: 0,
                factor: Vec3::ONE,
                wrap: crate::scene::Wrap::Repeat,
                scale: Vec2::ONE,
                offset: Vec2::ZERO,
            })
        } else {
            crate::scene::Texture::Constant(Vec3::splat(0.5))
        };
        let mut scene = copies(0, |_| Vec3::ZERO);
        scene.materials = vec![Material::Diffuse { albedo }];
        scene.shapes = vec![Shape::Triangles {
            triangles,
            material: 0,
        }];
        scene
    }

    /// The geometry of a million triangles stays within its share (~120 B) of the ~200 B
    /// a triangle the whole process may use. Measured: 62.1 B plain (36 primitive, 16
    /// links, 10 BVH nodes), 98.1 B with shading normals (+36), 122.1 B with texture
    /// coordinates too (+24); each bound is the measurement with 2 B to spare. Scenes
    /// this large have no screen-tile lists (primary.rs), so this is all the tracer's
    /// geometry.
    #[test]
    fn a_million_triangles_fit_their_memory_budget() {
        for (normals, uvs, budget) in [
            (false, false, 64.0),
            (true, false, 100.0),
            (true, true, 124.0),
        ] {
            let geo = Geometry::build(&grid_mesh(708, normals, uvs));
            let n = geo.prims.len();
            assert_eq!(n, 2 * 708 * 708);
            assert!(n > crate::tracer::primary::MAX_PRIMS);
            let per_tri = geo.heap_bytes() as f64 / n as f64;
            eprintln!("normals {normals}, uvs {uvs}: {per_tri:.1} B per triangle");
            assert!(
                per_tri <= budget,
                "{per_tri:.1} B > {budget} B per triangle"
            );
        }
    }

    #[test]
    fn sphere_uv_is_longitude_and_latitude() {
        let at = |n: Vec3| sphere_uv(n.normalize());
        assert_eq!(at(Vec3::X), Vec2::new(0.0, 0.5));
        assert!((at(Vec3::NEG_Z) - Vec2::new(0.25, 0.5)).length() < 1e-6);
        assert!((at(Vec3::NEG_X) - Vec2::new(0.5, 0.5)).length() < 1e-6);
        assert!((at(Vec3::Z) - Vec2::new(0.75, 0.5)).length() < 1e-6);
        assert_eq!(at(Vec3::Y).y, 0.0);
        assert!((at(Vec3::NEG_Y).y - 1.0).abs() < 1e-6);
        // Just short of a full turn stays below 1 (a texture wraps there).
        let u = at(Vec3::new(1.0, 0.0, 1e-4)).x;
        assert!(u > 0.99 && u < 1.0, "{u}");
    }

    #[test]
    fn tie_breaking_only_grows_a_box_and_by_a_hair() {
        let a = Aabb::new(Vec3A::new(1.0, 2.0, 3.0), Vec3A::new(2.0, 2.0, 5.0));
        for i in 0..1000 {
            let b = tie_broken(a, i);
            assert!(b.min.cmple(a.min).all() && b.max.cmpge(a.max).all());
            let growth = (a.min - b.min).max_element();
            assert!(growth > 0.0 && growth <= 2.0 * 1.5 * TIE_BREAK, "{growth}");
        }
        assert_ne!(tie_broken(a, 0).min, tie_broken(a, 1).min);
        // A point (a zero-size box) is grown relative to where it is.
        let p = Aabb::new(Vec3A::splat(1e6), Vec3A::splat(1e6));
        assert!(tie_broken(p, 3).max.x > 1e6);
    }
}
