//! `million bench learner` (without `--reference`): learner updates per second on random
//! segments of the config's sizes, the multiply-adds an update makes and the rate it reaches,
//! and with `--against OTHER` another build's learner (an earlier commit's `million`), or with
//! `--against-config OTHER` this build on another config (say, another `model.matmul_dtype`),
//! timed in alternating rounds on the same machine, so that a change to the learner is
//! measured as a ratio side by side (BENCHMARKS.md, "The learner").

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use serde::Serialize;

use super::{load_average, random_batch};
use crate::config::AgentConfig;
use crate::learner::Learner;
use crate::run_config::RunConfig;

#[derive(Debug, Args)]
pub struct AgainstArgs {
    /// Another `million` binary (say, a build of an earlier commit): its `bench learner` on
    /// the same config is timed in alternating rounds with this one's, and the ratio printed.
    #[arg(long, conflicts_with = "reference")]
    pub against: Option<PathBuf>,
    /// Another config of the same sizes (say, with `model.matmul_dtype = "bfloat16"` or other
    /// `runtime.intra_op_threads`): this build's learner on it is timed in alternating rounds
    /// with the `--config` one's, each side under its own runtime settings.
    #[arg(long, conflicts_with_all = ["reference", "against"])]
    pub against_config: Option<PathBuf>,
    /// Rounds per side with --against or --against-config, the order alternating.
    #[arg(long, default_value_t = 3)]
    pub against_rounds: usize,
}

/// Multiply-adds of one update's matrix products at the config's sizes: the online network's
/// forward over `b · T` steps, its backward (twice the forward: the gradients of inputs and of
/// weights) and, with `vmpo.kl_reference = "target"`, the target network's forward without
/// its value head. Element-wise work is not counted.
pub fn update_multiply_adds(cfg: &AgentConfig) -> f64 {
    let m = &cfg.model;
    let (d, l, ff) = (m.d_model as f64, m.layers as f64, m.ff_dim as f64);
    let (t, mem) = (m.segment_len as f64, m.memory_len as f64);
    let keys = mem + t;
    let mut embed = m.fields_dim() as f64 * d;
    if m.instruction_words > 0 {
        // Key and value of every slot's word, the query's dot products, the output layer.
        let k = m.instruction_words as f64;
        embed += k * (2.0 * m.word_dim() as f64 * d + d) + d * d;
    }
    // Per step and layer: q and the output (d²), keys and values of the step's share of the
    // `[memory; segment]` rows (2d² · keys/T), two gates (W: 3d², U_rz: 2d², U_g: d² each),
    // the feed-forward (2·d·ff), and scores and values over the keys (2·keys·d).
    let layer = 2.0 * d * d + 2.0 * d * d * keys / t + 12.0 * d * d + 2.0 * d * ff + 2.0 * keys * d;
    let policy = d * m.policy_hidden as f64 + m.policy_hidden as f64 * 2.0 * m.action_dim as f64;
    let value = d * m.value_hidden as f64;
    let steps = (cfg.buffer.batch_segments * m.segment_len) as f64;
    let online = steps * (embed + l * layer + policy + value);
    let target = match cfg.vmpo.kl_reference {
        crate::config::KlReference::Target => steps * (embed + l * layer + policy),
        crate::config::KlReference::Behaviour => 0.0,
    };
    3.0 * online + target
}

/// Updates/s of `iters` updates on one random batch, after one untimed update.
fn time_updates(cfg: &AgentConfig, device: tch::Device, iters: usize) -> anyhow::Result<f64> {
    let mut learner = Learner::new(cfg.clone(), device);
    let batch = random_batch(cfg, cfg.buffer.batch_segments as i64);
    learner.update(&batch)?;
    let start = Instant::now();
    for _ in 0..iters {
        learner.update(&batch)?;
    }
    Ok(iters as f64 / start.elapsed().as_secs_f64())
}

/// Updates/s of another build's `bench learner` on the same config (its first output line
/// `learner: … (N updates/s, …)`, which every build since the command existed prints).
fn time_other(binary: &Path, config: &Path, iters: usize) -> anyhow::Result<f64> {
    let out = Command::new(binary)
        .args([
            "bench",
            "learner",
            "--iters",
            &iters.to_string(),
            "--config",
        ])
        .arg(config)
        .output()
        .with_context(|| format!("cannot run {}", binary.display()))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        bail!(
            "{} bench learner failed:\n{}",
            binary.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let rate = text
        .lines()
        .find_map(|line| {
            let (_, rest) = line.strip_prefix("learner: ")?.split_once('(')?;
            rest.split_whitespace().next()?.parse::<f64>().ok()
        })
        .with_context(|| format!("no updates/s in {}'s output:\n{text}", binary.display()))?;
    Ok(rate)
}

#[derive(Debug, Serialize)]
struct Against {
    this_updates_per_s: Vec<f64>,
    other_updates_per_s: Vec<f64>,
    /// Mean of this build's rounds ÷ mean of the other's.
    ratio: f64,
}

/// The other side of a side-by-side timing: another build on the same config, or this build
/// on another config (and the file it came from).
enum Other {
    Build(PathBuf),
    Config(PathBuf, Box<RunConfig>),
}

impl Other {
    /// How the two sides are named in the output: (this side, the other side).
    fn labels(&self, config: &Path) -> (String, String) {
        match self {
            Other::Build(binary) => ("this build".into(), binary.display().to_string()),
            Other::Config(path, _) => (config.display().to_string(), path.display().to_string()),
        }
    }

    fn time(&self, config: &Path, device: tch::Device, iters: usize) -> anyhow::Result<f64> {
        match self {
            Other::Build(binary) => time_other(binary, config, iters),
            Other::Config(_, other) => {
                other.runtime.apply();
                time_updates(&other.agent(), device, iters)
            }
        }
    }
}

pub fn run(config: &Path, iters: usize, against: &AgainstArgs) -> anyhow::Result<()> {
    if iters == 0 {
        bail!("--iters must be at least 1");
    }
    let cfg = RunConfig::from_file(config)?;
    cfg.runtime.apply();
    let agent = cfg.agent();
    let device = cfg.runtime.device();
    let macs = update_multiply_adds(&agent);
    let other = match (&against.against, &against.against_config) {
        (Some(binary), _) => Some(Other::Build(binary.clone())),
        (None, Some(path)) => {
            let other = RunConfig::from_file(path)?;
            if update_multiply_adds(&other.agent()) != macs {
                bail!(
                    "{} and {} have different sizes: compare learners on equal work",
                    config.display(),
                    path.display()
                );
            }
            Some(Other::Config(path.clone(), Box::new(other)))
        }
        (None, None) => None,
    };
    let describe = |rate: f64| {
        format!(
            "{:.3} s/update ({:.2} updates/s, {:.0} learned steps/s, {:.1} G multiply-adds/s)",
            1.0 / rate,
            rate,
            (agent.buffer.batch_segments * agent.model.segment_len) as f64 * rate,
            macs * rate / 1e9
        )
    };
    let Some(other) = other else {
        let rate = time_updates(&agent, device, iters)?;
        println!(
            "learner: {} b={} T={}, {:.0} M multiply-adds per update, {} intra-op threads",
            describe(rate),
            agent.buffer.batch_segments,
            agent.model.segment_len,
            macs / 1e6,
            cfg.runtime.intra_op_threads
        );
        return Ok(());
    };
    if against.against_rounds == 0 {
        bail!("--against-rounds must be at least 1");
    }
    let load_before = load_average();
    let (mut this, mut that) = (Vec::new(), Vec::new());
    let time_this = || {
        cfg.runtime.apply();
        time_updates(&agent, device, iters)
    };
    for round in 0..against.against_rounds {
        if round % 2 == 0 {
            this.push(time_this()?);
            that.push(other.time(config, device, iters)?);
        } else {
            that.push(other.time(config, device, iters)?);
            this.push(time_this()?);
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let result = Against {
        ratio: mean(&this) / mean(&that),
        this_updates_per_s: this,
        other_updates_per_s: that,
    };
    let fmt = |v: Option<f64>| v.map_or("?".to_string(), |x| format!("{x:.2}"));
    println!(
        "learner, {} rounds x {iters} updates per side (alternating), load {} -> {}, {:.0} M multiply-adds per update:",
        against.against_rounds,
        fmt(load_before),
        fmt(load_average()),
        macs / 1e6
    );
    let (this_name, other_name) = other.labels(config);
    println!(
        "  {this_name}   {}",
        describe(mean(&result.this_updates_per_s))
    );
    println!(
        "  {other_name}  {}",
        describe(mean(&result.other_updates_per_s))
    );
    println!("  ratio (this ÷ other): {:.3}", result.ratio);
    println!("{}", serde_json::to_string(&result)?);
    Ok(())
}
