//! `million bench <kind>`: every benchmark of BENCHMARKS.md, one entry point. `acting` and
//! `train` are here; `env`, `learner`, `learning`, the PyTorch reference of `learner` and
//! the env server's Python benchmarks (`script`) have a module each. The Python they run
//! lives in bench/ at the repository's root.

mod env;
mod learner;
mod learning;
mod reference;
mod script;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Args, Subcommand};
use serde::Serialize;
use tch::{Device, Kind, Tensor};

use crate::algo::buffer::SegmentBatch;
use crate::config::AgentConfig;
use crate::procstat::{self, ChildSampler, ProcessUsage};
use crate::run_config::RunConfig;
use crate::train::session::{TrainOptions, train};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Learner updates per second on random segments of the config's sizes.
    Learner {
        #[command(flatten)]
        bench: ModelBench,
        #[command(flatten)]
        reference: reference::ReferenceArgs,
        #[command(flatten)]
        against: learner::AgainstArgs,
    },
    /// Acting steps per second (all env slots) of the config's model, no envs.
    Acting(ModelBench),
    /// End-to-end training throughput: agent steps/s, updates/s, actor/learner CPU split,
    /// CPU seconds and peak memory of the agent and of every local env server.
    Train(TrainBench),
    /// Env steps/s served through the API against the same envs stepped in-process.
    Env(env::EnvBench),
    /// Whether a config learns to its success targets within a wall-clock budget, and its
    /// first-trial gap to an ablation at the same agent steps (RESULTS.md's targets).
    Learning(learning::LearningBench),
    /// One of the env server's Python benchmarks (bench/env/), run with the repository's
    /// Python; the arguments after NAME go to the script (`NAME --help` lists them).
    Script(script::ScriptBench),
}

#[derive(Debug, Args)]
pub struct ModelBench {
    #[arg(long)]
    pub config: PathBuf,
    /// Timed repetitions.
    #[arg(long, default_value_t = 5)]
    pub iters: usize,
}

#[derive(Debug, Args)]
pub struct TrainBench {
    #[arg(long)]
    pub config: PathBuf,
    #[arg(long, default_value_t = 60.0)]
    pub seconds: f64,
    #[arg(long = "env-server")]
    pub env_servers: Vec<String>,
    /// One JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

fn random_batch(cfg: &AgentConfig, b: i64) -> SegmentBatch {
    let m = &cfg.model;
    let t = m.segment_len as i64;
    let a = m.action_dim as i64;
    let opts = (Kind::Float, Device::Cpu);
    let flags = |p: f64| Tensor::rand([b, t], opts).lt(p);
    SegmentBatch {
        obs: Tensor::randn([b, t, m.obs_dim() as i64], opts),
        actions: Tensor::randn([b, t, a], opts),
        rewards: Tensor::randn([b, t], opts),
        terminated: flags(0.003),
        truncated: flags(0.0),
        episode_start: flags(0.003),
        instruction: flags(0.1),
        task: Tensor::randint(m.num_tasks as i64, [b, t], (Kind::Int64, Device::Cpu)),
        behaviour_mean: Tensor::randn([b, t, a], opts).tanh(),
        behaviour_std: Tensor::rand([b, t, a], opts) + 0.3,
        bootstrap_obs: Tensor::randn([b, m.obs_dim() as i64], opts),
        bootstrap_start: Tensor::rand([b], opts).lt(0.003),
        memory: Tensor::randn(
            [m.layers as i64, b, m.memory_len as i64, m.d_model as i64],
            opts,
        ),
        memory_len: Tensor::full([b], m.memory_len as i64, (Kind::Int64, Device::Cpu)),
    }
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<ExitCode> {
    // On stderr, so that a bench's JSON on stdout stays whole.
    if let Some(cpu) = crate::machine::cpu_description() {
        eprintln!("machine: {cpu}");
    }
    match cmd {
        BenchCommand::Learner {
            bench: b,
            reference,
            against,
        } => {
            if reference.reference {
                return reference::run(&b.config, b.iters, &reference, random_batch);
            }
            learner::run(&b.config, b.iters, &against)?;
        }
        BenchCommand::Acting(b) => {
            let cfg = RunConfig::from_file(&b.config)?;
            cfg.runtime.apply();
            let vs = tch::nn::VarStore::new(cfg.runtime.device());
            let model = crate::model::Model::new(&vs.root(), &cfg.model, &cfg.popart);
            let rows = (cfg.env.num_envs / cfg.env.groups) as i64;
            let mut state = model.acting_state(rows);
            let obs = Tensor::randn(
                [rows, cfg.model.obs_dim() as i64],
                (Kind::Float, Device::Cpu),
            );
            let start_flags = Tensor::zeros([rows], (Kind::Bool, Device::Cpu));
            let steps = b.iters * cfg.model.segment_len;
            let start = Instant::now();
            for _ in 0..steps {
                model.act(&mut state, &obs, &start_flags);
            }
            let s = start.elapsed().as_secs_f64();
            println!(
                "acting: {:.2} ms per batched step of {rows} slots, {:.0} agent steps/s",
                1e3 * s / steps as f64,
                rows as f64 * steps as f64 / s
            );
        }
        BenchCommand::Train(b) => train_bench(b)?,
        BenchCommand::Env(b) => return env::run(&b),
        BenchCommand::Learning(b) => learning::run(&b)?,
        BenchCommand::Script(b) => return script::run(&b),
    }
    Ok(ExitCode::SUCCESS)
}

#[derive(Debug, Serialize)]
struct TrainBenchReport {
    agent_steps_per_s: f64,
    updates_per_s: f64,
    wall_s: f64,
    replay_ratio: f64,
    actor_thread_cpu_share: f64,
    learner_thread_cpu_share: f64,
    agent: ProcessUsage,
    env_servers: Vec<ProcessUsage>,
    /// The CPU it ran on (timings compare between like CPUs only).
    machine: Option<String>,
}

fn train_bench(b: TrainBench) -> anyhow::Result<()> {
    let mut cfg = RunConfig::from_file(&b.config)?;
    cfg.train.total_agent_steps = u64::MAX;
    let rt = super::runtime(cfg.runtime.io_threads)?;
    let children = ChildSampler::start(Duration::from_millis(500));
    let summary = rt.block_on(train(TrainOptions {
        servers: b.env_servers,
        max_seconds: Some(b.seconds),
        evaluate: false,
        ..TrainOptions::local(cfg)
    }))?;
    let env_servers = children.finish();
    let agent = procstat::usage(std::process::id()).unwrap_or_default();
    let report = TrainBenchReport {
        agent_steps_per_s: summary.agent_steps_per_s,
        updates_per_s: summary.updates_per_s,
        wall_s: summary.wall_s,
        replay_ratio: summary.replay_ratio,
        actor_thread_cpu_share: summary.actor_cpu_s / summary.wall_s,
        learner_thread_cpu_share: summary.learner_cpu_s / summary.wall_s,
        agent,
        env_servers,
        machine: crate::machine::cpu_description(),
    };
    if b.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!(
        "train: {:.0} agent steps/s, {:.2} updates/s over {:.0} s; CPU actor thread {:.0}% , learner thread {:.0}% of wall time; replay ratio {:.2}",
        report.agent_steps_per_s,
        report.updates_per_s,
        report.wall_s,
        100.0 * report.actor_thread_cpu_share,
        100.0 * report.learner_thread_cpu_share,
        report.replay_ratio
    );
    let all = std::iter::once(("agent", &report.agent))
        .chain(report.env_servers.iter().map(|u| ("env server", u)));
    let mut total_rss = 0.0;
    for (role, u) in all {
        total_rss += u.peak_rss_mb;
        println!(
            "  {role:<10} pid {:>7}: {:>7.1} CPU s ({:>3.0}% of a core), peak RSS {:>7.0} MB",
            u.pid,
            u.cpu_s,
            100.0 * u.cpu_s / report.wall_s,
            u.peak_rss_mb
        );
    }
    println!("  peak RSS summed over processes: {total_rss:.0} MB");
    Ok(())
}

/// The 1-minute load average, reported with timings: other work on the machine skews them.
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The Python that runs a bench's Python side: `explicit` (`--python`), else the
/// repository's `.venv/bin/python`, else `python3` on PATH.
fn python(explicit: Option<&Path>) -> PathBuf {
    explicit
        .map(Path::to_path_buf)
        .or_else(|| million_env::find_in_repository(Path::new(".venv/bin/python")))
        .unwrap_or_else(|| "python3".into())
}
