//! Deterministic evaluation: `episodes` envs of a split, one episode each, mean actions;
//! per-task success = successful trials / trials.
//!
//! Every task of the split is scored on the same number of episodes: after the reset the
//! envs are grouped by their `task_name`, and only the first k envs of each task count, k
//! being the smallest group. Envs made with `task_order = "cycle"` start at task
//! (seed + i) mod n, so `episodes` a multiple of n wastes none.

use std::collections::BTreeMap;

use million_env::{AutoresetMode, ClientConfig, EnvPool, PoolConfig, StepBatch};
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
    /// k → share of first trials that succeeded within k env steps, for each k of
    /// `eval.first_trial_within`; empty when the env does not report `steps_to_success`.
    /// How soon, where `first_trial` says only whether: an agent that reads the goal goes
    /// straight to it, one that must search for it gets there later if at all.
    pub first_trial_within: BTreeMap<u64, f64>,
    /// Success rate of the later trials that follow a successful one in their episode
    /// (NaN if none): the protocol gives no new instruction then, so this is the goal
    /// recalled from memory; below `first_trial` means the memory loses it.
    pub after_success: f64,
    /// Success rate of the later trials that follow a failed one (NaN if none): they are
    /// re-instructed and can use the failure; above `first_trial` is learning by trial and
    /// error (the harder goals are the ones retried, so it starts lower).
    pub after_failure: f64,
    /// Trials that `after_success` and `after_failure` rest on (with one first trial per
    /// episode, they sum to `trials - episodes`).
    pub after_success_trials: u64,
    pub after_failure_trials: u64,
    pub mean_return: f64,
}

/// The evaluation of one split. Its envs exist only while it runs: a split of 100 Meta-World
/// episodes holds ~1 GB per env server, which a run would otherwise keep between
/// evaluations, and runs side by side ran out of memory so.
pub struct Evaluator {
    split: EvalSplit,
    pool_cfg: PoolConfig,
    bounds: ActionBounds,
    episodes: usize,
    first_trial_within: Vec<u64>,
}

impl Evaluator {
    /// Checks the split by making its envs once (a bad id or kwarg fails here, at start-up,
    /// not at the first evaluation), then lets them go.
    pub async fn connect(
        servers: &[String],
        split: EvalSplit,
        episodes: usize,
        first_trial_within: &[u64],
        seed: u64,
        client: ClientConfig,
        action_dim: usize,
    ) -> anyhow::Result<Self> {
        let mut pool_cfg = PoolConfig::new(servers.to_vec(), split.env_id.clone(), episodes);
        pool_cfg.kwargs = split.kwargs.clone();
        pool_cfg.seed = Some(seed);
        pool_cfg.autoreset = AutoresetMode::SameStep;
        pool_cfg.client = client;
        let pool = Self::open(&split, &pool_cfg).await?;
        let bounds = ActionBounds::from_space(&pool.spec().action_space, action_dim)?;
        pool.close().await?;
        Ok(Self {
            split,
            pool_cfg,
            bounds,
            episodes,
            first_trial_within: first_trial_within.to_vec(),
        })
    }

    async fn open(split: &EvalSplit, cfg: &PoolConfig) -> anyhow::Result<EnvPool> {
        EnvPool::connect(cfg.clone())
            .await
            .map_err(|e| anyhow::anyhow!("eval split {} ({}): {e}", split.name, split.env_id))
    }

    pub fn split(&self) -> &EvalSplit {
        &self.split
    }

    /// Scores the split. An env server lost partway through (its episodes come back cut)
    /// voids the attempt: the trials that had ended by then are the short ones, often the
    /// successful ones, so scoring them alone overstates success (seen: 1.00 on a split whose
    /// true rate was ~0.2). The pool has rebuilt the envs by then, and the retry's reset
    /// with the first seeds scores the same episodes.
    pub async fn run(&mut self, model: &Model) -> anyhow::Result<EvalReport> {
        let mut pool = Self::open(&self.split, &self.pool_cfg).await?;
        let mut result = None;
        for attempt in 1..=EVAL_ATTEMPTS {
            match self.run_once(&mut pool, model).await {
                Ok(Some(report)) => {
                    result = Some(Ok(report));
                    break;
                }
                Ok(None) if attempt < EVAL_ATTEMPTS => tracing::warn!(
                    split = %self.split.name,
                    attempt,
                    "an env server was lost during the evaluation; scoring it again"
                ),
                Ok(None) => {}
                Err(e) => {
                    result = Some(Err(e));
                    break;
                }
            }
        }
        // Dropping the pool would free the envs too; closing says so to the servers at once.
        if let Err(e) = pool.close().await {
            tracing::warn!(split = %self.split.name, "closing the evaluation's envs: {e}");
        }
        result.unwrap_or_else(|| {
            Err(anyhow::anyhow!(
                "eval split {}: an env server was lost during each of {EVAL_ATTEMPTS} attempts",
                self.split.name
            ))
        })
    }

    /// One attempt; `None` when an env server was lost during it (an episode it scores was
    /// cut). A server lost during the reset is no loss: the pool rebuilds its envs with the
    /// seeds the reset asked for, so they begin the same episodes.
    async fn run_once(
        &self,
        pool: &mut EnvPool,
        model: &Model,
    ) -> anyhow::Result<Option<EvalReport>> {
        // Same seeds every time: the tasks, goals and starts of an eval are those of the
        // last one, so successive evals compare like with like and every task keeps its share
        // (unseeded resets would continue each env's task cycle from wherever it stopped).
        let reset = pool.reset_to_first_episodes(0).await?;
        let env_id = self.split.env_id.clone();
        let tasks: Vec<String> = (0..self.episodes)
            .map(|row| text(&reset.info, "task_name", row).unwrap_or_else(|| env_id.clone()))
            .collect();
        let mut tally = EvalTally::new(&tasks, &env_id, &self.first_trial_within);
        let mut actor = GroupActor::new(model, pool, 0);
        actor.observe_reset(model, &reset.obs, &reset.info)?;
        while !tally.finished() {
            actor.act_and_send(model, pool, &self.bounds, true)?;
            let step = pool.recv(0).await?;
            actor.observe_step(model, &step, false)?;
            if tally.observe(&step) == Scoring::Void {
                return Ok(None);
            }
        }
        Ok(Some(tally.report(&self.split.name, env_id)))
    }
}

/// Attempts at one evaluation before it fails (each lost server voids one).
const EVAL_ATTEMPTS: usize = 3;

/// Whether an evaluation can still be scored after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scoring {
    Going,
    /// A scored episode was cut by a lost env server: the attempt must be repeated.
    Void,
}

/// The scoring of one deterministic evaluation, fed one step reply at a time: the rows
/// of `equal_share_per_task` play one episode each; successes per task and first-trial
/// successes are counted, and a cut episode voids the lot.
#[derive(Debug, Clone)]
pub struct EvalTally {
    /// Rows not scored are done from the start: their trials and returns are ignored.
    done: Vec<bool>,
    scored: usize,
    per_task_episodes: usize,
    /// Each row's last trial outcome in its episode (None before its first trial).
    previous: Vec<Option<bool>>,
    table: SuccessTable,
    first: SuccessTable,
    /// Env steps to the first success of each scored first trial (None: it failed).
    first_steps: Vec<Option<u64>>,
    /// Whether the env reports `steps_to_success` (else `first_steps` says nothing).
    steps_reported: bool,
    within: Vec<u64>,
    after_success: SuccessTable,
    after_failure: SuccessTable,
    tracker: TrialTracker,
    returns: Vec<f64>,
}

impl EvalTally {
    /// `tasks`: each row's task at the reset; `default_task` names trials of envs
    /// that report no task; `first_trial_within`: the env-step budgets k of
    /// `EvalReport::first_trial_within`.
    pub fn new(tasks: &[String], default_task: &str, first_trial_within: &[u64]) -> Self {
        let (scored, per_task_episodes) = equal_share_per_task(tasks);
        Self {
            done: scored.iter().map(|s| !s).collect(),
            scored: scored.iter().filter(|&&s| s).count(),
            per_task_episodes,
            previous: vec![None; tasks.len()],
            table: SuccessTable::default(),
            first: SuccessTable::default(),
            first_steps: vec![],
            steps_reported: false,
            within: first_trial_within.to_vec(),
            after_success: SuccessTable::default(),
            after_failure: SuccessTable::default(),
            tracker: TrialTracker::new(tasks.len(), default_task),
            returns: vec![0.0; tasks.len()],
        }
    }

    /// Every scored episode has ended.
    pub fn finished(&self) -> bool {
        self.done.iter().all(|&d| d)
    }

    /// Counts the trials and returns of one step reply of every row.
    pub fn observe(&mut self, step: &StepBatch) -> Scoring {
        if step
            .cut
            .iter()
            .zip(&self.done)
            .any(|(&cut, &done)| cut && !done)
        {
            return Scoring::Void;
        }
        self.steps_reported |= step.info.get("steps_to_success").is_some();
        for t in self.tracker.outcomes(0, step) {
            if self.done[t.row] {
                continue;
            }
            self.table.record(&t.task, t.success);
            match self.previous[t.row] {
                None => {
                    self.first.record("all", t.success);
                    self.first_steps.push(t.steps_to_success);
                }
                Some(true) => self.after_success.record("all", t.success),
                Some(false) => self.after_failure.record("all", t.success),
            }
            self.previous[t.row] = Some(t.success);
        }
        for (row, end) in step.ended().into_iter().enumerate() {
            if !self.done[row] {
                self.returns[row] += step.reward[row];
                self.done[row] = end;
            }
        }
        Scoring::Going
    }

    pub fn report(&self, split: &str, env_id: String) -> EvalReport {
        EvalReport {
            split: split.to_owned(),
            env_id,
            episodes: self.scored,
            episodes_per_task: self.per_task_episodes,
            trials: self.table.trials(),
            per_task: self.table.per_task(),
            per_task_trials: self
                .table
                .tasks
                .iter()
                .map(|(k, (_, n))| (k.clone(), *n))
                .collect(),
            mean: self.table.mean(),
            first_trial: self.first.mean(),
            first_trial_within: self.first_trial_within(),
            after_success: self.after_success.mean(),
            after_failure: self.after_failure.mean(),
            after_success_trials: self.after_success.trials(),
            after_failure_trials: self.after_failure.trials(),
            mean_return: self.returns.iter().sum::<f64>() / self.scored.max(1) as f64,
        }
    }

    fn first_trial_within(&self) -> BTreeMap<u64, f64> {
        if !self.steps_reported || self.first_steps.is_empty() {
            return BTreeMap::new();
        }
        let n = self.first_steps.len() as f64;
        self.within
            .iter()
            .map(|&k| {
                let hits = self
                    .first_steps
                    .iter()
                    .filter(|s| s.is_some_and(|s| s <= k))
                    .count();
                (k, hits as f64 / n)
            })
            .collect()
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
    use crate::train::outcomes::fixtures::{step, trial_info};

    /// One step reply in which every row ends its first trial, with its success and its
    /// `steps_to_success` (or without that field).
    fn first_trials_end(success: &[bool], steps: Option<&[i64]>) -> StepBatch {
        let n = success.len();
        step(
            trial_info(&vec![true; n], success, steps),
            None,
            vec![false; n],
        )
    }

    #[test]
    fn first_trials_within_a_budget_count_the_successes_that_came_that_soon() {
        let tasks: Vec<String> = vec!["reach".into(); 4];
        let mut tally = EvalTally::new(&tasks, "none", &[50, 100, 200]);
        let step = first_trials_end(&[true, true, false, true], Some(&[42, 120, -1, 50]));
        assert_eq!(tally.observe(&step), Scoring::Going);
        let r = tally.report("train", "million/ML1-train".into());
        assert_eq!(r.first_trial, 0.75);
        let within: Vec<(u64, f64)> = r.first_trial_within.into_iter().collect();
        assert_eq!(within, [(50, 0.5), (100, 0.5), (200, 0.75)]);

        // An env that does not say how soon gets no such figures, not zeros.
        let mut tally = EvalTally::new(&tasks, "none", &[50]);
        tally.observe(&first_trials_end(&[true, true, false, true], None));
        let r = tally.report("train", "other".into());
        assert_eq!(r.first_trial, 0.75);
        assert!(r.first_trial_within.is_empty());
    }

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
