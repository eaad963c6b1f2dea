//! The render service: REST jobs, a durable embedded store, a worker pool and WebSocket
//! streaming (shared/spec/service-api.md). The only async code and the only wire JSON.
//! Owned by issue #5.
//!
//! Layout:
//! - [`http`]: router, limit layers, extractors, `ApiError` (the only type that knows
//!   status codes);
//! - [`jobs`]: bounded queue, worker threads, cancellation, state transitions, ETA;
//! - [`store`]: SQLite (sqlx, WAL) job records and the final images beside them;
//! - [`ws`]: the stream protocol over a `watch` channel per job;
//! - [`metrics`]: Prometheus text; [`auth`]: the optional bearer token;
//! - [`examples`]: the bundled scenes; [`viewer`]: the browser page.

pub mod auth;
pub mod examples;
pub mod http;
pub mod jobs;
pub mod metrics;
pub mod store;
pub mod viewer;
pub mod ws;

use crate::scene::Limits;
use std::path::PathBuf;
use std::sync::Arc;

/// Everything the service needs, parsed once in `main`.
#[derive(Clone, Debug)]
pub struct Config {
    pub data_dir: PathBuf,
    /// Concurrent renders (each render already uses every core through rayon, so more
    /// than one or two workers only helps many small jobs).
    pub workers: usize,
    /// If set, every `/v1` call needs `Authorization: Bearer <token>`.
    pub token: Option<String>,
    /// Jobs waiting for a worker before submissions get `429 queue_full`: bounds memory
    /// and tells clients early that the server is saturated.
    pub queue_capacity: usize,
    /// Largest request body (a scene with an inline mesh); above it `413 too_large`.
    pub max_body_bytes: usize,
    /// Scene size limits for requests (pixels, sample budget, objects, triangles).
    pub limits: Limits,
    /// Open job streams, all jobs together; beyond it `503 unavailable` (each stream holds
    /// a connection, a task and possibly an encoded frame).
    pub max_watchers: usize,
}

impl Config {
    /// Defaults for everything but the data folder.
    #[must_use]
    pub fn new(data_dir: impl Into<PathBuf>) -> Self {
        Self {
            data_dir: data_dir.into(),
            workers: 1,
            token: None,
            queue_capacity: DEFAULT_QUEUE_CAPACITY,
            max_body_bytes: DEFAULT_MAX_BODY_BYTES,
            limits: server_limits(),
            max_watchers: DEFAULT_MAX_WATCHERS,
        }
    }
}

/// 64 waiting jobs: at a few seconds each, minutes of backlog; more is better refused.
pub const DEFAULT_QUEUE_CAPACITY: usize = 64;
/// 256 streams: a lecture room watching one job, with room to spare.
pub const DEFAULT_MAX_WATCHERS: usize = 256;
/// 8 MiB: room for a mesh of ~100k triangles in JSON, small enough to buffer per request.
pub const DEFAULT_MAX_BODY_BYTES: usize = 8 << 20;

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
        max_bounces: 64,
    }
}

/// Serves on `listener` until `shutdown` resolves.
///
/// Shutdown order: stop accepting connections and close open streams; cancel running
/// renders and put their jobs back to `queued` in the store (they run again after a
/// restart); join the workers; close the database; return.
pub async fn run(
    listener: tokio::net::TcpListener,
    config: Config,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let store = store::Store::open(&config.data_dir).await.map_err(|e| {
        anyhow::anyhow!(
            "cannot open the job store in {}: {e}",
            config.data_dir.display()
        )
    })?;
    let metrics = Arc::new(metrics::Metrics::default());
    let jobs = jobs::Jobs::start(
        store,
        config.limits,
        config.workers,
        config.queue_capacity,
        Arc::clone(&metrics),
    )
    .await
    .map_err(|e| anyhow::anyhow!("cannot start the workers: {e}"))?;
    let stop = tokio_util::sync::CancellationToken::new();
    let state = http::AppState {
        jobs: jobs.clone(),
        metrics,
        token: config.token.filter(|t| !t.is_empty()).map(Arc::from),
        stop: stop.clone(),
        max_body_bytes: config.max_body_bytes,
        max_watchers: config.max_watchers,
    };
    let app = http::router(state);
    let stop2 = stop.clone();
    tokio::spawn(async move {
        shutdown.await;
        stop2.cancel();
    });
    let served = axum::serve(listener, app)
        .with_graceful_shutdown(stop.clone().cancelled_owned())
        .await;
    // Also reached if serving failed: never leave workers rendering behind us.
    stop.cancel();
    jobs.shutdown().await;
    served.map_err(|e| anyhow::anyhow!("server error: {e}"))
}
