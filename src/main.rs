//! `glimpse`: parse the command line, run it, print one clear sentence on error.

use clap::Parser;

fn main() -> std::process::ExitCode {
    // Parse first: `serve --log-format json` decides how the subscriber formats.
    let cli = glimpse::cli::Cli::parse();
    let logs = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr);
    match cli.log_format() {
        glimpse::cli::LogFormat::Json => logs.json().init(),
        glimpse::cli::LogFormat::Text => logs.init(),
    }
    match glimpse::cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
