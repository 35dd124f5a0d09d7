use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use clap::{Args, Subcommand};
use tch::{Device, Kind, Tensor};

use crate::algo::buffer::SegmentBatch;
use crate::config::AgentConfig;
use crate::learner::Learner;
use crate::run_config::RunConfig;
use crate::train::session::{TrainOptions, train};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Learner updates per second on random segments of the config's sizes.
    Learner(ModelBench),
    /// Acting steps per second (all env slots) of the config's model, no envs.
    Acting(ModelBench),
    /// End-to-end training throughput: agent steps/s, updates/s, actor/learner CPU split.
    Train(TrainBench),
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
        memory: Tensor::randn(
            [m.layers as i64, b, m.memory_len as i64, m.d_model as i64],
            opts,
        ),
        memory_len: Tensor::full([b], m.memory_len as i64, (Kind::Int64, Device::Cpu)),
    }
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        BenchCommand::Learner(b) => {
            let cfg = RunConfig::from_file(&b.config)?;
            cfg.runtime.apply();
            let agent = cfg.agent();
            let mut learner = Learner::new(agent.clone(), cfg.runtime.device());
            let batch = random_batch(&agent, agent.buffer.batch_segments as i64);
            learner.update(&batch)?;
            let start = Instant::now();
            for _ in 0..b.iters {
                learner.update(&batch)?;
            }
            let s = start.elapsed().as_secs_f64() / b.iters as f64;
            println!(
                "learner: {:.3} s/update ({:.2} updates/s, {:.0} learned steps/s) b={} T={}",
                s,
                1.0 / s,
                (agent.buffer.batch_segments * agent.model.segment_len) as f64 / s,
                agent.buffer.batch_segments,
                agent.model.segment_len
            );
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
        BenchCommand::Train(b) => {
            let mut cfg = RunConfig::from_file(&b.config)?;
            cfg.train.total_agent_steps = u64::MAX;
            let rt = super::runtime(cfg.runtime.io_threads)?;
            let summary = rt.block_on(train(TrainOptions {
                config: cfg,
                servers: b.env_servers,
                env_access: Default::default(),
                run_dir: None,
                resume: false,
                progress: false,
                max_seconds: Some(b.seconds),
                evaluate: false,
                interrupt: Arc::new(AtomicBool::new(false)),
            }))?;
            println!(
                "train: {:.0} agent steps/s, {:.2} updates/s over {:.0} s; CPU actor thread {:.0}% , learner thread {:.0}% of wall time; replay ratio {:.2}",
                summary.agent_steps_per_s,
                summary.updates_per_s,
                summary.wall_s,
                100.0 * summary.actor_cpu_s / summary.wall_s,
                100.0 * summary.learner_cpu_s / summary.wall_s,
                summary.replay_ratio
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
