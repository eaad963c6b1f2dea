//! How long a progressive render has left: one estimator for the service's `progress`
//! and the command line's progress bar.
//!
//! Method: the render ends at the first of two events, both extrapolated from the
//! iterations so far.
//! - **Every triangle final.** The mean perceptual distance between successive frames
//!   (`mean_distance` of each iteration, F&P04 §4.2) shrinks roughly geometrically as the
//!   mesh refines, and the render is done about [`TAIL_ITERATIONS`] after the mean falls
//!   below `t0` (the loop stops on each triangle's distance, not on the mean). With two or
//!   more distances we fit `ln d_k = a + b·k` by least squares over the last
//!   [`EtaTracker::WINDOW`] iterations with `d_k > 0`; if `b < 0` the mean reaches t0 at
//!   `k* = (ln t0 − a) / b` (capped at `max_iterations`).
//! - **The endgame.** The untraced pixels of the triangles not final (`open_pixels`) also
//!   shrink geometrically; once they fall to [`endgame_pixels`] the loop traces them all
//!   and ends one iteration later ([`EtaTracker::for_scene`]: `ln open_k` extrapolated
//!   over the last two frames). A render whose mean distance falls slowly (the door) ends
//!   this way, well before `k*`.
//!
//! Later iterations are shorter (fewer triangles are left to refine), so the time left for
//! `n` more iterations is not `n` times an iteration so far but a shrinking series: the
//! mean of the last two iterations' times `τ` times `r + r² + … + rⁿ` with `r` =
//! [`TAIL_RATIO`].
//!
//! Before two distances exist there is no decay to fit, so the first two frames get an
//! estimate from the time so far, honestly wide: after the first frame (no distance yet)
//! [`FIRST_FRAME_FACTOR`] times the time so far; after the second (one distance `d`)
//! [`ONE_DISTANCE_FACTOR`] · elapsed · max(ln(d / t0), ½): the iterations still needed
//! grow as ln(d / t0) (a geometric decay); each within its stage's [`Spread`]. These
//! constants are calibrated on the traces of the bundled scenes and of an 8-scene
//! generated corpus together (`ETA_TRACE=FILE cargo bench --bench eta` writes every frame)
//! and checked on a second corpus (`GLIMPSE_ETA_SEED=2`). With `t0 = 0` ("every pixel
//! ends up traced") the traced-pixel fraction is extrapolated linearly instead.
//!
//! The answer is a range, never a bare number, and a calibrated one: at each stage (first
//! frame, one distance, the fitted decay, a single pixel pass) the middle estimate is
//! widened by that stage's [`Spread`], quantiles of `ln(left / middle)` measured on the
//! bench's recorded runs, so that the range contains the time in fact left in at least
//! 80 % of the bench's cells (`cargo bench --bench eta` prints the coverage). The fit's
//! confidence (R² shrunk by the number of points, `R² · n / (n + 2)`) is reported beside
//! it but no longer sets the width: on the recorded runs it did not tell good fits from
//! bad ones.
//! When the mean distance is predicted below `t0` already (one iteration left), or the loop
//! has planned its last iteration (it traces every open pixel at once,
//! [`IterationStats::finishing`](super::IterationStats)), the answer is [`Eta::Finishing`],
//! so a running render never reads "0 ms left".

use super::driver::endgame_pixels;
use super::Frame;
use crate::scene::Scene;

/// How much shorter each iteration is than the one before, once the loop refines: on the
/// bundled scenes the iterations after the longest take 0.4–0.9 of their predecessor's
/// time (`ETA_TRACE=1 cargo bench --bench eta` prints every frame); 0.8 gave the smallest
/// errors there of 0.5–0.8.
pub const TAIL_RATIO: f64 = 0.8;

/// Iterations after the mean distance falls below t0 (the loop stops when every triangle
/// is final; on the bundled scenes the mean falls from about t0 to near 0 in one more).
pub const TAIL_ITERATIONS: f64 = 1.0;

/// After the first frame (no distance yet), the time left is about this many times the
/// time so far (the loop's runs on the bundled scenes and on generated scenes of two
/// seeds, `ETA_TRACE=FILE cargo bench --bench eta`: 1.8–13, median 5.8; 5 and 6 replayed
/// on those traces did no better).
pub const FIRST_FRAME_FACTOR: f64 = 5.5;

/// After the second frame (one distance `d`), the time left is about this times the time
/// so far times ln(d / t0) (the same traces: 0.3–4.4, median 1.8).
pub const ONE_DISTANCE_FACTOR: f64 = 1.8;

/// How far the time in fact left strays from a middle estimate: `ln(left / middle)` lies
/// in `low..=high` for all but [`SPREAD_TAILS`] of the estimates of the tuning traces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    pub low: f64,
    pub high: f64,
}

/// The share of the tuning set's estimates left outside each stage's [`Spread`] (half below,
/// half above): the largest share (so the narrowest range) for which the range contains
/// the time left in at least 80 % of the cells on the bundled scenes (95.6 %) and on the
/// tuning corpus (81.2 %, against 79.2 % at 0.10). About 12 % of the corpus's cells can
/// never be covered by a range (no frame yet at 25 % of a short run, "finishing" with more
/// than 1.5 iterations left), so the stages' ranges must hold ~92 % of their own cells.
pub const SPREAD_TAILS: f64 = 0.08;

/// After the first frame: the SPREAD_TAILS/2 and 1 − SPREAD_TAILS/2 quantiles of
/// `ln(left / middle)` over the bench's cells (the estimate standing at 25, 50 and 75 % of
/// each run) answered at this stage, on the traces of `ETA_TRACE=FILE
/// GLIMPSE_ETA_CORPUS=32 GLIMPSE_ETA_SEED=1 cargo bench --bench eta` replayed
/// (`ETA_REPLAY=FILE ETA_CELLS=1`): the bundled scenes (9 runs, each weighing 1/9 of a
/// cell) and 32 corpus scenes of seed 1; seed 2 was kept to check. The time so far says
/// little of the rest: the middle runs up to ×4 long.
pub const FIRST_FRAME_SPREAD: Spread = Spread {
    low: -1.43,
    high: 0.34,
};

/// After one distance (or while the distances do not fall yet): the same quantiles. The
/// middle mostly runs short (median `ln(left / middle)` +0.2).
pub const ONE_DISTANCE_SPREAD: Spread = Spread {
    low: -0.40,
    high: 1.35,
};

/// From the fitted decay (two or more distances): the same quantiles. It runs short more
/// than long: late iterations slow down less than [`TAIL_RATIO`] says on some scenes.
pub const FIT_SPREAD: Spread = Spread {
    low: -0.37,
    high: 0.99,
};

/// A single pass over every pixel ([`PassEta`]): the same quantiles (15 cells, so the
/// extremes); the pace since the first report overstates the rest when the first batches
/// are slow.
pub const PASS_SPREAD: Spread = Spread {
    low: -1.03,
    high: 0.39,
};

/// Open pixels are extrapolated over this many iterations (the open area falls fast at
/// first, then slower: the last two say most about the next).
const OPEN_WINDOW: usize = 2;

/// What is known of the time left.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Eta {
    /// Too early to tell (fewer than two usable iterations, or the error does not fall).
    Unknown,
    /// At most about one iteration is left.
    Finishing,
    /// Between `low_ms` and `high_ms` left; `ms` is the central estimate.
    Left {
        ms: f64,
        low_ms: f64,
        high_ms: f64,
        confidence: f64,
    },
    /// The render has ended.
    Done,
}

impl Eta {
    /// A range around `ms` whose half-width shrinks from ±100 % to ±25 % as the
    /// confidence grows from 0 to 1.
    #[must_use]
    pub fn around(ms: f64, confidence: f64) -> Self {
        let c = confidence.clamp(0.0, 1.0);
        let spread = 0.25 + 0.75 * (1.0 - c);
        Self::Left {
            ms,
            low_ms: ms * (1.0 - spread).max(0.0),
            high_ms: ms * (1.0 + spread),
            confidence: c,
        }
    }

    /// Between `low_ms` and `high_ms`, centred on `ms`, for estimates that come from a
    /// calibration rather than a fit (the range is what the calibration saw).
    #[must_use]
    pub fn between(ms: f64, low_ms: f64, high_ms: f64, confidence: f64) -> Self {
        Self::Left {
            ms,
            low_ms: low_ms.min(ms),
            high_ms: high_ms.max(ms),
            confidence: confidence.clamp(0.0, 1.0),
        }
    }

    /// The range `ms · e^low ..= ms · e^high` of a calibrated [`Spread`], widened to
    /// contain `ms` (so low ≤ middle ≤ high) and never below 0.
    #[must_use]
    pub fn spread(ms: f64, spread: Spread, confidence: f64) -> Self {
        let ms = ms.max(0.0);
        Self::Left {
            ms,
            low_ms: ms * spread.low.min(0.0).exp(),
            high_ms: ms * spread.high.max(0.0).exp(),
            confidence: confidence.clamp(0.0, 1.0),
        }
    }

    /// The central estimate in ms, when there is one (`Finishing` and `Done` have none).
    #[must_use]
    pub fn ms(&self) -> Option<f64> {
        match self {
            Self::Left { ms, .. } => Some(*ms),
            _ => None,
        }
    }

    /// In words, for a person: "4.2–6.0 s left", "finishing", "estimating…", "done".
    #[must_use]
    pub fn describe(&self) -> String {
        match self {
            Self::Unknown => "estimating time left…".into(),
            Self::Finishing => "finishing".into(),
            Self::Done => "done".into(),
            Self::Left {
                low_ms, high_ms, ..
            } => {
                format!("{}–{} left", seconds(*low_ms), seconds(*high_ms))
            }
        }
    }
}

/// A duration in words with its unit: "850 ms", "4.2 s", "3 min 10 s".
#[must_use]
pub fn seconds(ms: f64) -> String {
    if ms < 1000.0 {
        format!("{:.0} ms", ms.max(0.0))
    } else if ms < 60_000.0 {
        format!("{:.1} s", ms / 1e3)
    } else {
        let s = (ms / 1e3).round() as u64;
        format!("{} min {} s", s / 60, s % 60)
    }
}

/// The time left of a single pass over every pixel (the reference mode's, or a render
/// traced whole because its paths are too cheap for the loop), told `(done, total)` after
/// each batch from the tracing threads: the rest at the rate since the pass's first report,
/// so that what came before the pass (the probe, the setup) does not count as its pace.
#[derive(Default)]
pub struct PassEta {
    /// (elapsed ms, pixels done) at the first report.
    origin: std::sync::Mutex<Option<(f64, usize)>>,
}

impl PassEta {
    /// The estimate once `done` of `total` pixels are traced, `elapsed_ms` into the render.
    pub fn update(&self, done: usize, total: usize, elapsed_ms: f64) -> Eta {
        if done >= total {
            return Eta::Finishing;
        }
        let mut origin = self
            .origin
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let (ms0, done0) = *origin.get_or_insert((elapsed_ms, done));
        if done <= done0 || elapsed_ms <= ms0 {
            return Eta::Unknown;
        }
        let per_pixel = (elapsed_ms - ms0) / (done - done0) as f64;
        Eta::spread(
            per_pixel * (total - done) as f64,
            PASS_SPREAD,
            done as f64 / total as f64,
        )
    }
}

/// What the estimator reads of a frame: its number, whether it is the preview or the last,
/// and its last iteration's mean distance, open pixels and plan
/// ([`IterationStats`](super::IterationStats)).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Observed {
    pub iteration: u32,
    pub preview: bool,
    pub last: bool,
    /// The last iteration's mean distance (the render's final mean when no iteration ran).
    pub mean_distance: f64,
    pub open_pixels: u64,
    pub finishing: bool,
    pub pixel_fraction: f64,
}

/// Follows one render's frames and estimates the time left after each.
#[derive(Debug)]
pub struct EtaTracker {
    t0: f64,
    max_iterations: u32,
    /// [`endgame_pixels`] of the render, when known.
    endgame: Option<f64>,
    points: Vec<(f64, f64)>,
    /// (iteration, ln open pixels) of the last [`OPEN_WINDOW`] frames.
    open: Vec<(f64, f64)>,
    /// Elapsed time at each frame so far.
    frame_ms: Vec<f64>,
}

impl EtaTracker {
    /// Iterations the decay is fitted over.
    pub const WINDOW: usize = 6;

    /// A tracker that predicts the end from the distances alone.
    #[must_use]
    pub fn new(t0: f64, max_iterations: u32) -> Self {
        Self {
            t0,
            max_iterations,
            endgame: None,
            points: Vec::new(),
            open: Vec::new(),
            frame_ms: Vec::new(),
        }
    }

    /// A tracker for a progressive render of `scene`, which also knows when the loop will
    /// trace what is left at once ([`endgame_pixels`]).
    #[must_use]
    pub fn for_scene(scene: &Scene) -> Self {
        Self::for_render(
            f64::from(scene.progressive.t0),
            scene.progressive.max_iterations,
            u64::from(scene.width) * u64::from(scene.height),
            scene.render.samples_per_pixel,
        )
    }

    /// A tracker for a progressive render of `pixels` pixels at `samples_per_pixel` (what
    /// [`Self::for_scene`] reads off the scene; the bench's replay of recorded traces
    /// builds it from the trace).
    #[must_use]
    pub fn for_render(t0: f64, max_iterations: u32, pixels: u64, samples_per_pixel: u32) -> Self {
        Self {
            endgame: Some(endgame_pixels(pixels, samples_per_pixel)),
            ..Self::new(t0, max_iterations)
        }
    }

    /// The estimate after `frame`, `elapsed_ms` into the render.
    pub fn update(&mut self, frame: &Frame, elapsed_ms: f64) -> Eta {
        let last = frame.stats.per_iteration.last();
        self.observe(
            &Observed {
                iteration: frame.iteration,
                preview: frame.preview,
                last: frame.last,
                mean_distance: last.map_or(frame.stats.final_mean_distance, |s| s.mean_distance),
                open_pixels: last.map_or(0, |s| s.open_pixels),
                finishing: last.is_some_and(|s| s.finishing),
                pixel_fraction: frame.stats.pixel_fraction,
            },
            elapsed_ms,
        )
    }

    /// The estimate after a frame of which only what the estimator reads is known (a
    /// recorded trace replayed), `elapsed_ms` into the render.
    pub fn observe(&mut self, frame: &Observed, elapsed_ms: f64) -> Eta {
        if frame.preview {
            return Eta::Unknown; // no iteration has run: nothing to extrapolate
        }
        let d = frame.mean_distance;
        if d.is_finite() && d > 0.0 {
            self.points.push((f64::from(frame.iteration), d.ln()));
            if self.points.len() > Self::WINDOW {
                self.points.remove(0);
            }
        }
        if frame.open_pixels > 0 {
            self.open
                .push((f64::from(frame.iteration), (frame.open_pixels as f64).ln()));
            if self.open.len() > OPEN_WINDOW {
                self.open.remove(0);
            }
        }
        self.frame_ms.push(elapsed_ms);
        if frame.last {
            return Eta::Done;
        }
        if frame.finishing {
            // The loop has planned its last iteration: it traces what is left and ends.
            return Eta::Finishing;
        }
        if self.t0 <= 0.0 {
            let f = frame.pixel_fraction;
            if f > 0.0 && f < 1.0 {
                return Eta::around(elapsed_ms * (1.0 - f) / f, 0.5);
            }
            return Eta::Unknown;
        }
        match self.points.len() {
            0 => return before_any_distance(elapsed_ms),
            1 => return after_one_distance(elapsed_ms, self.points[0].1.exp(), self.t0),
            _ => {}
        }
        let Some(fit) = fit_line(&self.points) else {
            return Eta::Unknown;
        };
        if fit.slope >= 0.0 {
            // No decay shows yet (noise between two close distances): the last distance's
            // height above t0 is all there is to go on, as after the second frame.
            let d = self.points[self.points.len() - 1].1.exp();
            return after_one_distance(elapsed_ms, d, self.t0);
        }
        let k_now = f64::from(frame.iteration);
        // Iterations are numbered from 0, so the last possible one is max_iterations − 1.
        let k_last = f64::from(self.max_iterations.saturating_sub(1));
        let k_star = ((self.t0.ln() - fit.intercept) / fit.slope).min(k_last);
        let by_distance = k_star.max(k_now) + TAIL_ITERATIONS;
        let end = match self.endgame_iteration().map(|k| k + 1.0) {
            // The mean is below t0 already, yet the loop goes on until every triangle is
            // final or the open pixels reach the endgame: on generated scenes it ran 2–4
            // more iterations, so the open pixels say when, not the mean.
            Some(endgame) if k_star <= k_now => endgame,
            Some(endgame) => by_distance.min(endgame),
            None => by_distance,
        };
        let remaining = end - k_now;
        if remaining <= 1.0 {
            return Eta::Finishing;
        }
        let n = self.points.len() as f64;
        let series = TAIL_RATIO * (1.0 - TAIL_RATIO.powf(remaining)) / (1.0 - TAIL_RATIO);
        Eta::spread(
            self.recent_iteration_ms() * series,
            FIT_SPREAD,
            fit.r2 * n / (n + 2.0),
        )
    }

    /// The iteration at which the open pixels fall to the endgame's threshold: the loop
    /// then plans to trace them all, and ends one iteration later
    /// ([`crate::progressive::IterationStats::finishing`]). `None` while the open area does
    /// not shrink or the threshold is unknown.
    fn endgame_iteration(&self) -> Option<f64> {
        let threshold = self.endgame.filter(|&e| e >= 1.0)?.ln();
        let fit = fit_line(&self.open).filter(|f| f.slope < 0.0)?;
        Some((threshold - fit.intercept) / fit.slope)
    }

    /// The mean time of the last two iterations (the first one counts from the start).
    fn recent_iteration_ms(&self) -> f64 {
        let t = &self.frame_ms;
        let durations: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(k, &ms)| if k == 0 { ms } else { ms - t[k - 1] })
            .collect();
        let last = &durations[durations.len().saturating_sub(2)..];
        last.iter().sum::<f64>() / last.len().max(1) as f64
    }
}

/// The first frame: no distance yet, so a calibrated multiple of the time so far.
fn before_any_distance(elapsed_ms: f64) -> Eta {
    Eta::spread(FIRST_FRAME_FACTOR * elapsed_ms, FIRST_FRAME_SPREAD, 0.1)
}

/// The second frame: one distance `d`, no decay yet; a calibrated multiple of the time so
/// far, growing with how far `d` is above t0. "Finishing" once `d` is already below it.
fn after_one_distance(elapsed_ms: f64, d: f64, t0: f64) -> Eta {
    let x = (d / t0).ln();
    if !x.is_finite() || x <= 0.0 {
        return Eta::Finishing;
    }
    let ms = ONE_DISTANCE_FACTOR * elapsed_ms * x.max(0.5);
    Eta::spread(ms, ONE_DISTANCE_SPREAD, 0.3)
}

struct Line {
    intercept: f64,
    slope: f64,
    r2: f64,
}

/// Least-squares line through `points`; `None` for fewer than two distinct x.
fn fit_line(points: &[(f64, f64)]) -> Option<Line> {
    if points.len() < 2 {
        return None;
    }
    let n = points.len() as f64;
    let (sx, sy) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let (mx, my) = (sx / n, sy / n);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for (x, y) in points {
        sxx += (x - mx) * (x - mx);
        sxy += (x - mx) * (y - my);
        syy += (y - my) * (y - my);
    }
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    let r2 = if syy > 0.0 {
        (sxy * sxy / (sxx * syy)).clamp(0.0, 1.0)
    } else {
        1.0
    };
    Some(Line {
        intercept: my - slope * mx,
        slope,
        r2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(iteration: u32, d: f64, last: bool) -> Frame {
        Frame::fixture(iteration, d, last)
    }

    #[test]
    fn a_pass_over_every_pixel_goes_at_its_own_pace() {
        let p = PassEta::default();
        // The first report sets the pace's origin: 200 ms went before the pass began.
        assert_eq!(p.update(10, 100, 210.0), Eta::Unknown);
        let Eta::Left {
            ms,
            low_ms,
            high_ms,
            confidence,
        } = p.update(25, 100, 240.0)
        else {
            panic!("a quarter done leaves a time");
        };
        // 15 pixels in 30 ms: the 75 left take 150 ms, not 240 × 3.
        assert!((ms - 150.0).abs() < 1e-9 && (confidence - 0.25).abs() < 1e-12);
        assert!(low_ms < ms && ms < high_ms);
        assert_eq!(p.update(100, 100, 400.0), Eta::Finishing);
    }

    #[test]
    fn says_finishing_once_the_loop_plans_its_last_iteration() {
        // A distance far above t0 would predict many iterations; the plan knows better.
        let mut t = EtaTracker::new(1.0, 64);
        t.update(&frame(0, 40.0, false), 100.0);
        let mut f = frame(1, 30.0, false);
        assert!(matches!(t.update(&f, 200.0), Eta::Left { .. }));
        let mut t = EtaTracker::new(1.0, 64);
        t.update(&frame(0, 40.0, false), 100.0);
        f.stats.per_iteration[0].finishing = true;
        assert_eq!(t.update(&f, 200.0), Eta::Finishing);
    }

    #[test]
    fn follows_a_geometric_decay_as_a_range() {
        // d_k = 16 / 2^k reaches t0 = 1 at k = 4, and the loop ends one iteration later;
        // after iteration 1 (2 iterations of 100 ms) 3 + 1 remain, each 0.8 of the one
        // before: 100·(0.8 + 0.8² + 0.8³ + 0.8⁴) = 236.16 ms; perfect fit, confidence 2/4.
        let mut t = EtaTracker::new(1.0, 64);
        t.update(&frame(0, 16.0, false), 100.0);
        let eta = t.update(&frame(1, 8.0, false), 200.0);
        let Eta::Left {
            ms,
            low_ms,
            high_ms,
            confidence,
        } = eta
        else {
            panic!("{eta:?}")
        };
        assert!((ms - 236.16).abs() < 1e-6, "{eta:?}");
        assert!((confidence - 0.5).abs() < 1e-9, "{eta:?}");
        // The fit's calibrated spread around it.
        assert!(
            (low_ms - 236.16 * FIT_SPREAD.low.exp()).abs() < 1e-6,
            "{eta:?}"
        );
        assert!(
            (high_ms - 236.16 * FIT_SPREAD.high.exp()).abs() < 1e-6,
            "{eta:?}"
        );
        assert_eq!(
            eta.describe(),
            format!(
                "{}–{} left",
                seconds(236.16 * FIT_SPREAD.low.exp()),
                seconds(236.16 * FIT_SPREAD.high.exp())
            )
        );
    }

    #[test]
    fn the_range_contains_the_time_left_of_a_geometric_decay() {
        // d_k = 16 / 2^k against t0 = 1, each iteration 0.8 of the one before (100 ms
        // first): the loop ends at k = 5. Every range contains the time in fact left, is
        // ordered and not negative, and the end reads "finishing", then "done".
        let durations: Vec<f64> = (0..6).map(|k| 100.0 * 0.8f64.powi(k)).collect();
        let total: f64 = durations.iter().sum();
        let mut t = EtaTracker::new(1.0, 64);
        let mut elapsed = 0.0;
        for k in 0..6u32 {
            elapsed += durations[k as usize];
            let eta = t.update(&frame(k, 16.0 / f64::from(1 << k), k == 5), elapsed);
            let left = total - elapsed;
            match (k, eta) {
                (
                    0..=3,
                    Eta::Left {
                        ms,
                        low_ms,
                        high_ms,
                        ..
                    },
                ) => {
                    assert!(
                        0.0 <= low_ms && low_ms <= ms && ms <= high_ms,
                        "{k}: {eta:?}"
                    );
                    // The first frame (one distance) is the calibration's, not this decay's.
                    if k > 0 {
                        assert!(low_ms <= left && left <= high_ms, "{k}: {left} {eta:?}");
                    }
                }
                (4, Eta::Finishing) | (5, Eta::Done) => {}
                _ => panic!("{k}: {eta:?}"),
            }
        }
    }

    #[test]
    fn a_calibrated_spread_contains_its_middle_and_is_never_negative() {
        let e = Eta::spread(
            100.0,
            Spread {
                low: 0.2,
                high: 0.5,
            },
            2.0,
        );
        assert_eq!(
            e,
            Eta::Left {
                ms: 100.0,
                low_ms: 100.0,
                high_ms: 100.0 * 0.5f64.exp(),
                confidence: 1.0
            }
        );
        let e = Eta::spread(-5.0, FIT_SPREAD, 0.5);
        assert!(
            matches!(e, Eta::Left { ms, low_ms, high_ms, .. } if ms == 0.0 && low_ms == 0.0 && high_ms == 0.0)
        );
        for s in [
            FIRST_FRAME_SPREAD,
            ONE_DISTANCE_SPREAD,
            FIT_SPREAD,
            PASS_SPREAD,
        ] {
            assert!(s.low <= 0.0 && 0.0 <= s.high, "{s:?}");
        }
    }

    #[test]
    fn the_first_two_frames_get_a_wide_calibrated_range() {
        // No distance yet: 5.5 times the time so far, within the first frame's spread.
        let mut t = EtaTracker::new(1.0, 64);
        assert_eq!(
            t.update(&frame(0, 0.0, false), 100.0),
            Eta::spread(550.0, FIRST_FRAME_SPREAD, 0.1)
        );
        // One distance of e² JND against t0 = 1: 1.8 · 200 ms · 2 = 720 ms.
        let eta = t.update(&frame(1, std::f64::consts::E.powi(2), false), 200.0);
        assert_eq!(eta, Eta::spread(720.0, ONE_DISTANCE_SPREAD, 0.3));
        assert!((eta.ms().unwrap() - 720.0).abs() < 1e-6, "{eta:?}");
        // A first distance already below t0: the end is near.
        let mut t = EtaTracker::new(1.0, 64);
        t.update(&frame(0, 0.0, false), 100.0);
        assert_eq!(t.update(&frame(1, 0.5, false), 150.0), Eta::Finishing);
    }

    #[test]
    fn a_render_that_reaches_its_endgame_first_ends_there() {
        // The distance halves each iteration from 2^10 (t0 = 1 at k = 10, the end at 11),
        // but the open pixels fall from 64 000 to a quarter each iteration, and the loop
        // traces what is open once it is at most 1 111 (100² px at 9 spp): ln open meets
        // that at k = log₄ 57.6 ≈ 2.92, the render ends one iteration later, so after k = 1
        // about 2.9 iterations remain, not ten.
        let open = |k: u32| 64_000.0 / 4f64.powi(k as i32);
        let at = |k: u32| {
            let mut f = frame(k, 1024.0 / f64::from(1 << k), false);
            f.stats.per_iteration[0].open_pixels = open(k) as u64;
            f
        };
        let mut slow = EtaTracker::new(1.0, 64);
        let mut t = EtaTracker::new(1.0, 64);
        t.endgame = Some(endgame_pixels(100 * 100, 9));
        for tracker in [&mut slow, &mut t] {
            tracker.update(&at(0), 100.0);
        }
        // Two iterations of 100 ms so far, each next one 0.8 of the one before.
        let series = |n: f64| 100.0 * 0.8 * (1.0 - 0.8f64.powf(n)) / 0.2;
        let endgame = (64_000.0f64 / (10_000.0 / 9.0)).ln() / 4f64.ln();
        let eta = t.update(&at(1), 200.0);
        assert!(
            (eta.ms().unwrap() - series(endgame)).abs() < 1e-6,
            "{eta:?}"
        );
        let eta = slow.update(&at(1), 200.0);
        assert!((eta.ms().unwrap() - series(10.0)).abs() < 1e-6, "{eta:?}");
        t.update(&at(2), 300.0);
        assert_eq!(t.update(&at(3), 400.0), Eta::Finishing);
    }

    #[test]
    fn a_mean_below_t0_waits_for_the_open_pixels() {
        // The mean distance is below t0 = 1 from iteration 1, but the open pixels (64 000,
        // then a quarter each iteration) reach the endgame (1 111 px) only at k ≈ 2.92:
        // the render is not finishing after k = 1, it has about 2.9 iterations left.
        let at = |k: u32, d: f64| {
            let mut f = frame(k, d, false);
            f.stats.per_iteration[0].open_pixels = (64_000.0 / 4f64.powi(k as i32)) as u64;
            f
        };
        let mut t = EtaTracker::new(1.0, 64);
        t.endgame = Some(endgame_pixels(100 * 100, 9));
        t.update(&at(0, 1.5), 100.0);
        let eta = t.update(&at(1, 0.8), 200.0);
        let endgame = (64_000.0f64 / (10_000.0 / 9.0)).ln() / 4f64.ln();
        let series = 100.0 * 0.8 * (1.0 - 0.8f64.powf(endgame)) / 0.2;
        assert!((eta.ms().unwrap() - series).abs() < 1e-6, "{eta:?}");
        t.update(&at(2, 0.6), 300.0);
        assert_eq!(t.update(&at(3, 0.5), 400.0), Eta::Finishing);
    }

    #[test]
    fn says_finishing_instead_of_zero_while_running() {
        // The same decay: after iteration 3 (d = 2) two are left; after iteration 4 the
        // mean is at t0 and one is left.
        let mut t = EtaTracker::new(1.0, 64);
        for k in 0..3 {
            t.update(&frame(k, 16.0 / f64::from(1 << k), false), 100.0);
        }
        assert!(t.update(&frame(3, 2.0, false), 400.0).ms().is_some());
        assert_eq!(t.update(&frame(4, 1.0, false), 500.0), Eta::Finishing);
        assert_eq!(Eta::Finishing.describe(), "finishing");
    }

    #[test]
    fn reads_the_last_distance_when_the_error_does_not_fall_and_done_at_the_end() {
        // 4 then 5 JND: no decay to fit, so as after one distance: 1.8 · 20 ms · ln 5.
        let mut t = EtaTracker::new(1.0, 64);
        t.update(&frame(0, 4.0, false), 10.0);
        assert_eq!(
            t.update(&frame(1, 5.0, false), 20.0),
            Eta::spread(1.8 * 20.0 * 5f64.ln(), ONE_DISTANCE_SPREAD, 0.3)
        );
        assert_eq!(t.update(&frame(2, f64::NAN, true), 30.0), Eta::Done);
        // A preview frame: no iteration has run yet.
        let mut f = frame(0, 0.0, false);
        f.preview = true;
        assert_eq!(EtaTracker::new(1.0, 64).update(&f, 5.0), Eta::Unknown);
    }

    #[test]
    fn is_capped_by_max_iterations() {
        // Very slow decay: k* would be huge; capped at 10 iterations in all (k = 9), so
        // 8 + 1 remain after k = 1, the first 0.8 of 10 ms: 10·4·(1 − 0.8⁹).
        let mut t = EtaTracker::new(1.0, 10);
        t.update(&frame(0, 100.0, false), 10.0);
        let eta = t.update(&frame(1, 99.0, false), 20.0);
        let want = 40.0 * (1.0 - 0.8f64.powi(9));
        assert!((eta.ms().unwrap() - want).abs() < 1e-6, "{eta:?}");
    }

    #[test]
    fn durations_read_with_their_unit() {
        assert_eq!(seconds(850.4), "850 ms");
        assert_eq!(seconds(4_240.0), "4.2 s");
        assert_eq!(seconds(190_000.0), "3 min 10 s");
        assert_eq!(seconds(-3.0), "0 ms");
    }
}
