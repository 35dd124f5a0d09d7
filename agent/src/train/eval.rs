//! Deterministic evaluation: `episodes` envs of a split, one episode each, mean actions;
//! per-task success = successful trials / trials.
//!
//! Every task of the split is scored on the same number of episodes: after the reset the
//! envs are grouped by their `task_name`, and only the first k envs of each task count, k
//! being the smallest group. Envs made with `task_order = "cycle"` start at task
//! (seed + i) mod n, so `episodes` a multiple of n wastes none.

use std::collections::BTreeMap;

use million_env::{AutoresetMode, ClientConfig, EnvPool, PoolConfig};
use serde::Serialize;

use crate::model::Model;
use crate::run_config::EvalSplit;
use crate::train::actor::{ActionBounds, GroupActor};
use crate::train::outcomes::{SuccessTable, TrialTracker, text};

/// Result of evaluating one split.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    pub split: String,
    pub env_id: String,
    /// Episodes scored (`episodes_per_task` × tasks; envs beyond that are not scored).
    pub episodes: usize,
    /// Deterministic episodes scored per task (the same for every task).
    pub episodes_per_task: usize,
    pub trials: u64,
    /// task → success rate
    pub per_task: BTreeMap<String, f64>,
    /// task → trials the rate rests on
    pub per_task_trials: BTreeMap<String, u64>,
    /// Mean of the per-task success rates.
    pub mean: f64,
    /// Success rate of first trials only (instruction following without trial and error).
    pub first_trial: f64,
    pub mean_return: f64,
}

/// A persistent evaluation pool for one split.
pub struct Evaluator {
    split: EvalSplit,
    pool: EnvPool,
    bounds: ActionBounds,
    episodes: usize,
}

impl Evaluator {
    pub async fn connect(
        servers: &[String],
        split: EvalSplit,
        episodes: usize,
        seed: u64,
        client: ClientConfig,
        action_dim: usize,
    ) -> anyhow::Result<Self> {
        let mut cfg = PoolConfig::new(servers.to_vec(), split.env_id.clone(), episodes);
        cfg.kwargs = split.kwargs.clone();
        cfg.seed = Some(seed);
        cfg.autoreset = AutoresetMode::SameStep;
        cfg.client = client;
        let pool = EnvPool::connect(cfg)
            .await
            .map_err(|e| anyhow::anyhow!("eval split {} ({}): {e}", split.name, split.env_id))?;
        let bounds = ActionBounds::from_space(&pool.spec().action_space, action_dim)?;
        Ok(Self {
            split,
            pool,
            bounds,
            episodes,
        })
    }

    pub fn split(&self) -> &EvalSplit {
        &self.split
    }

    pub async fn run(&mut self, model: &Model) -> anyhow::Result<EvalReport> {
        // Same seeds every time: the tasks, goals and starts of an eval are those of the
        // last one, so successive evals compare like with like and every task keeps its share
        // (unseeded resets would continue each env's task cycle from wherever it stopped).
        let reset = self.pool.reset_to_first_episodes(0).await?;
        let env_id = self.split.env_id.clone();
        let tasks: Vec<String> = (0..self.episodes)
            .map(|row| text(&reset.info, "task_name", row).unwrap_or_else(|| env_id.clone()))
            .collect();
        let (scored, per_task_episodes) = equal_share_per_task(&tasks);
        let mut actor = GroupActor::new(model, &self.pool, 0);
        actor.observe_reset(model, &reset.obs)?;
        // Rows not scored are done from the start: their trials and returns are ignored.
        let mut done: Vec<bool> = scored.iter().map(|s| !s).collect();
        let mut trial_index = vec![0usize; self.episodes];
        let mut table = SuccessTable::default();
        let mut first = SuccessTable::default();
        let mut tracker = TrialTracker::new(self.episodes, &env_id);
        let mut returns = vec![0.0; self.episodes];
        while done.iter().any(|d| !d) {
            actor.act_and_send(model, &mut self.pool, &self.bounds, true)?;
            let step = self.pool.recv(0).await?;
            actor.observe_step(model, &step, false)?;
            for t in tracker.outcomes(0, &step) {
                if done[t.row] {
                    continue;
                }
                table.record(&t.task, t.success);
                if trial_index[t.row] == 0 {
                    first.record("all", t.success);
                }
                trial_index[t.row] += 1;
            }
            for (row, end) in step.ended().into_iter().enumerate() {
                if !done[row] {
                    returns[row] += step.reward[row];
                    done[row] = end;
                }
            }
        }
        let scored_episodes = scored.iter().filter(|&&s| s).count();
        Ok(EvalReport {
            split: self.split.name.clone(),
            env_id,
            episodes: scored_episodes,
            episodes_per_task: per_task_episodes,
            trials: table.trials(),
            per_task: table.per_task(),
            per_task_trials: table
                .tasks
                .iter()
                .map(|(k, (_, n))| (k.clone(), *n))
                .collect(),
            mean: table.mean(),
            first_trial: first.mean(),
            mean_return: returns.iter().sum::<f64>() / scored_episodes.max(1) as f64,
        })
    }

    pub async fn close(self) -> anyhow::Result<()> {
        self.pool.close().await?;
        Ok(())
    }
}

/// Which rows to score so that every task gets the same number of episodes: the first k rows
/// of each task, k = the smallest number of rows of any task. Returns the flags and k.
pub fn equal_share_per_task(tasks: &[String]) -> (Vec<bool>, usize) {
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    for t in tasks {
        *counts.entry(t.as_str()).or_default() += 1;
    }
    let k = counts.values().copied().min().unwrap_or(0);
    let mut taken: BTreeMap<&str, usize> = BTreeMap::new();
    let scored = tasks
        .iter()
        .map(|t| {
            let n = taken.entry(t.as_str()).or_default();
            *n += 1;
            *n <= k
        })
        .collect();
    (scored, k)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_task_gets_the_smallest_tasks_count() {
        let tasks: Vec<String> = ["a", "b", "a", "c", "b", "a", "c", "b"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let (scored, k) = equal_share_per_task(&tasks);
        // a ×3, b ×3, c ×2 → the first two of each.
        assert_eq!(k, 2);
        assert_eq!(
            scored,
            vec![true, true, true, true, true, false, true, false]
        );
        assert_eq!(equal_share_per_task(&[]), (vec![], 0));
    }
}
