//! `model.goal_prediction` on a real run: the env's `goal` info reaches the token's end on
//! every step (training and evaluation), and the goal head's error is logged per update.
//! The quickstart, shortened: a local env server, PointGoal, libtorch.

use crate::common::{metrics_records, shipped_config, train_in};
use million::config::GoalPrediction;

#[test]
fn a_run_with_the_goal_probe_logs_how_far_its_goal_is_from_the_envs() {
    let mut cfg = shipped_config("quickstart.toml");
    cfg.model.goal_prediction = GoalPrediction::Probe;
    cfg.train.total_agent_steps = 8_192;
    cfg.train.log_interval = 1_024;
    cfg.train.eval_interval = 0;
    cfg.train.checkpoint_interval = 0;
    cfg.eval.episodes = 8;
    let dir = tempfile::tempdir().unwrap();
    let summary = train_in(cfg, dir.path(), true, 600.0);
    assert!(summary.updates > 0);
    assert!(!summary.final_eval.is_empty(), "the final evaluation ran");
    let errors: Vec<f64> = metrics_records(dir.path())
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
    let per_task = metrics_records(dir.path())
        .iter()
        .any(|r| r.keys().any(|k| k.starts_with("learner/task_goal_error/")));
    assert!(per_task, "no per-task goal error was logged");
}
