//! When the loop stops: its own criteria (F&P04 §4.2: every triangle final) and the
//! caller's budgets (pixels, wall time, iterations), as one typed reason.

use std::time::{Duration, Instant};

/// Why a render ended. The statistics carry it as text ([`Stop::as_str`], the API's
/// `stop_reason`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    /// Every pixel is traced: the frame is the reference.
    AllTraced,
    /// No triangle asks for another sample.
    AllFinal,
    /// The triangles still open were traced whole, which cost less than another
    /// iteration (`Plan::finish_if_cheaper`).
    TracedRest,
    /// Every pixel was traced before any of the loop's work: the paths are so cheap here
    /// that the loop's own work would have cost more than the pixels it saves
    /// (`cost::loop_pays`). The frame is the reference.
    ReferenceCheaper,
    MaxPixels,
    MaxTime,
    MaxIterations,
    /// An image one pixel wide or high has no triangle; it is traced whole.
    NoTriangles,
}

impl Stop {
    #[must_use]
    pub fn as_str(self) -> &'static str {
        match self {
            Stop::AllTraced => "all_traced",
            Stop::AllFinal => "all_final",
            Stop::TracedRest => "traced_rest",
            Stop::ReferenceCheaper => "reference_cheaper",
            Stop::MaxPixels => "max_pixels",
            Stop::MaxTime => "max_time",
            Stop::MaxIterations => "max_iterations",
            Stop::NoTriangles => "no_triangles",
        }
    }
}

/// The caller's limits, and which one the tracing ran into.
pub(super) struct Budget {
    max_pixels: Option<u64>,
    max_time: Option<Duration>,
    max_iterations: u32,
    start: Instant,
    hit: Option<Stop>,
}

impl Budget {
    pub(super) fn new(
        max_pixels: Option<u64>,
        max_time: Option<Duration>,
        max_iterations: u32,
        start: Instant,
    ) -> Self {
        Self {
            max_pixels,
            max_time,
            max_iterations,
            start,
            hit: None,
        }
    }

    /// Whether a budget can cut a trace short (otherwise every queued pixel is traced).
    pub(super) fn can_cut(&self) -> bool {
        self.max_pixels.is_some() || self.max_time.is_some()
    }

    pub(super) fn time_up(&self) -> bool {
        self.max_time.is_some_and(|t| self.start.elapsed() >= t)
    }

    /// The head of `list` the pixel budget still allows, `traced` pixels having been
    /// traced; records the hit when it cuts.
    pub(super) fn allow<'l>(&mut self, list: &'l [usize], traced: u64) -> &'l [usize] {
        let Some(max) = self.max_pixels else {
            return list;
        };
        let left = max.saturating_sub(traced) as usize;
        if list.len() >= left {
            self.hit = Some(Stop::MaxPixels);
            return &list[..left];
        }
        list
    }

    /// Records that the time budget stopped a trace.
    pub(super) fn time_hit(&mut self) {
        if self.hit.is_none() {
            self.hit = Some(Stop::MaxTime);
        }
    }

    /// Whether the loop stops after iteration `iter`: the image is complete, a budget was
    /// hit, nothing is left to trace (`idle`), or the time or iteration count is spent.
    pub(super) fn stop(&self, all_traced: bool, idle: bool, iter: u32) -> Option<Stop> {
        if all_traced {
            Some(Stop::AllTraced)
        } else if let Some(hit) = self.hit {
            Some(hit)
        } else if idle {
            Some(Stop::AllFinal)
        } else if self.time_up() {
            Some(Stop::MaxTime)
        } else if iter + 1 >= self.max_iterations {
            Some(Stop::MaxIterations)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pixel_budget_cuts_the_list_and_says_so() {
        let mut b = Budget::new(Some(10), None, 100, Instant::now());
        let list: Vec<usize> = (0..8).collect();
        assert_eq!(b.allow(&list, 0).len(), 8);
        assert_eq!(b.stop(false, false, 0), None);
        assert_eq!(b.allow(&list, 4).len(), 6);
        assert_eq!(b.stop(false, false, 0), Some(Stop::MaxPixels));
        assert_eq!(
            b.stop(true, false, 0),
            Some(Stop::AllTraced),
            "complete wins"
        );
    }

    #[test]
    fn reasons_come_in_order_of_precedence() {
        let b = Budget::new(None, None, 3, Instant::now());
        assert_eq!(b.stop(false, true, 5), Some(Stop::AllFinal));
        assert_eq!(b.stop(false, false, 1), None);
        assert_eq!(b.stop(false, false, 2), Some(Stop::MaxIterations));
        let t = Budget::new(None, Some(Duration::ZERO), 3, Instant::now());
        assert!(t.time_up() && t.can_cut());
        assert_eq!(t.stop(false, false, 0), Some(Stop::MaxTime));
    }

    #[test]
    fn the_time_budget_counts_from_the_renders_start() {
        // What came before the loop (a large image's preview) is part of the user's time.
        let start = Instant::now()
            .checked_sub(Duration::from_millis(50))
            .expect("the clock runs past 50 ms");
        let b = Budget::new(None, Some(Duration::from_millis(20)), 3, start);
        assert!(b.time_up());
        assert_eq!(b.stop(false, false, 0), Some(Stop::MaxTime));
    }
}
