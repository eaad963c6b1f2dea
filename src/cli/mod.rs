//! The command line (shared/spec/cli.md): one function per subcommand, all returning
//! `anyhow::Result` so `main` prints one clear sentence and exits non-zero.

pub mod compare;
pub mod render;

use clap::{Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(name = "glimpse", version, about = "Progressive perceptual rendering (Farrugia & Péroche 2004)")]
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
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Render(a) => render::run(&a),
        Command::Compare(a) => compare::run(&a),
        Command::Serve(a) => serve(a),
        Command::Bench(_a) => anyhow::bail!("bench: not built yet (issue #4)"),
    }
}

fn serve(a: ServeArgs) -> anyhow::Result<()> {
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&a.addr)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", a.addr))?;
        tracing::info!("listening on http://{}", listener.local_addr()?);
        let config = crate::service::Config { data_dir: a.data, workers: a.workers.max(1), token: a.token };
        crate::service::run(listener, config, async {
            let _ = tokio::signal::ctrl_c().await;
        })
        .await
    })
}
