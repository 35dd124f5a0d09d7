//! Trial outcomes and episode returns read from the pool's step replies.
//!
//! Under SAME_STEP autoreset a row that ended carries the next episode's reset info, so the
//! ending step's `trial_end`/`success` are read from `final_info` for those rows.

use std::collections::BTreeMap;

use million_env::{InfoBatch, StepBatch};
use serde::Serialize;

/// One finished trial: the task it belonged to, whether it succeeded and, where the env
/// says (MILLION envs' `steps_to_success`), after how many env steps it first did.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    pub row: usize,
    pub task: String,
    pub success: bool,
    /// None for a failed trial, or when the env does not report it.
    pub steps_to_success: Option<u64>,
}

/// One row of an info field as a one-row tensor, when the row has it.
fn row_value(info: &InfoBatch, name: &str, row: usize) -> Option<million_env::Tensor> {
    let f = info.get(name).filter(|f| f.present[row])?;
    f.value.slice_rows(row..row + 1).ok()
}

fn flag(info: &InfoBatch, name: &str, row: usize) -> bool {
    row_value(info, name, row)
        .and_then(|t| t.to_bool_vec().ok())
        .is_some_and(|v| v.first().copied().unwrap_or(false))
}

/// A non-negative integer info field of one row; None when absent or negative (MILLION's
/// `steps_to_success` is -1 for a trial that has not succeeded).
fn count(info: &InfoBatch, name: &str, row: usize) -> Option<u64> {
    let v = *row_value(info, name, row)?.to_i64_vec().ok()?.first()?;
    u64::try_from(v).ok()
}

/// A text info field of one row (e.g. `task_name`), when the row has it.
pub fn text(info: &InfoBatch, name: &str, row: usize) -> Option<String> {
    let f = info.get(name).filter(|f| f.present[row])?;
    f.value.strings().get(row).cloned()
}

/// Turns step replies into finished trials. MILLION envs mark the end of each trial
/// (`trial_end`, with `success` and `task_name`). Any other env (a plain Gymnasium id such as
/// `Meta-World/MT1`) is read as one trial per episode, successful when `success` was set at
/// any of its steps (Meta-World's own criterion), under the tracker's default task name.
#[derive(Debug, Clone)]
pub struct TrialTracker {
    default_task: String,
    succeeded: Vec<bool>,
}

impl TrialTracker {
    pub fn new(rows: usize, default_task: &str) -> Self {
        Self {
            default_task: default_task.to_owned(),
            succeeded: vec![false; rows],
        }
    }

    /// The trials that ended at this step of the rows `offset..offset + step.rows()`.
    pub fn outcomes(&mut self, offset: usize, step: &StepBatch) -> Vec<TrialOutcome> {
        let ended = step.ended();
        let mut out = vec![];
        for (row, &end) in ended.iter().enumerate() {
            let info = match (&step.final_info, end) {
                (Some(fi), true) => fi,
                _ => &step.info,
            };
            let task = || text(info, "task_name", row).unwrap_or_else(|| self.default_task.clone());
            if info.get("trial_end").is_some() {
                if flag(info, "trial_end", row) {
                    let success = flag(info, "success", row);
                    out.push(TrialOutcome {
                        row,
                        task: task(),
                        success,
                        steps_to_success: count(info, "steps_to_success", row).filter(|_| success),
                    });
                }
                continue;
            }
            let seen = &mut self.succeeded[offset + row];
            *seen |= flag(info, "success", row);
            if end {
                let success = std::mem::take(seen);
                out.push(TrialOutcome {
                    row,
                    task: task(),
                    success,
                    steps_to_success: None,
                });
            }
        }
        out
    }
}

/// Success counts per task.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SuccessTable {
    /// task → (successful trials, trials)
    pub tasks: BTreeMap<String, (u64, u64)>,
}

impl SuccessTable {
    pub fn record(&mut self, task: &str, success: bool) {
        let e = self.tasks.entry(task.to_owned()).or_default();
        e.0 += u64::from(success);
        e.1 += 1;
    }

    pub fn trials(&self) -> u64 {
        self.tasks.values().map(|e| e.1).sum()
    }

    /// Success rate of each task.
    pub fn per_task(&self) -> BTreeMap<String, f64> {
        self.tasks
            .iter()
            .map(|(k, (s, n))| (k.clone(), *s as f64 / (*n).max(1) as f64))
            .collect()
    }

    /// Mean over tasks of the per-task success rate (NaN with no trials).
    pub fn mean(&self) -> f64 {
        if self.tasks.is_empty() {
            return f64::NAN;
        }
        self.per_task().values().sum::<f64>() / self.tasks.len() as f64
    }
}

/// Running episode returns per env slot; finished returns are collected until taken.
#[derive(Debug, Clone)]
pub struct EpisodeReturns {
    running: Vec<f64>,
    finished: Vec<f64>,
}

impl EpisodeReturns {
    pub fn new(rows: usize) -> Self {
        Self {
            running: vec![0.0; rows],
            finished: vec![],
        }
    }

    pub fn record(&mut self, offset: usize, step: &StepBatch) {
        for (i, (r, end)) in step.reward.iter().zip(step.ended()).enumerate() {
            self.running[offset + i] += r;
            if end {
                self.finished.push(self.running[offset + i]);
                self.running[offset + i] = 0.0;
            }
        }
    }

    pub fn take_finished(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.finished)
    }
}

/// Step replies built by hand, for the tests of what is read from them.
#[cfg(test)]
pub(crate) mod fixtures {
    use million_env::{Fields, InfoBatch, InfoField, StepBatch, Tensor};

    fn field(name: &str, value: Tensor) -> InfoField {
        let rows = value.rows();
        InfoField {
            name: name.into(),
            value,
            present: vec![true; rows],
        }
    }

    /// A MILLION step info of `trial_end` and `success` per row, and `steps_to_success`
    /// unless None (an env that does not report it).
    pub(crate) fn trial_info(end: &[bool], success: &[bool], steps: Option<&[i64]>) -> InfoBatch {
        let n = end.len();
        let mut fields = vec![
            field("trial_end", Tensor::from_bool(vec![n], end).unwrap()),
            field("success", Tensor::from_bool(vec![n], success).unwrap()),
        ];
        if let Some(steps) = steps {
            let value = Tensor::from_i64(vec![n], steps).unwrap();
            fields.push(field("steps_to_success", value));
        }
        InfoBatch(fields)
    }

    pub(crate) fn step(
        info: InfoBatch,
        final_info: Option<InfoBatch>,
        terminated: Vec<bool>,
    ) -> StepBatch {
        let n = terminated.len();
        StepBatch {
            group: 0,
            env_offset: 0,
            obs: Fields::default(),
            reward: vec![0.0; n],
            terminated,
            truncated: vec![false; n],
            cut: vec![false; n],
            info,
            final_obs: None,
            final_info,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::fixtures::{step, trial_info};
    use super::*;

    #[test]
    fn trial_outcomes_carry_how_soon_a_success_came() {
        // Row 0 ends a successful trial mid-episode, row 1 a failed one, row 2 runs on, and
        // row 3 ends its episode with a success: under SAME_STEP its `info` is the next
        // episode's reset (-1) and the ended trial's figures are in `final_info`.
        let now = trial_info(
            &[true, true, false, false],
            &[true, false, false, false],
            Some(&[42, -1, 7, -1]),
        );
        let ending = trial_info(
            &[false, false, false, true],
            &[false, false, false, true],
            Some(&[0, 0, 0, 9]),
        );
        let mut tracker = TrialTracker::new(4, "none");
        let out = tracker.outcomes(0, &step(now, Some(ending), vec![false, false, false, true]));
        let got: Vec<(usize, bool, Option<u64>)> = out
            .iter()
            .map(|t| (t.row, t.success, t.steps_to_success))
            .collect();
        assert_eq!(
            got,
            [(0, true, Some(42)), (1, false, None), (3, true, Some(9))]
        );
    }

    #[test]
    fn an_env_without_steps_to_success_reports_none() {
        let n = 1;
        let only_ends = trial_info(&[true], &[true], None);
        let mut tracker = TrialTracker::new(n, "none");
        let out = tracker.outcomes(0, &step(only_ends, None, vec![false]));
        assert_eq!(out.len(), 1);
        assert!(out[0].success);
        assert_eq!(out[0].steps_to_success, None);
    }

    #[test]
    fn success_table_means_over_tasks() {
        let mut t = SuccessTable::default();
        t.record("a", true);
        t.record("a", false);
        t.record("b", true);
        assert_eq!(t.trials(), 3);
        assert_eq!(t.per_task()["a"], 0.5);
        assert!((t.mean() - 0.75).abs() < 1e-12);
        assert!(SuccessTable::default().mean().is_nan());
    }
}
