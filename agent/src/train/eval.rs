//! Deterministic evaluation: `episodes` envs of a split, one episode each, mean actions;
//! per-task success = successful trials / trials.

use std::collections::BTreeMap;

use million_env::{AutoresetMode, ClientConfig, EnvPool, PoolConfig};
use serde::Serialize;

use crate::model::Model;
use crate::run_config::EvalSplit;
use crate::train::actor::{ActionBounds, GroupActor};
use crate::train::outcomes::{SuccessTable, trial_outcomes};

/// Result of evaluating one split.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    pub split: String,
    pub env_id: String,
    pub episodes: usize,
    pub trials: u64,
    /// task → success rate
    pub per_task: BTreeMap<String, f64>,
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
        let reset = self.pool.reset(0).await?;
        let mut actor = GroupActor::new(model, &self.pool, 0);
        actor.observe_reset(model, &reset.obs)?;
        let mut done = vec![false; self.episodes];
        let mut trial_index = vec![0usize; self.episodes];
        let mut table = SuccessTable::default();
        let mut first = SuccessTable::default();
        let mut returns = vec![0.0; self.episodes];
        while done.iter().any(|d| !d) {
            actor.act_and_send(model, &mut self.pool, &self.bounds, true)?;
            let step = self.pool.recv(0).await?;
            actor.observe_step(model, &step, false)?;
            for t in trial_outcomes(&step) {
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
        Ok(EvalReport {
            split: self.split.name.clone(),
            env_id: self.split.env_id.clone(),
            episodes: self.episodes,
            trials: table.trials(),
            per_task: table.per_task(),
            mean: table.mean(),
            first_trial: first.mean(),
            mean_return: returns.iter().sum::<f64>() / self.episodes as f64,
        })
    }

    pub async fn close(self) -> anyhow::Result<()> {
        self.pool.close().await?;
        Ok(())
    }
}
