use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, ValueEnum};
use tch::nn::VarStore;

use crate::checkpoint;
use crate::cli::access::EnvAccessArgs;
use crate::learner::Learner;
use crate::model::Model;
use crate::run_config::RunConfig;
use crate::run_dir::latest_checkpoint;
use crate::train::eval::{EvalReport, Evaluator};
use crate::train::servers::{client_config, start_local_servers};
use crate::train::session::RUN_CONFIG_KEY;
use crate::video::{VideoOptions, record_split};

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
    /// Env kwarg for every evaluated split, over the run config's (repeatable), e.g.
    /// `--kwarg instruction_goal=reflected` to test whether the agent reads the goal word.
    #[arg(long = "kwarg", value_name = "NAME=VALUE", value_parser = million_env::parse_kwarg)]
    pub kwargs: Vec<(String, million_env::Value)>,
    /// host:port of an env server (repeatable); none = start local servers.
    #[arg(long = "env-server")]
    pub env_servers: Vec<String>,
    #[command(flatten)]
    pub access: EnvAccessArgs,
    /// Instead of the statistics: one GIF per task of a deterministic episode, written to
    /// DIR/<split>/<task>.gif (and the last frame as .png); needs a server that renders.
    #[arg(long, value_name = "DIR")]
    pub video: Option<PathBuf>,
    /// Videos: render every k-th agent step of a trial.
    #[arg(long, default_value_t = 2, value_name = "K")]
    pub video_every: usize,
    /// Videos: size of the rendered picture in pixels (square).
    #[arg(long, default_value_t = 224, value_name = "PIXELS")]
    pub video_size: u32,
    /// Videos: camera name (Meta-World: corner, corner2, corner3, corner4, topview, ...);
    /// default: the server's view.
    #[arg(long, default_value = "")]
    pub video_camera: String,
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
        .map(|mut s| {
            s.kwargs.extend(a.kwargs.iter().cloned());
            s
        })
        .collect();
    anyhow::ensure!(!splits.is_empty(), "the run config has no such eval split");
    let env_access = a.access.resolve()?;
    let rt = super::runtime(cfg.runtime.io_threads)?;
    if let Some(dir) = &a.video {
        let opts = crate::video::VideoOptions {
            every: a.video_every,
            width: a.video_size,
            height: a.video_size,
            camera: a.video_camera.clone(),
            ..Default::default()
        };
        let client = client_config(&cfg, &env_access);
        return rt.block_on(write_videos(&a, &cfg, &model, splits, dir, &opts, client));
    }
    let reports: Vec<EvalReport> = rt.block_on(async {
        let (_local, servers) = if a.env_servers.is_empty() {
            let local = start_local_servers(1, &cfg.runtime.env_server_args).await?;
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
                &cfg.eval.first_trial_within,
                cfg.eval.seed,
                client_config(&cfg, &env_access),
                cfg.model.action_dim,
            )
            .await?;
            out.push(ev.run(&model).await?);
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
            for (k, v) in &r.first_trial_within {
                println!(
                    "  {:<28} {v:>6.3}",
                    format!("first trials within {k} steps")
                );
            }
            println!(
                "  {:<28} {:>6.3}",
                "trials after a success", r.after_success
            );
            println!(
                "  {:<28} {:>6.3}",
                "trials after a failure", r.after_failure
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `--video DIR`: one GIF per task of each split, on the first env server.
async fn write_videos(
    a: &EvalArgs,
    cfg: &RunConfig,
    model: &Model,
    splits: Vec<crate::run_config::EvalSplit>,
    dir: &std::path::Path,
    opts: &VideoOptions,
    client_config: million_env::ClientConfig,
) -> anyhow::Result<ExitCode> {
    let (_local, server) = if a.env_servers.is_empty() {
        let local = start_local_servers(1, &cfg.runtime.env_server_args).await?;
        let addr = local[0].addr().to_owned();
        (local, addr)
    } else {
        (vec![], a.env_servers[0].clone())
    };
    let client = million_env::EnvClient::connect(&server, client_config).await?;
    let mut all = vec![];
    for split in splits {
        let out = dir.join(&split.name);
        let videos = record_split(&client, &split, model, cfg.eval.seed, opts, &out).await?;
        for v in &videos {
            let outcomes: Vec<&str> = v
                .trials
                .iter()
                .map(|&s| if s { "success" } else { "failed" })
                .collect();
            if !a.json {
                println!(
                    "{}  {} frames, {} agent steps, {:.1} s  [{}]",
                    v.path.display(),
                    v.frames,
                    v.agent_steps,
                    v.seconds,
                    outcomes.join(", ")
                );
            }
        }
        all.push((split.name.clone(), videos));
    }
    if a.json {
        let json: serde_json::Map<String, serde_json::Value> = all
            .into_iter()
            .map(|(k, v)| Ok((k, serde_json::to_value(v)?)))
            .collect::<anyhow::Result<_>>()?;
        println!("{}", serde_json::to_string_pretty(&json)?);
    }
    Ok(ExitCode::SUCCESS)
}
