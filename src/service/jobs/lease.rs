//! A claimed job's lease (cluster.md "Promises"): heartbeats while it renders, the fence
//! before its files are written, and the reaper every node runs.

use super::{relay, Inner, LiveJob, WRITE_RETRY};
use crate::service::store::{Beat, LeaseToken, News, MAX_LEASE_ATTEMPTS};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

/// Beside a render, until it ends: renews the lease every [`super::Node::heartbeat`]
/// (with the render's progress on a shared database, after its latest frame is in the
/// job folder, so that the progress other nodes read always has its frame), and acts on
/// what the heartbeat learns: a cancel asked on any node stops the render as a user's
/// cancel would; a lost lease stops it and nothing more is written.
pub(super) async fn keep(inner: Arc<Inner>, live: Arc<LiveJob>, token: LeaseToken) {
    let beat = inner.node.heartbeat();
    let shared = inner.store.is_shared();
    let tick = if shared {
        beat.min(relay::FRAME_INTERVAL)
    } else {
        beat
    };
    let mut frames = relay::Written::default();
    let dir = inner.store.attempt_dir(live.id, token);
    let mut last_try = Instant::now();
    let mut last_held = Instant::now();
    loop {
        tokio::time::sleep(tick).await;
        let snap = live.snapshot();
        if snap.job.state.is_finished() {
            return;
        }
        let mut progress = None;
        if shared {
            if let Some(lf) = snap.frame.clone() {
                progress = frames.write(&dir, live.id, lf).await;
            }
        }
        drop(snap);
        // Nothing new to tell and the beat not yet due.
        if progress.is_none() && last_try.elapsed() + tick / 2 < beat {
            continue;
        }
        last_try = Instant::now();
        let beat_result = inner
            .store
            .heartbeat(live.id, token, inner.node.lease, progress.as_ref())
            .await;
        match beat_result {
            Ok(Beat::Held { cancel_requested }) => {
                inner.wrote(RENEWING);
                if last_held.elapsed() > 2 * beat {
                    inner
                        .metrics
                        .heartbeats_late
                        .fetch_add(1, Ordering::Relaxed);
                }
                last_held = Instant::now();
                if progress.is_some() {
                    // Its frame is in the job folder: the nodes relaying it read it now.
                    inner.store.announce(News::Progress(live.id)).await;
                }
                if cancel_requested && !live.cancel.is_cancelled() {
                    tracing::info!(id = %live.id, "cancel asked on another node: stopping");
                    live.user_cancelled.store(true, Ordering::SeqCst);
                    live.cancel.cancel();
                }
            }
            Ok(Beat::Lost) => {
                inner.wrote(RENEWING);
                if !live.snapshot().job.state.is_finished() {
                    lost(&inner, &live);
                }
                return;
            }
            // Reported by /healthz on either backend: unrenewed, the lease runs out and
            // the job goes to another attempt.
            Err(e) => inner.write_failed(RENEWING, &e),
        }
    }
}

/// The kinds of writes `/healthz` reports while they fail.
const RENEWING: &str = "renewing a lease";
const REAPING: &str = "reaping expired leases";
const FENCING: &str = "renewing a lease before the final image";

/// The lease is gone: the job was presumed dead and may run elsewhere already.
fn lost(inner: &Inner, live: &LiveJob) {
    tracing::warn!(id = %live.id, "lease lost (presumed dead): stopping the render, writing nothing more");
    inner.metrics.lease_losses.fetch_add(1, Ordering::Relaxed);
    live.lease_lost.store(true, Ordering::SeqCst);
    live.cancel.cancel();
}

/// Before a worker on a shared database writes a job's final files: renews the lease,
/// so that it holds for a whole lease more while the files are written (milliseconds),
/// or finds it lost, and then writes nothing (the files may be another worker's by now;
/// the record would refuse the end anyway, `Store::finish_leased`). Retried while the
/// database is away; false if the lease is lost or the node stops meanwhile. Always
/// true on the embedded store: its one node holds every lease it took.
///
/// A worker paused for longer than a lease between this renewal and its file writes
/// writes them into its own attempt's folder (`Store::attempt_dir`), which its refused
/// end never names: the files of the worker that took over stay the job's.
pub(super) fn fence(inner: &Inner, live: &LiveJob, token: LeaseToken) -> bool {
    if !inner.store.is_shared() {
        return true;
    }
    loop {
        let r = inner.rt.block_on(
            inner
                .store
                .heartbeat(live.id, token, inner.node.lease, None),
        );
        match r {
            Ok(Beat::Held { .. }) => {
                inner.wrote(FENCING);
                return true;
            }
            Ok(Beat::Lost) => {
                inner.wrote(FENCING);
                lost(inner, live);
                return false;
            }
            Err(e) => inner.write_failed(FENCING, &e),
        }
        if inner.shutting_down.load(Ordering::SeqCst) {
            return false;
        }
        std::thread::sleep(WRITE_RETRY);
    }
}

/// The reaper, on every node: each heartbeat period, the running jobs whose lease has
/// expired go back to `queued` (or end `failed` after [`MAX_LEASE_ATTEMPTS`], or
/// `cancelled` if a cancel was asked). Idempotent (`Store::reap`), so any number of
/// nodes may run it at once.
pub(super) async fn reap(inner: Arc<Inner>) {
    let every = inner.node.heartbeat();
    loop {
        tokio::select! {
            () = tokio::time::sleep(every) => {}
            () = inner.stop.cancelled() => return,
        }
        match inner.store.reap(MAX_LEASE_ATTEMPTS).await {
            Ok(r) => {
                inner.wrote(REAPING);
                let total = r.requeued + r.failed + r.cancelled;
                if total > 0 {
                    tracing::warn!(
                        requeued = r.requeued,
                        failed = r.failed,
                        cancelled = r.cancelled,
                        "expired leases reaped (their workers are presumed dead)"
                    );
                    inner
                        .metrics
                        .jobs_reaped
                        .fetch_add(total, Ordering::Relaxed);
                }
                if r.requeued > 0 {
                    inner.wake_workers();
                    inner.store.announce(News::Queued).await;
                }
            }
            // On PostgreSQL the shared database's health is what /healthz's ping says
            // (a failing reaper there is the database's, and every node runs one); on
            // SQLite the store is this node's own disk.
            Err(e) if inner.store.is_shared() => tracing::debug!("reaper: {e}"),
            Err(e) => inner.write_failed(REAPING, &e),
        }
    }
}
