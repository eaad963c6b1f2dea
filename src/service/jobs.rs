//! The job machinery: workers that claim jobs from the store, cancellation, and the
//! state transitions of service-api.md (`queued → running → succeeded | failed |
//! cancelled`, and `running → queued` on a graceful shutdown or a lost worker).
//!
//! The store is the queue (cluster.md): a worker claims the oldest queued job in one
//! statement, under a lease with an attempt token (`store/lease.rs`); [`lease`] keeps
//! that lease with heartbeats (which also bring a cancel asked on any node) and reaps
//! the leases of workers presumed dead. A job is rendered by whichever node claims it, so
//! submitting never hands a job to a worker of this node directly: it wakes them.
//!
//! Renders never run on the async runtime (tokio docs, "CPU-bound tasks"): each worker is
//! a plain `std::thread` that calls [`progressive::render`], which fans out on rayon. The
//! worker talks to the store through `Handle::block_on` (it is not a runtime thread).
//!
//! Every job a worker of this node runs has a [`LiveJob`] with a `watch` channel holding
//! the latest [`Snapshot`] (job object + latest frame): the WebSocket streams and `GET
//! .../frame` read it; slow readers simply see the newest value. Jobs queued or running
//! elsewhere are followed through the store and the shared job folder ([`relay`]).

use super::error_code::ErrorCode;
use super::metrics::{Metrics, StoreCounts};
use super::store::health::WriteFaults;
use super::store::{
    self, JobError, JobRecord, JobState, Layer, LeaseToken, Progress, Store, StoreError,
};
use crate::cancel::CancelToken;
use crate::progressive::eta::{Eta, EtaTracker};
use crate::progressive::memory::MemoryEstimate;
use crate::progressive::{self, Frame, RenderError, RenderOptions};
use crate::scene::{parse_scene, Limits, SceneOrigin};
use crate::tracer::PathTracer;
use bytes::Bytes;
use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};

mod lease;
mod news;
mod relay;
pub use super::live::LiveFrame;
use super::live::OTHER_ENCODINGS;
use std::time::Instant;
use tokio::sync::watch;
use uuid::Uuid;

/// Locks a std mutex, ignoring poisoning: every critical section here leaves the data
/// consistent (plain pushes/pops), and a render panic is caught before it could poison.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

// ---------------------------------------------------------------------------------------
// Live state

/// What watchers of a job see: the job object as it is now and the latest frame.
#[derive(Clone)]
pub struct Snapshot {
    pub job: JobRecord,
    pub frame: Option<Arc<LiveFrame>>,
}

/// A job a worker of this node runs, from its claim until it is finished and its
/// secondary files are written (after that, finished jobs live only in the store).
pub struct LiveJob {
    pub id: Uuid,
    pub cancel: CancelToken,
    /// Set by `POST .../cancel` (on this node, or on any node through the heartbeat); a
    /// cancel without it or `lease_lost` is a shutdown (the job is released).
    user_cancelled: AtomicBool,
    /// Set when the heartbeat finds the lease gone (presumed dead, the job went to
    /// another worker): the render stops and writes nothing more.
    lease_lost: AtomicBool,
    pub tx: watch::Sender<Arc<Snapshot>>,
    /// True once the worker is done with the job, files included (DELETE waits for it,
    /// so it never races the late writes).
    settled: watch::Sender<bool>,
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
            lease_lost: AtomicBool::new(false),
            tx,
            settled: watch::Sender::new(false),
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
// Progress

fn progress_of(frame: &Frame, elapsed_ms: f64, eta: Eta) -> Progress {
    let (low, high, confidence) = match eta {
        Eta::Left {
            low_ms,
            high_ms,
            confidence,
            ..
        } => (Some(low_ms), Some(high_ms), Some(confidence)),
        Eta::Done => (Some(0.0), Some(0.0), Some(1.0)),
        Eta::Unknown | Eta::Finishing => (None, None, None),
    };
    let round = |v: f64| v.round() as u64;
    let d = frame.stats.final_mean_distance;
    Progress {
        iteration: frame.iteration,
        pixels_traced: frame.stats.pixels_traced,
        pixel_fraction: frame.stats.pixel_fraction,
        elapsed_ms: round(elapsed_ms),
        mean_distance: d.is_finite().then_some(d),
        eta_ms: match eta {
            Eta::Done => Some(0),
            _ => eta.ms().map(round),
        },
        eta_low_ms: low.map(round),
        eta_high_ms: high.map(round),
        eta_confidence: confidence,
        finishing: eta == Eta::Finishing,
        denoised: frame.stats.denoised,
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

/// Encoded frame bytes as the jobs API hands them out: a live frame's, shared from
/// memory, or a stored file, to be streamed (never read whole per request: a 4096² EXR is
/// 201 MB).
pub enum FrameBytes {
    Memory(Bytes),
    File(std::path::PathBuf),
}

/// What [`Jobs::frame`] found.
pub enum FrameLookup {
    NotFound,
    /// The job exists but has no frame yet (or ended without one).
    NoFrame,
    /// The frame lacks this layer (`distance` in reference mode, a late file not written).
    NoLayer,
    /// No frame of this iteration is kept; these are (oldest first).
    NoIteration(Vec<u32>),
    EncodingFailed(String),
    Found(FrameBytes),
}

/// A finished job's stored final frame: the image file and the layers stored with it.
pub struct StoredFrame {
    pub image: std::path::PathBuf,
    pub layers: Vec<Layer>,
}

/// One iteration of a job whose frame can be had, and its layers.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct KeptIteration {
    pub iteration: u32,
    pub layers: Vec<Layer>,
}

/// What a stream follows ([`Jobs::watch`]).
pub enum Watch {
    NotFound,
    /// Snapshots of a job not yet finished: its worker's own, or relayed ([`relay`]).
    Live(watch::Receiver<Arc<Snapshot>>),
    Stored(Box<JobRecord>, Option<StoredFrame>),
}

pub enum DeleteOutcome {
    NotFound,
    NotFinished(Box<JobRecord>),
    Deleted,
}

/// How a worker renders a validated scene. The service always uses [`render_scene`];
/// unit tests substitute renderers that panic or block, to test the job boundary.
pub type RenderFn = fn(
    crate::scene::Scene,
    &RenderOptions,
    &mut dyn FnMut(&Frame),
    &CancelToken,
) -> Result<Frame, RenderError>;

/// The production renderer: the path tracer under the progressive loop.
pub fn render_scene(
    mut scene: crate::scene::Scene,
    opts: &RenderOptions,
    on_frame: &mut dyn FnMut(&Frame),
    cancel: &CancelToken,
) -> Result<Frame, RenderError> {
    // Preparing the scene (seconds for the largest mesh a request may hold, a million
    // near-duplicate triangles) stops within a fraction of a second of a cancel.
    let tracer = PathTracer::prepare(&scene, cancel)?;
    // The tracer holds its own copy of every primitive: the scene's triangles (about as
    // many bytes again) go back before the render starts.
    scene.release_geometry();
    crate::service::trim::release_free_memory();
    progressive::render(&scene, &tracer, opts, on_frame, cancel)
}

/// How this node takes part in rendering (cluster.md).
#[derive(Clone, Debug)]
pub struct Node {
    /// The `worker` recorded in the jobs this node claims; `None` on the embedded store,
    /// whose one process is the only node (the job object's `worker` stays null there).
    pub name: Option<String>,
    /// Jobs rendered at once on this node; 0 makes a node that only serves.
    pub workers: usize,
    /// A claimed job's lease: a worker silent for this long is presumed dead and its job
    /// is queued again by any node's reaper.
    pub lease: std::time::Duration,
    /// The memory one job may use, in bytes: a submission that would need more is
    /// refused, and the denoiser's scratch is what a job's own memory leaves of it
    /// ([`crate::progressive::memory`]).
    pub job_memory: u64,
}

/// 10 GB a job: two workers' jobs fit a 24 GiB (25.8 GB) machine with room for the
/// server, the page cache and the database, and the largest image the default limits
/// accept, 4096², fits in every mode with the denoiser (docs/measurements.md "Memory
/// of one job").
pub const DEFAULT_JOB_MEMORY: u64 = 10_000_000_000;

/// 20 s: a worker killed mid-render loses its job to another worker within 20 s (plus
/// one reaper pass); ten heartbeats fit in it, so a database restart of a few seconds
/// costs no lease.
pub const DEFAULT_LEASE: std::time::Duration = std::time::Duration::from_secs(20);

impl Node {
    /// The embedded store's one node with `workers` workers.
    #[must_use]
    pub fn single(workers: usize) -> Self {
        Self {
            name: None,
            workers,
            lease: DEFAULT_LEASE,
            job_memory: DEFAULT_JOB_MEMORY,
        }
    }

    /// How often a running job's lease is renewed (and its cancel flag read), and how
    /// often the reaper looks for expired leases: ten times per lease.
    #[must_use]
    pub fn heartbeat(&self) -> std::time::Duration {
        (self.lease / 10).max(std::time::Duration::from_millis(20))
    }
}

struct Inner {
    store: Store,
    node: Node,
    render: RenderFn,
    limits: Limits,
    /// Queued jobs (in the store, all nodes together) beyond which submissions get 429.
    queue_capacity: usize,
    /// Submissions on this node between their capacity check and their insert, so that
    /// concurrent ones cannot all pass the check.
    reserved: AtomicUsize,
    /// Makes [`Jobs::reserve`]'s count-then-take one step per node. Only the taking is
    /// under it: a reservation is given back at once after the insert, so a committed
    /// job is not counted twice (queued and reserved) while others wait for the count.
    reserving: tokio::sync::Mutex<()>,
    /// The jobs this node's workers run.
    live: Mutex<HashMap<Uuid, Arc<LiveJob>>>,
    /// The jobs this node follows for its watchers without running them ([`relay`]).
    relays: Mutex<HashMap<Uuid, watch::Sender<Arc<Snapshot>>>>,
    /// Bumped by each submission on this node, each reaped lease and shutdown: wakes the
    /// idle workers (jobs submitted on other nodes are found by polling, [`idle_poll`]).
    work: (Mutex<u64>, Condvar),
    /// Bumped each time a worker of this node claims a job: a relay of that job switches
    /// to the worker's own channel at once.
    claimed: watch::Sender<u64>,
    /// The ids of running jobs whose progress another node announced ([`news`]): their
    /// relays read the store at once instead of at their next poll.
    progressed: tokio::sync::broadcast::Sender<Uuid>,
    /// The scene of the latest submission as it was validated, so that the worker which
    /// claims it (usually one of this node's, at once) does not read the document back and
    /// parse it a second time (for an 8 MiB mesh, most of a second). One at most: a
    /// parsed million-triangle mesh is ~100 MB.
    parsed: Mutex<Option<(Uuid, crate::scene::Scene)>>,
    metrics: Arc<Metrics>,
    rt: tokio::runtime::Handle,
    shutting_down: AtomicBool,
    /// Ends the reaper and the relays on shutdown.
    stop: tokio_util::sync::CancellationToken,
    /// A render running longer than this is stopped and its job failed (`timeout`).
    job_timeout: std::time::Duration,
    /// The kinds of store and job-file writes failing now (a full or unwritable disk):
    /// `/healthz` reports them.
    store_faults: WriteFaults,
    /// Jobs whose `DELETE` removed their files but not yet their record.
    deleting: Mutex<std::collections::HashSet<Uuid>>,
    workers: Mutex<Vec<std::thread::JoinHandle<()>>>,
    /// Test hook, called by the worker between a job's `done` and its late file writes
    /// (to hold it there and look at what a crash at that point would leave).
    after_done: Mutex<Option<AfterDoneHook>>,
}

type AfterDoneHook = Arc<dyn Fn(Uuid) + Send + Sync>;

impl Inner {
    fn live(&self, id: Uuid) -> Option<Arc<LiveJob>> {
        lock(&self.live).get(&id).cloned()
    }

    /// Records a failed store or file write (the disk may be full).
    fn write_failed(&self, what: &'static str, e: &dyn std::fmt::Display) {
        self.store_faults.failed(what, e);
    }

    /// A write of kind `what` succeeded: that kind works again.
    fn wrote(&self, what: &'static str) {
        self.store_faults.succeeded(what);
    }

    /// Wakes this node's idle workers: there may be a job to claim.
    fn wake_workers(&self) {
        *lock(&self.work.0) += 1;
        self.work.1.notify_all();
    }

    /// The scene a submission on this node validated for job `id`, if it is still held.
    fn take_parsed(&self, id: Uuid) -> Option<crate::scene::Scene> {
        let mut p = lock(&self.parsed);
        match p.take() {
            Some((pid, scene)) if pid == id => Some(scene),
            other => {
                *p = other;
                None
            }
        }
    }

    /// Runs a blocking `write` until it succeeds, pausing [`WRITE_RETRY`] after each
    /// failure (recorded as the store's fault); false if the server stops meanwhile.
    fn write_until_done<E: std::fmt::Display>(
        &self,
        what: &'static str,
        mut write: impl FnMut() -> Result<(), E>,
    ) -> bool {
        loop {
            match write() {
                Ok(()) => {
                    self.wrote(what);
                    return true;
                }
                Err(e) => self.write_failed(what, &e),
            }
            if self.shutting_down.load(Ordering::SeqCst) {
                return false;
            }
            std::thread::sleep(WRITE_RETRY);
        }
    }
}

/// How long a worker waits before trying a failed store write again: the disk is full or
/// unwritable until an operator acts, so a second is soon enough and costs nothing.
const WRITE_RETRY: std::time::Duration = std::time::Duration::from_secs(1);

/// A render's time limit unless `--job-timeout` says otherwise: the largest job the
/// server takes (a 4096² image at 256 spp, `server_limits`) runs for minutes to an hour.
pub const DEFAULT_JOB_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(2 * 3600);

/// How long `/healthz` waits for the database before it says the node cannot reach it.
const PING_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(2);

/// Handle to the job machinery (cheap to clone; shared by every request handler).
#[derive(Clone)]
pub struct Jobs {
    inner: Arc<Inner>,
}

impl Jobs {
    /// Starts this node's part: on the embedded store, recovers it first (service-api.md
    /// "Durability": this process is its only node, so a job found running was
    /// interrupted by its crash); on a shared database, touches nobody's running jobs
    /// (their workers may be alive: only expired leases are reaped). Then starts the
    /// reaper and `node.workers` worker threads. Must be called inside the tokio runtime.
    pub async fn start(
        store: Store,
        node: Node,
        limits: Limits,
        queue_capacity: usize,
        job_timeout: std::time::Duration,
        metrics: Arc<Metrics>,
    ) -> Result<Self, StoreError> {
        Self::start_with(
            store,
            node,
            limits,
            queue_capacity,
            job_timeout,
            metrics,
            render_scene,
        )
        .await
    }

    /// [`Self::start`] with another renderer (tests).
    pub async fn start_with(
        store: Store,
        node: Node,
        limits: Limits,
        queue_capacity: usize,
        job_timeout: std::time::Duration,
        metrics: Arc<Metrics>,
        render: RenderFn,
    ) -> Result<Self, StoreError> {
        if !store.is_shared() {
            let recovered = store.recover().await?;
            if !recovered.is_empty() {
                tracing::info!(count = recovered.len(), "jobs queued again after a restart");
            }
        }
        let workers = node.workers;
        let inner = Arc::new(Inner {
            store,
            node,
            render,
            limits,
            queue_capacity: queue_capacity.max(1),
            reserved: AtomicUsize::new(0),
            reserving: tokio::sync::Mutex::new(()),
            live: Mutex::new(HashMap::new()),
            relays: Mutex::new(HashMap::new()),
            work: (Mutex::new(0), Condvar::new()),
            claimed: watch::Sender::new(0),
            progressed: tokio::sync::broadcast::Sender::new(64),
            parsed: Mutex::new(None),
            metrics,
            rt: tokio::runtime::Handle::current(),
            shutting_down: AtomicBool::new(false),
            stop: tokio_util::sync::CancellationToken::new(),
            job_timeout,
            store_faults: WriteFaults::default(),
            deleting: Mutex::default(),
            workers: Mutex::new(Vec::new()),
            after_done: Mutex::new(None),
        });
        tokio::spawn(lease::reap(Arc::clone(&inner)));
        tokio::spawn(news::listen(Arc::clone(&inner)));
        let mut handles = Vec::new();
        for k in 0..workers {
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

    /// What is wrong with the store's disk: the kinds of writes failing now.
    #[must_use]
    pub fn store_fault(&self) -> Option<String> {
        self.inner.store_faults.current()
    }

    /// Jobs in the store by state (for `/metrics`).
    pub async fn count_by_state(&self) -> Result<Vec<(JobState, i64)>, StoreError> {
        self.inner.store.count_by_state().await
    }

    /// Does this node reach its database? (`/healthz`; a database that does not answer
    /// within [`PING_TIMEOUT`] counts as unreachable.)
    pub async fn ping_store(&self) -> Result<(), String> {
        match tokio::time::timeout(PING_TIMEOUT, self.inner.store.ping()).await {
            Ok(r) => r.map_err(|e| e.to_string()),
            Err(_) => Err(format!("no answer within {PING_TIMEOUT:?}")),
        }
    }

    /// `sqlite` or `postgres`.
    #[must_use]
    pub fn store_backend(&self) -> &'static str {
        self.inner.store.backend()
    }

    #[must_use]
    pub fn limits(&self) -> &Limits {
        &self.inner.limits
    }

    /// The memory one job may use on this node, in bytes (`--max-job-memory`).
    #[must_use]
    pub fn job_memory(&self) -> u64 {
        self.inner.node.job_memory
    }

    /// Jobs waiting for a worker, all nodes together.
    pub async fn queue_depth(&self) -> Result<i64, StoreError> {
        self.inner.store.queued_count().await
    }

    /// What `/metrics` reads from the store, read now (a store that does not answer
    /// counts nothing rather than failing the scrape).
    pub async fn store_counts(&self) -> StoreCounts {
        StoreCounts {
            by_state: self.count_by_state().await.unwrap_or_default(),
            queue_depth: self.queue_depth().await.unwrap_or_default(),
            node_name: self.node_name().map(str::to_owned),
        }
    }

    /// This node's name in the jobs it claims (`None` on the embedded store).
    #[must_use]
    pub fn node_name(&self) -> Option<&str> {
        self.inner.node.name.as_deref()
    }

    fn live(&self, id: Uuid) -> Option<Arc<LiveJob>> {
        self.inner.live(id)
    }

    /// One layer of a job's latest frame: from memory while a worker of this node runs
    /// it (encoded once per frame and shared by every request,
    /// `LiveFrame::encoded_blocking`), from the frame a worker on another node relayed
    /// (the image layer only, [`relay`]), from its stored file once it is finished. The
    /// one place that decides "live, relayed or stored".
    pub async fn frame(
        &self,
        id: Uuid,
        layer: Layer,
        exr: bool,
    ) -> Result<FrameLookup, StoreError> {
        if let Some(live) = self.live(id) {
            let Some(lf) = live.snapshot().frame.clone() else {
                return Ok(FrameLookup::NoFrame);
            };
            drop(live);
            return Ok(encoded_lookup(lf, layer, exr).await);
        }
        let Some(job) = self.inner.store.get(id).await? else {
            return Ok(FrameLookup::NotFound);
        };
        if !job.state.is_finished() {
            // Queued, or running on another node: its latest relayed frame, image only.
            return Ok(match relay::latest_frame_path(&self.inner.store, &job) {
                Some(path) if layer == Layer::Image && !exr => {
                    match tokio::fs::try_exists(&path).await {
                        Ok(true) => FrameLookup::Found(FrameBytes::File(path)),
                        _ => FrameLookup::NoFrame,
                    }
                }
                Some(_) => FrameLookup::NoLayer,
                None => FrameLookup::NoFrame,
            });
        }
        if !job.has_frame {
            return Ok(FrameLookup::NoFrame);
        }
        self.inner.store.check_files(&job).await?;
        let path = self.inner.store.layer_path(&job, layer, exr);
        Ok(match store::file_present(&path).await {
            Ok(true) => FrameLookup::Found(FrameBytes::File(path)),
            Ok(false) => FrameLookup::NoLayer,
            Err(e) => return Err(e.into()),
        })
    }

    /// One layer of iteration `iteration` of a job: the live frame's if it is that
    /// iteration, a kept earlier iteration's file ([`super::iterations`]), or the
    /// finished job's final frame if it is that iteration.
    pub async fn iteration_frame(
        &self,
        id: Uuid,
        iteration: u32,
        layer: Layer,
    ) -> Result<FrameLookup, StoreError> {
        let live = self.live(id);
        // The live frame itself (not "the latest" looked up again, which may have moved on).
        let live_snap = live.as_ref().map(|l| l.snapshot());
        let live_frame = live_snap.as_ref().and_then(|s| s.frame.clone());
        if let Some(lf) = live_frame.filter(|f| f.iteration == iteration) {
            return Ok(encoded_lookup(lf, layer, false).await);
        }
        let job = match live_snap {
            Some(snap) => snap.job.clone(),
            None => match self.inner.store.get(id).await? {
                Some(job) => {
                    self.inner.store.check_files(&job).await?;
                    job
                }
                None => return Ok(FrameLookup::NotFound),
            },
        };
        let path = store::iteration_path(&self.inner.store.files_dir(&job), iteration, layer);
        if store::file_present(&path).await? {
            return Ok(FrameLookup::Found(FrameBytes::File(path)));
        }
        if live.is_none()
            && job.has_frame
            && job.progress.as_ref().map(|p| p.iteration) == Some(iteration)
        {
            return self.frame(id, layer, false).await;
        }
        let kept = self.iterations(id).await?.unwrap_or_default();
        Ok(if kept.iter().any(|k| k.iteration == iteration) {
            FrameLookup::NoLayer
        } else {
            FrameLookup::NoIteration(kept.iter().map(|k| k.iteration).collect())
        })
    }

    /// The iterations of a job whose frames can be had (`None` if there is no such job):
    /// the kept earlier ones and the latest (live, or the finished job's final frame),
    /// oldest first, each with its layers.
    pub async fn iterations(&self, id: Uuid) -> Result<Option<Vec<KeptIteration>>, StoreError> {
        let (latest, dir) = match self.live(id) {
            Some(live) => {
                let snap = live.snapshot();
                let latest = snap.frame.as_ref().map(|f| (f.iteration, f.layers.clone()));
                (latest, self.inner.store.files_dir(&snap.job))
            }
            None => {
                let Some(job) = self.inner.store.get(id).await? else {
                    return Ok(None);
                };
                self.inner.store.check_files(&job).await?;
                let latest = match (job.has_frame, &job.progress) {
                    (true, Some(p)) => self
                        .stored_frame(&job)
                        .await
                        .map(|f| (p.iteration, f.layers)),
                    _ => None,
                };
                (latest, self.inner.store.files_dir(&job))
            }
        };
        let mut kept = tokio::task::spawn_blocking(move || store::kept_iterations_blocking(&dir))
            .await
            .map_err(|e| std::io::Error::other(e.to_string()))??;
        if let Some((n, layers)) = latest {
            kept.retain(|(k, _)| *k != n);
            kept.push((n, layers));
        }
        Ok(Some(
            kept.into_iter()
                .map(|(iteration, layers)| KeptIteration { iteration, layers })
                .collect(),
        ))
    }

    /// What a stream of job `id` follows: the live snapshots while a worker of this node
    /// runs it (and while its late files are written); while it is queued or runs on
    /// another node, the snapshots this node relays from the store and the job folder;
    /// else the finished record with its stored final frame.
    pub async fn watch(&self, id: Uuid) -> Result<Watch, StoreError> {
        if let Some(live) = self.live(id) {
            return Ok(Watch::Live(live.tx.subscribe()));
        }
        let Some(job) = self.inner.store.get(id).await? else {
            return Ok(Watch::NotFound);
        };
        if !job.state.is_finished() {
            return Ok(Watch::Live(relay::follow(&self.inner, job)));
        }
        let frame = if job.has_frame {
            let frame = self.stored_frame(&job).await;
            if frame.is_none() {
                // A frame it had is gone: say so rather than stream a job without one.
                self.inner.store.check_files(&job).await?;
            }
            frame
        } else {
            None
        };
        Ok(Watch::Stored(Box::new(job), frame))
    }

    /// What a stream follows next once the channel [`Self::watch`] gave it closed before
    /// the job finished: on a shared database the job left this node's worker (its lease
    /// was lost, or the node released it) and runs again, on a worker of any node, so the
    /// stream follows it there. `None` on the embedded store and while this node stops:
    /// there the job waits for a restart, and the stream ends.
    pub async fn watch_again(&self, id: Uuid) -> Result<Option<Watch>, StoreError> {
        if !self.inner.store.is_shared() || self.inner.shutting_down.load(Ordering::SeqCst) {
            return Ok(None);
        }
        self.watch(id).await.map(Some)
    }

    /// The stored final image of a finished job and the layers stored beside it; `None`
    /// if its image file is gone.
    async fn stored_frame(&self, job: &JobRecord) -> Option<StoredFrame> {
        let store = &self.inner.store;
        let image = store.layer_path(job, Layer::Image, false);
        if !tokio::fs::try_exists(&image).await.unwrap_or(false) {
            return None;
        }
        let mut layers = Vec::new();
        for l in Layer::ALL {
            if tokio::fs::try_exists(store.layer_path(job, l, false))
                .await
                .unwrap_or(false)
            {
                layers.push(l);
            }
        }
        Some(StoredFrame { image, layers })
    }

    /// Accepts a validated document: the record is committed before this returns
    /// (so the caller's 201 is durable); the job is then in the queue every node's
    /// workers claim from, and this node's idle workers are woken.
    pub async fn submit(&self, name: &str, scene_json: &str) -> Result<JobRecord, SubmitError> {
        self.submit_parsed(name, scene_json, None, &[]).await
    }

    /// [`Self::submit`] with the scene `scene_json` parses to (under [`Self::limits`]),
    /// handed to this node's worker if one of them claims the job, and what the
    /// submission was warned of, kept with the job.
    pub async fn submit_parsed(
        &self,
        name: &str,
        scene_json: &str,
        parsed: Option<crate::scene::Scene>,
        warnings: &[String],
    ) -> Result<JobRecord, SubmitError> {
        let inner = &self.inner;
        if inner.shutting_down.load(Ordering::SeqCst) {
            return Err(SubmitError::ShuttingDown);
        }
        self.reserve().await?;
        let id = Uuid::now_v7();
        if let Some(scene) = parsed {
            // Before the insert: a worker may claim the job as soon as it is committed.
            *lock(&inner.parsed) = Some((id, scene));
        }
        let inserted = inner.store.insert(id, name, scene_json, warnings).await;
        inner.reserved.fetch_sub(1, Ordering::SeqCst);
        let rec = match inserted {
            Ok(r) => {
                inner.wrote("storing a new job");
                r
            }
            Err(e) => {
                drop(inner.take_parsed(id));
                inner.write_failed("storing a new job", &e);
                return Err(e.into());
            }
        };
        inner.wake_workers();
        inner.store.announce(store::News::Queued).await;
        inner.metrics.jobs_submitted.fetch_add(1, Ordering::Relaxed);
        // One log line per state transition, keyed by `id`, so an operator can follow a job.
        tracing::info!(%id, name, state = "queued", "job accepted");
        Ok(rec)
    }

    /// Takes a place in the queue if there is room: fewer than the capacity queued in
    /// the store (all nodes together) and being inserted on this node. Two nodes may
    /// each let one submission past a full queue at the same moment; no more.
    async fn reserve(&self) -> Result<(), SubmitError> {
        let inner = &self.inner;
        let _turn = inner.reserving.lock().await;
        let queued = inner.store.queued_count().await?;
        let queued = usize::try_from(queued).unwrap_or(usize::MAX);
        let reserved = inner.reserved.load(Ordering::SeqCst);
        if queued.saturating_add(reserved) >= inner.queue_capacity {
            return Err(SubmitError::QueueFull(queued));
        }
        inner.reserved.fetch_add(1, Ordering::SeqCst);
        Ok(())
    }

    /// The job as it is now: the live snapshot while this node runs it (it carries the
    /// progress of every frame), the store otherwise (where a worker on another node
    /// records its progress with each heartbeat).
    pub async fn get(&self, id: Uuid) -> Result<Option<JobRecord>, StoreError> {
        if let Some(live) = self.live(id) {
            return Ok(Some(live.snapshot().job.clone()));
        }
        let rec = self.inner.store.get(id).await?;
        Ok(rec.filter(|r| !self.half_deleted(r)))
    }

    /// Whether a `DELETE` on this node removed `job`'s files (first, to free the space a
    /// full disk needs) and then could not remove its record. It reads as deleted, never
    /// as succeeded without its image, and the record's removal is tried again now (and
    /// by any later `DELETE`). A job whose files went any other way (by hand, a data
    /// folder restored without them) reads as it is, its frames answer `410
    /// files_missing` ([`Store::check_files`]), and its record is never removed for it:
    /// a folder that is only missing for a while must not cost the records.
    fn half_deleted(&self, job: &JobRecord) -> bool {
        if !lock(&self.inner.deleting).contains(&job.id) {
            return false;
        }
        let jobs = self.clone();
        let id = job.id;
        tokio::spawn(async move {
            let _ = jobs.remove_finished(id).await;
        });
        true
    }

    /// The scene document a job was submitted with, as its client wrote it (a JSON
    /// submission's own text; for an import, the document the import produced).
    pub async fn scene(&self, id: Uuid) -> Result<Option<String>, StoreError> {
        self.inner.store.scene(id).await
    }

    /// Finished jobs newest first, with when they finished (unreadable ids are skipped).
    pub async fn finished_newest_first(
        &self,
    ) -> Result<Vec<(Uuid, Option<time::OffsetDateTime>)>, StoreError> {
        let rows = self.inner.store.finished().await?;
        Ok(rows
            .into_iter()
            .filter_map(|(id, at)| {
                let at = at.and_then(|s| {
                    time::OffsetDateTime::parse(&s, &time::format_description::well_known::Rfc3339)
                        .ok()
                });
                Some((Uuid::parse_str(&id).ok()?, at))
            })
            .collect())
    }

    pub async fn list(
        &self,
        state: Option<JobState>,
        limit: u32,
    ) -> Result<Vec<JobRecord>, StoreError> {
        let mut jobs = self.inner.store.list(state, limit).await?;
        jobs.retain(|j| !self.half_deleted(j));
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

    /// Cancels a queued or running job. The request is durable before this returns
    /// (a restart ends the job cancelled); a render on this node stops at its next batch
    /// of pixels, one on another node at its worker's next heartbeat.
    pub async fn cancel(&self, id: Uuid) -> Result<CancelOutcome, StoreError> {
        let Some(rec) = self.get(id).await? else {
            return Ok(CancelOutcome::NotFound);
        };
        if rec.state.is_finished() {
            return Ok(CancelOutcome::AlreadyFinished(rec));
        }
        if let Err(e) = self.inner.store.request_cancel(id).await {
            self.inner.write_failed("recording a cancel", &e);
            return Err(e);
        }
        self.inner.wrote("recording a cancel");
        if let Some(l) = self.live(id) {
            // Flag first, then the token: the worker reads the flag after seeing the token.
            l.user_cancelled.store(true, Ordering::SeqCst);
            l.cancel.cancel();
        }
        let cancelled_queued = match self.inner.store.cancel_queued(id).await {
            Ok(c) => {
                self.inner.wrote("cancelling a queued job");
                c
            }
            Err(e) => {
                // The cancel is recorded, so no worker claims the job any more: the write
                // that finishes it is retried until the disk takes it.
                self.inner.write_failed("cancelling a queued job", &e);
                let inner = Arc::clone(&self.inner);
                tokio::task::spawn_blocking(move || {
                    inner.write_until_done("cancelling a queued job", || {
                        inner.rt.block_on(inner.store.cancel_queued(id)).map(|_| ())
                    })
                });
                false
            }
        };
        if cancelled_queued {
            // Never claimed: finished now, and its place in the queue is free at once.
            tracing::info!(%id, state = "cancelled", ms = 0u64, "job finished (cancelled while queued)");
            let rec = self.inner.store.get(id).await?.unwrap_or(rec);
            return Ok(CancelOutcome::Accepted(rec));
        }
        // Running: the worker finishes the job as `cancelled`, keeping its latest frame.
        Ok(CancelOutcome::Accepted(self.get(id).await?.unwrap_or(rec)))
    }

    pub async fn delete(&self, id: Uuid) -> Result<DeleteOutcome, StoreError> {
        // The store's record, also when half deleted ([`Self::half_deleted`]).
        let rec = match self.live(id) {
            Some(live) => Some(live.snapshot().job.clone()),
            None => self.inner.store.get(id).await?,
        };
        let Some(rec) = rec else {
            return Ok(DeleteOutcome::NotFound);
        };
        if !rec.state.is_finished() {
            return Ok(DeleteOutcome::NotFinished(Box::new(rec)));
        }
        // Finished but still live: its worker is writing the secondary files. Let it
        // finish, or they would land in a folder we just removed.
        if let Some(live) = self.live(id) {
            let mut settled = live.settled.subscribe();
            drop(live);
            let _ = settled.wait_for(|s| *s).await;
        }
        Ok(if self.remove_finished(id).await? {
            DeleteOutcome::Deleted
        } else {
            DeleteOutcome::NotFound
        })
    }

    /// Removes a finished job's files and record; whether there was one to remove.
    async fn remove_finished(&self, id: Uuid) -> Result<bool, StoreError> {
        lock(&self.inner.deleting).insert(id);
        let removed = self.inner.store.delete_finished(id).await;
        match &removed {
            Ok(_) => self.inner.wrote("deleting a job"),
            Err(e) => self.inner.write_failed("deleting a job", e),
        }
        // Half deleted ([`Self::half_deleted`]) only while its files are gone and its
        // record is not.
        if removed.is_ok() || self.inner.store.job_dir(id).exists() {
            lock(&self.inner.deleting).remove(&id);
        }
        removed
    }

    /// The first step of [`Self::shutdown`], at once when the stop is asked (not after
    /// the requests in flight are drained): no new submission or claim, and every
    /// running render stops at its next batch of pixels.
    pub fn stop_rendering(&self) {
        let inner = &self.inner;
        inner.shutting_down.store(true, Ordering::SeqCst);
        inner.wake_workers();
        for l in lock(&inner.live).values() {
            l.cancel.cancel();
        }
    }

    /// Graceful stop, in this order: refuse new submissions; wake idle workers so they
    /// exit; cancel running renders (they stop at the next pixel batch and release their
    /// jobs to `queued`, for any node to run again); join the workers; stop the reaper
    /// and relays; close the database.
    pub async fn shutdown(&self) {
        self.stop_rendering();
        let inner = &self.inner;
        let handles = std::mem::take(&mut *lock(&inner.workers));
        let _ = tokio::task::spawn_blocking(move || {
            for h in handles {
                let _ = h.join();
            }
        })
        .await;
        inner.stop.cancel();
        inner.store.close().await;
    }
}

// ---------------------------------------------------------------------------------------
// Workers

/// Idle workers look for jobs submitted on other nodes this often (their own node wakes
/// them at once). On the embedded store only this node submits, so the poll is a
/// safety net for a lease the reaper freed.
/// One layer of a frame held in memory, encoded (once, off the async runtime) and
/// answered as a lookup.
async fn encoded_lookup(lf: Arc<LiveFrame>, layer: Layer, exr: bool) -> FrameLookup {
    let encoded = tokio::task::spawn_blocking(move || lf.encoded_blocking(layer, exr))
        .await
        .map_err(|e| e.to_string())
        .and_then(|r| r);
    match encoded {
        Ok(Some(bytes)) => FrameLookup::Found(FrameBytes::Memory(bytes)),
        Ok(None) => FrameLookup::NoLayer,
        Err(e) => FrameLookup::EncodingFailed(e),
    }
}

fn idle_poll(store: &Store) -> std::time::Duration {
    if store.is_shared() {
        std::time::Duration::from_millis(250)
    } else {
        std::time::Duration::from_secs(1)
    }
}

fn worker_loop(inner: &Arc<Inner>) {
    while !inner.shutting_down.load(Ordering::SeqCst) {
        let seen = *lock(&inner.work.0);
        let name = inner.node.name.as_deref();
        match inner.rt.block_on(inner.store.claim(name, inner.node.lease)) {
            Ok(Some(claim)) => {
                inner.wrote("claiming a job");
                inner.metrics.claims.fetch_add(1, Ordering::Relaxed);
                run_claim(inner, &claim);
            }
            Ok(None) => {
                inner.wrote("claiming a job");
                wait_for_work(inner, seen, idle_poll(&inner.store));
            }
            Err(e) => {
                // The disk is full or the database is away: the job stays queued for
                // this or another worker, and the claim is tried again after a pause.
                // A shared database's health is what `/healthz`'s ping reports (a claim
                // failing there is no fault of this node's store); on SQLite the store
                // is this node's own disk.
                if inner.store.is_shared() {
                    tracing::warn!("claiming a job: {e}");
                } else {
                    inner.write_failed("claiming a job", &e);
                }
                wait_for_work(inner, seen, WRITE_RETRY);
            }
        }
    }
}

/// Sleeps until this node has news for its workers (`seen` is the count read before the
/// claim that found nothing, so a submission in between is not missed) or `at_most`.
fn wait_for_work(inner: &Inner, seen: u64, at_most: std::time::Duration) {
    let (count, news) = &inner.work;
    let guard = lock(count);
    if *guard == seen && !inner.shutting_down.load(Ordering::SeqCst) {
        drop(news.wait_timeout(guard, at_most));
    }
}

/// Runs a claimed job under its lease: a [`LiveJob`] while it renders, heartbeats beside
/// it ([`lease::keep`]), and every write naming the claim's token.
fn run_claim(inner: &Arc<Inner>, claim: &store::Claim) {
    let id = claim.id;
    let job = match inner.rt.block_on(inner.store.get(id)) {
        Ok(Some(j)) => j,
        Ok(None) => return,
        Err(e) => {
            tracing::error!(%id, "cannot read a claimed job: {e}; released");
            let _ = inner.rt.block_on(inner.store.release(id, claim.token));
            return;
        }
    };
    let live = LiveJob::new(job.clone());
    lock(&inner.live).insert(id, Arc::clone(&live));
    if inner.shutting_down.load(Ordering::SeqCst) {
        // Claimed while the node began to stop (after its renders were cancelled): the
        // render stops at once and the job is released.
        live.cancel.cancel();
    }
    inner.claimed.send_modify(|n| *n += 1);
    tracing::info!(%id, attempt = claim.attempt, state = "running", "job started");
    inner.metrics.jobs_running.fetch_add(1, Ordering::Relaxed);
    let keeper = inner.rt.spawn(lease::keep(
        Arc::clone(inner),
        Arc::clone(&live),
        claim.token,
    ));
    run_job(inner, &live, job, claim.token);
    keeper.abort();
    inner.metrics.jobs_running.fetch_sub(1, Ordering::Relaxed);
    lock(&inner.live).remove(&id);
    live.settled.send_replace(true);
    drop(live);
    super::trim::after_job(&inner.rt);
}

enum Outcome {
    Done(Box<Frame>),
    Cancelled,
    Failed(JobError),
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

/// A claimed job, from its scene to its published end: load, render (publishing every
/// frame), decide how it ended, then store and publish that end.
fn run_job(inner: &Arc<Inner>, live: &Arc<LiveJob>, job: JobRecord, token: LeaseToken) {
    let id = live.id;
    let start = Instant::now();
    let Some(input) = load_scene(inner, id) else {
        return;
    };
    // The job's folder and its (empty) final image file are made durable while the job
    // renders, off the path between the render's end and `done` (store.rs).
    let files_dir = inner.store.attempt_dir(id, token);
    let prepared = {
        let dir = files_dir.clone();
        inner
            .rt
            .spawn_blocking(move || store::prepare_job_dir_blocking(&dir))
    };
    let keeper = super::iterations::Keeper::start(files_dir.clone());
    let rendered = render_job(inner, live, &job, input, &keeper, start);
    let prepared = match inner.rt.block_on(prepared) {
        Ok(r) => r.map_err(|e| e.to_string()),
        Err(e) => Err(e.to_string()),
    };
    match &prepared {
        Ok(()) => inner.wrote("preparing a job's folder"),
        // Not fatal: the final image then goes through temp file + rename + folder sync.
        Err(e) => inner.write_failed("preparing a job's folder", e),
    }
    if let Some(end) = decide_end(inner, live, token, rendered, start) {
        record_end(inner, live, job, token, &files_dir, end, start);
    }
}

/// What a job renders: the scene its submission already parsed, or its document.
enum SceneInput {
    Parsed(Box<crate::scene::Scene>),
    Document(String),
}

/// The job's scene, or `None` when there is nothing to run (deleted under us, or the
/// store cannot say).
fn load_scene(inner: &Arc<Inner>, id: Uuid) -> Option<SceneInput> {
    if let Some(s) = inner.take_parsed(id) {
        return Some(SceneInput::Parsed(Box::new(s)));
    }
    match inner.rt.block_on(inner.store.scene(id)) {
        Ok(Some(s)) => Some(SceneInput::Document(s)),
        Ok(None) => None,
        Err(e) => {
            tracing::error!(%id, "cannot read scene: {e}");
            None
        }
    }
}

/// How a render ended, with the latest frame it published.
struct Rendered {
    outcome: Outcome,
    latest: Option<Arc<LiveFrame>>,
    /// The scene's display exposure, for a final frame made here.
    exposure: f32,
    /// The server's time limit cancelled it.
    timed_out: bool,
}

/// Renders the job under its time limit, publishing every frame; a panic becomes a
/// failed job.
fn render_job(
    inner: &Arc<Inner>,
    live: &Arc<LiveJob>,
    job: &JobRecord,
    input: SceneInput,
    keeper: &super::iterations::Keeper,
    start: Instant,
) -> Rendered {
    // The time limit cancels the render like a user would, and says why.
    let timed_out = Arc::new(AtomicBool::new(false));
    let timer = {
        let (cancel, timed_out, limit) = (
            live.cancel.clone(),
            Arc::clone(&timed_out),
            inner.job_timeout,
        );
        inner.rt.spawn(async move {
            tokio::time::sleep(limit).await;
            timed_out.store(true, Ordering::SeqCst);
            cancel.cancel();
        })
    };
    let mut frames = FramePublisher::new(inner, live, job, keeper, start);
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        let scene = match scene_of(inner, live, input) {
            Ok(s) => s,
            Err(outcome) => return outcome,
        };
        frames.exposure = scene.display.exposure;
        frames.eta = Some(EtaTracker::for_scene(&scene));
        let opts = render_options(&scene, inner.node.job_memory);
        match (inner.render)(scene, &opts, &mut |f| frames.publish(f), &live.cancel) {
            Ok(f) => Outcome::Done(Box::new(f)),
            Err(RenderError::Cancelled) => Outcome::Cancelled,
            Err(e @ RenderError::Denoise(_)) => {
                Outcome::Failed(JobError::new(ErrorCode::DenoiseFailed, e.to_string()))
            }
        }
    }));
    timer.abort();
    let outcome = outcome.unwrap_or_else(|p| {
        let msg = panic_message(p.as_ref());
        tracing::error!(id = %live.id, "render panicked: {msg}");
        Outcome::Failed(JobError::new(
            ErrorCode::RenderFailed,
            format!("the render failed: {msg}"),
        ))
    });
    frames.count_render_time();
    Rendered {
        outcome,
        latest: frames.latest.take(),
        exposure: frames.exposure,
        timed_out: timed_out.load(Ordering::SeqCst),
    }
}

/// A job's render options: the scene's own settings, the denoiser's scratch memory
/// what the job's own memory leaves of the node's budget.
fn render_options(scene: &crate::scene::Scene, job_memory: u64) -> RenderOptions {
    let opts = RenderOptions::default();
    RenderOptions {
        denoise_memory_mb: MemoryEstimate::of(scene, &opts).denoise_scratch_mb(job_memory),
        ..opts
    }
}

/// The scene to render; a job read back from the store (recovered after a restart, or
/// submitted on another node) is parsed again: up to 0.7 s for an 8 MiB mesh, which a
/// cancel abandons like the BVH build.
fn scene_of(
    inner: &Arc<Inner>,
    live: &Arc<LiveJob>,
    input: SceneInput,
) -> Result<crate::scene::Scene, Outcome> {
    let scene = match input {
        SceneInput::Parsed(s) => *s,
        SceneInput::Document(json) => {
            let limits = inner.limits;
            match crate::cancel::abandonable(&live.cancel, move || {
                parse_scene(&json, &SceneOrigin::Request, &limits)
            }) {
                Err(crate::cancel::Cancelled) => return Err(Outcome::Cancelled),
                Ok(Ok(s)) => s,
                // Accepted earlier, refused now (limits changed across a restart).
                Ok(Err(e)) => {
                    return Err(Outcome::Failed(JobError::new(
                        ErrorCode::InvalidScene,
                        e.to_string(),
                    )))
                }
            }
        }
    };
    // The node that took the submission had the denoiser; this one (another node of a
    // cluster) must too, or the job fails saying so rather than coming back noisy.
    if let Err(e) = crate::progressive::denoiser_for(&scene, &Default::default()) {
        return Err(Outcome::Failed(JobError::new(
            ErrorCode::DenoiserUnavailable,
            format!("this node cannot denoise: {e}"),
        )));
    }
    Ok(scene)
}
/// Publishes each frame of a running render: its progress with the time left, the
/// counters, the kept iterations, the watchers.
struct FramePublisher<'a> {
    inner: &'a Arc<Inner>,
    live: &'a Arc<LiveJob>,
    job: &'a JobRecord,
    keeper: &'a super::iterations::Keeper,
    start: Instant,
    exposure: f32,
    /// Set once the scene is known (frames come only after).
    eta: Option<EtaTracker>,
    latest: Option<Arc<LiveFrame>>,
    last_pixels: u64,
    /// Render time is counted as it passes (per frame), so the counter moves during long
    /// jobs.
    counted_s: f64,
}

impl<'a> FramePublisher<'a> {
    fn new(
        inner: &'a Arc<Inner>,
        live: &'a Arc<LiveJob>,
        job: &'a JobRecord,
        keeper: &'a super::iterations::Keeper,
        start: Instant,
    ) -> Self {
        Self {
            inner,
            live,
            job,
            keeper,
            start,
            exposure: 1.0,
            eta: None,
            latest: None,
            last_pixels: 0,
            counted_s: 0.0,
        }
    }

    fn publish(&mut self, f: &Frame) {
        let elapsed = self.start.elapsed().as_secs_f64() * 1e3;
        let eta = self
            .eta
            .as_mut()
            .map_or(Eta::Unknown, |e| e.update(f, elapsed));
        let progress = progress_of(f, elapsed, eta);
        let metrics = &self.inner.metrics;
        metrics.pixels_traced.fetch_add(
            f.stats.pixels_traced.saturating_sub(self.last_pixels),
            Ordering::Relaxed,
        );
        self.last_pixels = self.last_pixels.max(f.stats.pixels_traced);
        self.count_render_time();
        // The copy (0.1-0.4 ms at 512²) is the only per-frame cost on the render's
        // thread; the PNG is encoded later, only if someone takes this frame. The
        // preview is there to be seen at once: the PNG the stream sends of it (at most
        // `live::PREVIEW_SIDE` pixels a side) is encoded here, on the render's thread,
        // before watchers are woken (once per job), rather than by a watcher's task
        // competing with the render for the cores; its copy waits until after.
        let lf = Arc::new(if f.preview {
            LiveFrame::preview(f, self.exposure, progress.clone(), Arc::clone(metrics))
        } else {
            LiveFrame::new(
                f.clone(),
                self.exposure,
                progress.clone(),
                Arc::clone(metrics),
            )
        });
        self.keeper.offer(&lf);
        self.latest = Some(Arc::clone(&lf));
        let mut j = self.job.clone();
        j.progress = Some(progress);
        self.live.publish(j, Some(Arc::clone(&lf)));
        if f.preview {
            lf.keep_preview_pixels(f);
        }
    }

    /// Adds the render time since the last count to the counter.
    fn count_render_time(&mut self) {
        let now_s = self.start.elapsed().as_secs_f64();
        self.inner
            .metrics
            .add_render_seconds(now_s - self.counted_s);
        self.counted_s = now_s;
    }
}

/// How a job ends: its state, statistics, error and final frame.
struct End {
    state: JobState,
    stats: Option<crate::progressive::RenderStats>,
    error: Option<JobError>,
    final_frame: Option<Arc<LiveFrame>>,
}

/// The end a render's outcome means, or `None` when this worker records nothing: its
/// lease was lost (the job is another worker's now, and what this attempt wrote goes), or
/// the server is shutting down (the job goes back to `queued`).
fn decide_end(
    inner: &Arc<Inner>,
    live: &Arc<LiveJob>,
    token: LeaseToken,
    mut r: Rendered,
    start: Instant,
) -> Option<End> {
    let id = live.id;
    let user_cancelled = live.user_cancelled.load(Ordering::SeqCst);
    let end = |state, error, final_frame| End {
        state,
        stats: None,
        error,
        final_frame,
    };
    Some(match r.outcome {
        // A cancel that came as the render ended wins: the person asked for it.
        Outcome::Done(_) if user_cancelled => end(JobState::Cancelled, None, r.latest),
        Outcome::Done(f) => {
            let elapsed = start.elapsed().as_secs_f64() * 1e3;
            let progress = progress_of(&f, elapsed, Eta::Done);
            let stats = Some(f.stats.clone());
            let lf = match r.latest.take() {
                // The callback already saw this final frame: reuse it (and its PNG).
                Some(l) if l.iteration == f.iteration && l.is_last() => l,
                _ => Arc::new(LiveFrame::new(
                    *f,
                    r.exposure,
                    progress,
                    Arc::clone(&inner.metrics),
                )),
            };
            End {
                stats,
                ..end(JobState::Succeeded, None, Some(lf))
            }
        }
        Outcome::Cancelled if live.lease_lost.load(Ordering::SeqCst) => {
            tracing::warn!(%id, "render stopped: its lease was lost");
            inner.store.discard_attempt_blocking(id, token);
            return None;
        }
        Outcome::Cancelled if r.timed_out && !user_cancelled => {
            let limit = inner.job_timeout.as_secs_f64();
            let error = JobError::new(
                ErrorCode::Timeout,
                format!("the render ran longer than the server's limit of {limit} s (--job-timeout); its latest frame is kept"),
            );
            end(JobState::Failed, Some(error), r.latest)
        }
        Outcome::Cancelled if !user_cancelled => {
            // Shutdown, not a user: back to `queued`, to run again from the start.
            match inner.rt.block_on(inner.store.release(id, token)) {
                Ok(_) => inner.rt.block_on(inner.store.announce(store::News::Queued)),
                Err(e) => tracing::error!(%id, "cannot release job: {e}"),
            }
            tracing::info!(%id, state = "queued", "job released (shutdown)");
            return None;
        }
        Outcome::Cancelled => end(JobState::Cancelled, None, r.latest),
        Outcome::Failed(err) => end(JobState::Failed, Some(err), r.latest),
    })
}

/// Stores a job's end and publishes it.
///
/// What `done` promises (service-api.md "Durability": a finished job keeps its state,
/// statistics and final image) is on disk before `done` is published: the image layer's
/// PNG (usually already encoded for the watchers), then the record. The other layers and
/// the EXR follow (`write_secondary_files`); until they are written the job stays live, so
/// `GET .../frame` serves any layer complete from memory meanwhile. A full or unwritable
/// disk does not end the job in a state that lies: the image and then the record are
/// tried again until they are stored (the job stays `running`, live, meanwhile), or the
/// server stops and the restart runs the job again.
fn record_end(
    inner: &Arc<Inner>,
    live: &Arc<LiveJob>,
    mut job: JobRecord,
    token: LeaseToken,
    files_dir: &std::path::Path,
    end: End,
    start: Instant,
) {
    let id = live.id;
    let Some(has_frame) = store_final_image(inner, live, token, files_dir, &end) else {
        return;
    };
    let progress = end
        .final_frame
        .as_ref()
        .map(|f| f.progress.clone())
        .or_else(|| job.progress.clone());
    let mut finished = None;
    if !inner.write_until_done("recording the end of a job", || {
        inner
            .rt
            .block_on(inner.store.finish_leased(
                id,
                token,
                end.state,
                progress.as_ref(),
                end.stats.as_ref(),
                end.error.as_ref(),
                has_frame,
            ))
            .map(|t| finished = Some(t))
    }) {
        return;
    }
    let Some(finished) = finished.flatten() else {
        // Refused: the lease went to another worker between the fence and now.
        inner.metrics.lease_losses.fetch_add(1, Ordering::Relaxed);
        tracing::warn!(%id, "the end of the job was refused: its lease was lost");
        inner.store.discard_attempt_blocking(id, token);
        return;
    };
    relay::remove_frames(files_dir);
    inner.store.remove_other_attempts_blocking(id, token);
    tracing::info!(
        %id,
        state = end.state.as_str(),
        ms = u64::try_from(start.elapsed().as_millis()).unwrap_or(u64::MAX),
        "job finished"
    );
    job.finished_at = Some(finished);
    job.state = end.state;
    job.progress = progress;
    job.stats = end.stats;
    job.error = end.error;
    job.has_frame = has_frame;
    live.publish(job, end.final_frame.clone());
    publish_done(inner, id, files_dir, has_frame, end.final_frame.as_ref());
}

/// The final image stored under a renewed lease: `Some(whether there is one)`, or `None`
/// when this worker must write nothing more. On a shared database the lease is renewed
/// first: a worker presumed dead must not touch the files of a job another worker now
/// owns (`lease::fence`). A worker paused for longer than its lease after this fence
/// writes only into its attempt's folder, which its refused end never names
/// (`Store::attempt_dir`).
fn store_final_image(
    inner: &Arc<Inner>,
    live: &Arc<LiveJob>,
    token: LeaseToken,
    files_dir: &std::path::Path,
    end: &End,
) -> Option<bool> {
    let id = live.id;
    let png = end.final_frame.as_ref().map(|lf| lf.image_png_blocking());
    if !lease::fence(inner, live, token) {
        inner.store.discard_attempt_blocking(id, token);
        return None;
    }
    let has_frame = match &png {
        Some(Ok(png)) => {
            if !inner.write_until_done("storing a final image", || {
                store::write_final_image_blocking(files_dir, png)
            }) {
                return None;
            }
            true
        }
        Some(Err(e)) => {
            tracing::error!(%id, "cannot encode the final frame: {e}");
            false
        }
        None => false,
    };
    if !has_frame {
        remove_placeholder(files_dir);
    }
    Some(has_frame)
}

/// After `done`: the test hook, then the frame's other layers and EXR.
fn publish_done(
    inner: &Arc<Inner>,
    id: Uuid,
    files_dir: &std::path::Path,
    has_frame: bool,
    final_frame: Option<&Arc<LiveFrame>>,
) {
    let hook = lock(&inner.after_done).clone();
    if let Some(hook) = hook {
        hook(id);
    }
    if let (true, Some(lf)) = (has_frame, final_frame) {
        // Not retried: `DELETE` waits for these writes, and must free space on a full disk.
        match write_secondary_files(files_dir, lf) {
            Ok(()) => inner.wrote("storing a frame's other layers"),
            Err(e) => inner.write_failed("storing a frame's other layers", &e),
        }
    }
}

/// Best effort: the empty final-image file (and then the empty folder) of a job that
/// ends without a frame.
fn remove_placeholder(dir: &std::path::Path) {
    let _ = std::fs::remove_file(dir.join(store::FINAL_IMAGE_FILE));
    let _ = std::fs::remove_dir(dir);
}

/// Encodes the final frame's layers other than the image, and the EXR, and writes them
/// beside the image (atomically, synced). Runs after `done`: nothing the durability
/// contract names depends on them, and they cost ~7 ms of CPU at 512² (4 ms of it the
/// distance colour map) and four file syncs plus the folder's, which used to sit between
/// the render's end and `done` (with the old EXR encoder, 24-28 ms in all). A crash before they are written
/// leaves a finished job whose `GET .../frame?layer=samples` (etc.) answers 404
/// "no samples layer" while its image, state and statistics are intact.
fn write_secondary_files(dir: &std::path::Path, lf: &LiveFrame) -> Result<(), String> {
    use rayon::prelude::*;
    // The other layers' PNGs and the EXR, encoded in parallel (or taken from the
    // encodings a request already made).
    let files = OTHER_ENCODINGS
        .par_iter()
        .map(|&(layer, exr)| {
            let name = layer.file_name(exr);
            Ok(lf.encoded_blocking(layer, exr)?.map(|b| (name, b)))
        })
        .collect::<Result<Vec<_>, String>>()?;
    let files: Vec<(String, Bytes)> = files.into_iter().flatten().collect();
    store::write_files_blocking(dir, &files).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progressive::{ClassCell, SampleCell};
    use crate::raster::{Image, Rgb};

    fn frame(iteration: u32, d: f64, last: bool) -> Frame {
        Frame::fixture(iteration, d, last)
    }

    const TINY: &str = r#"{"version": 1, "image": {"width": 4, "height": 3},
        "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40},
        "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}]}"#;

    /// Sends one frame, then panics as a buggy tracer would.
    fn panicking(
        scene: crate::scene::Scene,
        _opts: &RenderOptions,
        on_frame: &mut dyn FnMut(&Frame),
        _cancel: &CancelToken,
    ) -> Result<Frame, RenderError> {
        let mut f = frame(0, 2.0, false);
        f.image = Image::filled(scene.width, scene.height, Rgb::splat(0.5));
        f.samples = Image::filled(scene.width, scene.height, SampleCell::New);
        f.classes = Image::filled(scene.width, scene.height, ClassCell::None);
        on_frame(&f);
        panic!("boom in the tracer");
    }

    /// Five frames of a 8×6 image, the last one final, with every layer.
    fn five_frames(
        scene: crate::scene::Scene,
        _opts: &RenderOptions,
        on_frame: &mut dyn FnMut(&Frame),
        _cancel: &CancelToken,
    ) -> Result<Frame, RenderError> {
        let mut f = frame(0, 2.0, false);
        for k in 0..5u32 {
            f = frame(k, 2.0 / f64::from(k + 1), k == 4);
            f.image = Image::from_fn(scene.width, scene.height, |x, y| {
                Rgb::new(x as f32 / 8.0, y as f32 / 6.0, k as f32 / 4.0)
            });
            f.samples = Image::filled(scene.width, scene.height, SampleCell::Traced);
            f.classes = Image::filled(scene.width, scene.height, ClassCell::Smooth);
            f.distance = Some(Image::filled(scene.width, scene.height, 0.5));
            f.objects = Arc::new(Image::filled(scene.width, scene.height, 0));
            on_frame(&f);
        }
        Ok(f)
    }

    const SMALL: &str = r#"{"version": 1, "image": {"width": 8, "height": 6},
        "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov_y": 40},
        "materials": {"w": {"type": "diffuse", "albedo": [0.5, 0.5, 0.5]}},
        "objects": [{"type": "sphere", "center": [0, 0, 0], "radius": 1, "material": "w"}]}"#;

    async fn start_five(dir: &std::path::Path) -> (Jobs, Arc<Metrics>) {
        start_rendering(dir, five_frames).await
    }

    /// One worker on an embedded store in `dir`, rendering with `render`.
    async fn start_rendering(dir: &std::path::Path, render: RenderFn) -> (Jobs, Arc<Metrics>) {
        let metrics = Arc::new(Metrics::default());
        let store = Store::open(dir).await.unwrap();
        let jobs = Jobs::start_with(
            store,
            Node::single(1),
            crate::service::server_limits(),
            4,
            DEFAULT_JOB_TIMEOUT,
            Arc::clone(&metrics),
            render,
        )
        .await
        .unwrap();
        (jobs, metrics)
    }

    /// Waits until the worker is done with the job, secondary files included.
    async fn settled(jobs: &Jobs, id: Uuid) -> JobRecord {
        let deadline = Instant::now() + std::time::Duration::from_secs(10);
        loop {
            // Finished and no longer live: claimed, rendered, its files written.
            let j = jobs.get(id).await.unwrap().unwrap();
            if j.state.is_finished() && jobs.live(id).is_none() {
                return j;
            }
            assert!(Instant::now() < deadline, "job never settled");
            tokio::time::sleep(std::time::Duration::from_millis(2)).await;
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn frames_nobody_watches_are_never_encoded_and_every_file_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let (jobs, metrics) = start_five(dir.path()).await;
        let id = jobs.submit("quiet", SMALL).await.unwrap().id;
        let j = settled(&jobs, id).await;
        assert_eq!(j.state, JobState::Succeeded);
        // Five frames, no watcher: each encoded at most once, for its file: the final
        // one and those kept as earlier iterations (the keeper skips a frame rather than
        // make the render wait, so how many it kept depends on timing).
        let store = &jobs.inner.store;
        let kept = store::kept_iterations_blocking(&store.job_dir(id)).unwrap();
        assert!(
            kept.len() <= 4 && kept.iter().all(|(n, _)| *n < 4),
            "{kept:?}"
        );
        let encoded = metrics.frames_encoded.load(Ordering::Relaxed);
        assert_eq!(encoded, 1 + kept.len() as u64);
        for layer in Layer::ALL {
            let png = std::fs::read(store.job_dir(id).join(layer.file_name(false))).unwrap();
            let img = crate::raster::decode_image(&png).unwrap();
            assert_eq!((img.width(), img.height()), (8, 6), "{layer:?}");
        }
        let exr = std::fs::read(store.job_dir(id).join(Layer::Image.file_name(true))).unwrap();
        let img = crate::raster::decode_image(&exr).unwrap();
        // The last frame's linear values (k = 4: blue 1.0), not an earlier frame's.
        assert_eq!(img.get(7, 5).z, 1.0);
        assert_eq!(img.get(4, 3).x, 0.5);
        // A second unwatched job likewise adds one encoding per file.
        let id = jobs.submit("watched", SMALL).await.unwrap().id;
        settled(&jobs, id).await;
        let kept2 = store::kept_iterations_blocking(&store.job_dir(id)).unwrap();
        assert_eq!(
            metrics.frames_encoded.load(Ordering::Relaxed),
            encoded + 1 + kept2.len() as u64
        );
        jobs.shutdown().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn done_is_durable_before_the_late_writes_which_get_and_delete_wait_for() {
        let dir = tempfile::tempdir().unwrap();
        let (jobs, _) = start_five(dir.path()).await;
        // Hold the worker between `done` and the secondary files.
        let (at_hook_tx, at_hook_rx) = std::sync::mpsc::channel::<Uuid>();
        let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
        let release_rx = Mutex::new(release_rx);
        let at_hook_tx = Mutex::new(at_hook_tx);
        *lock(&jobs.inner.after_done) = Some(Arc::new(move |id| {
            let _ = lock(&at_hook_tx).send(id);
            let _ = lock(&release_rx).recv();
        }));
        let id = jobs.submit("held", SMALL).await.unwrap().id;
        let held = tokio::task::spawn_blocking(move || at_hook_rx.recv().unwrap())
            .await
            .unwrap();
        assert_eq!(held, id);

        // What a crash right now would leave: the record, committed, and the image.
        let other = Store::open(dir.path()).await.unwrap();
        let rec = other.get(id).await.unwrap().unwrap();
        assert_eq!(rec.state, JobState::Succeeded);
        assert!(rec.has_frame && rec.stats.is_some() && rec.finished_at.is_some());
        let png = std::fs::read(other.job_dir(id).join(Layer::Image.file_name(false))).unwrap();
        let img = crate::raster::decode_image(&png).unwrap();
        assert_eq!((img.width(), img.height()), (8, 6));
        assert!(!other
            .job_dir(id)
            .join(Layer::Samples.file_name(false))
            .exists());
        assert!(!other
            .job_dir(id)
            .join(Layer::Image.file_name(true))
            .exists());
        // A restart over it keeps the job finished (it is not run again).
        assert!(other.recover().await.unwrap().is_empty());
        other.close().await;

        // Meanwhile the running server serves every layer complete, from memory.
        let state = super::super::http::AppState {
            jobs: jobs.clone(),
            metrics: Arc::new(Metrics::default()),
            token: None,
            stop: tokio_util::sync::CancellationToken::new(),
            max_body_bytes: 1 << 20,
            request_deadline: super::super::http::REQUEST_DEADLINE,
            max_watchers: 4,
            origin: Arc::default(),
            uploads: Arc::new(tokio::sync::Semaphore::new(1024)),
            upload_budget_kib: 1024,
        };
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let server =
            tokio::spawn(
                async move { axum::serve(listener, super::super::http::router(state)).await },
            );
        let c = reqwest::Client::new();
        for q in [
            "layer=samples",
            "layer=distance",
            "layer=classes",
            "format=exr",
        ] {
            let r = c
                .get(format!("http://{addr}/v1/jobs/{id}/frame?{q}"))
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 200, "{q}");
            let img = crate::raster::decode_image(&r.bytes().await.unwrap()).unwrap();
            assert_eq!((img.width(), img.height()), (8, 6), "{q}");
        }

        // DELETE waits for the late writes instead of racing them.
        let jobs2 = jobs.clone();
        let delete = tokio::spawn(async move { jobs2.delete(id).await });
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        assert!(
            !delete.is_finished(),
            "DELETE must wait for the late writes"
        );
        release_tx.send(()).unwrap();
        assert!(matches!(
            delete.await.unwrap().unwrap(),
            DeleteOutcome::Deleted
        ));
        assert!(
            !jobs.inner.store.job_dir(id).exists(),
            "nothing written after DELETE"
        );
        server.abort();
        jobs.shutdown().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_panicking_render_fails_the_job_keeps_its_frame_and_the_worker_lives_on() {
        let dir = tempfile::tempdir().unwrap();
        let (jobs, _) = start_rendering(dir.path(), panicking).await;
        let a = jobs.submit("a", TINY).await.unwrap().id;
        let b = jobs.submit("b", TINY).await.unwrap().id;
        for id in [a, b] {
            let j = settled(&jobs, id).await;
            // The second job also ran: the worker survived the first panic.
            assert_eq!(j.state, JobState::Failed);
            let err = j.error.unwrap();
            assert_eq!(err.code, ErrorCode::RenderFailed);
            assert!(err.message.contains("boom in the tracer"), "{err:?}");
            assert!(j.has_frame && j.finished_at.is_some());
            let png = std::fs::read(
                jobs.inner
                    .store
                    .job_dir(id)
                    .join(Layer::Image.file_name(false)),
            )
            .unwrap();
            assert_eq!(crate::raster::decode_image(&png).unwrap().width(), 4);
        }
        jobs.shutdown().await;
    }

    /// Sends a grey frame 0 of the scene's size, as a render's first, and returns it.
    fn first_grey_frame(scene: &crate::scene::Scene, on_frame: &mut dyn FnMut(&Frame)) -> Frame {
        let mut f = frame(0, 2.0, false);
        f.image = Image::filled(scene.width, scene.height, Rgb::splat(0.5));
        on_frame(&f);
        f
    }

    /// Sends a frame, waits for a cancel (at most 10 s) and then ends as if it had not
    /// seen it: a render whose last step (a denoise) does not look at the token.
    fn finishing_despite_a_cancel(
        scene: crate::scene::Scene,
        _opts: &RenderOptions,
        on_frame: &mut dyn FnMut(&Frame),
        cancel: &CancelToken,
    ) -> Result<Frame, RenderError> {
        let mut f = first_grey_frame(&scene, on_frame);
        let deadline = Instant::now() + std::time::Duration::from_secs(10);
        while !cancel.is_cancelled() && Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        f.last = true;
        f.iteration = 1;
        on_frame(&f);
        Ok(f)
    }

    /// Sends a frame, then the denoiser fails.
    fn failing_denoise(
        scene: crate::scene::Scene,
        _opts: &RenderOptions,
        on_frame: &mut dyn FnMut(&Frame),
        _cancel: &CancelToken,
    ) -> Result<Frame, RenderError> {
        first_grey_frame(&scene, on_frame);
        Err(RenderError::Denoise(crate::denoise::DenoiseError::Library(
            "denoising a 100000x1 image: out of memory".into(),
        )))
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_cancel_wins_over_a_render_that_ends_after_it() {
        let dir = tempfile::tempdir().unwrap();
        let (jobs, _) = start_rendering(dir.path(), finishing_despite_a_cancel).await;
        let id = jobs.submit("a", TINY).await.unwrap().id;
        let deadline = Instant::now() + std::time::Duration::from_secs(10);
        while jobs.get(id).await.unwrap().unwrap().state != JobState::Running {
            assert!(Instant::now() < deadline, "job never ran");
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
        assert!(matches!(
            jobs.cancel(id).await.unwrap(),
            CancelOutcome::Accepted(_)
        ));
        let j = settled(&jobs, id).await;
        assert_eq!(j.state, JobState::Cancelled, "{j:?}");
        assert!(j.error.is_none() && j.has_frame);
        jobs.shutdown().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_failed_denoise_fails_the_job_with_its_reason() {
        let dir = tempfile::tempdir().unwrap();
        let (jobs, _) = start_rendering(dir.path(), failing_denoise).await;
        let id = jobs.submit("a", TINY).await.unwrap().id;
        let j = settled(&jobs, id).await;
        assert_eq!(j.state, JobState::Failed);
        let err = j.error.unwrap();
        assert_eq!(err.code, ErrorCode::DenoiseFailed);
        assert!(
            err.message.contains("could not be denoised") && err.message.contains("100000x1"),
            "{err:?}"
        );
        assert!(j.has_frame, "the frames before the failure are kept");
        jobs.shutdown().await;
    }
}
