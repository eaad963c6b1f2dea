//! Frames across nodes (cluster.md: "a watcher connected to any API node sees the frames
//! of a job rendered on any worker, latest first, without the database growing with every
//! frame"). The job folder is on storage every node reaches (`--data`, README "Running a
//! cluster"), so:
//!
//! - the worker writes the image layer of its latest frame to `live-<iteration>.png` in
//!   the job's folder at most every [`FRAME_INTERVAL`], then stores that frame's progress
//!   with its heartbeat (one row per job, updated in place); it keeps the previous file
//!   too (a reader may have just read the progress naming it) and removes the rest;
//! - a node with watchers of a job it does not run follows it here: one task per job
//!   (however many watchers) reads the row every [`POLL`] and, when the progress names a
//!   new iteration, that frame's file, and publishes both on a `watch` channel like a
//!   local render's. When a worker of this node claims the job, the task forwards that
//!   worker's own channel instead.

use super::{lock, Inner, LiveFrame, Snapshot};
use crate::service::store::{JobRecord, JobState, Layer, Progress, Store};
use bytes::Bytes;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use uuid::Uuid;

/// A worker relays at most two frames a second: a watcher elsewhere sees the render move,
/// and the encoding costs the worker ~2 % of a core at 512² (measured, README).
pub(crate) const FRAME_INTERVAL: Duration = Duration::from_millis(500);

/// How often a node reads the row of a job it follows for its watchers.
const POLL: Duration = Duration::from_millis(400);

const PREFIX: &str = "live-";

/// A relayed frame's file in the folder of the attempt that renders it
/// (`Store::attempt_dir`).
fn frame_file(dir: &Path, iteration: u32) -> PathBuf {
    dir.join(format!("{PREFIX}{iteration}.png"))
}

/// The relayed frame a queued or running job's stored progress names, if any.
pub(super) fn latest_frame_path(store: &Store, job: &JobRecord) -> Option<PathBuf> {
    let p = job
        .progress
        .as_ref()
        .filter(|_| job.state == JobState::Running)?;
    Some(frame_file(&store.files_dir(job), p.iteration))
}

/// Removes a finished job's relayed frames (best effort: a file left over is removed
/// with its folder).
pub(super) fn remove_frames(dir: &std::path::Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        if e.file_name().to_string_lossy().starts_with(PREFIX) {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// The frames a worker has relayed for its job.
#[derive(Default)]
pub(super) struct Written {
    /// Iterations written, oldest first (at most two kept).
    iterations: Vec<u32>,
}

impl Written {
    /// Writes `lf` to the attempt's folder `dir` unless it is already there; the progress
    /// to store with the next heartbeat if it was written.
    pub(super) async fn write(
        &mut self,
        dir: &Path,
        id: Uuid,
        lf: Arc<LiveFrame>,
    ) -> Option<Progress> {
        if self.iterations.last() == Some(&lf.iteration) {
            return None;
        }
        let png = lf.image_png().await.ok()?;
        let path = frame_file(dir, lf.iteration);
        let write = tokio::task::spawn_blocking(move || write_atomically(&path, &png)).await;
        if let Ok(Err(e)) | Err(e) = write.map_err(std::io::Error::other) {
            tracing::warn!(%id, "cannot relay a frame: {e}");
            return None;
        }
        self.iterations.push(lf.iteration);
        if self.iterations.len() > 2 {
            let old = self.iterations.remove(0);
            let _ = tokio::fs::remove_file(frame_file(dir, old)).await;
        }
        Some(lf.progress.clone())
    }
}

/// Temporary file and rename: a reader sees the whole frame or none. Not synced: a
/// relayed frame is worth nothing after a crash.
fn write_atomically(path: &std::path::Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(path);
    std::fs::create_dir_all(dir)?;
    let tmp = dir.join(format!(".{}.tmp", Uuid::now_v7().simple()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

/// A channel of `job`'s snapshots for a watcher on this node, which does not run it:
/// the one this node already relays, or a new relay.
pub(super) fn follow(inner: &Arc<Inner>, job: JobRecord) -> watch::Receiver<Arc<Snapshot>> {
    let mut relays = lock(&inner.relays);
    if let Some(tx) = relays.get(&job.id) {
        return tx.subscribe();
    }
    let (tx, rx) = watch::channel(Arc::new(Snapshot {
        job: job.clone(),
        frame: None,
    }));
    relays.insert(job.id, tx.clone());
    tokio::spawn(run(Arc::clone(inner), job, tx));
    rx
}

/// One job's relay, until it is finished, deleted, or nobody watches it.
async fn run(inner: Arc<Inner>, mut job: JobRecord, tx: watch::Sender<Arc<Snapshot>>) {
    let id = job.id;
    let mut claimed = inner.claimed.subscribe();
    let mut progressed = inner.progressed.subscribe();
    let mut frame: Option<Arc<LiveFrame>> = None;
    loop {
        if let Some(live) = inner.live(id) {
            let rx = live.tx.subscribe();
            drop(live);
            if forward(&tx, rx).await {
                break;
            }
        } else {
            match inner.store.get(id).await {
                Ok(Some(now)) if now.state.is_finished() => {
                    let frame = final_frame(&inner, &now).await;
                    tx.send_replace(Arc::new(Snapshot { job: now, frame }));
                    break;
                }
                Ok(Some(now)) => {
                    let fresh = new_frame(&inner, &now, frame.as_ref()).await;
                    if fresh.is_some() || differs(&job, &now) {
                        frame = fresh.or(frame);
                        tx.send_replace(Arc::new(Snapshot {
                            job: now.clone(),
                            frame: frame.clone(),
                        }));
                    }
                    job = now;
                }
                Ok(None) => break, // deleted
                Err(e) => tracing::debug!(%id, "relay: {e}"),
            }
        }
        {
            // Under the map's lock: a watcher arriving now either subscribed before this
            // check or finds no relay and starts a new one.
            let mut relays = lock(&inner.relays);
            if tx.receiver_count() == 0 {
                relays.remove(&id);
                return;
            }
        }
        tokio::select! {
            () = tokio::time::sleep(POLL) => {}
            _ = claimed.changed() => {}
            () = announced(&mut progressed, id) => {}
            () = inner.stop.cancelled() => break,
        }
    }
    let mut relays = lock(&inner.relays);
    if relays.get(&id).is_some_and(|t| t.same_channel(&tx)) {
        relays.remove(&id);
    }
}

/// Returns once another node announces progress of job `id` (`store::News`), or
/// announcements were missed (the relay then reads the store anyway).
async fn announced(rx: &mut tokio::sync::broadcast::Receiver<Uuid>, id: Uuid) {
    loop {
        match rx.recv().await {
            Ok(of) if of == id => return,
            Ok(_) => {}
            Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => return,
            // The node stops: the relay's other branches end it.
            Err(tokio::sync::broadcast::error::RecvError::Closed) => {
                std::future::pending::<()>().await;
            }
        }
    }
}

/// Forwards a local worker's snapshots until the job is finished (true) or the worker
/// lets go of it or nobody watches (false).
async fn forward(
    tx: &watch::Sender<Arc<Snapshot>>,
    mut rx: watch::Receiver<Arc<Snapshot>>,
) -> bool {
    loop {
        let snap = rx.borrow_and_update().clone();
        let finished = snap.job.state.is_finished();
        tx.send_replace(snap);
        if finished {
            return true;
        }
        tokio::select! {
            r = rx.changed() => if r.is_err() { return false },
            () = tx.closed() => return false,
        }
    }
}

/// What a watcher would see change: the state, the attempt, the worker, the progress.
fn differs(a: &JobRecord, b: &JobRecord) -> bool {
    a.state != b.state || a.attempt != b.attempt || a.worker != b.worker || a.progress != b.progress
}

/// The relayed frame `job`'s progress names, if it is newer than `shown` and its file
/// is there.
async fn new_frame(
    inner: &Inner,
    job: &JobRecord,
    shown: Option<&Arc<LiveFrame>>,
) -> Option<Arc<LiveFrame>> {
    let progress = job.progress.clone()?;
    if shown.is_some_and(|f| f.iteration == progress.iteration) {
        return None;
    }
    let path = latest_frame_path(&inner.store, job)?;
    let png = tokio::fs::read(&path).await.ok()?;
    Some(Arc::new(LiveFrame::relayed(
        progress,
        Bytes::from(png),
        vec![Layer::Image],
        Arc::clone(&inner.metrics),
    )))
}

/// A finished job's stored final image, as the last frame of its relay.
async fn final_frame(inner: &Inner, job: &JobRecord) -> Option<Arc<LiveFrame>> {
    if !job.has_frame {
        return None;
    }
    let progress = job.progress.clone()?;
    let png = tokio::fs::read(inner.store.layer_path(job, Layer::Image, false))
        .await
        .ok()?;
    let mut layers = Vec::new();
    for l in Layer::ALL {
        if tokio::fs::try_exists(inner.store.layer_path(job, l, false))
            .await
            .unwrap_or(false)
        {
            layers.push(l);
        }
    }
    Some(Arc::new(LiveFrame::relayed(
        progress,
        Bytes::from(png),
        layers,
        Arc::clone(&inner.metrics),
    )))
}
