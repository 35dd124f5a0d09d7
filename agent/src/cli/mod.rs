//! The `million` command line: `train`, `eval`, `report`, `bench`, `env-check`, `config`.

mod access;
mod bench;
mod config;
mod env_check;
mod eval;
mod report;
mod train;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(name = "million", version, about = "The MILLION meta-RL agent")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Train with a run config; local env servers are started unless --env-server is given.
    Train(train::TrainArgs),
    /// Evaluate a checkpoint deterministically (per-task trial success).
    Eval(eval::EvalArgs),
    /// Figures (PNG) and report.md from run directories: learning curves, per-task success.
    Report(report::ReportArgs),
    /// Throughput benchmarks.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Check env servers against the API contract (exit code 1 on a failure).
    EnvCheck(env_check::EnvCheckArgs),
    /// Print the config a file resolves to (its `base =` chain and the defaults applied).
    Config(config::ConfigArgs),
}

/// Logs to stderr, filtered by RUST_LOG (default: info).
pub fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

/// A tokio runtime whose workers carry the gRPC streams; acting runs on the calling thread.
pub fn runtime(io_threads: usize) -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .worker_threads(io_threads.max(1))
        .enable_all()
        .build()?)
}

pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Train(a) => train::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Report(a) => report::run(a),
        Command::Bench(b) => bench::run(b),
        Command::EnvCheck(a) => env_check::run(a),
        Command::Config(a) => config::run(a),
    }
}
