//! A run directory as the report reads it: `metrics.jsonl` (one JSON object per line, see
//! `crate::metrics`) and `config.toml`. Only the keys the report needs are read; any other
//! key is ignored, and each one it reads is optional, so records with new keys (or runs of
//! older versions) still make a report.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::run_dir;

/// One point of a split's learning curve (a deterministic evaluation).
#[derive(Debug, Clone, PartialEq)]
pub struct CurvePoint {
    pub step: u64,
    pub success: f64,
    /// Success of first trials only; None when the record lacks it.
    pub first_trial: Option<f64>,
}

/// The last evaluation of a split.
#[derive(Debug, Clone, PartialEq)]
pub struct FinalEval {
    pub step: u64,
    pub success: f64,
    pub first_trial: Option<f64>,
    /// task → success rate (`eval/<split>/task/<task>`).
    pub per_task: BTreeMap<String, f64>,
}

/// What the report knows of one run.
#[derive(Debug, Clone)]
pub struct RunData {
    /// The directory's name, used in legends and tables.
    pub name: String,
    pub dir: PathBuf,
    /// `[env] id` of config.toml ("" when absent).
    pub env_id: String,
    /// How the test split differs from training, e.g. `million/PointGoal, heldout sentences`.
    pub test_split: Option<String>,
    /// Largest agent step recorded.
    pub last_step: u64,
    /// Seconds between the first and the last record (0 with fewer than two).
    pub wall_s: f64,
    /// Agent steps per second over that span (evaluation time included).
    pub steps_per_s: Option<f64>,
    /// split ("train", "test") → evaluation points in step order.
    pub curves: BTreeMap<String, Vec<CurvePoint>>,
    /// split → its last evaluation.
    pub final_eval: BTreeMap<String, FinalEval>,
    /// Lines of metrics.jsonl that were not JSON objects with a step (e.g. a line cut short
    /// when a run was killed); skipped.
    pub skipped_lines: usize,
}

impl RunData {
    /// The Meta-World benchmark of the run ("ML10", "ML45"), for the reference points.
    pub fn benchmark(&self) -> Option<&'static str> {
        ["ML10", "ML45"]
            .into_iter()
            .find(|b| self.env_id.contains(b))
    }

    pub fn splits(&self) -> impl Iterator<Item = &str> {
        self.curves.keys().map(String::as_str)
    }

    /// Mean success (or first-trial success) over a split's last `k` evaluations, with the
    /// number of evaluations it averages. Deterministic evaluations of one run swing by
    /// ±0.2–0.4 between checkpoints (docs/experiments/), so one last point is a poor summary.
    pub fn recent_mean(&self, split: &str, k: usize, first_trial: bool) -> Option<(f64, usize)> {
        let points = self.curves.get(split)?;
        let values: Vec<f64> = points
            .iter()
            .rev()
            .take(k)
            .filter_map(|p| {
                if first_trial {
                    p.first_trial
                } else {
                    Some(p.success)
                }
            })
            .collect();
        (!values.is_empty()).then(|| {
            (
                values.iter().sum::<f64>() / values.len() as f64,
                values.len(),
            )
        })
    }

    /// The final evaluations in reading order: train, test, then any other split.
    pub fn final_evals(&self) -> Vec<(&str, &FinalEval)> {
        let rank = |s: &str| match s {
            "train" => 0,
            "test" => 1,
            _ => 2,
        };
        let mut v: Vec<(&str, &FinalEval)> = self
            .final_eval
            .iter()
            .map(|(k, f)| (k.as_str(), f))
            .collect();
        v.sort_by_key(|(k, _)| (rank(k), *k));
        v
    }
}

fn number(record: &serde_json::Map<String, serde_json::Value>, key: &str) -> Option<f64> {
    record.get(key).and_then(serde_json::Value::as_f64)
}

/// Splits of a record: the `<split>` of its `eval/<split>/success` keys.
fn eval_splits(record: &serde_json::Map<String, serde_json::Value>) -> Vec<String> {
    record
        .keys()
        .filter_map(|k| run_dir::eval::split_of_success(k))
        .map(str::to_owned)
        .collect()
}

/// Reads a run directory (`metrics.jsonl` required, `config.toml` optional).
pub fn read_run(dir: &Path) -> anyhow::Result<RunData> {
    let path = dir.join(run_dir::METRICS_FILE);
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {} (is it a run directory?)", path.display()))?;
    let name = dir
        .canonicalize()
        .unwrap_or_else(|_| dir.to_owned())
        .file_name()
        .map_or_else(
            || dir.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
    let mut run = RunData {
        name,
        dir: dir.to_owned(),
        env_id: String::new(),
        test_split: None,
        last_step: 0,
        wall_s: 0.0,
        steps_per_s: None,
        curves: BTreeMap::new(),
        final_eval: BTreeMap::new(),
        skipped_lines: 0,
    };
    let mut first: Option<(u64, f64)> = None;
    let mut last: Option<(u64, f64)> = None;
    let mut records = 0usize;
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let Ok(serde_json::Value::Object(record)) = serde_json::from_str(line) else {
            run.skipped_lines += 1;
            continue;
        };
        let Some(step) = record
            .get(run_dir::STEP_KEY)
            .and_then(serde_json::Value::as_u64)
        else {
            run.skipped_lines += 1;
            continue;
        };
        records += 1;
        run.last_step = run.last_step.max(step);
        if let Some(t) = number(&record, run_dir::WALL_TIME_KEY) {
            first.get_or_insert((step, t));
            last = Some((step, t));
        }
        for split in eval_splits(&record) {
            let Some(success) = number(&record, &run_dir::eval::success(&split)) else {
                continue; // null: no trials
            };
            let first_trial = number(&record, &run_dir::eval::first_trial_success(&split));
            let prefix = run_dir::eval::task_prefix(&split);
            let per_task: BTreeMap<String, f64> = record
                .iter()
                .filter_map(|(k, v)| {
                    let task = k.strip_prefix(&prefix)?;
                    // Only `eval/<split>/task/<task>` itself: deeper keys are other values.
                    (!task.contains('/')).then_some(())?;
                    Some((task.to_owned(), v.as_f64()?))
                })
                .collect();
            run.curves
                .entry(split.clone())
                .or_default()
                .push(CurvePoint {
                    step,
                    success,
                    first_trial,
                });
            run.final_eval.insert(
                split,
                FinalEval {
                    step,
                    success,
                    first_trial,
                    per_task,
                },
            );
        }
    }
    anyhow::ensure!(records > 0, "{} holds no metrics records", path.display());
    if let (Some((s0, t0)), Some((s1, t1))) = (first, last) {
        run.wall_s = (t1 - t0).max(0.0);
        if t1 > t0 && s1 > s0 {
            run.steps_per_s = Some((s1 - s0) as f64 / (t1 - t0));
        }
    }
    for points in run.curves.values_mut() {
        points.sort_by_key(|p| p.step);
    }
    read_config(dir, &mut run);
    Ok(run)
}

/// The env id and the test split's description from `config.toml`, when readable. The file
/// is read as plain TOML (not as a `RunConfig`), so configs of other versions still work.
fn read_config(dir: &Path, run: &mut RunData) {
    let Ok(text) = std::fs::read_to_string(dir.join(run_dir::CONFIG_FILE)) else {
        return;
    };
    let Ok(table) = text.parse::<toml::Table>() else {
        return;
    };
    let get = |section: &str, key: &str| table.get(section)?.get(key).cloned();
    if let Some(toml::Value::String(id)) = get("env", "id") {
        run.env_id = id;
    }
    if let Some(toml::Value::String(test_id)) = get("eval", "test_id")
        && !test_id.is_empty()
    {
        let kwargs = get("eval", "test_kwargs");
        let sentences = kwargs
            .as_ref()
            .and_then(|k| k.get("instruction_set"))
            .and_then(toml::Value::as_str)
            .unwrap_or("train");
        let words = match kwargs.as_ref().and_then(|k| k.get("instructions")) {
            Some(toml::Value::Boolean(false)) => "no instructions".to_owned(),
            _ => format!("{sentences} sentences"),
        };
        run.test_split = Some(format!("{test_id}, {words}"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_curves_final_evals_and_ignores_unknown_keys() {
        let dir = tempfile::tempdir().unwrap();
        let lines = [
            r#"{"step":100,"wall_time":10.0,"train/success":0.5}"#,
            r#"{"step":200,"wall_time":12.0,"eval/train/success":0.25,"eval/train/first_trial_success":0.5,"eval/train/task/a":0.25,"eval/train/task/a/episodes":7,"eval/train/new_key":3}"#,
            r#"{"step":400,"wall_time":14.0,"eval/train/success":0.75,"eval/test/success":null,"eval/train/task/a":0.5,"eval/train/task/b":1.0}"#,
            r#"{"step":"#,
        ];
        std::fs::write(dir.path().join("metrics.jsonl"), lines.join("\n")).unwrap();
        std::fs::write(
            dir.path().join("config.toml"),
            "[env]\nid = \"million/ML10-train\"\n[eval]\ntest_id = \"million/ML10-test\"\ntest_kwargs = { instruction_set = \"heldout\" }\n",
        )
        .unwrap();
        let run = read_run(dir.path()).unwrap();
        assert_eq!(run.last_step, 400);
        assert_eq!(run.skipped_lines, 1);
        assert_eq!(run.wall_s, 4.0);
        assert_eq!(run.steps_per_s, Some(75.0));
        assert_eq!(run.curves["train"].len(), 2);
        assert!(
            !run.curves.contains_key("test"),
            "a null success is no point"
        );
        let fin = &run.final_eval["train"];
        assert_eq!((fin.step, fin.success, fin.first_trial), (400, 0.75, None));
        assert_eq!(fin.per_task.len(), 2);
        assert_eq!(run.curves["train"][0].first_trial, Some(0.5));
        assert_eq!(run.recent_mean("train", 3, false), Some((0.5, 2)));
        assert_eq!(run.recent_mean("train", 1, false), Some((0.75, 1)));
        // Only the points that carry a first-trial figure are averaged.
        assert_eq!(run.recent_mean("train", 3, true), Some((0.5, 1)));
        assert_eq!(run.recent_mean("test", 3, false), None);
        assert_eq!(run.benchmark(), Some("ML10"));
        assert_eq!(
            run.test_split.as_deref(),
            Some("million/ML10-test, heldout sentences")
        );
    }
}
