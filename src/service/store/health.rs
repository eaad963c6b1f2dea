//! Which kinds of store and job-file writes are failing now (a full or unwritable disk),
//! for `/healthz` and the logs.
//!
//! Kept per kind of write ("storing a final image", "storing a new job", …) rather than
//! as "the last write failed": when only some writes fail (a quota on the job files, a
//! database that refuses one statement), a successful write of another kind says
//! nothing about them. A kind is reported until a write of that kind succeeds, or for
//! [`FAULT_MEMORY`] after its last failure: the writes a worker retries fail again every
//! second for as long as the fault lasts, and a one-off (a refused submission) must not
//! keep the node unhealthy for ever once space is back, when no client may try again
//! because `/healthz` keeps sending them elsewhere.

use std::collections::BTreeMap;
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

/// How long a failed write is reported without a new failure: the `Retry-After` given
/// to clients, so a client that waited as told finds the fault either gone or current.
pub const FAULT_MEMORY: Duration = Duration::from_secs(30);

/// The failing kinds of writes, with their last error and when it happened.
#[derive(Default)]
pub struct WriteFaults(Mutex<BTreeMap<&'static str, (String, Instant)>>);

impl WriteFaults {
    /// A write of kind `what` failed with `error`.
    pub fn failed(&self, what: &'static str, error: &dyn std::fmt::Display) {
        tracing::error!("{what}: {error}");
        let mut m = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        m.insert(what, (error.to_string(), Instant::now()));
    }

    /// A write of kind `what` succeeded.
    pub fn succeeded(&self, what: &'static str) {
        let mut m = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        if m.remove(what).is_some() {
            tracing::info!("{what}: the store is writable again");
        }
    }

    /// The kinds failing now (`what: error`, joined by "; "), or `None`.
    #[must_use]
    pub fn current(&self) -> Option<String> {
        self.at(Instant::now())
    }

    fn at(&self, now: Instant) -> Option<String> {
        let mut m = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        m.retain(|_, (_, at)| now.saturating_duration_since(*at) < FAULT_MEMORY);
        let all: Vec<String> = m.iter().map(|(w, (e, _))| format!("{w}: {e}")).collect();
        (!all.is_empty()).then(|| all.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::{WriteFaults, FAULT_MEMORY};
    use std::time::{Duration, Instant};

    #[test]
    fn a_kind_is_reported_until_it_succeeds_or_its_failure_is_old() {
        let f = WriteFaults::default();
        assert_eq!(f.current(), None);
        f.failed("storing a new job", &"No space left on device");
        f.failed("storing a final image", &"No space left on device");
        // Another kind succeeding says nothing about these.
        f.succeeded("starting a job");
        let now = f.current().unwrap();
        assert!(now.contains("storing a new job: No space"), "{now}");
        assert!(now.contains("storing a final image"), "{now}");
        f.succeeded("storing a final image");
        assert_eq!(
            f.current().as_deref(),
            Some("storing a new job: No space left on device")
        );
        // A one-off failure is forgotten after FAULT_MEMORY.
        let later = Instant::now() + FAULT_MEMORY + Duration::from_millis(1);
        assert_eq!(f.at(later), None);
    }
}
