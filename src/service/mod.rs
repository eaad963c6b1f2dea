//! The render service: REST jobs, a durable embedded store, a worker pool and WebSocket
//! streaming (shared/spec/service-api.md). The only async code and the only wire JSON.
//!
//! Layout:
//! - [`http`]: router, limit layers, extractors, `ApiError` (the only type that knows
//!   status codes);
//! - [`jobs`]: workers claiming jobs from the store under leases, the reaper,
//!   cancellation from any node, state transitions, live and relayed frames;
//! - [`store`]: job records on SQLite or PostgreSQL (sqlx), claims and leases, and the
//!   final images beside them; [`error_code`]: the stable error codes;
//! - [`ws`]: the stream protocol over a `watch` channel per job;
//! - [`metrics`]: Prometheus text; [`auth`]: the optional bearer token;
//! - [`iterations`]: the earlier iterations kept per job (slider, `frame?iteration=N`);
//! - [`examples`]: the bundled scenes; [`viewer`]: the browser page.

pub mod auth;
pub mod error;
pub mod error_code;
pub mod examples;
pub mod extract;
pub mod handlers;
pub mod http;
pub mod iterations;
pub mod jobs;
pub mod live;
pub mod metrics;
pub mod origin;
pub mod parse_error;
pub mod retention;
pub mod stall;
pub mod state;
pub mod store;
pub mod trim;
pub mod viewer;
pub mod ws;

use crate::scene::Limits;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

/// Everything the service needs, parsed once in `main`.
#[derive(Clone, Debug)]
pub struct Config {
    /// The image files of finished jobs (and, without `database`, the SQLite store).
    pub data_dir: PathBuf,
    /// `--database`: SQLite in `data_dir` when absent.
    pub database: Option<store::Database>,
    /// Concurrent renders (each render already uses every core through rayon, so more
    /// than one or two workers only helps many small jobs); 0 on a shared database makes
    /// a node that only serves.
    pub workers: usize,
    /// This node's name in the jobs its workers claim on a shared database (`--name`;
    /// [`default_node_name`]).
    pub node_name: Option<String>,
    /// The lease of a claimed job ([`jobs::DEFAULT_LEASE`]; `--lease`).
    pub lease: Duration,
    /// If set, every `/v1` call needs `Authorization: Bearer <token>`.
    pub token: Option<String>,
    /// Jobs waiting for a worker before submissions get `429 queue_full`: bounds memory
    /// and tells clients early that the server is saturated.
    pub queue_capacity: usize,
    /// Largest request body (a scene with an inline mesh); above it `413 too_large`, the
    /// only 413 (a scene's parameters above `limits` are `422 over_limit`).
    pub max_body_bytes: usize,
    /// Scene size limits for requests (pixels, sample budget, objects, triangles, the
    /// bounce cap); `glimpse serve --max-*`.
    pub limits: Limits,
    /// Open job streams, all jobs together; beyond it `503 unavailable` (each stream holds
    /// a connection, a task and possibly an encoded frame).
    pub max_watchers: usize,
    /// A request's header must arrive within this ([`HEADER_TIMEOUT`]), the rest of it
    /// within `request_deadline` ([`http::REQUEST_DEADLINE`]); tests shorten them.
    pub header_timeout: Duration,
    pub request_deadline: Duration,
    /// A response or stream whose client reads nothing for this long is cut
    /// ([`stall::StallLimit`]); `--client-stall`.
    pub client_stall: Duration,
    /// A render running longer is stopped and its job failed (`timeout`); `--job-timeout`.
    pub job_timeout: Duration,
    /// The memory one job may use, in bytes ([`jobs::DEFAULT_JOB_MEMORY`];
    /// `--max-job-memory`).
    pub job_memory: u64,
    /// Without a token, requests must name this server in `Host`: its listen address, a
    /// loopback name, or one of these (`--allowed-host`); see `http::check_origin`.
    pub allowed_hosts: Vec<String>,
    /// Request bodies being read and validated at once, in bytes ([`VALIDATION_BUDGET`]).
    pub validation_budget: usize,
    /// How many finished jobs, how old and how many bytes are kept (`--keep-*`).
    pub retention: retention::Retention,
}

impl Config {
    /// Defaults for everything but the data folder.
    #[must_use]
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        Self {
            data_dir: data_dir.into(),
            database: None,
            workers: 1,
            node_name: None,
            lease: jobs::DEFAULT_LEASE,
            token: None,
            queue_capacity: DEFAULT_QUEUE_CAPACITY,
            max_body_bytes: DEFAULT_MAX_BODY_BYTES,
            limits: server_limits(),
            max_watchers: DEFAULT_MAX_WATCHERS,
            header_timeout: HEADER_TIMEOUT,
            request_deadline: http::REQUEST_DEADLINE,
            client_stall: CLIENT_STALL,
            job_timeout: jobs::DEFAULT_JOB_TIMEOUT,
            job_memory: jobs::DEFAULT_JOB_MEMORY,
            allowed_hosts: Vec::new(),
            validation_budget: VALIDATION_BUDGET,
            retention: retention::Retention::default(),
        }
    }
}

/// 64 waiting jobs: at a few seconds each, minutes of backlog; more is better refused.
pub const DEFAULT_QUEUE_CAPACITY: usize = 64;
/// 256 streams: a lecture room watching one job, with room to spare.
pub const DEFAULT_MAX_WATCHERS: usize = 256;
/// 8 MiB: room for a mesh of ~100k triangles in JSON, small enough to buffer per request.
pub const DEFAULT_MAX_BODY_BYTES: usize = 8 << 20;
/// A request header (a few hundred bytes) that has not arrived in 10 s never will: the
/// connection is closed. `axum::serve` sets no such timeout, so a client sending half a
/// header held its connection for good (measured: still open after 45 s), and enough of
/// them exhaust the file descriptors ("slowloris").
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// Bytes of request bodies read and validated at once, all requests together. Validating
/// a scene peaks at ~26× its body (an 8 MiB mesh: ~210 MB), so 24 MiB of bodies in flight
/// is ~650 MB at most; further submissions wait for their turn before their body is read.
/// Measured before: 48 concurrent 8 MiB submissions held 4.8 GB. A body larger than the
/// budget (with `--max-body` raised beyond it) waits for the whole budget. A zip upload
/// is charged what its directory says it unpacks to besides its body (a 250 KB zip can
/// hold 250 MiB), so a bundle larger than the budget is imported alone.
pub const VALIDATION_BUDGET: usize = 24 << 20;
/// 20 s without reading a byte: a live viewer on a poor link still takes something in
/// that time (a 64 KiB fragment at 26 kbit/s); a client that has stopped reading is cut
/// before it holds much (its frame, a file handle).
pub const CLIENT_STALL: Duration = Duration::from_secs(20);
/// How long shutdown waits for requests in flight before closing their connections.
const DRAIN_ON_SHUTDOWN: Duration = Duration::from_secs(10);

/// What one request may ask of the server: up to a 4096² image and 2^32 paths (a 4096²
/// image at 256 spp; a 512² image at 16k spp), i.e. minutes to an hour of CPU, not days.
/// `tests/scenes-bad/` (README) assumes these width, sample and spp limits.
#[must_use]
pub fn server_limits() -> Limits {
    Limits {
        max_width: 4096,
        max_height: 4096,
        // One frame with its layers stays under ~400 MB; a progressive render of this size
        // peaks at ~4.1 GB resident (README "When the progressive loop does not pay").
        max_pixels: 4096 * 4096,
        max_sample_budget: 1 << 32,
        max_objects: 10_000,
        // ~100 bytes of JSON per triangle: the 8 MiB body limit bites first anyway.
        max_triangles: 1_000_000,
        max_samples_per_pixel: 4096,
        // Russian roulette (`tracer::integrator`, from `RR_START`, survival ≤ 0.95 a
        // bounce) ends a path past 64 bounces with probability ≥ 1 − 0.95^61 ≈ 96 % even
        // in an all-white scene, and the mean path is ≤ 23 bounces whatever this cap: a
        // high cap costs nearly nothing, and downloaded scenes (pbrt `maxdepth 65`) render
        // unchanged, as on the command line (`Limits::command_line`).
        max_bounces: 1024,
    }
}

/// Serves on `listener` until `shutdown` resolves: [`start`], then [`Started::serve`].
pub async fn run(
    listener: tokio::net::TcpListener,
    config: Config,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    start(config).await?.serve(listener, shutdown).await
}

/// A node whose job store is open, checked and recovered and whose workers run, before
/// it listens: everything at start-up that can fail (a corrupt or foreign database, an
/// unreachable one, a refused option) fails here, so "listening on …" is never logged
/// by a server about to exit.
pub struct Started {
    config: Config,
    jobs: jobs::Jobs,
    metrics: Arc<metrics::Metrics>,
}

/// Opens the store (running its migrations and, on the embedded store, its recovery)
/// and starts this node's workers.
pub async fn start(config: Config) -> anyhow::Result<Started> {
    let database = config
        .database
        .clone()
        .unwrap_or_else(|| store::Database::Sqlite(config.data_dir.clone()));
    // With `sqlite://DIR` the images live beside that database, as with `--data DIR`.
    let files_dir = match &database {
        store::Database::Sqlite(dir) => dir.clone(),
        store::Database::Postgres(_) => config.data_dir.clone(),
    };
    let store = store::Store::connect(&database, &files_dir)
        .await
        .map_err(|e| anyhow::anyhow!("cannot open the job store {}: {e}", database.display()))?;
    if config.workers == 0 && !store.is_shared() {
        anyhow::bail!("--workers 0 needs a shared database (--database postgres://…): on the embedded store nobody else would render the jobs");
    }
    let metrics = Arc::new(metrics::Metrics::default());
    let jobs = jobs::Jobs::start(
        store,
        node(&config, config.workers),
        config.limits,
        config.queue_capacity,
        config.job_timeout,
        Arc::clone(&metrics),
    )
    .await
    .map_err(|e| anyhow::anyhow!("cannot start the workers: {e}"))?;
    Ok(Started {
        config,
        jobs,
        metrics,
    })
}

impl Started {
    /// Serves on `listener` until `shutdown` resolves.
    ///
    /// Shutdown order: stop accepting connections and close open streams; cancel running
    /// renders and release their jobs to `queued` in the store (they run again after a
    /// restart, or on another node); join the workers; close the database; return.
    pub async fn serve(
        self,
        listener: tokio::net::TcpListener,
        shutdown: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> anyhow::Result<()> {
        let Self {
            config,
            jobs,
            metrics,
        } = self;
        let stop = tokio_util::sync::CancellationToken::new();
        let state = app_state(&config, &jobs, metrics, &stop);
        tokio::spawn(retention::run(
            jobs.clone(),
            config.data_dir.join("jobs"),
            config.retention,
            stop.clone(),
        ));
        let app = http::router(state);
        let stop2 = stop.clone();
        let jobs2 = jobs.clone();
        tokio::spawn(async move {
            shutdown.await;
            stop2.cancel();
            jobs2.stop_rendering();
        });
        serve(
            listener,
            app,
            &stop,
            config.header_timeout,
            config.client_stall,
        )
        .await;
        // Never leave workers rendering behind us.
        stop.cancel();
        jobs.shutdown().await;
        Ok(())
    }

    /// Stops the workers without having served (the listener could not be had).
    pub async fn abandon(self) {
        self.jobs.shutdown().await;
    }
}

/// What the HTTP handlers share, from the configuration.
fn app_state(
    config: &Config,
    jobs: &jobs::Jobs,
    metrics: Arc<metrics::Metrics>,
    stop: &tokio_util::sync::CancellationToken,
) -> http::AppState {
    http::AppState {
        jobs: jobs.clone(),
        metrics,
        origin: Arc::new(origin::OriginPolicy::new(&config.allowed_hosts)),
        uploads: Arc::new(tokio::sync::Semaphore::new(
            config.validation_budget.div_ceil(1024).max(1),
        )),
        upload_budget_kib: config.validation_budget.div_ceil(1024).max(1),
        token: config
            .token
            .clone()
            .filter(|t| !t.is_empty())
            .map(Arc::from),
        stop: stop.clone(),
        max_body_bytes: config.max_body_bytes,
        request_deadline: config.request_deadline,
        max_watchers: config.max_watchers,
    }
}

/// This node as the job machinery sees it: on a shared database it is named (`--name`,
/// else [`default_node_name`]); on the embedded store it is the only node and unnamed.
fn node(config: &Config, workers: usize) -> jobs::Node {
    let shared = matches!(config.database, Some(store::Database::Postgres(_)));
    jobs::Node {
        name: shared.then(|| config.node_name.clone().unwrap_or_else(default_node_name)),
        workers,
        lease: config.lease,
        job_memory: config.job_memory,
    }
}

/// `HOST-PID`: unique among the processes of a farm, and says where to look.
#[must_use]
pub fn default_node_name() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|h| h.trim().to_owned())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "node".to_owned());
    format!("{host}-{}", std::process::id())
}

/// A worker node (`glimpse worker`, cluster.md), started: its store open and its one
/// worker running, before its `--metrics-addr` is bound (see [`Started`]).
pub async fn start_worker(config: Config) -> anyhow::Result<Started> {
    let Some(database @ store::Database::Postgres(_)) = config.database.clone() else {
        anyhow::bail!("glimpse worker needs a shared database: --database postgres://USER@HOST/DB (the embedded SQLite store has one node, `glimpse serve`, which renders its own jobs)");
    };
    let store = store::Store::connect(&database, &config.data_dir)
        .await
        .map_err(|e| anyhow::anyhow!("cannot open the job store {}: {e}", database.display()))?;
    let metrics = Arc::new(metrics::Metrics::default());
    let jobs = jobs::Jobs::start(
        store,
        node(&config, 1),
        config.limits,
        config.queue_capacity,
        config.job_timeout,
        Arc::clone(&metrics),
    )
    .await
    .map_err(|e| anyhow::anyhow!("cannot start the worker: {e}"))?;
    tracing::info!(
        name = jobs.node_name().unwrap_or_default(),
        "worker started on {}",
        database.display()
    );
    Ok(Started {
        config,
        jobs,
        metrics,
    })
}

/// A worker node: renders jobs claimed from the shared database, one at a time, until
/// `shutdown` resolves; then releases its job (to `queued`, for another worker) and
/// returns. With `metrics` (`--metrics-addr`) it serves its own `/healthz` and
/// `/metrics` there, under the same rules as an API node's (`http::node_router`); no
/// other HTTP.
pub async fn run_worker(
    config: Config,
    metrics: Option<tokio::net::TcpListener>,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    start_worker(config).await?.work(metrics, shutdown).await
}

impl Started {
    /// [`run_worker`] once started.
    pub async fn work(
        self,
        metrics: Option<tokio::net::TcpListener>,
        shutdown: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> anyhow::Result<()> {
        let Self {
            config,
            jobs,
            metrics: counters,
        } = self;
        let stop = tokio_util::sync::CancellationToken::new();
        let served = metrics.map(|listener| {
            let app = http::node_router(app_state(&config, &jobs, counters, &stop));
            let (stop, header, stall) = (stop.clone(), config.header_timeout, config.client_stall);
            tokio::spawn(async move { serve(listener, app, &stop, header, stall).await })
        });
        shutdown.await;
        stop.cancel();
        if let Some(served) = served {
            let _ = served.await;
        }
        jobs.shutdown().await;
        Ok(())
    }
}

/// `axum::serve` with timeouts, which it does not offer: hyper HTTP/1 connections (with
/// upgrades, for the streams) on `listener` until `stop` fires; then requests in flight get
/// [`DRAIN_ON_SHUTDOWN`] to finish (streams end by themselves on `stop`, see `ws`).
///
/// HTTP/1 only: axum's auto-detection of HTTP/2 waits for a connection's first bytes with
/// no timeout (measured: a silent connection, or an h2c one after its preface, was still
/// open after 25 s), and no client of this service needs HTTP/2 over plain TCP. hyper's
/// header timeout also runs while the connection is silent or idle between requests.
async fn serve(
    listener: tokio::net::TcpListener,
    app: axum::Router,
    stop: &tokio_util::sync::CancellationToken,
    header_timeout: Duration,
    client_stall: Duration,
) {
    use hyper_util::rt::{TokioIo, TokioTimer};
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(header_timeout);
    let connections = tokio_util::task::TaskTracker::new();
    loop {
        let stream = tokio::select! {
            r = listener.accept() => match r {
                Ok((stream, _)) => stream,
                Err(e) => {
                    // As axum::serve: a connection that died in the backlog is nothing;
                    // anything else (out of file descriptors) is worth a pause.
                    if !matches!(
                        e.kind(),
                        std::io::ErrorKind::ConnectionAborted
                            | std::io::ErrorKind::ConnectionRefused
                            | std::io::ErrorKind::ConnectionReset
                    ) {
                        tracing::error!("accept error: {e}");
                        tokio::time::sleep(Duration::from_secs(1)).await;
                    }
                    continue;
                }
            },
            () = stop.cancelled() => break,
        };
        let _ = stream.set_nodelay(true);
        let service = hyper_util::service::TowerToHyperService::new(app.clone());
        let conn = http
            .serve_connection(
                TokioIo::new(parse_error::JsonParseErrors::new(stall::StallLimit::new(
                    stream,
                    client_stall,
                ))),
                service,
            )
            .with_upgrades();
        let stop = stop.clone();
        connections.spawn(async move {
            let mut conn = std::pin::pin!(conn);
            let ended = tokio::select! {
                r = conn.as_mut() => r,
                () = stop.cancelled() => {
                    // Finish the request in flight, then close (idle ones close at once).
                    conn.as_mut().graceful_shutdown();
                    conn.await
                }
            };
            if let Err(e) = ended {
                tracing::debug!("connection ended: {e}");
            }
        });
    }
    drop(listener);
    connections.close();
    if tokio::time::timeout(DRAIN_ON_SHUTDOWN, connections.wait())
        .await
        .is_err()
    {
        // They end with the runtime; the workers are stopped next either way.
        tracing::warn!("requests still in flight after {DRAIN_ON_SHUTDOWN:?}: not waited for");
    }
}
