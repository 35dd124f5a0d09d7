//! The run folder and its metric names, in one place: `million train` writes them, `eval`,
//! `report` and the Python tools (tools/*.py) read them.
//!
//! ```text
//! <run dir>/
//!   config.toml                       the resolved run config
//!   metrics.jsonl                     one JSON object per log or evaluation: "step" (agent
//!                                     steps), "wall_time" (Unix seconds), then metric names
//!   events.out.tfevents.*             the same scalars for TensorBoard
//!   checkpoints/step-<15 digits>.safetensors
//! ```
//!
//! Metric names are `<group>/<name>`: `train/…` (acting and throughput), `learner/…` (the
//! latest update, per-task maps as `learner/<name>/<task id>`), `cpu/…`, `env/…`, and
//! `eval/<split>/…` ([`eval`]).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;

pub const CONFIG_FILE: &str = "config.toml";
pub const METRICS_FILE: &str = "metrics.jsonl";
/// Records a resumed (or restarted) run no longer continues: those after its checkpoint.
pub const SUPERSEDED_METRICS_FILE: &str = "metrics.superseded.jsonl";
pub const CHECKPOINTS_DIR: &str = "checkpoints";
/// Keys of every metrics record besides the metrics.
pub const STEP_KEY: &str = "step";
pub const WALL_TIME_KEY: &str = "wall_time";

/// `run_dir/checkpoints/step-<agent steps>.safetensors`
pub fn checkpoint_path(run_dir: &Path, agent_steps: u64) -> PathBuf {
    run_dir
        .join(CHECKPOINTS_DIR)
        .join(format!("step-{agent_steps:015}.safetensors"))
}

/// The newest checkpoint of a run directory (or `path` itself when it is a file).
pub fn latest_checkpoint(path: &Path) -> anyhow::Result<PathBuf> {
    if path.is_file() {
        return Ok(path.to_owned());
    }
    let dir = path.join(CHECKPOINTS_DIR);
    let mut found: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("no checkpoints in {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("step-") && n.ends_with(".safetensors"))
        })
        .collect();
    found.sort();
    found
        .pop()
        .with_context(|| format!("no checkpoint files in {}", dir.display()))
}

/// Writes `bytes` to `path` through a synced temporary file beside it, renamed over `path`:
/// a crash at any moment leaves the old file or the new one whole, never a part of either.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("file");
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let written = std::fs::File::create(&tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    if let Err(e) = written.and_then(|()| std::fs::rename(&tmp, path)) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    Ok(())
}

/// Whether a logged metric measures the machine (rates, CPU and wait times) rather than the
/// run: everything else is the same for two lockstep runs of one config and seed on one kind
/// of CPU.
pub fn depends_on_the_machine(name: &str) -> bool {
    name.ends_with("_per_s") || name.starts_with("cpu/") || name.ends_with("_wait_s")
}

/// Names of an evaluation's metrics, `eval/<split>/<name>`.
pub mod eval {
    /// Trial success over every trial, each task weighted equally.
    pub fn success(split: &str) -> String {
        format!("eval/{split}/success")
    }
    pub fn first_trial_success(split: &str) -> String {
        format!("eval/{split}/first_trial_success")
    }
    /// First trials that succeeded within `k` env steps.
    pub fn first_trial_success_within(split: &str, k: u64) -> String {
        format!("eval/{split}/first_trial_success_within/{k}")
    }
    pub fn after_success_trial_success(split: &str) -> String {
        format!("eval/{split}/after_success_trial_success")
    }
    pub fn after_failure_trial_success(split: &str) -> String {
        format!("eval/{split}/after_failure_trial_success")
    }
    pub fn episode_return(split: &str) -> String {
        format!("eval/{split}/episode_return")
    }
    /// One task's trial success: `eval/<split>/task/<task name>`.
    pub fn task_prefix(split: &str) -> String {
        format!("eval/{split}/task/")
    }
    /// The split of an `eval/<split>/success` key.
    pub fn split_of_success(key: &str) -> Option<&str> {
        key.strip_prefix("eval/")?
            .strip_suffix("/success")
            .filter(|s| !s.contains('/'))
    }
}
