//! `model.goal_prediction` on a real run: the env's `goal` info reaches the token's end on
//! every step (training and evaluation), the goal head's error is logged per update, and a
//! probe leaves the run as it is without one. The quickstart, shortened: a local env server,
//! PointGoal, libtorch.

use std::path::Path;

use crate::common::{metrics_records, shipped_config, train_in};
use crate::lockstep::machine_free_metrics;
use million::config::GoalPrediction;
use million::train::session::TrainSummary;

/// 8,192 agent steps of the quickstart with the given goal head, evaluated at the end.
fn quickstart(goal: GoalPrediction, dir: &Path) -> TrainSummary {
    let mut cfg = shipped_config("quickstart.toml");
    cfg.model.goal_prediction = goal;
    cfg.train.total_agent_steps = 8_192;
    cfg.train.log_interval = 1_024;
    cfg.train.eval_interval = 0;
    cfg.train.checkpoint_interval = 0;
    cfg.eval.episodes = 8;
    train_in(cfg, dir, true, 600.0)
}

/// A run's machine-free metrics without the goal head's own (and the total loss, which
/// includes its loss).
fn without_the_goal_head(dir: &Path) -> Vec<Vec<(String, String)>> {
    machine_free_metrics(dir)
        .into_iter()
        .map(|r| {
            r.into_iter()
                .filter(|(k, _)| k != "learner/loss" && !k.contains("goal_"))
                .collect()
        })
        .collect()
}

#[test]
fn a_run_with_the_goal_probe_logs_how_far_its_goal_is_and_acts_as_without_it() {
    let dir = tempfile::tempdir().unwrap();
    let summary = quickstart(GoalPrediction::Probe, dir.path());
    assert!(summary.updates > 0);
    assert!(!summary.final_eval.is_empty(), "the final evaluation ran");
    let records = metrics_records(dir.path());
    let errors: Vec<f64> = records
        .iter()
        .filter_map(|r| r.get("learner/goal_error")?.as_f64())
        .collect();
    assert!(!errors.is_empty(), "no goal error was logged");
    // PointGoal's goals lie on a circle of radius 0.6 around the start: an error of metres
    // would mean the head is not fed the env's goal.
    assert!(
        errors.iter().all(|e| e.is_finite() && *e > 0.0 && *e < 2.0),
        "{errors:?}"
    );
    let per_task = records
        .iter()
        .any(|r| r.keys().any(|k| k.starts_with("learner/task_goal_error/")));
    assert!(per_task, "no per-task goal error was logged");
    // The same seed without a goal head: the same updates, losses and evaluations.
    let off_dir = tempfile::tempdir().unwrap();
    let off = quickstart(GoalPrediction::Off, off_dir.path());
    assert_eq!(off.updates, summary.updates);
    assert_eq!(
        without_the_goal_head(dir.path()),
        without_the_goal_head(off_dir.path())
    );
    let successes = |s: &TrainSummary| s.final_eval.iter().map(|r| r.mean).collect::<Vec<_>>();
    assert_eq!(successes(&summary), successes(&off));
}
