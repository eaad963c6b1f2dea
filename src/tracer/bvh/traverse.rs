//! Rays through obvhs's compressed 8-wide BVH (Ylitie, Karras and Laine, "Efficient
//! Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", HPG 2017), with the
//! eight child boxes of a node tested in one AVX2 pass.
//!
//! The traversal is the paper's (§4, Algorithm 1, as obvhs's `traverse!` writes it for a
//! CPU): node groups and primitive groups as (base index, hit mask) pairs, children
//! visited in the order the ray's octant gives them, a stack of 32 groups. What differs
//! is the child box test. obvhs widens each quantised plane from `u8` to `f32` one at a
//! time (48 scalar conversions a node); here each of the six plane sets (eight `u8`) is
//! widened at once (`vpmovzxbd` + `vcvtdq2ps`), the near and far plane of each axis
//! chosen once per ray rather than per node, and the eight slabs tested in one 256-bit
//! register. The arithmetic is obvhs's operation for operation (a multiply then an add,
//! no FMA; the same `max`/`min` nesting), so every box test, and with the same visiting
//! order every hit, is bit-identical to `CwBvh::ray_traverse`. Without AVX2 obvhs's own
//! traversal runs.

use glam::Vec3A;
use obvhs::cwbvh::node::CwBvhNode;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};

/// True where [`closest`] and [`any`] can take the AVX2 path.
#[must_use]
pub fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    return std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// The primitive nearest along `ray` among those `t_of` reports a distance below the
/// ray's `tmax` for (which shrinks to each hit found), as (leaf slot, `t`).
/// `t_of(ray, slot)` is the primitive test; `avx2` must be [`has_avx2`]'s answer.
#[inline]
pub fn closest<F: FnMut(&Ray, u32) -> f32>(
    bvh: &CwBvh,
    ray: Ray,
    avx2: bool,
    mut t_of: F,
) -> Option<(u32, f32)> {
    let tmax = ray.tmax;
    let mut best = None;
    let mut found = |r: &mut Ray, slot: u32| {
        let t = t_of(r, slot);
        if t < r.tmax {
            best = Some((slot, t));
            r.tmax = t;
        }
        false
    };
    if avx2 {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the caller checked the CPU has AVX2.
        unsafe {
            avx2::walk(bvh, ray, &mut found)
        };
    } else {
        let mut hit = RayHit::none();
        if bvh.ray_traverse(ray, &mut hit, |r, slot| t_of(r, slot as u32)) {
            best = Some((hit.primitive_id, hit.t));
        }
    }
    best.filter(|&(_, t)| t < tmax)
}

/// True if `t_of` reports a distance below `ray.tmax` for any primitive whose leaf the ray
/// reaches (the first such ends the walk).
#[inline]
pub fn any<F: FnMut(&Ray, u32) -> f32>(bvh: &CwBvh, ray: Ray, avx2: bool, mut t_of: F) -> bool {
    if avx2 {
        let mut blocked = false;
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the caller checked the CPU has AVX2.
        unsafe {
            avx2::walk(bvh, ray, &mut |r: &mut Ray, slot| {
                blocked = t_of(r, slot) < r.tmax;
                blocked
            })
        };
        blocked
    } else {
        !bvh.ray_traverse_miss(ray, |r, slot| t_of(r, slot as u32))
    }
}

/// Entries of the traversal stack: obvhs's `TRAVERSAL_STACK_SIZE`. A full stack
/// overwrites its top entry, as obvhs's does (an 8-wide tree 32 groups deep holds far
/// more than any scene's primitives).
const STACK: usize = 32;

/// Near side of a node box, in obvhs's units (`CwBvhNode::intersect_ray_simd`).
const EPSILON: f32 = 0.0001;

/// The ray octant as obvhs encodes it (`ray_get_octant_inv4`): per byte, bit 2 set for
/// +x, bit 1 for +y, bit 0 for +z, so that `child slot ^ octant` visits the near
/// children first.
#[inline(always)]
fn octant_inv4(d: Vec3A) -> u32 {
    (if d.x < 0.0 { 0 } else { 0x0404_0404 })
        | (if d.y < 0.0 { 0 } else { 0x0202_0202 })
        | (if d.z < 0.0 { 0 } else { 0x0101_0101 })
}

/// The hit mask of a node (Ylitie et al. §4: child slots in the top byte, leaf primitives
/// in the low 24 bits) from `boxes`, the children whose slab test passed (bit `i` for
/// child `i`).
#[inline(always)]
fn hit_mask(node: &CwBvhNode, oct_inv4: u32, mut boxes: u32) -> u32 {
    let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
    let mut mask = 0;
    while boxes != 0 {
        let shift = boxes.trailing_zeros() * 8;
        let bits = ((child_bits8 >> shift) as u32) & 0xff;
        let index = ((bit_index8 >> shift) as u32) & 0xff;
        mask |= bits << index;
        boxes &= boxes - 1;
    }
    mask
}

/// Index of the highest set bit of a non-zero `v`.
#[inline(always)]
fn first_bit_high(v: u32) -> u32 {
    31 - v.leading_zeros()
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{first_bit_high, hit_mask, octant_inv4, EPSILON, STACK};
    use glam::{UVec2, Vec3A};
    use obvhs::cwbvh::node::CwBvhNode;
    use obvhs::cwbvh::CwBvh;
    use obvhs::ray::Ray;
    use std::arch::x86_64::*;

    /// Which of a node's quantised plane sets is the near and which the far one on each
    /// axis for this ray: the min planes are near where the direction is positive.
    #[derive(Clone, Copy)]
    struct Sides {
        negative: [bool; 3],
    }

    impl Sides {
        #[inline(always)]
        fn planes(self, node: &CwBvhNode) -> [[&[u8; 8]; 2]; 3] {
            let side = |neg: bool, lo, hi| if neg { [hi, lo] } else { [lo, hi] };
            [
                side(self.negative[0], &node.child_min_x, &node.child_max_x),
                side(self.negative[1], &node.child_min_y, &node.child_max_y),
                side(self.negative[2], &node.child_min_z, &node.child_max_z),
            ]
        }
    }

    /// Eight quantised planes as floats.
    #[target_feature(enable = "avx2")]
    fn widen(q: &[u8; 8]) -> __m256 {
        // SAFETY: `q` is 8 readable bytes, what the 64-bit load reads.
        let bytes = unsafe { _mm_loadl_epi64(q.as_ptr().cast()) };
        _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(bytes))
    }

    /// Bit `i` set where the ray meets child `i`'s box before `ray.tmax`
    /// (`CwBvhNode::intersect_ray_simd` on all eight children at once).
    #[target_feature(enable = "avx2")]
    fn boxes_hit(node: &CwBvhNode, ray: &Ray, sides: Sides) -> u32 {
        let scale = node.compute_extent() * ray.inv_direction;
        let shift = (Vec3A::from(node.p) - ray.origin) * ray.inv_direction;
        let planes = sides.planes(node);
        let slab = |axis: usize| {
            let (s, o) = (_mm256_set1_ps(scale[axis]), _mm256_set1_ps(shift[axis]));
            let near = _mm256_add_ps(_mm256_mul_ps(widen(planes[axis][0]), s), o);
            let far = _mm256_add_ps(_mm256_mul_ps(widen(planes[axis][1]), s), o);
            (near, far)
        };
        let (nx, fx) = slab(0);
        let (ny, fy) = slab(1);
        let (nz, fz) = slab(2);
        let near = _mm256_max_ps(nx, _mm256_max_ps(ny, nz));
        let far = _mm256_min_ps(fx, _mm256_min_ps(fy, fz));
        let near = _mm256_max_ps(near, _mm256_set1_ps(EPSILON));
        let far = _mm256_min_ps(far, _mm256_set1_ps(ray.tmax));
        _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(near, far)) as u32
    }

    /// The walk of Ylitie et al. Algorithm 1: `leaf(ray, slot)` is called for each
    /// primitive of each leaf reached, may shrink `ray.tmax`, and ends the walk by
    /// returning true.
    #[target_feature(enable = "avx2")]
    pub(super) fn walk<F: FnMut(&mut Ray, u32) -> bool>(bvh: &CwBvh, ray: Ray, leaf: &mut F) {
        let mut ray = ray;
        let oct_inv4 = octant_inv4(ray.direction);
        let sides = Sides {
            negative: [
                ray.direction.x < 0.0,
                ray.direction.y < 0.0,
                ray.direction.z < 0.0,
            ],
        };
        let mut stack = [UVec2::ZERO; STACK];
        let mut depth = 0usize;
        // (first child node, child hits in the top byte | internal-child mask) and
        // (first primitive, primitive hits).
        let mut nodes = UVec2::new(0, if bvh.nodes.is_empty() { 0 } else { 0x8000_0000 });
        let mut prims = UVec2::ZERO;
        loop {
            while prims.y != 0 {
                let local = first_bit_high(prims.y);
                prims.y &= !(1 << local);
                if leaf(&mut ray, prims.x + local) {
                    return;
                }
            }
            if nodes.y & 0xff00_0000 != 0 {
                let hits = nodes.y;
                let child = first_bit_high(hits);
                nodes.y &= !(1 << child);
                if nodes.y & 0xff00_0000 != 0 {
                    stack[depth] = nodes;
                    depth = (depth + 1).min(STACK - 1);
                }
                let slot = (child - 24) ^ (oct_inv4 & 0xff);
                let below = (hits & !(u32::MAX << slot)).count_ones();
                let Some(node) = bvh.nodes.get((nodes.x + below) as usize) else {
                    return;
                };
                let mask = hit_mask(node, oct_inv4, boxes_hit(node, &ray, sides));
                nodes = UVec2::new(
                    node.child_base_idx,
                    (mask & 0xff00_0000) | node.imask as u32,
                );
                prims = UVec2::new(node.primitive_base_idx, mask & 0x00ff_ffff);
            } else {
                nodes = UVec2::ZERO;
            }
            if prims.y == 0 && nodes.y & 0xff00_0000 == 0 {
                if depth == 0 {
                    return;
                }
                depth -= 1;
                nodes = stack[depth];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use obvhs::aabb::Aabb;
    use obvhs::BvhBuildParams;

    /// A jittered field of small boxes standing in for primitives, hit where the ray
    /// meets the box (slab test): the walk's own answers can then be compared with
    /// obvhs's traversal ray by ray.
    fn field(n: usize) -> (Vec<Aabb>, CwBvh) {
        let mut s = 12345u32;
        let mut rnd = move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s as f32 / u32::MAX as f32
        };
        let boxes: Vec<Aabb> = (0..n)
            .map(|_| {
                let c = Vec3A::new(rnd(), rnd(), rnd()) * 20.0 - 10.0;
                let h = Vec3A::new(rnd(), rnd(), rnd()) * 0.4 + 0.01;
                Aabb::new(c - h, c + h)
            })
            .collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh(
            &boxes,
            BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        let leaf_order = bvh.primitive_indices.iter().map(|&i| boxes[i as usize]);
        (leaf_order.collect(), bvh)
    }

    fn box_t(r: &Ray, b: &Aabb) -> f32 {
        let t = b.intersect_ray(r);
        if t > r.tmin && t < r.tmax {
            t
        } else {
            f32::INFINITY
        }
    }

    fn rays(n: usize) -> Vec<Ray> {
        (0..n)
            .map(|i| {
                let a = i as f32 * 0.618_034 * std::f32::consts::TAU;
                let z = 1.0 - 2.0 * ((i as f32 + 0.5) / n as f32);
                let s = (1.0 - z * z).sqrt();
                let d = Vec3A::new(s * a.cos(), s * a.sin(), z);
                let o = Vec3A::new((i % 7) as f32 - 3.0, (i % 5) as f32 - 2.0, 0.5);
                // Axis-aligned directions too (zero components: `safe_inverse`).
                let d = if i % 50 == 0 { Vec3A::X } else { d };
                Ray::new(o, d, 0.0, if i % 3 == 0 { 6.0 } else { f32::INFINITY })
            })
            .collect()
    }

    #[test]
    fn the_wide_walk_finds_what_obvhs_finds() {
        if !has_avx2() {
            eprintln!("no AVX2: nothing to compare");
            return;
        }
        let (boxes, bvh) = field(5000);
        let (mut hits, mut blocked) = (0, 0);
        for r in rays(4000) {
            let wide = closest(&bvh, r, true, |r, i| box_t(r, &boxes[i as usize]));
            let base = closest(&bvh, r, false, |r, i| box_t(r, &boxes[i as usize]));
            assert_eq!(
                wide.map(|(i, t)| (i, t.to_bits())),
                base.map(|(i, t)| (i, t.to_bits()))
            );
            let any_wide = any(&bvh, r, true, |r, i| box_t(r, &boxes[i as usize]));
            assert_eq!(any_wide, base.is_some());
            assert_eq!(
                any_wide,
                any(&bvh, r, false, |r, i| box_t(r, &boxes[i as usize]))
            );
            hits += usize::from(wide.is_some());
            blocked += usize::from(any_wide);
        }
        // Both kinds of answer occur (the comparison is not vacuous).
        assert!(hits > 400 && hits < 3900, "{hits}");
        assert_eq!(blocked, hits);
    }

    #[test]
    fn an_empty_tree_is_never_hit() {
        let bvh = obvhs::cwbvh::builder::build_cwbvh::<Aabb>(
            &[],
            BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        let r = Ray::new_inf(Vec3A::ZERO, Vec3A::X);
        for avx2 in [false, has_avx2()] {
            assert!(closest(&bvh, r, avx2, |_, _| 1.0).is_none());
            assert!(!any(&bvh, r, avx2, |_, _| 1.0));
        }
    }

    #[test]
    fn the_hit_mask_puts_children_above_leaf_primitives() {
        let mut node = CwBvhNode::default();
        // Child 0: internal, in slot 0 (meta 0b001_11000); child 1: a leaf of two
        // primitives from offset 3 (meta 0b011_00011).
        node.child_meta[0] = 0b0011_1000;
        node.child_meta[1] = 0b0110_0011;
        node.imask = 1;
        // Octant all negative: slots keep their order.
        assert_eq!(hit_mask(&node, 0, 0b01), 1 << 24);
        assert_eq!(hit_mask(&node, 0, 0b10), 0b11 << 3);
        assert_eq!(hit_mask(&node, 0, 0b11), (1 << 24) | (0b11 << 3));
        // All positive: the internal child's slot index is flipped (7 ^ 0 = 7).
        assert_eq!(hit_mask(&node, 0x0707_0707, 0b01), 1 << 31);
        assert_eq!(hit_mask(&node, 0x0707_0707, 0), 0);
    }
}
