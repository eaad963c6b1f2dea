//! Cooperative cancellation shared by every long computation.
//!
//! Renders run on rayon threads and cannot be aborted from outside; they poll a
//! [`CancelToken`] between batches of pixels, so a cancel ends a render within one batch.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::RecvTimeoutError;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::Duration;

/// A cheap, clonable flag. Cancelling any clone cancels them all.
#[derive(Clone, Debug, Default)]
pub struct CancelToken(Arc<AtomicBool>);

impl CancelToken {
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    #[must_use]
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// Returned by computations that stopped because their token was cancelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

impl CancelToken {
    /// `Err(Cancelled)` if cancelled: `token.check()?` between the phases of a computation.
    pub fn check(&self) -> Result<(), Cancelled> {
        if self.is_cancelled() {
            Err(Cancelled)
        } else {
            Ok(())
        }
    }
}

/// Runs `work`, which cannot stop midway (one library call: the BVH build of a million
/// triangles takes seconds), on a thread of its own and waits for it while polling
/// `cancel`: a cancel returns `Err(Cancelled)` within [`POLL`], and the abandoned work
/// finishes on its thread with its result dropped. At most [`MAX_ABANDONABLE`] such
/// threads run at once, counting abandoned ones (others wait, cancellably, for a slot),
/// so cancelling job after job cannot pile up builds. A panic in `work` is resumed here.
pub fn abandonable<T: Send + 'static>(
    cancel: &CancelToken,
    work: impl FnOnce() -> T + Send + 'static,
) -> Result<T, Cancelled> {
    let slot = Slot::acquire(cancel)?;
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    // Shared so that the work can still run here if no thread can be started.
    let cell = Arc::new(Mutex::new(Some(work)));
    let on_thread = Arc::clone(&cell);
    let spawned = std::thread::Builder::new()
        .name("glimpse-prepare".to_owned())
        .spawn(move || {
            let _slot = slot;
            let work = on_thread
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .take();
            if let Some(work) = work {
                let _ = tx.send(work());
            }
        });
    let Ok(handle) = spawned else {
        // No thread to be had (a process limit): run it here, uncancellable.
        let work = cell.lock().unwrap_or_else(PoisonError::into_inner).take();
        return work.map(|w| w()).ok_or(Cancelled);
    };
    loop {
        match rx.recv_timeout(POLL) {
            Ok(t) => return Ok(t),
            Err(RecvTimeoutError::Timeout) => cancel.check()?,
            Err(RecvTimeoutError::Disconnected) => match handle.join() {
                Err(panic) => std::panic::resume_unwind(panic),
                Ok(()) => return Err(Cancelled),
            },
        }
    }
}

/// How often [`abandonable`] looks at its token.
pub const POLL: Duration = Duration::from_millis(20);

/// Threads [`abandonable`] runs at once: enough for a few workers preparing scenes side
/// by side, few enough that abandoned builds (each up to seconds of one core and the
/// memory of its scene's boxes) cannot crowd out the renders.
pub const MAX_ABANDONABLE: usize = 4;

/// One of [`MAX_ABANDONABLE`] places, given back when dropped (by the work's thread,
/// when the work ends, whether or not anyone still waits for it).
struct Slot;

static SLOTS: Mutex<usize> = Mutex::new(0);
static SLOT_FREED: Condvar = Condvar::new();

impl Slot {
    fn acquire(cancel: &CancelToken) -> Result<Self, Cancelled> {
        let mut used = SLOTS.lock().unwrap_or_else(PoisonError::into_inner);
        while *used >= MAX_ABANDONABLE {
            cancel.check()?;
            used = SLOT_FREED
                .wait_timeout(used, POLL)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
        *used += 1;
        Ok(Self)
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut used = SLOTS.lock().unwrap_or_else(PoisonError::into_inner);
        *used -= 1;
        SLOT_FREED.notify_one();
    }
}

#[cfg(test)]
mod tests {
    use super::{abandonable, CancelToken, Cancelled, MAX_ABANDONABLE};
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    #[test]
    fn work_returns_its_result_or_is_abandoned_at_a_cancel() {
        let never = CancelToken::new();
        assert_eq!(abandonable(&never, || 6 * 7), Ok(42));

        // A cancel during a long piece of work returns within the poll, not at its end;
        // the work still runs to its end on its thread.
        let ran = Arc::new(AtomicUsize::new(0));
        let cancel = CancelToken::new();
        let t = Instant::now();
        let (c2, r2) = (cancel.clone(), Arc::clone(&ran));
        let canceller = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(50));
            c2.cancel();
        });
        let r = abandonable(&cancel, move || {
            std::thread::sleep(Duration::from_millis(600));
            r2.fetch_add(1, Ordering::SeqCst);
        });
        canceller.join().unwrap();
        assert_eq!(r, Err(Cancelled));
        assert!(
            t.elapsed() < Duration::from_millis(400),
            "{:?}",
            t.elapsed()
        );
        assert_eq!(ran.load(Ordering::SeqCst), 0);
        // It ends ~550 ms later; a loaded machine may take longer to schedule it.
        let deadline = Instant::now() + Duration::from_secs(10);
        while ran.load(Ordering::SeqCst) == 0 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(
            ran.load(Ordering::SeqCst),
            1,
            "abandoned work runs to its end"
        );
    }

    #[test]
    fn abandoned_work_holds_its_slot_until_it_ends_and_panics_come_back() {
        // Fill every slot with abandoned work; a cancelled caller then gets no slot.
        let cancelled = CancelToken::new();
        cancelled.cancel();
        let start = Instant::now();
        let busy: Vec<_> = (0..MAX_ABANDONABLE)
            .map(|_| {
                std::thread::spawn(|| {
                    let c = CancelToken::new();
                    let c2 = c.clone();
                    std::thread::spawn(move || {
                        std::thread::sleep(Duration::from_millis(30));
                        c2.cancel();
                    });
                    abandonable(&c, || std::thread::sleep(Duration::from_millis(700)))
                })
            })
            .collect();
        for b in busy {
            assert_eq!(b.join().unwrap(), Err(Cancelled));
        }
        // Other tests may hold slots too; all that matters is that a cancelled caller
        // never waits for one and that the slots come back.
        assert_eq!(abandonable(&cancelled, || ()), Err(Cancelled));
        assert_eq!(abandonable(&CancelToken::new(), || 1), Ok(1));
        assert!(start.elapsed() < Duration::from_secs(5));

        let p = std::panic::catch_unwind(|| abandonable(&CancelToken::new(), || panic!("boom")));
        assert!(p.is_err());
    }
}
