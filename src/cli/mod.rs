//! The command line (shared/spec/cli.md): one function per subcommand, all returning
//! `anyhow::Result` so `main` prints one clear sentence and exits non-zero.

pub mod compare;
pub mod convert;
pub mod render;

use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "glimpse",
    version,
    about = "Progressive perceptual rendering (Farrugia & Péroche 2004)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run the render service (REST, WebSocket, viewer).
    Serve(ServeArgs),
    /// Render one scene without a server.
    Render(render::RenderArgs),
    /// Import a scene (.pbrt) and write the scene document Glimpse understood.
    Convert(convert::ConvertArgs),
    /// Perceptual distance between two images.
    Compare(compare::CompareArgs),
    /// The speed-versus-accuracy study.
    Bench(BenchArgs),
}

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: String,
    #[arg(long, default_value = "./glimpse-data")]
    pub data: PathBuf,
    #[arg(long, default_value_t = 1)]
    pub workers: usize,
    /// Require `Authorization: Bearer TOKEN` on every /v1 call.
    #[arg(long, env = "GLIMPSE_TOKEN")]
    pub token: Option<String>,
    /// Jobs that may wait for a worker before new submissions get 429 queue_full.
    #[arg(long, default_value_t = crate::service::DEFAULT_QUEUE_CAPACITY)]
    pub queue: usize,
    /// Largest image a request may ask for, in pixels (width × height).
    #[arg(long)]
    pub max_pixels: Option<u64>,
    /// Largest request body in bytes.
    #[arg(long, default_value_t = crate::service::DEFAULT_MAX_BODY_BYTES)]
    pub max_body: usize,
    /// Log format on stderr: `text` for people, `json` (one object per line) for log
    /// collectors. Read by `main` before the subscriber is installed.
    #[arg(long, value_enum, env = "GLIMPSE_LOG_FORMAT", default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
}

/// How `main` formats tracing output (issue #6, operations).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LogFormat {
    #[default]
    Text,
    Json,
}

impl Cli {
    /// The log format asked for: only `serve` has the option; other commands log text.
    #[must_use]
    pub fn log_format(&self) -> LogFormat {
        match &self.command {
            Command::Serve(a) => a.log_format,
            _ => LogFormat::Text,
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    #[arg(long, default_value = "scenes")]
    pub scenes: PathBuf,
    #[arg(long, default_value = "bench-out")]
    pub out: PathBuf,
    /// Small sizes that fit in CI.
    #[arg(long)]
    pub quick: bool,
    /// Multiply every scene's samples per pixel by this: the loop's own cost stays, the
    /// tracing grows, and the report shows how the time ratios move with a pixel's cost.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub spp_factor: u32,
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Render(a) => render::run(&a),
        Command::Compare(a) => compare::run(&a),
        Command::Convert(a) => convert::run(&a),
        Command::Serve(a) => serve(a),
        Command::Bench(a) => bench(&a),
    }
}

fn serve(a: ServeArgs) -> anyhow::Result<()> {
    if a.workers == 0 {
        anyhow::bail!("--workers must be at least 1");
    }
    if a.queue == 0 {
        anyhow::bail!("--queue must be at least 1");
    }
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&a.addr)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", a.addr))?;
        tracing::info!("listening on http://{}", listener.local_addr()?);
        let mut config = crate::service::Config::new(a.data);
        config.workers = a.workers;
        config.token = a.token;
        config.queue_capacity = a.queue;
        config.max_body_bytes = a.max_body;
        if let Some(p) = a.max_pixels {
            config.limits.max_pixels = p;
        }
        crate::service::run(listener, config, shutdown_signal()).await
    })
}

/// Ctrl-C, or SIGTERM on Unix (what service managers and containers send).
async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {}
        () = term => {}
    }
    tracing::info!("shutting down");
}

fn bench(a: &BenchArgs) -> anyhow::Result<()> {
    let cfg = crate::bench::BenchConfig {
        scenes_dir: a.scenes.clone(),
        out_dir: a.out.clone(),
        quick: a.quick,
        spp_factor: a.spp_factor,
    };
    let results = crate::bench::run(&cfg)?;
    eprintln!(
        "bench: {} scenes; report in {}",
        results.len(),
        a.out.join("report.md").display()
    );
    Ok(())
}
