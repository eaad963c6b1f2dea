//! Per-sample random numbers that are a pure function of (seed, pixel, sample index).
//!
//! No thread-local or shared state: a pixel traced alone equals the same pixel of a full
//! render on any thread count (the progressive renderer's contract, tracer/mod.rs).

/// SplitMix64 finaliser (Steele et al. 2014): a strong 64-bit bijective mixer.
#[inline]
#[must_use]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Hashes (seed, x, y, sample) into one 64-bit state. Each input is folded in through
/// the mixer so that neighbouring pixels and sample indices decorrelate.
#[inline]
#[must_use]
pub fn sample_hash(seed: u64, x: u32, y: u32, sample: u32) -> u64 {
    let mut h = mix64(seed ^ 0x9e37_79b9_7f4a_7c15);
    h = mix64(h ^ (u64::from(x) | (u64::from(y) << 32)));
    mix64(h ^ u64::from(sample).wrapping_mul(0xd1b5_4a32_d192_ed03))
}

/// PCG32 (O'Neill 2014, XSH-RR variant): small state, good statistics, fast.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
    inc: u64,
}

impl Rng {
    const MUL: u64 = 6_364_136_223_846_793_005;

    /// A generator whose state and stream both derive from `hash`.
    #[inline]
    #[must_use]
    pub fn new(hash: u64) -> Self {
        let mut r = Self {
            state: 0,
            inc: (mix64(hash ^ 0xda3e_39cb_94b9_5bdb) << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(hash);
        r.next_u32();
        r
    }

    /// The generator for sample `sample` of pixel (x, y) under `seed`.
    #[inline]
    #[must_use]
    pub fn for_sample(seed: u64, x: u32, y: u32, sample: u32) -> Self {
        Self::new(sample_hash(seed, x, y, sample))
    }

    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(Self::MUL).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in [0, 1): the top 24 bits, so 1.0 is never returned.
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    #[inline]
    pub fn next_2d(&mut self) -> glam::Vec2 {
        let a = self.next_f32();
        glam::Vec2::new(a, self.next_f32())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_inputs_same_stream_and_unit_interval() {
        let mut a = Rng::for_sample(7, 3, 4, 5);
        let mut b = Rng::for_sample(7, 3, 4, 5);
        for _ in 0..1000 {
            let (x, y) = (a.next_f32(), b.next_f32());
            assert_eq!(x.to_bits(), y.to_bits());
            assert!((0.0..1.0).contains(&x));
        }
    }

    #[test]
    fn neighbouring_samples_differ_and_mean_is_half() {
        let mut sum = 0.0f64;
        let mut firsts = std::collections::HashSet::new();
        for s in 0..4096 {
            let mut r = Rng::for_sample(1, 0, 0, s);
            let v = r.next_f32();
            firsts.insert(v.to_bits());
            sum += f64::from(v);
        }
        // 4096 draws of U(0,1): the mean's standard deviation is 0.0045.
        assert!((sum / 4096.0 - 0.5).abs() < 0.02, "mean {}", sum / 4096.0);
        assert!(firsts.len() > 4000, "first draws collide: {}", firsts.len());
    }
}
