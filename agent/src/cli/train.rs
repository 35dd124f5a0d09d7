use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use clap::Args;
use tokio::signal::unix::SignalKind;

use crate::checkpoint;
use crate::cli::access::EnvAccessArgs;
use crate::run_config::RunConfig;
use crate::run_dir::{CHECKPOINTS_DIR, latest_checkpoint};
use crate::train::session::{RUN_CONFIG_KEY, TrainOptions, train};

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Run config (TOML), e.g. configs/ml10.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// host:port of an env server (repeatable); a name with several addresses (a scaled
    /// Docker service, a Kubernetes headless Service) means every replica. None = local servers.
    #[arg(long = "env-server")]
    pub env_servers: Vec<String>,
    /// Where metrics and checkpoints go (default runs/<config name>).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// Continue from the newest checkpoint in the run directory.
    #[arg(long)]
    pub resume: bool,
    /// Replicate N of the run: agent seed N, env seeds N·10000 + i (the config's seeds are
    /// replaced; evaluation seeds are kept). Default run directory runs/<config name>-seedN.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Stop this leg of the run at this many agent steps (final checkpoint and evaluation),
    /// to go on later with --resume. A run cut into legs at the same steps gives the same
    /// curve again; a run killed mid-leg resumes from its last checkpoint instead.
    #[arg(long)]
    pub until: Option<u64>,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub access: EnvAccessArgs,
}

/// `runs/<prefix><config name>[-seedN]`: where a run of `config` goes unless told.
pub(super) fn default_run_dir(prefix: &str, config: &Path, seed: Option<u64>) -> PathBuf {
    let name = config
        .file_stem()
        .map_or_else(|| "run".into(), |s| s.to_string_lossy().into_owned());
    let suffix = seed.map(|n| format!("-seed{n}")).unwrap_or_default();
    PathBuf::from("runs").join(format!("{prefix}{name}{suffix}"))
}

/// Checks the run directory before anything starts: a new run refuses a folder that holds
/// another run's checkpoints (a later --resume would take the newest, possibly the other
/// run's); a resumed run needs a checkpoint and the settings it started with. Some(steps)
/// when the resumed run has nothing left to train before `stop_at`.
fn check_run_dir(
    run_dir: &Path,
    config: &RunConfig,
    resume: bool,
    stop_at: u64,
) -> anyhow::Result<Option<u64>> {
    // The newest checkpoint's metadata, read once for whichever check needs it.
    let newest = match latest_checkpoint(run_dir) {
        Ok(path) => Some(
            checkpoint::read_meta(&path).with_context(|| format!("reading {}", path.display()))?,
        ),
        Err(_) => None,
    };
    match (resume, newest) {
        (false, Some(meta)) => anyhow::bail!(
            "{} already holds a run (newest checkpoint at {} agent steps): add --resume to \
             continue it, or give another --run-dir",
            run_dir.display(),
            meta.counters.agent_steps
        ),
        (false, None) => Ok(None),
        (true, None) => anyhow::bail!(
            "--resume: no checkpoint in {} (the run directory follows --run-dir, else the \
             config's name and --seed)",
            run_dir.join(CHECKPOINTS_DIR).display()
        ),
        (true, Some(meta)) => {
            if let Some(started) = meta.extra.get(RUN_CONFIG_KEY) {
                let started: toml::Value = toml::from_str(started)
                    .with_context(|| format!("the run config kept in {}", run_dir.display()))?;
                let changed = learning_settings_changed(&started, &toml::Value::try_from(config)?);
                if !changed.is_empty() {
                    anyhow::bail!(
                        "--resume: {} was started with other settings of what is learned ({}); \
                         a run resumed with them would be neither run (was --seed the same?). \
                         Give a new --run-dir for new settings",
                        run_dir.display(),
                        changed.join(", ")
                    );
                }
            }
            let at = meta.counters.agent_steps;
            Ok((at >= stop_at).then_some(at))
        }
    }
}

/// Dotted keys whose values differ between the config a run started with and the one it is
/// resumed with, outside the sections that may change between legs (budget, intervals,
/// evaluation, machine). A key the older config lacks is a setting added since: not a change.
fn learning_settings_changed(started: &toml::Value, now: &toml::Value) -> Vec<String> {
    const MAY_CHANGE: [&str; 3] = ["train", "eval", "runtime"];
    fn walk(prefix: &str, a: &toml::Value, b: &toml::Value, out: &mut Vec<String>) {
        match (a, b) {
            (toml::Value::Table(a), toml::Value::Table(b)) => {
                for (key, value) in a {
                    let path = if prefix.is_empty() {
                        key.clone()
                    } else {
                        format!("{prefix}.{key}")
                    };
                    match b.get(key) {
                        Some(other) => walk(&path, value, other, out),
                        None => out.push(path),
                    }
                }
            }
            _ if a != b => out.push(prefix.to_owned()),
            _ => {}
        }
    }
    let mut out = vec![];
    walk("", started, now, &mut out);
    out.retain(|key| !MAY_CHANGE.contains(&key.split('.').next().unwrap_or_default()));
    out
}

pub fn run(a: TrainArgs) -> anyhow::Result<ExitCode> {
    let mut config = RunConfig::from_file(&a.config)?;
    if let Some(n) = a.seed {
        config.env.replicate(n);
    }
    let env_access = a.access.resolve()?;
    let run_dir = a
        .run_dir
        .unwrap_or_else(|| default_run_dir("", &a.config, a.seed));
    let stop_at = config.leg_end(a.until);
    if let Some(steps) = check_run_dir(&run_dir, &config, a.resume, stop_at)? {
        // A finished leg run again (a rerun script, a restarted container): nothing to do.
        println!(
            "{} is at {steps} agent steps, the end of this leg or budget ({stop_at}): nothing to train",
            run_dir.display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let rt = super::runtime(config.runtime.io_threads)?;
    let interrupt = Arc::new(AtomicBool::new(false));
    let summary = rt.block_on(async {
        let flag = interrupt.clone();
        tokio::spawn(async move {
            // Ctrl-C, or SIGTERM (`kill`, a stopped pod whose image sets no stop signal).
            let mut term = tokio::signal::unix::signal(SignalKind::terminate()).ok();
            let terminated = async {
                match term.as_mut() {
                    Some(t) => t.recv().await,
                    None => std::future::pending().await,
                }
            };
            let stopped = tokio::select! {
                r = tokio::signal::ctrl_c() => r.is_ok(),
                _ = terminated => true,
            };
            if stopped {
                eprintln!("interrupted: finishing the step, writing a final checkpoint");
                flag.store(true, Ordering::Relaxed);
            }
        });
        train(TrainOptions {
            servers: a.env_servers,
            env_access,
            run_dir: Some(run_dir.clone()),
            resume: a.resume,
            until: a.until,
            progress: true,
            interrupt,
            ..TrainOptions::local(config)
        })
        .await
    })?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "{} agent steps in {:.0} s ({:.0} steps/s), {} updates ({:.2}/s); CPU actor {:.0} s, learner {:.0} s",
            summary.agent_steps,
            summary.wall_s,
            summary.agent_steps_per_s,
            summary.updates,
            summary.updates_per_s,
            summary.actor_cpu_s,
            summary.learner_cpu_s
        );
        for r in &summary.final_eval {
            println!(
                "eval {}: success {:.3} (first trials {:.3}) over {} trials",
                r.split, r.mean, r.first_trial, r.trials
            );
        }
        if let Some(p) = &summary.final_checkpoint {
            println!("checkpoint: {}", p.display());
        }
        println!(
            "metrics: {}/metrics.jsonl (TensorBoard: {})",
            run_dir.display(),
            run_dir.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
