//! Where the next pass spends its samples (pure): tiles whose predicted visible error is
//! above t0 get the samples that would bring it down to t0, dearest-per-JND last.
//!
//! Monte Carlo error falls as 1/√n, and near threshold the vision model's distance grows
//! about linearly with the contrast of the error, so a tile at visible error v with n
//! samples per pixel needs about n·(v/t0)² to reach t0. A pass multiplies a tile's
//! samples by at least [`MIN_GROWTH`] (a tile just above t0 would otherwise creep up by a
//! few per cent a pass, each pass paying two denoises and a judgement) and at most [`MAX_GROWTH`]
//! (the estimate is a prediction; the next pass checks it), and the pass as a whole adds
//! at most the samples traced so far, so the error is re-measured at geometric intervals.

/// A tile's samples grow at least this much in one pass (each pass costs two denoises
/// and a judgement, so passes double at least).
pub const MIN_GROWTH: f64 = 2.0;
/// A tile's samples grow at most this much in one pass.
pub const MAX_GROWTH: u32 = 4;

/// One pooling tile as the allocator sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tile {
    /// Pixels in the tile.
    pub pixels: u32,
    /// Samples each of its pixels has (the fewest among them).
    pub samples: u32,
    /// Predicted visible error pooled over the tile, in units of what the tile may keep
    /// (1 JND, or a share of the reference's own visible error where that is more).
    pub visible: f32,
    /// Rays per sample (what a sample there costs); 1 when unknown.
    pub cost: f32,
}

/// The limits of one pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassLimits {
    /// Visible error at or below which a tile is done (JND).
    pub t0: f32,
    /// No pixel gets more samples than this.
    pub max_spp: u32,
    /// Samples this pass may add over the whole image.
    pub budget: u64,
}

/// Samples to add per pixel of each tile (0 = none). With `t0 = 0` every tile goes
/// straight to `max_spp` (the reference's samples: nothing is visible only at zero).
#[must_use]
pub fn plan(tiles: &[Tile], limits: &PassLimits) -> Vec<u32> {
    let mut extra: Vec<u32> = tiles.iter().map(|t| wanted(t, limits)).collect();
    // Most visible error per unit of cost first; the budget cuts the rest.
    let mut order: Vec<usize> = (0..tiles.len()).filter(|&i| extra[i] > 0).collect();
    order.sort_by(|&a, &b| {
        let worth = |t: &Tile| t.visible / t.cost.max(1e-6);
        worth(&tiles[b])
            .total_cmp(&worth(&tiles[a]))
            .then(a.cmp(&b))
    });
    let mut left = limits.budget;
    for i in order {
        let t = &tiles[i];
        let want = u64::from(extra[i]) * u64::from(t.pixels);
        if want <= left {
            left -= want;
        } else {
            // Whole samples per pixel only: what the budget still pays for, maybe none.
            extra[i] = u32::try_from(left / u64::from(t.pixels.max(1))).unwrap_or(u32::MAX);
            left -= u64::from(extra[i]) * u64::from(t.pixels);
        }
    }
    extra
}

/// A pass's own work (two denoises at `Fast` and the vision model) costs about what
/// tracing this many samples per pixel over the whole image does: measured at 512² on the
/// Cornell box (~1.0 s against ~0.25 s a sample per pixel) and the door (~0.5 s against
/// ~0.11 s). Counted in samples, not timed, so a render's passes do not depend on the
/// machine's load.
pub const PASS_COST_SPP: u64 = 4;

/// The endgame, as the F&P04 loop's (`traced_rest`): when taking every tile `plan` chose
/// straight to `max_spp` costs fewer samples than another pass's own work (`pass_cost`,
/// [`PASS_COST_SPP`] over the image), `plan` becomes that and the render ends after it.
/// Without it, a few tiles hovering at t0 drew dozens of passes of a few hundred pixels
/// each (the door with a finer metric: 64 passes, 28 s). The rest must also fit `budget`,
/// and a plan that already takes every open tile to `max_spp` is left as it is. Returns
/// whether it changed the plan.
pub fn finish_if_cheaper(
    tiles: &[Tile],
    plan: &mut [u32],
    max_spp: u32,
    pass_cost: u64,
    budget: u64,
) -> bool {
    let open = || tiles.iter().zip(plan.iter()).filter(|(_, &p)| p > 0);
    let rest: u64 = open()
        .map(|(t, _)| u64::from(max_spp.saturating_sub(t.samples)) * u64::from(t.pixels))
        .sum();
    let already = open().all(|(t, &p)| t.samples.saturating_add(p) >= max_spp);
    if rest == 0 || already || rest > budget || rest > pass_cost {
        return false;
    }
    for (t, p) in tiles.iter().zip(plan.iter_mut()) {
        if *p > 0 {
            *p = max_spp.saturating_sub(t.samples);
        }
    }
    true
}

/// What one tile would need to reach t0 (before the budget).
fn wanted(t: &Tile, l: &PassLimits) -> u32 {
    if t.samples >= l.max_spp {
        return 0;
    }
    let room = l.max_spp - t.samples;
    if l.t0 <= 0.0 {
        return room;
    }
    // A NaN error (an unjudged tile is +∞, not NaN) asks for nothing.
    if t.visible.is_nan() || t.visible <= l.t0 {
        return 0;
    }
    let ratio = f64::from(t.visible / l.t0);
    let n = f64::from(t.samples.max(1));
    let target = (n * ratio * ratio).max(n * MIN_GROWTH).ceil();
    let target = target
        .min(n * f64::from(MAX_GROWTH))
        .min(f64::from(l.max_spp)) as u32;
    target.saturating_sub(t.samples).clamp(1, room)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tile(samples: u32, visible: f32, cost: f32) -> Tile {
        Tile {
            pixels: 64,
            samples,
            visible,
            cost,
        }
    }

    const OPEN: PassLimits = PassLimits {
        t0: 1.0,
        max_spp: 1024,
        budget: u64::MAX,
    };

    #[test]
    fn a_tile_at_or_below_t0_gets_nothing() {
        assert_eq!(plan(&[tile(8, 1.0, 1.0), tile(8, 0.2, 1.0)], &OPEN), [0, 0]);
    }

    #[test]
    fn samples_grow_with_the_square_of_the_visible_error() {
        // 1.5 JND at 8 spp: 8·2.25 = 18 → 10 more.
        assert_eq!(plan(&[tile(8, 1.5, 1.0)], &OPEN), [10]);
        // 1.1 JND would want 10 (+2): at least as many again, 16.
        assert_eq!(plan(&[tile(8, 1.1, 1.0)], &OPEN), [8]);
        // 10 JND would want 800: capped at 4× per pass.
        assert_eq!(plan(&[tile(8, 10.0, 1.0)], &OPEN), [24]);
    }

    #[test]
    fn nothing_goes_past_max_spp() {
        let l = PassLimits {
            max_spp: 20,
            ..OPEN
        };
        assert_eq!(
            plan(&[tile(16, 10.0, 1.0), tile(20, 10.0, 1.0)], &l),
            [4, 0]
        );
    }

    #[test]
    fn t0_zero_takes_every_pixel_to_max_spp() {
        let l = PassLimits {
            t0: 0.0,
            max_spp: 64,
            ..OPEN
        };
        assert_eq!(plan(&[tile(8, 0.0, 1.0), tile(64, 3.0, 1.0)], &l), [56, 0]);
    }

    #[test]
    fn the_budget_goes_to_the_most_visible_error_per_cost_first() {
        // Same error, the second tile's samples cost 4×: the first is served first.
        let l = PassLimits {
            budget: 64 * 24 + 64 * 5,
            ..OPEN
        };
        let p = plan(&[tile(8, 10.0, 1.0), tile(8, 10.0, 4.0)], &l);
        assert_eq!(p, [24, 5]);
    }

    #[test]
    fn the_rest_is_traced_whole_when_cheaper_than_a_pass() {
        let tiles = [tile(8, 2.0, 1.0), tile(8, 0.5, 1.0), tile(60, 2.0, 1.0)];
        let mut p = plan(&tiles, &OPEN);
        assert_eq!(p, [24, 0, 180]);
        // Finishing the two open tiles: 64·(1024 − 8) + 64·(1024 − 60) samples.
        let rest = 64 * (1016 + 964);
        let mut q = p.clone();
        assert!(!finish_if_cheaper(&tiles, &mut q, 1024, rest - 1, u64::MAX));
        assert_eq!(q, p, "dearer than a pass: unchanged");
        assert!(
            !finish_if_cheaper(&tiles, &mut q, 1024, rest, 100),
            "over budget"
        );
        assert!(finish_if_cheaper(&tiles, &mut p, 1024, rest, u64::MAX));
        assert_eq!(p, [1016, 0, 964]);
        // Already every open tile to max_spp (t0 = 0's plan): not an endgame.
        assert!(!finish_if_cheaper(&tiles, &mut p, 1024, rest, u64::MAX));
    }

    #[test]
    fn non_finite_errors_do_not_panic_or_allocate_wildly() {
        let p = plan(
            &[tile(8, f32::NAN, 1.0), tile(8, f32::INFINITY, 0.0)],
            &OPEN,
        );
        assert_eq!(p[0], 0);
        assert_eq!(p[1], 24);
    }
}
