//! Prometheus text metrics (`GET /metrics`, service-api.md): jobs by state, queue depth,
//! pixels traced, render seconds, WebSocket watchers. Counters are plain atomics updated
//! by the workers and the stream handlers; job counts come from the store when scraped.

use super::store::JobState;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::sync::Arc;

#[derive(Debug, Default)]
pub struct Metrics {
    pub jobs_submitted: AtomicU64,
    pub jobs_running: AtomicI64,
    pub pixels_traced: AtomicU64,
    /// Render wall time in microseconds (an integer counter; exported in seconds).
    render_micros: AtomicU64,
    pub ws_watchers: AtomicI64,
    pub http_errors: AtomicU64,
    /// PNGs of a frame's image encoded for the streams and the final file. A frame is
    /// encoded only when a watcher (or the final file) takes it, so with nobody watching
    /// this grows by one per job, not by one per frame.
    pub frames_encoded: AtomicU64,
    /// Jobs this node's workers claimed (cluster.md: per node).
    pub claims: AtomicU64,
    /// Leases this node's workers lost (presumed dead, the job went elsewhere).
    pub lease_losses: AtomicU64,
    /// Heartbeats that came more than two periods after the previous one held.
    pub heartbeats_late: AtomicU64,
    /// Jobs whose expired lease this node's reaper ended or queued again.
    pub jobs_reaped: AtomicU64,
}

impl Metrics {
    pub fn add_render_seconds(&self, s: f64) {
        if s.is_finite() && s > 0.0 {
            self.render_micros
                .fetch_add((s * 1e6) as u64, Ordering::Relaxed);
        }
    }
}

/// Decrements the watcher gauge when a stream ends, however it ends.
pub struct WatcherGuard(Arc<Metrics>);

impl WatcherGuard {
    pub fn new(m: Arc<Metrics>) -> Self {
        m.ws_watchers.fetch_add(1, Ordering::Relaxed);
        Self(m)
    }
}

impl Drop for WatcherGuard {
    fn drop(&mut self) {
        self.0.ws_watchers.fetch_sub(1, Ordering::Relaxed);
    }
}

/// What the exposition reads from the job store when scraped.
#[derive(Debug, Default)]
pub struct StoreCounts {
    /// Jobs by state (a state absent from the list has none).
    pub by_state: Vec<(JobState, i64)>,
    /// Jobs waiting for a worker, on every node.
    pub queue_depth: i64,
    /// This node's name in the jobs it claims (cluster nodes only).
    pub node_name: Option<String>,
}

/// The exposition text (format 0.0.4).
#[must_use]
pub fn render(m: &Metrics, store: &StoreCounts) -> String {
    let mut out = jobs_by_state(&store.by_state);
    if let Some(name) = &store.node_name {
        out.push_str(&node(name));
    }
    for (name, kind, help, value) in counters(m, store) {
        let _ = writeln!(out, "# HELP {name} {help}");
        let _ = writeln!(out, "# TYPE {name} {kind}");
        let _ = writeln!(out, "{name} {value}");
    }
    out
}

fn jobs_by_state(counts: &[(JobState, i64)]) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# HELP glimpse_jobs Jobs in the store, by state.");
    let _ = writeln!(out, "# TYPE glimpse_jobs gauge");
    for st in JobState::ALL {
        let n = counts.iter().find(|(s, _)| *s == st).map_or(0, |(_, n)| *n);
        let _ = writeln!(out, "glimpse_jobs{{state=\"{}\"}} {n}", st.as_str());
    }
    out
}

/// Which node answered, for scrapers of many nodes (the name is ours or an operator's
/// `--name`; quotes and backslashes escaped as the format asks).
fn node(name: &str) -> String {
    let name = name
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n");
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# HELP glimpse_node This node's name in the jobs it claims."
    );
    let _ = writeln!(out, "# TYPE glimpse_node gauge");
    let _ = writeln!(out, "glimpse_node{{name=\"{name}\"}} 1");
    out
}

/// (name, type, help, value) of every counter and gauge besides the jobs and the node.
fn counters(
    m: &Metrics,
    store: &StoreCounts,
) -> [(&'static str, &'static str, &'static str, String); 11] {
    [
        (
            "glimpse_queue_depth",
            "gauge",
            "Jobs waiting for a worker (all nodes).",
            store.queue_depth.to_string(),
        ),
        (
            "glimpse_jobs_submitted_total",
            "counter",
            "Jobs accepted since start.",
            m.jobs_submitted.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_pixels_traced_total",
            "counter",
            "Pixels traced by all renders since start.",
            m.pixels_traced.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_render_seconds_total",
            "counter",
            "Wall time spent rendering since start.",
            format!(
                "{:.6}",
                m.render_micros.load(Ordering::Relaxed) as f64 / 1e6
            ),
        ),
        (
            "glimpse_websocket_watchers",
            "gauge",
            "Open job streams.",
            m.ws_watchers.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_http_errors_total",
            "counter",
            "Error responses sent.",
            m.http_errors.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_frames_encoded_total",
            "counter",
            "Frame images encoded as PNG (for watchers or the final file).",
            m.frames_encoded.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_claims_total",
            "counter",
            "Jobs this node's workers claimed.",
            m.claims.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_lease_losses_total",
            "counter",
            "Leases this node's workers lost (presumed dead; the job went to another worker).",
            m.lease_losses.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_heartbeats_late_total",
            "counter",
            "Heartbeats that held more than two periods after the previous one.",
            m.heartbeats_late.load(Ordering::Relaxed).to_string(),
        ),
        (
            "glimpse_jobs_reaped_total",
            "counter",
            "Jobs with an expired lease that this node's reaper queued again or ended.",
            m.jobs_reaped.load(Ordering::Relaxed).to_string(),
        ),
    ]
}
