//! `million bench env`: env steps/s through the API against the same envs stepped in-process.
//!
//! Served: K local `million-env-server` processes, the Rust pool over them, the batch split in
//! two groups that alternate (one steps on the servers while the other's reply is read, as in
//! training), uniform random actions. In-process: `bench/env/inprocess_rate.py`,
//! K Python processes stepping the same envs in a tight loop. Both run for the same seconds,
//! one after the other for each (env, K, batch), so load drifts hit both alike; the ratio
//! served ÷ in-process is what serving costs over simulating. `--latency` adds the round trip
//! of one step of a trivial env (CartPole-v1, batch 1), p50 and p99.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::Args;
use million_env::{
    ActionSampler, Actions, EnvPool, LocalServer, LocalServerOptions, PoolConfig,
    default_server_binary, find_in_repository,
};
use serde::Serialize;

use crate::train::servers::check_local_server_args;

/// The in-process side, run once per case.
const SCRIPT: &str = "bench/env/inprocess_rate.py";

#[derive(Debug, Args)]
pub struct EnvBench {
    /// Env ids (repeatable).
    #[arg(long = "env", default_values = ["million/ML10-train", "metaworld/ML10-train"])]
    pub envs: Vec<String>,
    /// Batch sizes (envs stepped together).
    #[arg(long, value_delimiter = ',', default_values = ["1", "4", "16", "64"])]
    pub batch: Vec<usize>,
    /// Server process counts K (the in-process side uses K worker processes).
    #[arg(long, value_delimiter = ',', default_values = ["1", "2"])]
    pub servers: Vec<usize>,
    /// Timed seconds of each side of each case (after a warm-up of a quarter as long).
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Round trips timed for the latency of a trivial env (0: skip).
    #[arg(long, default_value_t = 2000)]
    pub latency_steps: usize,
    /// One more command-line argument of every env server started (repeatable), e.g.
    /// `--server-arg=--idle-envs --server-arg=4`; as `runtime.env_server_args` of a config.
    #[arg(long = "server-arg", allow_hyphen_values = true)]
    pub server_args: Vec<String>,
    /// Python that runs the in-process side (default: the repository's .venv).
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// One JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Case {
    env: String,
    servers: usize,
    batch: usize,
    served_steps_per_s: f64,
    in_process_steps_per_s: f64,
    ratio: f64,
}

#[derive(Debug, Serialize)]
struct Latency {
    env: &'static str,
    round_trips: usize,
    p50_us: f64,
    p99_us: f64,
}

#[derive(Debug, Serialize)]
struct Report {
    cases: Vec<Case>,
    latency: Option<Latency>,
    load_average_before: Option<f64>,
    /// The CPU, as `million bench` prints it: timings compare between like CPUs only.
    machine: Option<String>,
}

pub fn run(args: &EnvBench) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(args.seconds > 0.0, "--seconds must be positive");
    check_local_server_args(&args.server_args).map_err(|e| anyhow::anyhow!("--server-arg: {e}"))?;
    let options = LocalServerOptions {
        extra_args: args.server_args.clone(),
        ..LocalServerOptions::default()
    };
    let python = super::python(args.python.as_deref());
    let script = find_in_repository(Path::new(SCRIPT))
        .with_context(|| format!("{SCRIPT} not found (set MILLION_ROOT)"))?;
    let binary = default_server_binary()?;
    let rt = crate::cli::runtime(2)?;
    let load_average_before = super::load_average();
    let mut cases = Vec::new();
    for env in &args.envs {
        for &servers in &args.servers {
            for &batch in &args.batch {
                if batch < servers {
                    continue;
                }
                let served = rt.block_on(served_rate(
                    &binary,
                    &options,
                    env,
                    servers,
                    batch,
                    args.seconds,
                ))?;
                let in_process =
                    in_process_rate(&python, &script, env, servers, batch, args.seconds)?;
                let case = Case {
                    env: env.clone(),
                    servers,
                    batch,
                    served_steps_per_s: served,
                    in_process_steps_per_s: in_process,
                    ratio: served / in_process,
                };
                if !args.json {
                    eprintln!(
                        "{:<22} K={} batch {:>3}: served {:>7.0} steps/s, in-process {:>7.0}, ratio {:.2}",
                        case.env, servers, batch, served, in_process, case.ratio
                    );
                }
                cases.push(case);
            }
        }
    }
    let latency = (args.latency_steps > 0)
        .then(|| rt.block_on(round_trip_latency(&binary, &options, args.latency_steps)))
        .transpose()?;
    let report = Report {
        cases,
        latency,
        load_average_before,
        machine: crate::machine::cpu_description(),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_table(&report);
    }
    Ok(ExitCode::SUCCESS)
}

fn print_table(report: &Report) {
    println!("| env | K | batch | served steps/s | in-process steps/s | served ÷ in-process |");
    println!("|---|---|---|---|---|---|");
    for c in &report.cases {
        println!(
            "| {} | {} | {} | {:.0} | {:.0} | {:.2} |",
            c.env, c.servers, c.batch, c.served_steps_per_s, c.in_process_steps_per_s, c.ratio
        );
    }
    if let Some(l) = &report.latency {
        println!(
            "\nround trip, {} batch 1, {} steps: p50 {:.0} µs, p99 {:.0} µs",
            l.env, l.round_trips, l.p50_us, l.p99_us
        );
    }
}

async fn start_servers(
    binary: &Path,
    options: &LocalServerOptions,
    count: usize,
) -> anyhow::Result<Vec<LocalServer>> {
    Ok(LocalServer::start_many(binary, options.clone(), count).await?)
}

async fn connect(servers: &[LocalServer], env: &str, batch: usize) -> anyhow::Result<EnvPool> {
    let mut cfg = PoolConfig::new(
        servers.iter().map(|s| s.addr().to_owned()).collect(),
        env,
        batch,
    );
    // Two alternating groups keep every server busy while a reply is read (as training).
    cfg.groups = if batch >= 2 * servers.len() { 2 } else { 1 };
    cfg.seed = Some(0);
    Ok(EnvPool::connect(cfg).await?)
}

/// Env steps/s of `batch` envs served by `servers` processes, pipelined over the groups.
async fn served_rate(
    binary: &Path,
    options: &LocalServerOptions,
    env: &str,
    servers: usize,
    batch: usize,
    seconds: f64,
) -> anyhow::Result<f64> {
    let procs = start_servers(binary, options, servers).await?;
    let mut pool = connect(&procs, env, batch).await?;
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 0)?;
    let groups = pool.num_groups();
    pool.reset_all().await?;
    for g in 0..groups {
        let rows = pool.group_envs(g).len();
        pool.send(g, Actions::Tensor(&sampler.sample(rows)))?;
    }
    let warm_up = Duration::from_secs_f64(seconds / 4.0);
    let timed = Duration::from_secs_f64(seconds);
    let start = Instant::now();
    let mut timing_from: Option<Instant> = None;
    let mut steps = 0usize;
    loop {
        for g in 0..groups {
            let step = pool.recv(g).await?;
            if timing_from.is_some() {
                steps += step.rows();
            }
            pool.send(g, Actions::Tensor(&sampler.sample(step.rows())))?;
        }
        match timing_from {
            None if start.elapsed() >= warm_up => timing_from = Some(Instant::now()),
            Some(t) if t.elapsed() >= timed => break,
            _ => {}
        }
    }
    let elapsed = timing_from.expect("timed").elapsed().as_secs_f64();
    for g in 0..groups {
        pool.recv(g).await?;
    }
    pool.close().await?;
    Ok(steps as f64 / elapsed)
}

fn in_process_rate(
    python: &Path,
    script: &Path,
    env: &str,
    workers: usize,
    batch: usize,
    seconds: f64,
) -> anyhow::Result<f64> {
    let out = Command::new(python)
        .arg(script)
        .args(["--env", env, "--batch", &batch.to_string()])
        .args([
            "--workers",
            &workers.to_string(),
            "--seconds",
            &seconds.to_string(),
        ])
        .output()
        .with_context(|| format!("cannot run {} (pass --python)", python.display()))?;
    anyhow::ensure!(
        out.status.success(),
        "{} failed ({}):\n{}",
        script.display(),
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let line = String::from_utf8_lossy(&out.stdout);
    let v: serde_json::Value = serde_json::from_str(line.trim())
        .with_context(|| format!("{} printed {line:?}, not JSON", script.display()))?;
    v["env_steps_per_s"]
        .as_f64()
        .context("in-process result has no env_steps_per_s")
}

/// Round trip of one step of CartPole-v1 (batch 1, one server): p50 and p99.
async fn round_trip_latency(
    binary: &Path,
    options: &LocalServerOptions,
    steps: usize,
) -> anyhow::Result<Latency> {
    const ENV: &str = "CartPole-v1";
    let procs = start_servers(binary, options, 1).await?;
    let mut pool = connect(&procs, ENV, 1).await?;
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 0)?;
    pool.reset_all().await?;
    let mut times = Vec::with_capacity(steps);
    for i in 0..steps + steps / 10 {
        let actions = sampler.sample(1);
        let t = Instant::now();
        pool.send(0, Actions::Tensor(&actions))?;
        pool.recv(0).await?;
        if i >= steps / 10 {
            times.push(t.elapsed().as_secs_f64() * 1e6);
        }
    }
    pool.close().await?;
    times.sort_by(f64::total_cmp);
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    Ok(Latency {
        env: ENV,
        round_trips: steps,
        p50_us: at(0.5),
        p99_us: at(0.99),
    })
}
