//! The numbers a path consumes: a pure function of (seed, pixel, sample index, dimension),
//! so a pixel traced alone equals the same pixel of a full render on any thread count
//! (tracer/mod.rs), and a pass that continues a pixel's samples draws the next ones of
//! the same sequence.
//!
//! Two samplers, chosen by `render.sampler` ([`crate::scene::SamplerKind`]):
//! - [`SobolSample`]: padded Owen-scrambled Sobol points (pbrt-v4's PaddedSobolSampler,
//!   Pharr et al. 2023 §8.7; hash-based Owen scrambling and index shuffling, Burley
//!   2020, "Practical Hash-based Owen Scrambling", JCGT 9(4)). Every dimension (a 1-D
//!   value or a 2-D pair) has its own shuffle of the sample index and its own scramble,
//!   so only Sobol's first two dimensions are needed and the index has no bound. The even
//!   and the odd samples of a pixel are two independently scrambled sequences
//!   (randomised QMC replicates, Owen 1997): the adaptive loop judges a pixel's error by
//!   the difference of its even and odd halves (`SampleSum::halves`), which says the
//!   error of their mean only when the halves are independent; two halves of one net are
//!   not (they fill each other's gaps, and their difference overstates the error).
//! - [`SobolSample::z_ordered`]: the same points laid along one Sobol sequence for the
//!   whole image in Morton (Z) order of the pixels (pbrt-v4's ZSobolSampler, Pharr et al.
//!   2023 §8.7, after Ahmed & Wonka 2020, "Screen-Space Blue-Noise Diffusion of Monte
//!   Carlo Sampling Error via Hierarchical Ordering of Pixels"). A pixel's samples are one
//!   aligned block of the sequence, and each 2×2, 4×4, … block of pixels holds one aligned
//!   block of blocks, so neighbouring pixels' samples fill each other's gaps: the error is
//!   spread as blue noise across pixels, which a viewer's contrast sensitivity (and FLIP)
//!   filters more than white noise of the same variance. The shuffle that scrambles
//!   the index (the same for every pixel) assigns the blocks, flipping each bit of the
//!   Morton index by a hash of the bits above it: a nested random assignment of
//!   quadrants, where pbrt permutes base-4 digits.
//! - [`Rng`]: an independent PCG32 stream per path (plain Monte Carlo).
//!
//! Dimensions follow a fixed layout ([`Dim`]): the camera's 2-D pair, then per bounce the
//! same five slots whether or not a bounce draws them, so a dimension never depends on
//! the path's history (what pbrt's samplers assume of their callers). A bounce draws its
//! slots in [`Dim`]'s order and always its BSDF sample, so a slot at or before the last
//! one drawn begins the next bounce: the sampler counts bounces itself.

use super::rng::{mix64, Rng};
use crate::raster::morton;
use glam::Vec2;

/// What a number is for: its slot in the per-bounce layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dim {
    /// The position inside the pixel (2-D, drawn once per path).
    Camera,
    /// Next-event estimation: which light (1-D).
    LightSelect,
    /// Next-event estimation: the point on the light (2-D).
    LightPoint,
    /// The BSDF's direction (2-D).
    Bsdf,
    /// The BSDF's lobe choice (1-D).
    Lobe,
    /// Russian roulette after the bounce (1-D).
    Roulette,
}

impl Dim {
    /// Slots per bounce.
    const PER_BOUNCE: u32 = 5;

    /// The slot's place within a bounce (the camera's: none).
    #[inline(always)]
    fn slot(self) -> Option<u32> {
        match self {
            Dim::Camera => None,
            Dim::LightSelect => Some(0),
            Dim::LightPoint => Some(1),
            Dim::Bsdf => Some(2),
            Dim::Lobe => Some(3),
            Dim::Roulette => Some(4),
        }
    }

    /// The dimension index of this slot at bounce `depth` (the camera is dimension 0).
    #[inline(always)]
    fn index(self, depth: u32) -> u32 {
        match self.slot() {
            None => 0,
            Some(slot) => 1u32
                .wrapping_add(depth.wrapping_mul(Self::PER_BOUNCE))
                .wrapping_add(slot),
        }
    }
}

/// The numbers of one path, drawn in the order the path uses them.
pub trait PathSampler {
    /// A value in [0, 1) for `dim`.
    fn get_1d(&mut self, dim: Dim) -> f32;
    /// A point in [0, 1)² for `dim`.
    fn get_2d(&mut self, dim: Dim) -> Vec2;
}

/// The independent sampler draws its stream in order: slots do not matter, and its
/// pictures are exactly those of the per-path PCG32 streams.
impl PathSampler for Rng {
    #[inline(always)]
    fn get_1d(&mut self, _dim: Dim) -> f32 {
        self.next_f32()
    }

    #[inline(always)]
    fn get_2d(&mut self, _dim: Dim) -> Vec2 {
        self.next_2d()
    }
}

/// One sample's Owen-scrambled Sobol point: padded per pixel ([`Self::for_sample`]) or
/// laid in Z order across the image ([`Self::z_ordered`]).
#[derive(Clone, Debug)]
pub struct SobolSample {
    /// The hash every dimension's scrambles derive from: of (seed, pixel, replicate) when
    /// padded, of (seed, replicate, round) in Z order.
    key: u64,
    /// The index along the scrambled sequence (padded: the pixel's sample index / 2; in
    /// Z order: [`ZOrder::index`]) with its bits reversed: the form the shuffle scrambles
    /// (kept once per path instead of reversed again for every dimension).
    index_reversed: u32,
    /// The bounce being drawn for (0 = the camera ray's hit), and the slot drawn last
    /// there (`None` before the first).
    depth: u32,
    last_slot: Option<u32>,
}

impl SobolSample {
    /// Sample `index` of pixel (x, y) under `seed`: point `index / 2` of the pixel's
    /// replicate `index % 2`.
    #[inline]
    #[must_use]
    pub fn for_sample(seed: u64, x: u32, y: u32, index: u32) -> Self {
        let h = mix64(seed ^ 0x6a09_e667_f3bc_c909);
        let pixel = mix64(h ^ (u64::from(x) | (u64::from(y) << 32)));
        let replicate = u64::from(index & 1).wrapping_mul(0xbb67_ae85_84ca_a73b);
        Self::at_index(mix64(pixel ^ replicate), index >> 1)
    }

    /// Sample `index` of pixel (x, y) under `seed`, in the image-wide Z order `order`:
    /// point `index / 2` of the pixel's block in replicate `index % 2`. As with
    /// [`Self::for_sample`], the two replicates are independently scrambled, so the
    /// adaptive loop's halves stay independent estimates.
    #[inline]
    #[must_use]
    pub fn z_ordered(seed: u64, x: u32, y: u32, index: u32, order: ZOrder) -> Self {
        let (global, round) = order.index(x, y, index >> 1);
        let h = mix64(seed ^ 0x3c6e_f372_fe94_f82b);
        let replicate = u64::from(index & 1).wrapping_mul(0xbb67_ae85_84ca_a73b);
        let round = u64::from(round).wrapping_mul(0xa54f_f53a_5f1d_36f1);
        Self::at_index(mix64(h ^ replicate ^ round), global)
    }

    #[inline(always)]
    fn at_index(key: u64, index: u32) -> Self {
        Self {
            key,
            index_reversed: index.reverse_bits(),
            depth: 0,
            last_slot: None,
        }
    }

    /// This sample with its next draws taken from bounce `depth`'s slots.
    #[cfg(test)]
    fn at_bounce(mut self, depth: u32) -> Self {
        self.depth = depth;
        self
    }

    /// The dimension `dim` takes now, counting a bounce each time a slot comes at or
    /// before the last one drawn.
    #[inline(always)]
    fn dimension(&mut self, dim: Dim) -> u32 {
        if let Some(slot) = dim.slot() {
            if self.last_slot.is_some_and(|last| slot <= last) {
                self.depth = self.depth.wrapping_add(1);
            }
            self.last_slot = Some(slot);
        }
        dim.index(self.depth)
    }

    /// The hash of dimension `d`: two independent 32-bit seeds per call.
    #[inline(always)]
    fn dim_hash(&self, d: u32) -> u64 {
        mix64(self.key ^ u64::from(d).wrapping_mul(0x9e37_79b9_7f4a_7c15))
    }
}

impl PathSampler for SobolSample {
    // Both draw `owen_scramble(sobol_d(shuffle(index)))` with the reversals that cancel
    // taken out: van der Corput reversed is the index itself, and the shuffle starts from
    // the reversed index kept in `index_reversed`.
    #[inline]
    fn get_1d(&mut self, dim: Dim) -> f32 {
        let d = self.dimension(dim);
        let h = self.dim_hash(d);
        let i = laine_karras(self.index_reversed, h as u32).reverse_bits();
        unit(laine_karras(i, (h >> 32) as u32).reverse_bits())
    }

    #[inline]
    fn get_2d(&mut self, dim: Dim) -> Vec2 {
        let d = self.dimension(dim);
        let h = self.dim_hash(d);
        let i = laine_karras(self.index_reversed, h as u32).reverse_bits();
        let sy = mix64(h) as u32;
        Vec2::new(
            unit(laine_karras(i, (h >> 32) as u32).reverse_bits()),
            unit(laine_karras(sobol_dim1_reversed(i), sy).reverse_bits()),
        )
    }
}

/// Where a render's pixels and samples lie along the one Sobol sequence of
/// [`SobolSample::z_ordered`]: bit for bit, the pixel's Morton code above its sample's
/// index within the pixel's block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ZOrder {
    /// Bits of the Morton code: twice those of the image's longer side rounded up to a
    /// power of two.
    pixel_bits: u32,
    /// Bits of a sample's place in its pixel's block: a replicate's share of the declared
    /// samples per pixel, rounded up to a power of two, as far as 32 bits allow.
    sample_bits: u32,
}

impl ZOrder {
    /// The order of a `width` × `height` render of `samples_per_pixel` samples.
    #[must_use]
    pub fn new(width: u32, height: u32, samples_per_pixel: u32) -> Self {
        let side = width.max(height).max(1).checked_next_power_of_two();
        let pixel_bits = side.map_or(32, |s| (2 * s.trailing_zeros()).min(32));
        // At most 2^31 (u32::MAX / 2 rounded up), so it has a next power of two and
        // `sample_bits` ≤ 31: every shift below is in range.
        let per_replicate = samples_per_pixel.div_ceil(2).max(1);
        let sample_bits = per_replicate
            .next_power_of_two()
            .trailing_zeros()
            .min(32 - pixel_bits);
        Self {
            pixel_bits,
            sample_bits,
        }
    }

    /// The bits of an index that are a sample's place in its pixel's block.
    #[inline(always)]
    fn within_mask(self) -> u32 {
        (1u32 << self.sample_bits) - 1
    }

    /// The index of point `j` of pixel (x, y)'s block, and the round it belongs to.
    /// Points past the block (an adaptive pass beyond the declared samples) start new
    /// rounds, each scrambled independently: the sequence never runs into another
    /// pixel's block.
    #[inline(always)]
    fn index(self, x: u32, y: u32, j: u32) -> (u32, u32) {
        let round = j >> self.sample_bits;
        let within = j & self.within_mask();
        let pixel = morton(x, y) & (1u64 << self.pixel_bits).wrapping_sub(1);
        let global = (pixel << self.sample_bits) as u32 | within;
        (global, round)
    }
}

/// A 32-bit fixed-point fraction as an f32 in [0, 1): its top 24 bits (f32's mantissa),
/// so 1.0 is never returned.
#[inline(always)]
fn unit(v: u32) -> f32 {
    (v >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// The Laine–Karras permutation (Laine & Karras 2011) with the hash of Vegdahl 2021
/// ("Building a Better LK Hash", used by pbrt-v4's FastOwenScrambler): a bijection of u32
/// in which each output bit depends only on the input bits at and below it.
#[inline(always)]
fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3d20_adea);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6c56);
    x ^= x.wrapping_mul(0x53a2_2864);
    x
}

/// Owen scrambling of a fraction in 32-bit fixed point (bit 31 = 1/2), Burley 2020 §3:
/// each digit is flipped by a hash of the digits above it, so every elementary interval
/// of a (t, m, s)-net maps onto one of the same size.
#[cfg(test)]
fn owen_scramble(v: u32, seed: u32) -> u32 {
    laine_karras(v.reverse_bits(), seed).reverse_bits()
}

/// The sample index shuffled (Burley 2020 §4): the index's bits scrambled as Owen
/// scrambles a fraction's digits, low bits first, so each bit is flipped by a hash of
/// the bits above it. Indices 0..2^m then map onto one aligned block of 2^m Sobol points,
/// for every m: each power-of-two prefix of a pixel's samples stays a (0, m, 2)-net,
/// with no bound on the count known in advance.
#[cfg(test)]
fn shuffle(index: u32, seed: u32) -> u32 {
    owen_scramble(index, seed)
}

/// Sobol's second dimension (primitive polynomial x + 1; its generator matrix is
/// Pascal's triangle mod 2): the XOR of the direction numbers of the index's set bits.
#[cfg(test)]
fn sobol_dim1(i: u32) -> u32 {
    sobol_dim1_reversed(i).reverse_bits()
}

/// [`sobol_dim1`] with its bits reversed (what Owen scrambling works on), looked up a
/// byte of the index at a time.
#[inline(always)]
fn sobol_dim1_reversed(i: u32) -> u32 {
    let t = &SOBOL_DIM1_BYTES;
    t[0][(i & 0xff) as usize]
        ^ t[1][((i >> 8) & 0xff) as usize]
        ^ t[2][((i >> 16) & 0xff) as usize]
        ^ t[3][(i >> 24) as usize]
}

/// Direction numbers of Sobol's second dimension, v_0 = 1/2, v_k = v_{k−1} ⊕ v_{k−1}/2
/// (Joe & Kuo 2008 with polynomial x + 1), in 32-bit fixed point.
const fn sobol_dim1_directions() -> [u32; 32] {
    let mut v = [0u32; 32];
    v[0] = 1 << 31;
    let mut k = 1;
    while k < 32 {
        v[k] = v[k - 1] ^ (v[k - 1] >> 1);
        k += 1;
    }
    v
}

/// `SOBOL_DIM1_BYTES[b][n]`: the XOR of the direction numbers of byte `b`'s set bits `n`,
/// bit-reversed.
const SOBOL_DIM1_BYTES: [[u32; 256]; 4] = {
    let v = sobol_dim1_directions();
    let mut t = [[0u32; 256]; 4];
    let mut b = 0;
    while b < 4 {
        let mut n = 0;
        while n < 256 {
            let mut x = 0u32;
            let mut j = 0;
            while j < 8 {
                if n & (1 << j) != 0 {
                    x ^= v[8 * b + j];
                }
                j += 1;
            }
            t[b][n] = x.reverse_bits();
            n += 1;
        }
        b += 1;
    }
    t
};

#[cfg(test)]
mod tests {
    use super::*;

    /// Sobol's first two dimensions at `i`, unscrambled, as fractions.
    fn sobol(i: u32) -> (f64, f64) {
        let f = |v: u32| f64::from(v) / 4_294_967_296.0;
        (f(i.reverse_bits()), f(sobol_dim1(i)))
    }

    /// Whether `pts` (2^m of them) hold one point in every elementary interval of area
    /// 2^−m: the (0, m, 2)-net property.
    fn is_net(pts: &[(f64, f64)]) -> bool {
        let m = pts.len().trailing_zeros();
        assert_eq!(pts.len(), 1 << m);
        (0..=m).all(|kx| {
            let (nx, ny) = (1usize << kx, 1usize << (m - kx));
            let mut seen = vec![false; 1 << m];
            pts.iter().all(|&(x, y)| {
                let cell = (x * nx as f64) as usize * ny + (y * ny as f64) as usize;
                !std::mem::replace(&mut seen[cell], true)
            })
        })
    }

    /// The first `n` points of replicate `r` (the pixel's samples r, r + 2, r + 4, …).
    fn scrambled(
        (seed, x, y, r): (u64, u32, u32, u32),
        n: u32,
        dim: Dim,
        depth: u32,
    ) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let mut s = SobolSample::for_sample(seed, x, y, 2 * i + r).at_bounce(depth);
                let p = s.get_2d(dim);
                (f64::from(p.x), f64::from(p.y))
            })
            .collect()
    }

    #[test]
    fn first_points_of_dimensions_0_and_1() {
        let want = [
            (0.0, 0.0),
            (0.5, 0.5),
            (0.25, 0.75),
            (0.75, 0.25),
            (0.125, 0.625),
            (0.625, 0.125),
            (0.375, 0.375),
            (0.875, 0.875),
        ];
        for (i, w) in want.iter().enumerate() {
            assert_eq!(sobol(i as u32), *w, "point {i}");
        }
    }

    #[test]
    fn the_drawn_values_are_the_scrambled_shuffled_sobol_points() {
        for index in [0, 1, 2, 77, 1 << 20, u32::MAX] {
            let mut s = SobolSample::for_sample(5, 6, 7, index).at_bounce(1);
            let h = s.dim_hash(Dim::Bsdf.index(1));
            let i = shuffle(index >> 1, h as u32);
            let x = owen_scramble(i.reverse_bits(), (h >> 32) as u32);
            let y = owen_scramble(sobol_dim1(i), mix64(h) as u32);
            assert_eq!(s.get_2d(Dim::Bsdf), Vec2::new(unit(x), unit(y)));
            let h = s.dim_hash(Dim::Lobe.index(1));
            let i = shuffle(index >> 1, h as u32);
            let v = owen_scramble(i.reverse_bits(), (h >> 32) as u32);
            assert_eq!(s.get_1d(Dim::Lobe), unit(v));
        }
    }

    #[test]
    fn direction_numbers_are_pascals_triangle_mod_2() {
        let v = sobol_dim1_directions();
        assert_eq!(
            &v[..5],
            &[
                0x8000_0000,
                0xc000_0000,
                0xa000_0000,
                0xf000_0000,
                0x8800_0000
            ]
        );
        for k in 0..32 {
            assert_eq!(sobol_dim1(1 << k), v[k as usize]);
        }
    }

    #[test]
    fn unscrambled_prefixes_and_blocks_are_nets() {
        for m in 0..=10 {
            let pts: Vec<_> = (0..1u32 << m).map(sobol).collect();
            assert!(is_net(&pts), "first 2^{m}");
        }
        // Any aligned block of 2^m points (what the shuffle maps a prefix onto).
        let pts: Vec<_> = (0..64u32)
            .map(|i| sobol(0xdead_0000 + 64 * 7 + i))
            .collect();
        assert!(is_net(&pts));
    }

    #[test]
    fn a_net_is_detected_and_a_non_net_is_not() {
        assert!(is_net(&[(0.1, 0.1), (0.6, 0.6)]));
        assert!(!is_net(&[(0.1, 0.1), (0.2, 0.6)]));
    }

    #[test]
    fn scrambled_prefixes_are_nets_in_every_slot() {
        for key in [
            (1, 0, 0, 0),
            (7, 33, 2, 1),
            (u64::MAX, u32::MAX, u32::MAX, 1),
        ] {
            for (dim, depth) in [(Dim::Camera, 0), (Dim::LightPoint, 0), (Dim::Bsdf, 3)] {
                for m in 0..=10 {
                    let pts = scrambled(key, 1 << m, dim, depth);
                    assert!(is_net(&pts), "{key:?} {dim:?}@{depth} 2^{m}");
                }
            }
        }
    }

    #[test]
    fn one_dimensional_prefixes_are_stratified() {
        for m in 0..=12u32 {
            let mut seen = vec![false; 1 << m];
            for i in 0..1u32 << m {
                let mut s = SobolSample::for_sample(3, 5, 8, 2 * i + 1).at_bounce(2);
                let v = s.get_1d(Dim::Roulette);
                let cell = (f64::from(v) * f64::from(1u32 << m)) as usize;
                assert!(!std::mem::replace(&mut seen[cell], true), "2^{m}: {i}");
            }
        }
    }

    #[test]
    fn shuffle_is_a_bijection_on_every_power_of_two_prefix() {
        for seed in [0, 1, 0x8000_0000, u32::MAX] {
            for m in [1, 4, 9] {
                let out: std::collections::HashSet<u32> =
                    (0..1u32 << m).map(|i| shuffle(i, seed) >> m).collect();
                // One aligned block: every index shares its high bits.
                assert_eq!(out.len(), 1, "seed {seed:#x} 2^{m}");
                let low: std::collections::HashSet<u32> =
                    (0..1u32 << m).map(|i| shuffle(i, seed)).collect();
                assert_eq!(low.len(), 1 << m);
            }
        }
    }

    #[test]
    fn values_stay_in_the_unit_interval_at_the_extremes() {
        for index in [0, 1, u32::MAX - 1, u32::MAX] {
            for (x, y) in [(0, 0), (u32::MAX, u32::MAX), (u32::MAX, 0)] {
                for depth in [0, 1, 63, u32::MAX] {
                    let mut s = SobolSample::for_sample(u64::MAX, x, y, index).at_bounce(depth);
                    for d in [Dim::LightSelect, Dim::Lobe, Dim::Roulette] {
                        assert!((0.0..1.0).contains(&s.get_1d(d)));
                    }
                    for d in [Dim::Camera, Dim::LightPoint, Dim::Bsdf] {
                        let p = s.get_2d(d);
                        assert!((0.0..1.0).contains(&p.x) && (0.0..1.0).contains(&p.y));
                    }
                }
            }
        }
        assert_eq!(unit(u32::MAX), 16_777_215.0 / 16_777_216.0);
        assert_eq!(unit(0), 0.0);
    }

    /// The 2-D points of `dim` at bounce `depth` of replicate `r`'s points `js` of every
    /// pixel in `pixels`, in Z order under `order`.
    fn z_points(
        order: ZOrder,
        pixels: impl Iterator<Item = (u32, u32)>,
        js: std::ops::Range<u32>,
        r: u32,
        (dim, depth): (Dim, u32),
    ) -> Vec<(f64, f64)> {
        let mut pts = Vec::new();
        for (x, y) in pixels {
            for j in js.clone() {
                let mut s = SobolSample::z_ordered(11, x, y, 2 * j + r, order).at_bounce(depth);
                let p = s.get_2d(dim);
                pts.push((f64::from(p.x), f64::from(p.y)));
            }
        }
        pts
    }

    fn block(x0: u32, y0: u32, side: u32) -> impl Iterator<Item = (u32, u32)> {
        (0..side * side).map(move |i| (x0 + i % side, y0 + i / side))
    }

    #[test]
    fn z_order_fits_pixels_and_samples_in_32_bits() {
        // 640 × 480 → a 1024 side: 20 bits of pixel; 64 spp → 32 per replicate: 5 bits.
        let o = ZOrder::new(640, 480, 64);
        assert_eq!((o.pixel_bits, o.sample_bits), (20, 5));
        assert_eq!(
            ZOrder::new(1, 1, 1),
            ZOrder {
                pixel_bits: 0,
                sample_bits: 0
            }
        );
        // Odd counts round up: 5 spp → 3 per replicate → blocks of 4.
        assert_eq!(ZOrder::new(2, 2, 5).sample_bits, 2);
        for (w, h, n) in [
            (u32::MAX, 1, u32::MAX),
            (65_536, 3, 1 << 20),
            (3, 2, u32::MAX),
        ] {
            let o = ZOrder::new(w, h, n);
            assert!(o.pixel_bits + o.sample_bits <= 32, "{w}×{h} {n}: {o:?}");
            let (g, round) = o.index(w - 1, h - 1, u32::MAX);
            assert!(u64::from(g) < 1u64 << (o.pixel_bits + o.sample_bits), "{g}");
            assert_eq!(round, u32::MAX >> o.sample_bits);
            let mut s = SobolSample::z_ordered(0, w - 1, h - 1, u32::MAX, o);
            assert!((0.0..1.0).contains(&s.get_1d(Dim::Roulette)), "{g} {round}");
        }
    }

    #[test]
    fn a_pixels_z_ordered_prefixes_are_nets() {
        let order = ZOrder::new(64, 48, 128);
        for (x, y) in [(0, 0), (37, 21), (63, 47)] {
            for slot in [(Dim::Camera, 0), (Dim::Bsdf, 2)] {
                for r in 0..2 {
                    for m in 0..=6 {
                        let pts = z_points(order, [(x, y)].into_iter(), 0..1 << m, r, slot);
                        assert!(is_net(&pts), "({x}, {y}) {slot:?} r{r} 2^{m}");
                    }
                }
            }
        }
    }

    #[test]
    fn aligned_blocks_of_pixels_share_one_net() {
        // What spreads the error as blue noise: the points of a 2^k × 2^k block of pixels
        // together are as evenly spread as one pixel's.
        let order = ZOrder::new(64, 64, 8);
        for (x0, y0, side) in [(0, 0, 2), (6, 10, 2), (4, 8, 4), (16, 0, 8)] {
            for slot in [(Dim::Camera, 0), (Dim::LightPoint, 1), (Dim::Bsdf, 4)] {
                let pts = z_points(order, block(x0, y0, side), 0..4, 1, slot);
                assert!(is_net(&pts), "({x0}, {y0}) side {side} {slot:?}");
            }
        }
        // Padded Sobol does not: each pixel is scrambled on its own.
        let padded: Vec<_> = block(0, 0, 4)
            .flat_map(|(x, y)| {
                (0..4).map(move |j| {
                    let p = SobolSample::for_sample(11, x, y, 2 * j).get_2d(Dim::Camera);
                    (f64::from(p.x), f64::from(p.y))
                })
            })
            .collect();
        assert!(!is_net(&padded));
    }

    #[test]
    fn points_past_the_declared_block_start_an_independent_round() {
        let order = ZOrder::new(16, 16, 8);
        let slot = (Dim::Bsdf, 1);
        let first = z_points(order, [(3, 5)].into_iter(), 0..4, 0, slot);
        let second = z_points(order, [(3, 5)].into_iter(), 4..8, 0, slot);
        assert!(is_net(&second));
        assert!(first.iter().all(|p| !second.contains(p)));
        // Another pixel's block is not reused.
        let neighbour = z_points(order, [(4, 5)].into_iter(), 0..4, 0, slot);
        assert!(second.iter().all(|p| !neighbour.contains(p)));
    }

    #[test]
    fn z_ordered_replicates_are_scrambled_apart() {
        let order = ZOrder::new(8, 8, 16);
        let even = z_points(order, block(0, 0, 8), 0..8, 0, (Dim::Camera, 0));
        let odd = z_points(order, block(0, 0, 8), 0..8, 1, (Dim::Camera, 0));
        let shared = even.iter().filter(|p| odd.contains(p)).count();
        assert!(shared < 4, "{shared} of {} points shared", even.len());
    }

    #[test]
    fn a_value_is_a_pure_function_of_its_inputs_not_of_the_draw_order() {
        let mut a = SobolSample::for_sample(9, 4, 5, 77).at_bounce(2);
        let mut b = SobolSample::for_sample(9, 4, 5, 77).at_bounce(2);
        let first = a.get_2d(Dim::Bsdf);
        // b draws other slots first (a vertex with next-event estimation).
        let _ = (b.get_1d(Dim::LightSelect), b.get_2d(Dim::LightPoint));
        assert_eq!(b.get_2d(Dim::Bsdf), first);
        // A second BSDF sample belongs to the next bounce.
        assert_ne!(a.get_2d(Dim::Bsdf), first);
    }

    #[test]
    fn bounces_are_counted_from_the_order_of_the_slots() {
        // A path: camera; bounce 0 with next-event estimation; bounce 1 on a mirror (no
        // light sample) with roulette; bounce 2 with next-event estimation.
        let path = [
            (Dim::Camera, 0),
            (Dim::LightSelect, 0),
            (Dim::LightPoint, 0),
            (Dim::Bsdf, 0),
            (Dim::Lobe, 0),
            (Dim::Bsdf, 1),
            (Dim::Lobe, 1),
            (Dim::Roulette, 1),
            (Dim::LightSelect, 2),
            (Dim::Bsdf, 2),
        ];
        let mut s = SobolSample::for_sample(1, 2, 3, 4);
        for (dim, depth) in path {
            assert_eq!(s.dimension(dim), dim.index(depth), "{dim:?}@{depth}");
        }
    }

    #[test]
    fn the_even_and_odd_samples_are_two_independent_replicates() {
        let even = scrambled((4, 9, 9, 0), 64, Dim::Bsdf, 1);
        let odd = scrambled((4, 9, 9, 1), 64, Dim::Bsdf, 1);
        assert!(is_net(&even) && is_net(&odd));
        // Independently scrambled: the union of the two nets is not one net of 128.
        let mut both = even.clone();
        both.extend(&odd);
        assert!(!is_net(&both));
        let xs = |p: &[(f64, f64)]| p.iter().map(|q| q.0).collect::<Vec<_>>();
        assert!(correlation(&xs(&even), &xs(&odd)).abs() < 0.4);
    }

    #[test]
    fn slots_never_share_a_dimension() {
        let mut seen = std::collections::HashSet::new();
        assert!(seen.insert(Dim::Camera.index(0)));
        for depth in 0..64 {
            for d in [
                Dim::LightSelect,
                Dim::LightPoint,
                Dim::Bsdf,
                Dim::Lobe,
                Dim::Roulette,
            ] {
                assert!(seen.insert(d.index(depth)), "{d:?}@{depth}");
            }
        }
    }

    /// Sample correlation of two equally long series.
    fn correlation(a: &[f64], b: &[f64]) -> f64 {
        let n = a.len() as f64;
        let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
        let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
        let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
        cov / (va * vb).sqrt()
    }

    #[test]
    fn pixels_seeds_and_dimensions_decorrelate() {
        let series = |seed: u64, x: u32, dim: Dim, depth: u32| -> Vec<f64> {
            (0..4096)
                .map(|i| {
                    let mut s = SobolSample::for_sample(seed, x, 0, i).at_bounce(depth);
                    f64::from(s.get_1d(dim))
                })
                .collect()
        };
        let base = series(1, 10, Dim::Lobe, 1);
        let others = [
            series(1, 11, Dim::Lobe, 1),
            series(2, 10, Dim::Lobe, 1),
            series(1, 10, Dim::Roulette, 1),
            series(1, 10, Dim::Lobe, 2),
        ];
        for o in &others {
            // Independent series of 4096: |r| is about 0.016 (1/√4096); 0.06 is 4σ.
            let r = correlation(&base, o);
            assert!(r.abs() < 0.06, "correlation {r}");
            assert_ne!(&base[..16], &o[..16]);
        }
        assert!((correlation(&base, &base) - 1.0).abs() < 1e-12);
        // Across pixels, the same sample index lands in different places.
        let firsts: std::collections::HashSet<u32> = (0..4096)
            .map(|x| {
                SobolSample::for_sample(1, x, 0, 0)
                    .get_1d(Dim::Lobe)
                    .to_bits()
            })
            .collect();
        assert!(
            firsts.len() > 4000,
            "first values collide: {}",
            firsts.len()
        );
    }

    #[test]
    fn the_independent_sampler_is_the_pcg32_stream_in_order() {
        let mut r = Rng::for_sample(3, 1, 2, 4);
        let mut s = Rng::for_sample(3, 1, 2, 4);
        assert_eq!(s.get_2d(Dim::Bsdf), r.next_2d());
        assert_eq!(s.get_1d(Dim::Camera), r.next_f32());
    }
}
