use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use tch::nn::VarStore;

use crate::checkpoint;
use crate::learner::Learner;
use crate::model::Model;
use crate::run_config::RunConfig;
use crate::train::eval::{EvalReport, Evaluator};
use crate::train::servers::{client_config, start_local_servers};
use crate::train::session::{RUN_CONFIG_KEY, latest_checkpoint};

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Split {
    Train,
    Test,
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// A checkpoint file, or a run directory (its newest checkpoint).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Split to evaluate (default: train, and test when the config has one).
    #[arg(long, value_enum)]
    pub split: Option<Split>,
    /// Episodes per split (default: the config's eval.episodes).
    #[arg(long)]
    pub episodes: Option<usize>,
    #[arg(long)]
    pub json: bool,
    /// host:port of an env server (repeatable); none = start local servers.
    #[arg(long = "env-server")]
    pub env_servers: Vec<String>,
}

pub fn run(a: EvalArgs) -> anyhow::Result<ExitCode> {
    let path = latest_checkpoint(&a.checkpoint)?;
    let meta = checkpoint::read_meta(&path)?;
    let config_text = meta
        .extra
        .get(RUN_CONFIG_KEY)
        .with_context(|| format!("{} holds no run config", path.display()))?;
    let mut cfg = RunConfig::from_toml_str(config_text)
        .with_context(|| format!("the run config stored in {}", path.display()))?;
    if let Some(n) = a.episodes {
        anyhow::ensure!(n > 0, "--episodes must be > 0");
        cfg.eval.episodes = n;
    }
    cfg.runtime.apply();
    let device = cfg.runtime.device();
    let mut learner = Learner::new(cfg.agent(), device);
    checkpoint::load(&path, &mut learner)?;
    let mut vs = VarStore::new(device);
    let model = Model::new(&vs.root(), &cfg.model, &cfg.popart);
    learner.copy_weights_to(&mut vs)?;
    let splits: Vec<_> = cfg
        .eval_splits()?
        .into_iter()
        .filter(|s| match a.split {
            None => true,
            Some(Split::Train) => s.name == "train",
            Some(Split::Test) => s.name == "test",
        })
        .collect();
    anyhow::ensure!(!splits.is_empty(), "the run config has no such eval split");
    let rt = super::runtime(cfg.runtime.io_threads)?;
    let reports: Vec<EvalReport> = rt.block_on(async {
        let (_local, servers) = if a.env_servers.is_empty() {
            let local = start_local_servers(1).await?;
            let addrs: Vec<String> = local.iter().map(|s| s.addr().to_owned()).collect();
            (local, addrs)
        } else {
            (vec![], a.env_servers.clone())
        };
        let mut out = vec![];
        for split in splits {
            let mut ev = Evaluator::connect(
                &servers,
                split,
                cfg.eval.episodes,
                cfg.eval.seed,
                client_config(&cfg),
                cfg.model.action_dim,
            )
            .await?;
            out.push(ev.run(&model).await?);
            ev.close().await?;
        }
        anyhow::Ok(out)
    })?;
    if a.json {
        let json: serde_json::Map<String, serde_json::Value> = reports
            .iter()
            .map(|r| Ok((r.split.clone(), serde_json::to_value(r)?)))
            .collect::<anyhow::Result<_>>()?;
        println!("{}", serde_json::to_string_pretty(&json)?);
    } else {
        for r in &reports {
            println!(
                "{} split ({}), {} episodes, {} trials",
                r.split, r.env_id, r.episodes, r.trials
            );
            for (task, v) in &r.per_task {
                println!("  {task:<28} {v:>6.3}");
            }
            println!("  {:<28} {:>6.3}", "mean", r.mean);
            println!("  {:<28} {:>6.3}", "first trials", r.first_trial);
        }
    }
    Ok(ExitCode::SUCCESS)
}
