//! The job machinery: a bounded queue, a pool of dedicated worker threads, cancellation,
//! and the state transitions of service-api.md (`queued → running → succeeded | failed |
//! cancelled`, and `running → queued` on a graceful shutdown).
//!
//! Renders never run on the async runtime (tokio docs, "CPU-bound tasks"): each worker is
//! a plain `std::thread` that pops job ids from [`Queue`] and calls
//! [`progressive::render`], which fans out on rayon. The worker talks to the store through
//! `Handle::block_on` (it is not a runtime thread, so that is allowed and cheap).
//!
//! Every running or queued job has a [`LiveJob`] with a `watch` channel holding the latest
//! [`Snapshot`] (job object + latest frame): the WebSocket streams and `GET .../frame`
//! read it; slow readers simply see the newest value (no unbounded buffering).

use super::metrics::Metrics;
use super::store::{self, JobRecord, JobState, Store, StoreError};
use crate::cancel::CancelToken;
use crate::progressive::{self, layers, Frame, RenderOptions};
use crate::scene::{parse_scene, Limits, SceneOrigin};
use crate::tracer::PathTracer;
use bytes::Bytes;
use serde_json::{json, Value};
use std::collections::{HashMap, VecDeque};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::Instant;
use tokio::sync::watch;
use uuid::Uuid;

/// Locks a std mutex, ignoring poisoning: every critical section here leaves the data
/// consistent (plain pushes/pops), and a render panic is caught before it could poison.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

// ---------------------------------------------------------------------------------------
// Queue

/// FIFO of job ids with a capacity for new submissions. Jobs recovered at start-up are
/// pushed regardless of the capacity: they were already accepted with a 201.
pub struct Queue {
    inner: Mutex<QueueInner>,
    ready: Condvar,
    capacity: usize,
}

struct QueueInner {
    items: VecDeque<Uuid>,
    /// Slots promised to submissions between the capacity check and the store insert.
    reserved: usize,
    closed: bool,
}

impl Queue {
    fn new(capacity: usize) -> Self {
        Self {
            inner: Mutex::new(QueueInner {
                items: VecDeque::new(),
                reserved: 0,
                closed: false,
            }),
            ready: Condvar::new(),
            capacity,
        }
    }

    /// Takes a slot if there is room (released by [`Self::push_reserved`] or [`Self::release`]).
    fn try_reserve(&self) -> bool {
        let mut q = lock(&self.inner);
        if q.closed || q.items.len() + q.reserved >= self.capacity {
            return false;
        }
        q.reserved += 1;
        true
    }

    fn release(&self) {
        let mut q = lock(&self.inner);
        q.reserved = q.reserved.saturating_sub(1);
    }

    fn push_reserved(&self, id: Uuid) {
        let mut q = lock(&self.inner);
        q.reserved = q.reserved.saturating_sub(1);
        q.items.push_back(id);
        self.ready.notify_one();
    }

    fn push_force(&self, id: Uuid) {
        lock(&self.inner).items.push_back(id);
        self.ready.notify_one();
    }

    fn remove(&self, id: Uuid) {
        lock(&self.inner).items.retain(|x| *x != id);
    }

    /// Blocks until a job is available; `None` once the queue is closed (shutdown).
    fn pop(&self) -> Option<Uuid> {
        let mut q = lock(&self.inner);
        loop {
            if q.closed {
                return None;
            }
            if let Some(id) = q.items.pop_front() {
                return Some(id);
            }
            q = self.ready.wait(q).unwrap_or_else(PoisonError::into_inner);
        }
    }

    fn close(&self) {
        lock(&self.inner).closed = true;
        self.ready.notify_all();
    }

    /// Jobs waiting for a worker.
    #[must_use]
    pub fn len(&self) -> usize {
        lock(&self.inner).items.len()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

// ---------------------------------------------------------------------------------------
// Live state

/// One frame as the stream serves it. The PNG of the image layer is encoded at most once
/// (lazily, on the blocking pool, only if someone watches) and shared by every watcher.
pub struct LiveFrame {
    pub frame: Frame,
    /// The scene's display exposure, for the `image` layer.
    pub exposure: f32,
    pub progress: Value,
    /// The layers this frame has (`distance` is absent in reference mode).
    pub layers: Vec<&'static str>,
    png: tokio::sync::OnceCell<Bytes>,
}

impl LiveFrame {
    fn new(frame: Frame, exposure: f32, progress: Value) -> Self {
        let layers = layers::LAYERS
            .into_iter()
            .filter(|l| *l != "distance" || frame.distance.is_some())
            .collect();
        Self {
            frame,
            exposure,
            progress,
            layers,
            png: tokio::sync::OnceCell::new(),
        }
    }

    /// The PNG of the image layer, encoded once, off the async runtime.
    pub async fn image_png(self: &Arc<Self>) -> Result<Bytes, String> {
        self.png
            .get_or_try_init(|| {
                let me = Arc::clone(self);
                async move {
                    tokio::task::spawn_blocking(move || me.encode_layer_blocking("image"))
                        .await
                        .map_err(|e| format!("encoder stopped: {e}"))?
                        .and_then(|o| o.ok_or_else(|| "no image layer".to_owned()))
                        .map(Bytes::from)
                }
            })
            .await
            .cloned()
    }

    /// Encodes one layer as PNG (`None` if the frame lacks it). Blocking.
    pub fn encode_layer_blocking(&self, layer: &str) -> Result<Option<Vec<u8>>, String> {
        layers::encode_layer(&self.frame, layer, self.exposure).map_err(|e| e.to_string())
    }
}

/// What watchers of a job see: the job object as it is now and the latest frame.
#[derive(Clone)]
pub struct Snapshot {
    pub job: JobRecord,
    pub frame: Option<Arc<LiveFrame>>,
}

/// A job that is queued or running (finished jobs live only in the store).
pub struct LiveJob {
    pub id: Uuid,
    pub cancel: CancelToken,
    /// Set by `POST .../cancel`; a cancel without it is a shutdown (the job is requeued).
    user_cancelled: AtomicBool,
    pub tx: watch::Sender<Arc<Snapshot>>,
}

impl LiveJob {
    fn new(job: JobRecord) -> Arc<Self> {
        let (tx, _rx) = watch::channel(Arc::new(Snapshot {
            job: job.clone(),
            frame: None,
        }));
        Arc::new(Self {
            id: job.id,
            cancel: CancelToken::new(),
            user_cancelled: AtomicBool::new(false),
            tx,
        })
    }

    #[must_use]
    pub fn snapshot(&self) -> Arc<Snapshot> {
        self.tx.borrow().clone()
    }

    fn publish(&self, job: JobRecord, frame: Option<Arc<LiveFrame>>) {
        self.tx.send_replace(Arc::new(Snapshot { job, frame }));
    }
}

// ---------------------------------------------------------------------------------------
// Progress and ETA

/// Estimates the time left from how fast the perceptual error falls.
///
/// Method: the mean perceptual distance between successive frames (`mean_distance` of
/// each iteration, F&P04 §4.2) shrinks roughly geometrically as the mesh refines, and
/// the render is done when it falls below `t0`. We fit `ln d_k = a + b·k` by least squares
/// over the last [`Self::WINDOW`] iterations with `d_k > 0`; if `b < 0` the iterations
/// still needed are `k* − k` with `k* = (ln t0 − a) / b` (capped at `max_iterations`),
/// and the ETA is that count times the mean iteration time so far. The confidence is the
/// fit's R² shrunk by the number of points (`R² · n / (n + 2)`), so two points never
/// claim certainty. Unknown (null) when fewer than two usable iterations, when the error
/// does not fall, or when `t0 = 0` and no pixel rate is known; with `t0 = 0` ("every pixel
/// ends up traced") the estimate instead extrapolates the traced-pixel fraction linearly.
struct EtaTracker {
    t0: f64,
    max_iterations: u32,
    points: Vec<(f64, f64)>,
}

impl EtaTracker {
    const WINDOW: usize = 6;

    fn new(t0: f64, max_iterations: u32) -> Self {
        Self {
            t0,
            max_iterations,
            points: Vec::new(),
        }
    }

    /// Returns `(eta_ms, confidence)`.
    fn update(&mut self, frame: &Frame, elapsed_ms: f64) -> (Option<f64>, Option<f64>) {
        let iterations_done = f64::from(frame.iteration + 1);
        let per_iter_ms = elapsed_ms / iterations_done;
        let d = frame
            .stats
            .per_iteration
            .last()
            .map_or(frame.stats.final_mean_distance, |s| s.mean_distance);
        if d.is_finite() && d > 0.0 {
            self.points.push((f64::from(frame.iteration), d.ln()));
            if self.points.len() > Self::WINDOW {
                self.points.remove(0);
            }
        }
        if frame.last {
            return (Some(0.0), Some(1.0));
        }
        if self.t0 <= 0.0 {
            let f = frame.stats.pixel_fraction;
            if f > 0.0 && f < 1.0 {
                return (Some(elapsed_ms * (1.0 - f) / f), Some(0.5));
            }
            return (None, None);
        }
        let n = self.points.len();
        if n < 2 {
            return (None, None);
        }
        let nf = n as f64;
        let (sx, sy) = self
            .points
            .iter()
            .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
        let (mx, my) = (sx / nf, sy / nf);
        let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
        for (x, y) in &self.points {
            sxx += (x - mx) * (x - mx);
            sxy += (x - mx) * (y - my);
            syy += (y - my) * (y - my);
        }
        if sxx <= 0.0 {
            return (None, None);
        }
        let b = sxy / sxx;
        let a = my - b * mx;
        if b >= 0.0 {
            return (None, None);
        }
        let k_now = f64::from(frame.iteration);
        // Iterations are numbered from 0, so the last possible one is max_iterations − 1.
        let k_last = f64::from(self.max_iterations.saturating_sub(1));
        let k_star = ((self.t0.ln() - a) / b).min(k_last);
        let remaining = (k_star - k_now).max(1.0);
        let r2 = if syy > 0.0 {
            (sxy * sxy / (sxx * syy)).clamp(0.0, 1.0)
        } else {
            1.0
        };
        (Some(remaining * per_iter_ms), Some(r2 * nf / (nf + 2.0)))
    }
}

fn progress_json(frame: &Frame, elapsed_ms: f64, eta: (Option<f64>, Option<f64>)) -> Value {
    json!({
        "iteration": frame.iteration,
        "pixels_traced": frame.stats.pixels_traced,
        "pixel_fraction": frame.stats.pixel_fraction,
        "elapsed_ms": elapsed_ms.round() as u64,
        "mean_distance": finite_or_null(frame.stats.final_mean_distance),
        "eta_ms": eta.0.map(|v| v.round() as u64),
        "eta_confidence": eta.1,
    })
}

fn finite_or_null(v: f64) -> Value {
    if v.is_finite() {
        json!(v)
    } else {
        Value::Null
    }
}

// ---------------------------------------------------------------------------------------
// The manager

/// Why a submission was refused.
#[derive(Debug, thiserror::Error)]
pub enum SubmitError {
    #[error("the queue is full ({0} jobs waiting)")]
    QueueFull(usize),
    #[error("the server is shutting down")]
    ShuttingDown,
    #[error(transparent)]
    Store(#[from] StoreError),
}

pub enum CancelOutcome {
    NotFound,
    AlreadyFinished(JobRecord),
    Accepted(JobRecord),
}

pub enum DeleteOutcome {
    NotFound,
    NotFinished(Box<JobRecord>),
    Deleted,
}

/// How a worker renders a validated scene. The service always uses [`render_scene`];
/// unit tests substitute renderers that panic or block, to test the job boundary.
pub type RenderFn = fn(
    &crate::scene::Scene,
    &mut dyn FnMut(&Frame),
    &CancelToken,
) -> Result<Frame, crate::cancel::Cancelled>;

/// The production renderer: the path tracer under the progressive loop.
pub fn render_scene(
    scene: &crate::scene::Scene,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, crate::cancel::Cancelled> {
    let tracer = PathTracer::new(scene);
    progressive::render(scene, &tracer, &RenderOptions::default(), on_frame, cancel)
}

struct Inner {
    store: Store,
    render: RenderFn,
    limits: Limits,
    queue: Queue,
    live: Mutex<HashMap<Uuid, Arc<LiveJob>>>,
    metrics: Arc<Metrics>,
    rt: tokio::runtime::Handle,
    shutting_down: AtomicBool,
    workers: Mutex<Vec<std::thread::JoinHandle<()>>>,
}

/// Handle to the job machinery (cheap to clone; shared by every request handler).
#[derive(Clone)]
pub struct Jobs {
    inner: Arc<Inner>,
}

impl Jobs {
    /// Recovers the store (service-api.md "Durability"), then starts `workers` threads.
    /// Must be called from inside the tokio runtime.
    pub async fn start(
        store: Store,
        limits: Limits,
        workers: usize,
        queue_capacity: usize,
        metrics: Arc<Metrics>,
    ) -> Result<Self, StoreError> {
        Self::start_with(
            store,
            limits,
            workers,
            queue_capacity,
            metrics,
            render_scene,
        )
        .await
    }

    /// [`Self::start`] with another renderer (tests).
    pub async fn start_with(
        store: Store,
        limits: Limits,
        workers: usize,
        queue_capacity: usize,
        metrics: Arc<Metrics>,
        render: RenderFn,
    ) -> Result<Self, StoreError> {
        let recovered = store.recover().await?;
        let inner = Arc::new(Inner {
            store: store.clone(),
            render,
            limits,
            queue: Queue::new(queue_capacity.max(1)),
            live: Mutex::new(HashMap::new()),
            metrics,
            rt: tokio::runtime::Handle::current(),
            shutting_down: AtomicBool::new(false),
            workers: Mutex::new(Vec::new()),
        });
        for id in &recovered {
            if let Some(rec) = store.get(*id).await? {
                lock(&inner.live).insert(*id, LiveJob::new(rec));
                inner.queue.push_force(*id);
            }
        }
        if !recovered.is_empty() {
            tracing::info!(count = recovered.len(), "re-enqueued jobs from the store");
        }
        let mut handles = Vec::new();
        for k in 0..workers.max(1) {
            let inner2 = Arc::clone(&inner);
            let h = std::thread::Builder::new()
                .name(format!("glimpse-worker-{k}"))
                .spawn(move || worker_loop(&inner2))
                .map_err(StoreError::Io)?;
            handles.push(h);
        }
        *lock(&inner.workers) = handles;
        Ok(Self { inner })
    }

    #[must_use]
    pub fn store(&self) -> &Store {
        &self.inner.store
    }

    #[must_use]
    pub fn limits(&self) -> &Limits {
        &self.inner.limits
    }

    #[must_use]
    pub fn queue_depth(&self) -> usize {
        self.inner.queue.len()
    }

    #[must_use]
    pub fn live(&self, id: Uuid) -> Option<Arc<LiveJob>> {
        lock(&self.inner.live).get(&id).cloned()
    }

    /// Accepts a validated document: the record is committed before this returns
    /// (so the caller's 201 is durable), then the job is queued.
    pub async fn submit(&self, name: &str, scene_json: &str) -> Result<JobRecord, SubmitError> {
        let inner = &self.inner;
        if inner.shutting_down.load(Ordering::SeqCst) {
            return Err(SubmitError::ShuttingDown);
        }
        if !inner.queue.try_reserve() {
            return Err(SubmitError::QueueFull(inner.queue.len()));
        }
        let id = Uuid::now_v7();
        let rec = match inner.store.insert(id, name, scene_json).await {
            Ok(r) => r,
            Err(e) => {
                inner.queue.release();
                return Err(e.into());
            }
        };
        lock(&inner.live).insert(id, LiveJob::new(rec.clone()));
        inner.queue.push_reserved(id);
        inner.metrics.jobs_submitted.fetch_add(1, Ordering::Relaxed);
        // One log line per state transition, keyed by `id` (issue #6, operations).
        tracing::info!(%id, name, state = "queued", "job accepted");
        Ok(rec)
    }

    /// The job as it is now: the live snapshot while queued/running (it carries the
    /// progress), the store otherwise.
    pub async fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        if let Some(live) = self.live(id) {
            return Ok(Some(live.snapshot().job.clone()));
        }
        self.inner.store.get(id).await
    }

    pub async fn list(
        &self,
        state: Option<JobState>,
        limit: u32,
    ) -> Result<Vec<JobRecord>, StoreError> {
        let mut jobs = self.inner.store.list(state, limit).await?;
        // Overlay live progress on running jobs (the store holds it only at the end).
        for j in &mut jobs {
            if j.state == JobState::Running {
                if let Some(live) = self.live(j.id) {
                    let snap = live.snapshot();
                    if snap.job.state == JobState::Running {
                        j.progress = snap.job.progress.clone();
                    }
                }
            }
        }
        Ok(jobs)
    }

    pub async fn cancel(&self, id: Uuid) -> Result<CancelOutcome, StoreError> {
        let Some(rec) = self.get(id).await? else {
            return Ok(CancelOutcome::NotFound);
        };
        if rec.state.is_finished() {
            return Ok(CancelOutcome::AlreadyFinished(rec));
        }
        let live = self.live(id);
        if let Some(l) = &live {
            // Flag first, then the token: the worker reads the flag after seeing the token.
            l.user_cancelled.store(true, Ordering::SeqCst);
            l.cancel.cancel();
        }
        if self.inner.store.cancel_queued(id).await? {
            // It never started: finished now, and its queue slot is free at once.
            self.inner.queue.remove(id);
            tracing::info!(%id, state = "cancelled", ms = 0u64, "job finished (cancelled while queued)");
            let rec = self.inner.store.get(id).await?.unwrap_or(rec);
            if let Some(l) = live {
                l.publish(rec.clone(), None);
            }
            lock(&self.inner.live).remove(&id);
            return Ok(CancelOutcome::Accepted(rec));
        }
        // Running: the worker sees the token between pixel batches and finishes the job
        // as `cancelled`, keeping its latest frame.
        Ok(CancelOutcome::Accepted(self.get(id).await?.unwrap_or(rec)))
    }

    pub async fn delete(&self, id: Uuid) -> Result<DeleteOutcome, StoreError> {
        let Some(rec) = self.get(id).await? else {
            return Ok(DeleteOutcome::NotFound);
        };
        if !rec.state.is_finished() {
            return Ok(DeleteOutcome::NotFinished(Box::new(rec)));
        }
        if self.inner.store.delete_finished(id).await? {
            Ok(DeleteOutcome::Deleted)
        } else {
            Ok(DeleteOutcome::NotFound)
        }
    }

    /// Graceful stop, in this order: refuse new submissions; close the queue so idle
    /// workers exit; cancel running renders (they stop at the next pixel batch and their
    /// jobs go back to `queued` in the store, to run again after a restart); join the
    /// workers; close the database.
    pub async fn shutdown(&self) {
        let inner = &self.inner;
        inner.shutting_down.store(true, Ordering::SeqCst);
        inner.queue.close();
        for l in lock(&inner.live).values() {
            l.cancel.cancel();
        }
        let handles = std::mem::take(&mut *lock(&inner.workers));
        let _ = tokio::task::spawn_blocking(move || {
            for h in handles {
                let _ = h.join();
            }
        })
        .await;
        inner.store.close().await;
    }
}

// ---------------------------------------------------------------------------------------
// Workers

fn worker_loop(inner: &Arc<Inner>) {
    while let Some(id) = inner.queue.pop() {
        let Some(live) = lock(&inner.live).get(&id).cloned() else {
            continue;
        };
        if live.cancel.is_cancelled() {
            continue; // cancelled while queued (the store already says so)
        }
        let started = match inner.rt.block_on(inner.store.mark_running(id)) {
            Ok(Some(s)) => s,
            Ok(None) => continue,
            Err(e) => {
                tracing::error!(%id, "cannot start job: {e}");
                continue;
            }
        };
        let mut job = live.snapshot().job.clone();
        job.state = JobState::Running;
        job.started_at = Some(started);
        live.publish(job.clone(), None);
        tracing::info!(%id, state = "running", "job started");
        inner.metrics.jobs_running.fetch_add(1, Ordering::Relaxed);
        run_job(inner, &live, job);
        inner.metrics.jobs_running.fetch_sub(1, Ordering::Relaxed);
        lock(&inner.live).remove(&id);
    }
}

enum Outcome {
    Done(Box<Frame>),
    Cancelled,
    Failed(Value),
}

fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic".to_owned()
    }
}

fn run_job(inner: &Arc<Inner>, live: &Arc<LiveJob>, mut job: JobRecord) {
    let id = live.id;
    let start = Instant::now();
    let scene_json = match inner.rt.block_on(inner.store.scene(id)) {
        Ok(Some(s)) => s,
        Ok(None) => return, // deleted under us: nothing to run
        Err(e) => {
            tracing::error!(%id, "cannot read scene: {e}");
            return;
        }
    };
    let mut latest: Option<Arc<LiveFrame>> = None;
    let mut exposure = 1.0f32;
    let mut last_pixels = 0u64;
    // Render time is counted as it passes (per frame), so the counter moves during long jobs.
    let mut counted_s = 0.0f64;
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        let scene = match parse_scene(&scene_json, &SceneOrigin::Request, &inner.limits) {
            Ok(s) => s,
            Err(e) => {
                // Accepted earlier, refused now (limits changed across a restart).
                return Outcome::Failed(json!({"code": "invalid_scene", "message": e.to_string()}));
            }
        };
        exposure = scene.display.exposure;
        let mut eta = EtaTracker::new(
            f64::from(scene.progressive.t0),
            scene.progressive.max_iterations,
        );
        let mut on_frame = |f: &Frame| {
            let elapsed = start.elapsed().as_secs_f64() * 1e3;
            let progress = progress_json(f, elapsed, eta.update(f, elapsed));
            inner.metrics.pixels_traced.fetch_add(
                f.stats.pixels_traced.saturating_sub(last_pixels),
                Ordering::Relaxed,
            );
            last_pixels = last_pixels.max(f.stats.pixels_traced);
            let now_s = elapsed / 1e3;
            inner.metrics.add_render_seconds(now_s - counted_s);
            counted_s = now_s;
            let lf = Arc::new(LiveFrame::new(f.clone(), exposure, progress.clone()));
            latest = Some(Arc::clone(&lf));
            let mut j = job.clone();
            j.progress = Some(progress);
            live.publish(j, Some(lf));
        };
        match (inner.render)(&scene, &mut on_frame, &live.cancel) {
            Ok(f) => Outcome::Done(Box::new(f)),
            Err(_) => Outcome::Cancelled,
        }
    }));
    let outcome = outcome.unwrap_or_else(|p| {
        let msg = panic_message(p.as_ref());
        tracing::error!(%id, "render panicked: {msg}");
        Outcome::Failed(
            json!({"code": "render_failed", "message": format!("the render failed: {msg}")}),
        )
    });
    inner
        .metrics
        .add_render_seconds(start.elapsed().as_secs_f64() - counted_s);

    let (state, stats, error, final_frame) = match outcome {
        Outcome::Done(f) => {
            let stats = serde_json::to_value(&f.stats).ok();
            let elapsed = start.elapsed().as_secs_f64() * 1e3;
            let progress = progress_json(&f, elapsed, (Some(0.0), Some(1.0)));
            let lf = match latest.take() {
                // The callback already saw this final frame: reuse it (and its PNG).
                Some(l) if l.frame.iteration == f.iteration && l.frame.last => l,
                _ => Arc::new(LiveFrame::new(*f, exposure, progress)),
            };
            (JobState::Succeeded, stats, None, Some(lf))
        }
        Outcome::Cancelled => {
            if !live.user_cancelled.load(Ordering::SeqCst) {
                // Shutdown, not a user: back to `queued`, to run again from the start.
                if let Err(e) = inner.rt.block_on(inner.store.requeue(id)) {
                    tracing::error!(%id, "cannot requeue job: {e}");
                }
                tracing::info!(%id, state = "queued", "job requeued (shutdown)");
                return;
            }
            (JobState::Cancelled, None, None, latest.take())
        }
        Outcome::Failed(err) => (JobState::Failed, None, Some(err), latest.take()),
    };

    // Keep the last frame on disk (latest frame of a cancelled job included).
    let mut has_frame = false;
    if let Some(lf) = &final_frame {
        match save_frame(&inner.store, id, lf) {
            Ok(png) => {
                let _ = lf.png.set(Bytes::from(png));
                has_frame = true;
            }
            Err(e) => tracing::error!(%id, "cannot store the final frame: {e}"),
        }
    }
    let progress = final_frame
        .as_ref()
        .map(|f| f.progress.clone())
        .or_else(|| job.progress.clone());
    match inner.rt.block_on(inner.store.finish(
        id,
        state,
        progress.as_ref(),
        stats.as_ref(),
        error.as_ref(),
        has_frame,
    )) {
        Ok(finished) => job.finished_at = Some(finished),
        Err(e) => tracing::error!(%id, "cannot record the end of the job: {e}"),
    }
    tracing::info!(
        %id,
        state = state.as_str(),
        ms = u64::try_from(start.elapsed().as_millis()).unwrap_or(u64::MAX),
        "job finished"
    );
    job.state = state;
    job.progress = progress;
    job.stats = stats;
    job.error = error;
    job.has_frame = has_frame;
    live.publish(job, final_frame);
}

/// Encodes every layer and the EXR and writes them under `jobs/<id>/`; returns the PNG of
/// the image layer (reused by the streams). The encodings are independent and run in
/// parallel: they sit between the end of the render and the job's `done`.
fn save_frame(store: &Store, id: Uuid, lf: &LiveFrame) -> Result<Vec<u8>, String> {
    use rayon::prelude::*;
    let encoded: Vec<(String, Vec<u8>)> = layers::LAYERS
        .par_iter()
        .map(|&layer| Some(layer))
        .chain(rayon::iter::once(None)) // None: the EXR
        .map(|layer| -> Result<Option<(String, Vec<u8>)>, String> {
            let Some(layer) = layer else {
                let exr = crate::raster::encode_exr(&lf.frame.image).map_err(|e| e.to_string())?;
                return Ok(Some(("image.exr".to_owned(), exr)));
            };
            let png = match lf.png.get() {
                Some(b) if layer == "image" => Some(b.to_vec()),
                _ => lf.encode_layer_blocking(layer)?,
            };
            Ok(png.map(|p| (format!("{layer}.png"), p)))
        })
        .collect::<Result<Vec<_>, String>>()?
        .into_iter()
        .flatten()
        .collect();
    store::write_files_blocking(&store.job_dir(id), &encoded).map_err(|e| e.to_string())?;
    encoded
        .into_iter()
        .find(|(name, _)| name == "image.png")
        .map(|(_, png)| png)
        .ok_or_else(|| "no image layer".to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progressive::{ClassCell, IterationStats, RenderStats, SampleCell};
    use crate::raster::{Image, Rgb};

    fn frame(iteration: u32, d: f64, last: bool) -> Frame {
        Frame {
            iteration,
            image: Image::filled(1, 1, Rgb::ZERO),
            samples: Image::filled(1, 1, SampleCell::New),
            distance: None,
            classes: Image::filled(1, 1, ClassCell::None),
            stats: RenderStats {
                per_iteration: vec![IterationStats {
                    iteration,
                    mean_distance: d,
                    ..Default::default()
                }],
                final_mean_distance: d,
                pixel_fraction: 0.1,
                ..Default::default()
            },
            last,
        }
    }

    #[test]
    fn eta_follows_a_geometric_decay() {
        // d_k = 16 / 2^k reaches t0 = 1 at k = 4; after iteration 2 (3 iterations in
        // 300 ms, 100 ms each) two iterations remain: 200 ms, with a perfect fit.
        let mut t = EtaTracker::new(1.0, 64);
        assert_eq!(t.update(&frame(0, 16.0, false), 100.0), (None, None));
        t.update(&frame(1, 8.0, false), 200.0);
        let (eta, conf) = t.update(&frame(2, 4.0, false), 300.0);
        assert!((eta.unwrap() - 200.0).abs() < 1e-6, "{eta:?}");
        assert!((conf.unwrap() - 0.6).abs() < 1e-9, "{conf:?}"); // R² = 1, n = 3
    }

    #[test]
    fn eta_is_unknown_when_the_error_does_not_fall_and_zero_at_the_end() {
        let mut t = EtaTracker::new(1.0, 64);
        t.update(&frame(0, 4.0, false), 10.0);
        assert_eq!(t.update(&frame(1, 5.0, false), 20.0), (None, None));
        assert_eq!(
            t.update(&frame(2, f64::NAN, true), 30.0),
            (Some(0.0), Some(1.0))
        );
    }

    #[test]
    fn eta_is_capped_by_max_iterations() {
        // Very slow decay: k* would be huge; capped at 10 iterations in all.
        let mut t = EtaTracker::new(1.0, 10);
        t.update(&frame(0, 100.0, false), 10.0);
        let (eta, _) = t.update(&frame(1, 99.0, false), 20.0);
        assert!((eta.unwrap() - 80.0).abs() < 1e-6, "{eta:?}");
    }

    #[test]
    fn queue_refuses_beyond_capacity_and_frees_on_pop() {
        let q = Queue::new(2);
        assert!(q.try_reserve());
        q.push_reserved(Uuid::nil());
        assert!(q.try_reserve());
        assert!(!q.try_reserve(), "one pushed + one reserved = full");
        q.release();
        assert!(q.try_reserve());
        q.push_reserved(Uuid::max());
        assert_eq!(q.pop(), Some(Uuid::nil()));
        assert!(q.try_reserve());
        q.close();
        assert_eq!(q.pop(), None);
    }

    const TINY: &str = r#"{"version": 1, "image": {"width": 4, "height": 3},
        "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40},
        "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}]}"#;

    /// Sends one frame, then panics as a buggy tracer would.
    fn panicking(
        scene: &crate::scene::Scene,
        on_frame: &mut dyn FnMut(&Frame),
        _cancel: &CancelToken,
    ) -> Result<Frame, crate::cancel::Cancelled> {
        let mut f = frame(0, 2.0, false);
        f.image = Image::filled(scene.width, scene.height, Rgb::splat(0.5));
        f.samples = Image::filled(scene.width, scene.height, SampleCell::New);
        f.classes = Image::filled(scene.width, scene.height, ClassCell::None);
        on_frame(&f);
        panic!("boom in the tracer");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_panicking_render_fails_the_job_keeps_its_frame_and_the_worker_lives_on() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).await.unwrap();
        let jobs = Jobs::start_with(
            store,
            crate::service::server_limits(),
            1,
            4,
            Arc::new(Metrics::default()),
            panicking,
        )
        .await
        .unwrap();
        let a = jobs.submit("a", TINY).await.unwrap().id;
        let b = jobs.submit("b", TINY).await.unwrap().id;
        for id in [a, b] {
            let deadline = Instant::now() + std::time::Duration::from_secs(10);
            let j = loop {
                let j = jobs.get(id).await.unwrap().unwrap();
                if j.state.is_finished() {
                    break j;
                }
                assert!(Instant::now() < deadline, "job never finished");
                tokio::time::sleep(std::time::Duration::from_millis(5)).await;
            };
            // The second job also ran: the worker survived the first panic.
            assert_eq!(j.state, JobState::Failed);
            let err = j.error.unwrap();
            assert_eq!(err["code"], "render_failed");
            assert!(
                err["message"]
                    .as_str()
                    .unwrap()
                    .contains("boom in the tracer"),
                "{err}"
            );
            assert!(j.has_frame && j.finished_at.is_some());
            let png = std::fs::read(jobs.store().layer_path(id, "image", false).unwrap()).unwrap();
            assert_eq!(crate::raster::decode_image(&png).unwrap().width(), 4);
        }
        jobs.shutdown().await;
    }
}
