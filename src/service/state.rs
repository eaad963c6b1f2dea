//! What every handler shares: the job engine, the counters, the token, the origin
//! policy, the limits on requests (the bottom of the HTTP layer: it imports no handler).

use super::jobs::Jobs;
use super::metrics::Metrics;
use std::sync::Arc;
use tokio_util::sync::CancellationToken;

/// Shared by every handler.
#[derive(Clone)]
pub struct AppState {
    pub jobs: Jobs,
    pub metrics: Arc<Metrics>,
    /// Bearer token for `/v1` (None: open).
    pub token: Option<Arc<str>>,
    /// Fires on shutdown: open streams close.
    pub stop: CancellationToken,
    pub max_body_bytes: usize,
    /// `http::REQUEST_DEADLINE` unless a test shortens it.
    pub request_deadline: std::time::Duration,
    pub max_watchers: usize,
    /// Which `Host` and `Origin` name this server (checked only without a token).
    pub origin: Arc<super::origin::OriginPolicy>,
    /// Bytes of request bodies in validation, in KiB permits (`Config::validation_budget`),
    /// and the budget's size.
    pub uploads: Arc<tokio::sync::Semaphore>,
    pub upload_budget_kib: usize,
}
