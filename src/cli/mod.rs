//! The command line (shared/spec/cli.md): one function per subcommand, all returning
//! `anyhow::Result` so `main` prints one clear sentence and exits non-zero.

pub mod compare;
pub mod convert;
pub mod phases;
pub mod render;

use anyhow::Context;
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
    /// Run a worker node: render jobs claimed from a shared PostgreSQL database, one at
    /// a time (shared/spec/cluster.md).
    Worker(WorkerArgs),
    /// Render one scene without a server.
    Render(render::RenderArgs),
    /// Import a scene (.pbrt, .gltf, .glb, .obj) and write the scene document Glimpse
    /// understood.
    Convert(convert::ConvertArgs),
    /// Perceptual distance between two images, in JNDs (just-noticeable differences).
    Compare(compare::CompareArgs),
    /// The speed-versus-accuracy study (runs anywhere: the examples are built in).
    Bench(BenchArgs),
}

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Address and port to listen on (HTTP and WebSocket; the viewer is at `/`). Beyond
    /// loopback, set a token.
    #[arg(long, default_value = "127.0.0.1:8080", value_name = "IP:PORT")]
    pub addr: String,
    /// Folder for the job database and every job's images (created if missing).
    #[arg(long, default_value = "./glimpse-data", value_name = "DIR")]
    pub data: PathBuf,
    /// Jobs rendered at once; each render uses every core, so more than 1 only helps
    /// short jobs wait less behind long ones. 0 (with a postgres:// database) makes an
    /// API node that only serves, leaving the rendering to worker nodes.
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub workers: usize,
    /// This node's name in the jobs it claims on a shared database (default HOST-PID).
    #[arg(long, value_name = "NAME")]
    pub name: Option<String>,
    /// Seconds a claimed job's lease lasts: a node silent for this long is presumed dead
    /// and its job runs again elsewhere. Heartbeats come ten times per lease.
    #[arg(long, default_value_t = crate::service::jobs::DEFAULT_LEASE.as_secs_f64(), value_parser = lease_seconds, value_name = "SECONDS")]
    pub lease: f64,
    /// Where the jobs live: `sqlite://DIR` (the same as `--data DIR`) or
    /// `postgres://USER@HOST/DB` (shared/spec/cluster.md); the password may come from
    /// `PGPASSWORD`.
    #[arg(long, value_parser = crate::service::store::Database::parse)]
    pub database: Option<crate::service::store::Database>,
    /// Require `Authorization: Bearer TOKEN` on every /v1 call.
    #[arg(long, env = "GLIMPSE_TOKEN")]
    pub token: Option<String>,
    /// Jobs that may wait for a worker before new submissions get 429 queue_full.
    #[arg(long, default_value_t = crate::service::DEFAULT_QUEUE_CAPACITY)]
    pub queue: usize,
    /// Largest image a request may ask for, in pixels (width × height; default 4096²).
    #[arg(long, value_name = "PIXELS")]
    pub max_pixels: Option<u64>,
    /// Largest image width a request may ask for (default 4096).
    #[arg(long, value_name = "PIXELS")]
    pub max_width: Option<u32>,
    /// Largest image height a request may ask for (default 4096).
    #[arg(long, value_name = "PIXELS")]
    pub max_height: Option<u32>,
    /// Most samples per pixel a request may ask for (default 4096).
    #[arg(long, value_name = "N")]
    pub max_spp: Option<u32>,
    /// Most paths one render may trace: samples per pixel × pixels (default 2^32).
    #[arg(long, value_name = "N")]
    pub max_samples: Option<u64>,
    /// Most objects in a request's scene (default 10000).
    #[arg(long, value_name = "N")]
    pub max_objects: Option<usize>,
    /// Most triangles in a request's scene, imported meshes included (default 1000000).
    #[arg(long, value_name = "N")]
    pub max_triangles: Option<usize>,
    /// Bounces a path may take at most (default 1024); a scene asking for more is
    /// rendered with this many, with a warning.
    #[arg(long, value_name = "N")]
    pub max_bounces: Option<u32>,
    /// Largest request body in bytes.
    #[arg(long, default_value_t = crate::service::DEFAULT_MAX_BODY_BYTES)]
    pub max_body: usize,
    /// Seconds a response or stream may wait for a client that reads nothing before
    /// its connection is cut.
    #[arg(long, default_value_t = crate::service::CLIENT_STALL.as_secs_f64(), value_parser = positive_seconds)]
    pub client_stall: f64,
    /// Seconds a render may run before it is stopped and its job failed (`timeout`).
    #[arg(long, default_value_t = crate::service::jobs::DEFAULT_JOB_TIMEOUT.as_secs_f64(), value_parser = positive_seconds)]
    pub job_timeout: f64,
    /// Gigabytes (10^9 bytes) one job may use: a submission whose size, mode and
    /// denoiser would need more gets 422 over_limit, and the denoiser works in tiles
    /// within what a job leaves of it.
    #[arg(long, default_value_t = crate::service::jobs::DEFAULT_JOB_MEMORY as f64 / 1e9, value_name = "GB", value_parser = positive_gb)]
    pub max_job_memory: f64,
    /// A host name (besides its addresses and `localhost`) by which clients reach this
    /// server, accepted in `Host` and `Origin` when there is no token; repeatable.
    #[arg(long = "allowed-host", value_name = "NAME")]
    pub allowed_hosts: Vec<String>,
    /// Finished jobs kept (the newest; older ones are forgotten with their pictures, as
    /// DELETE does); 0 keeps any number.
    #[arg(long, default_value_t = 1000, value_name = "N")]
    pub keep_jobs: usize,
    /// Days a finished job is kept; 0 keeps them for ever.
    #[arg(long, default_value_t = 30.0, value_name = "DAYS", value_parser = non_negative)]
    pub keep_days: f64,
    /// Gigabytes (10^9 bytes) the finished jobs' pictures may take on disk, the newest
    /// kept first; 0 is no limit.
    #[arg(long, default_value_t = 10.0, value_name = "GB", value_parser = non_negative)]
    pub keep_gb: f64,
    /// Log format on stderr: `text` for people, `json` (one object per line) for log
    /// collectors. Read by `main` before the subscriber is installed.
    #[arg(long, value_enum, env = "GLIMPSE_LOG_FORMAT", default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
}

#[derive(clap::Args, Debug)]
pub struct WorkerArgs {
    /// The shared job database: `postgres://USER@HOST/DB` (the password may come from
    /// `PGPASSWORD`).
    #[arg(long, value_parser = crate::service::store::Database::parse)]
    pub database: crate::service::store::Database,
    /// The folder of the jobs' images: the same shared storage every node of the
    /// cluster names with `--data` (README "Running a cluster").
    #[arg(long, default_value = "./glimpse-data", value_name = "DIR")]
    pub data: PathBuf,
    /// Threads per render (default: every core).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..=1024))]
    pub threads: Option<u16>,
    /// This worker's name in the jobs it claims (default HOST-PID).
    #[arg(long, value_name = "NAME")]
    pub name: Option<String>,
    /// Seconds a claimed job's lease lasts: a worker silent for this long is presumed
    /// dead and its job runs again elsewhere. Heartbeats come ten times per lease.
    #[arg(long, default_value_t = crate::service::jobs::DEFAULT_LEASE.as_secs_f64(), value_parser = lease_seconds, value_name = "SECONDS")]
    pub lease: f64,
    /// Seconds a render may run before it is stopped and its job failed (`timeout`).
    #[arg(long, default_value_t = crate::service::jobs::DEFAULT_JOB_TIMEOUT.as_secs_f64(), value_parser = positive_seconds)]
    pub job_timeout: f64,
    /// Gigabytes (10^9 bytes) one job may use: the denoiser works in tiles within what a
    /// job leaves of it (submissions are checked by the API node's own budget).
    #[arg(long, default_value_t = crate::service::jobs::DEFAULT_JOB_MEMORY as f64 / 1e9, value_name = "GB", value_parser = positive_gb)]
    pub max_job_memory: f64,
    /// Serve this worker's `/healthz` and `/metrics` on IP:PORT (as an API node does);
    /// none by default. Use a loopback address unless the network is trusted.
    #[arg(long, value_name = "IP:PORT")]
    pub metrics_addr: Option<String>,
    /// A host name (besides the address's and `localhost`) by which `/healthz` and
    /// `/metrics` are reached, accepted in `Host`; repeatable.
    #[arg(long = "allowed-host", value_name = "NAME")]
    pub allowed_hosts: Vec<String>,
    /// Log format on stderr: `text` for people, `json` (one object per line) for log
    /// collectors.
    #[arg(long, value_enum, env = "GLIMPSE_LOG_FORMAT", default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
}

/// How `main` formats tracing output.
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
            Command::Worker(a) => a.log_format,
            _ => LogFormat::Text,
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// A folder of scene documents (*.json) to study. Default: the five examples built
    /// into the binary (the project's `scenes/`), so the bench runs from any folder.
    #[arg(long, value_name = "DIR")]
    pub scenes: Option<PathBuf>,
    /// Where the report (report.md, results.json, plots) is written.
    #[arg(long, default_value = "bench-out", value_name = "DIR")]
    pub out: PathBuf,
    /// Small sizes that fit in CI.
    #[arg(long)]
    pub quick: bool,
    /// Multiply every scene's samples per pixel by this: the loop's own cost stays, the
    /// tracing grows, and the report shows how the time ratios move with a pixel's cost.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub spp_factor: u32,
    /// Scale every bundled scene up so its long side is at least this many pixels (the
    /// sizes people render: 512 or more); scenes already larger stay as they are.
    #[arg(long, value_name = "PIXELS", value_parser = clap::value_parser!(u32).range(1..=8192))]
    pub min_side: Option<u32>,
    /// Declared viewing conditions to judge every scene at, pixels per degree, comma
    /// separated (default 28,45,60,90; 28,60 with --quick).
    #[arg(long, value_delimiter = ',', value_parser = parse_ppd)]
    pub ppd: Vec<f32>,
    /// Also generate this many varied scenes (written to OUT/corpus/) and judge them.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub corpus: Option<u64>,
    /// Seed of the generated corpus: the same seed gives the same scenes.
    #[arg(long, default_value_t = 1, requires = "corpus")]
    pub seed: u64,
    /// Judge corpus scenes also at every --ppd condition, not only at their declared one.
    #[arg(long, requires = "corpus")]
    pub corpus_at_conditions: bool,
    /// Judge the corpus alone (skip the scenes of --scenes).
    #[arg(long, requires = "corpus")]
    pub corpus_only: bool,
    /// The corpus's sizes and samples: `small` (references under a second; what the tests
    /// run) or `users` (256–1024 px, 64–1024 spp, references of about 1–20 s).
    #[arg(long, value_enum, default_value_t, requires = "corpus")]
    pub corpus_profile: crate::bench::corpus::Profile,
    /// Also study the public scenes of DIR (each NAME/scene-v4.pbrt, e.g. the shared
    /// scenes-public folder) at 512 px on the long side, with the samples per pixel that
    /// make a reference of about 8 s here (16 at least). Not run with --quick.
    #[arg(long, value_name = "DIR")]
    pub public: Option<PathBuf>,
    /// Judge every scene at the --ppd conditions only (truth, Q and time, adaptive against
    /// uniform + OIDN), without the per-method table, the time split and the t0 sweeps.
    #[arg(long)]
    pub judge_only: bool,
    /// Alternating timed runs whose medians make each time ratio (default 3; 1 with --quick).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: Option<u32>,
    /// The longest one scene's truth may take to trace, seconds (default 300; 20 with
    /// --quick): the truth's samples double while its own error is above a quarter of the
    /// reference's, within this.
    #[arg(long, value_name = "SECONDS", value_parser = parse_seconds)]
    pub truth_cap: Option<f64>,
    /// Where converged renders are cached (default OUT/cache).
    #[arg(long)]
    pub cache: Option<PathBuf>,
}

/// Seconds: a finite number in (0, 1e6].
fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1e6 => Ok(v),
        _ => Err(format!("{s:?} is not a number of seconds in (0, 1000000]")),
    }
}

/// Pixels per degree: a finite number in (0, 1000] (1000 is far beyond any display seen
/// by a person; FLIP's filters grow with it).
fn parse_ppd(s: &str) -> Result<f32, String> {
    let v: f32 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number of pixels per degree"))?;
    if v.is_finite() && v > 0.0 && v <= 1000.0 {
        Ok(v)
    } else {
        Err(format!("pixels per degree must lie in (0, 1000], got {s}"))
    }
}

/// Runs the parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Render(a) => render::run(&a),
        Command::Compare(a) => compare::run(&a),
        Command::Convert(a) => convert::run(&a),
        Command::Serve(a) => serve(a),
        Command::Worker(a) => worker(a),
        Command::Bench(a) => bench(&a),
    }
}

fn serve(a: ServeArgs) -> anyhow::Result<()> {
    let mut limits = crate::service::server_limits();
    set_limits(&mut limits, &a);
    if a.queue == 0 {
        anyhow::bail!("--queue must be at least 1");
    }
    if let Some(t) = &a.token {
        // An empty token used to switch the check off silently; a blank one can never
        // match (the header's value is trimmed).
        if t.trim().is_empty() {
            anyhow::bail!(
                "the token (--token or GLIMPSE_TOKEN) is empty or blank; give a real one, or unset it to run without"
            );
        }
    }
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async move {
        let addr = a.addr.clone();
        let has_token = a.token.is_some();
        let mut config = crate::service::Config::new(a.data);
        config.database = a.database;
        config.workers = a.workers;
        config.node_name = a.name;
        config.lease = std::time::Duration::from_secs_f64(a.lease);
        config.token = a.token;
        config.queue_capacity = a.queue;
        config.max_body_bytes = a.max_body;
        config.client_stall = std::time::Duration::from_secs_f64(a.client_stall);
        config.job_timeout = std::time::Duration::from_secs_f64(a.job_timeout);
        config.job_memory = (a.max_job_memory * 1e9) as u64;
        config.allowed_hosts = a.allowed_hosts;
        config.retention = crate::service::retention::Retention {
            max_jobs: (a.keep_jobs > 0).then_some(a.keep_jobs),
            max_age: (a.keep_days > 0.0)
                .then(|| std::time::Duration::from_secs_f64(a.keep_days * 86_400.0)),
            max_bytes: (a.keep_gb > 0.0).then_some((a.keep_gb * 1e9) as u64),
        };
        config.limits = limits;
        // The store is opened and checked first: a server that cannot start never says
        // it is listening.
        let started = crate::service::start(config).await?;
        let listener = match tokio::net::TcpListener::bind(&addr).await {
            Ok(l) => l,
            Err(e) => {
                started.abandon().await;
                anyhow::bail!("cannot listen on {addr}: {e}");
            }
        };
        let local = listener.local_addr()?;
        tracing::info!("listening on http://{local}");
        if !has_token && !local.ip().is_loopback() {
            tracing::warn!(
                "listening on {local}, beyond this machine, without a token: anyone who can reach it can submit, cancel and delete jobs; set --token or GLIMPSE_TOKEN"
            );
        }
        started.serve(listener, shutdown_signal()).await
    })
}

/// The request limits given on the command line (`--max-*`), over the defaults of
/// `service::server_limits`.
fn set_limits(l: &mut crate::scene::Limits, a: &ServeArgs) {
    l.max_pixels = a.max_pixels.unwrap_or(l.max_pixels);
    l.max_width = a.max_width.unwrap_or(l.max_width);
    l.max_height = a.max_height.unwrap_or(l.max_height);
    l.max_samples_per_pixel = a.max_spp.unwrap_or(l.max_samples_per_pixel);
    l.max_sample_budget = a.max_samples.unwrap_or(l.max_sample_budget);
    l.max_objects = a.max_objects.unwrap_or(l.max_objects);
    l.max_triangles = a.max_triangles.unwrap_or(l.max_triangles);
    l.max_bounces = a.max_bounces.unwrap_or(l.max_bounces);
}

/// `glimpse worker`: a rayon pool of `--threads`, then the worker until Ctrl-C or SIGTERM.
fn worker(a: WorkerArgs) -> anyhow::Result<()> {
    if let Some(n) = a.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(usize::from(n))
            .build_global()
            .context("cannot start the render threads")?;
    }
    let mut config = crate::service::Config::new(a.data);
    config.database = Some(a.database);
    config.node_name = a.name;
    config.lease = std::time::Duration::from_secs_f64(a.lease);
    config.job_timeout = std::time::Duration::from_secs_f64(a.job_timeout);
    config.job_memory = (a.max_job_memory * 1e9) as u64;
    config.allowed_hosts = a.allowed_hosts;
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async move {
        // The store first, as for `serve`.
        let started = crate::service::start_worker(config).await?;
        let listener = match &a.metrics_addr {
            Some(addr) => {
                let l = match tokio::net::TcpListener::bind(addr).await {
                    Ok(l) => l,
                    Err(e) => {
                        started.abandon().await;
                        anyhow::bail!("cannot listen on {addr}: {e}");
                    }
                };
                let local = l.local_addr()?;
                tracing::info!("/healthz and /metrics on http://{local}");
                if !local.ip().is_loopback() {
                    tracing::warn!("/healthz and /metrics on {local}, beyond this machine: anyone who can reach it reads this worker's counters");
                }
                Some(l)
            }
            None => None,
        };
        started.work(listener, shutdown_signal()).await
    })
}

/// A lease in seconds: from 1 s (ten heartbeats of 100 ms) to an hour.
fn lease_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && (1.0..=3600.0).contains(&v) => Ok(v),
        _ => Err(format!("{s:?} must be a number of seconds from 1 to 3600")),
    }
}

/// A finite number at least 0 and at most 10^6 (days or gigabytes).
fn non_negative(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && (0.0..=1e6).contains(&v) => Ok(v),
        _ => Err(format!("{s:?} must be a number from 0 to 1000000")),
    }
}

/// A duration in seconds for a flag: finite, above zero, at most a day.
fn positive_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number of seconds"))?;
    if v.is_finite() && v > 0.0 && v <= 86_400.0 {
        Ok(v)
    } else {
        Err(format!("{s} s is outside (0, 86400]"))
    }
}

/// Gigabytes of memory for `--max-job-memory`: at least 0.5 (the server itself and a
/// small job need that much), at most 1 PB.
fn positive_gb(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a number of gigabytes"))?;
    if v.is_finite() && (0.5..=1e6).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{s} GB is outside [0.5, 1000000]"))
    }
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
    let scenes = match &a.scenes {
        Some(dir) => dir.clone(),
        None if a.corpus_only => a.out.join("examples"), // not read
        None => write_builtin_examples(&a.out)?,
    };
    let mut cfg = crate::bench::BenchConfig::new(scenes, a.out.clone(), a.quick);
    cfg.spp_factor = a.spp_factor;
    cfg.min_side = a.min_side;
    if !a.ppd.is_empty() {
        cfg.conditions.clone_from(&a.ppd);
    }
    if let Some(dir) = &a.cache {
        cfg.cache_dir.clone_from(dir);
    }
    cfg.bundled = !a.corpus_only;
    cfg.public_dir.clone_from(&a.public);
    cfg.judge_only = a.judge_only;
    if let Some(r) = a.runs {
        cfg.runs = r as usize;
    }
    if let Some(c) = a.truth_cap {
        cfg.truth_cap_s = c;
    }
    cfg.corpus = a.corpus.map(|n| crate::bench::CorpusConfig {
        scenes: usize::try_from(n).unwrap_or(usize::MAX),
        seed: a.seed,
        profile: a.corpus_profile,
        at_conditions: a.corpus_at_conditions,
    });
    let study = crate::bench::run(&cfg)?;
    eprintln!(
        "bench: {} scenes, {} corpus scenes; report in {}",
        study.scenes.len(),
        study.corpus.len(),
        a.out.join("report.md").display()
    );
    Ok(())
}

/// Writes the examples built into the binary into `OUT/examples/` and returns that folder:
/// the bench reads scenes from files (the peer renderer and the report name them).
fn write_builtin_examples(out: &std::path::Path) -> anyhow::Result<PathBuf> {
    let dir = out.join("examples");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for (name, text) in crate::scene::examples::EXAMPLES {
        let p = dir.join(format!("{name}.json"));
        std::fs::write(&p, text).with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ppd_is_a_positive_finite_number_up_to_a_thousand() {
        assert_eq!(parse_ppd("28"), Ok(28.0));
        assert_eq!(parse_ppd(" 60.5"), Ok(60.5));
        assert_eq!(parse_ppd("1000"), Ok(1000.0));
        for bad in ["0", "-5", "NaN", "inf", "1000.5", "sixty", ""] {
            assert!(parse_ppd(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_truth_cap_is_a_positive_finite_number_of_seconds() {
        assert_eq!(parse_seconds("300"), Ok(300.0));
        assert_eq!(parse_seconds(" 0.5"), Ok(0.5));
        for bad in ["0", "-1", "NaN", "inf", "1e7", "soon", ""] {
            assert!(parse_seconds(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_job_memory_budget_is_half_a_gigabyte_to_a_petabyte() {
        assert_eq!(positive_gb("10"), Ok(10.0));
        assert_eq!(positive_gb("0.5"), Ok(0.5));
        for bad in ["0.4", "0", "-1", "NaN", "inf", "1e7", "ten", ""] {
            assert!(positive_gb(bad).is_err(), "{bad}");
        }
    }

    /// Each `--max-*` flag sets its own limit and no other (the 422 tests reach two of
    /// them through a real server).
    #[test]
    fn each_serve_limit_flag_sets_its_own_limit() {
        let cli = Cli::try_parse_from([
            "glimpse",
            "serve",
            "--max-pixels",
            "1",
            "--max-width",
            "2",
            "--max-height",
            "3",
            "--max-spp",
            "4",
            "--max-samples",
            "5",
            "--max-objects",
            "6",
            "--max-triangles",
            "7",
            "--max-bounces",
            "8",
        ])
        .unwrap();
        let Command::Serve(a) = cli.command else {
            panic!("not serve");
        };
        let mut l = crate::service::server_limits();
        set_limits(&mut l, &a);
        assert_eq!(
            (
                l.max_pixels,
                l.max_width,
                l.max_height,
                l.max_samples_per_pixel,
                l.max_sample_budget,
                l.max_objects,
                l.max_triangles,
                l.max_bounces
            ),
            (1, 2, 3, 4, 5, 6, 7, 8)
        );
        // Without the flags the server's defaults stay.
        let Command::Serve(a) = Cli::try_parse_from(["glimpse", "serve"]).unwrap().command else {
            panic!("not serve");
        };
        let mut l = crate::service::server_limits();
        set_limits(&mut l, &a);
        let d = crate::service::server_limits();
        assert_eq!((l.max_width, l.max_bounces), (d.max_width, d.max_bounces));
    }
}
