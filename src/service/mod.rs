//! The render service: REST jobs, a durable embedded store, a worker pool and WebSocket
//! streaming (shared/spec/service-api.md). The only async code and the only wire JSON.
//! Owned by issue #5.

use std::path::PathBuf;

/// Everything the service needs, parsed once in `main`.
#[derive(Clone, Debug)]
pub struct Config {
    pub data_dir: PathBuf,
    /// Concurrent renders.
    pub workers: usize,
    /// If set, every `/v1` call needs `Authorization: Bearer <token>`.
    pub token: Option<String>,
}

/// Serves on `listener` until `shutdown` resolves.
pub async fn run(
    listener: tokio::net::TcpListener,
    config: Config,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let _ = (listener, config, shutdown);
    todo!("issue #5")
}
