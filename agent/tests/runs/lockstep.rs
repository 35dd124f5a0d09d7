//! Lockstep pacing (`buffer.pacing = "lockstep"`, the default): the learner makes exactly the
//! updates the replay ratio allows and the actor waits for it, so a seed's run is the same at
//! any speed and load. Real quickstart runs: a local env server, PointGoal, libtorch.

use std::path::Path;

use crate::common::{metrics_records, shipped_config, train_in};
use million::config::Pacing;
use million::run_config::RunConfig;
use million::run_dir::depends_on_the_machine;

/// The quickstart, shortened: `steps` agent steps, logged every 1,024, evaluated every 4,096.
fn quickstart(steps: u64) -> RunConfig {
    let mut cfg = shipped_config("quickstart.toml");
    assert_eq!(
        cfg.buffer.pacing,
        Pacing::Lockstep,
        "lockstep is the default"
    );
    cfg.train.total_agent_steps = steps;
    cfg.train.log_interval = 1_024;
    cfg.train.eval_interval = 4_096;
    cfg.train.checkpoint_interval = 0;
    cfg.eval.episodes = 16;
    cfg
}

/// A run's metrics without those that depend on the machine (rates, CPU and wall time).
pub(crate) fn machine_free_metrics(dir: &Path) -> Vec<Vec<(String, String)>> {
    metrics_records(dir)
        .into_iter()
        .map(|r| {
            r.into_iter()
                .filter(|(k, _)| k != "wall_time" && !depends_on_the_machine(k))
                .map(|(k, v)| (k, v.to_string()))
                .collect()
        })
        .collect()
}

#[test]
fn two_runs_of_one_seed_give_identical_metrics() {
    // 40 rounds of 1,024 agent steps at replay ratio 4: about 150 updates of 32 segments.
    let cfg = quickstart(40_960);
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let first = train_in(cfg.clone(), a.path(), true, 900.0);
    let second = train_in(cfg, b.path(), true, 900.0);
    assert!(first.updates >= 100, "only {} updates", first.updates);
    assert_eq!(first.updates, second.updates);
    let (ma, mb) = (
        machine_free_metrics(a.path()),
        machine_free_metrics(b.path()),
    );
    assert!(
        ma.iter()
            .any(|r| r.iter().any(|(k, _)| k == "learner/loss")),
        "no learner metrics were logged"
    );
    assert_eq!(ma.len(), mb.len(), "different numbers of records");
    for (ra, rb) in ma.iter().zip(&mb) {
        assert_eq!(ra, rb, "the two runs' metrics differ");
    }
    let successes = |s: &million::train::session::TrainSummary| {
        s.final_eval.iter().map(|r| r.mean).collect::<Vec<_>>()
    };
    assert_eq!(successes(&first), successes(&second));
}

#[test]
fn the_learner_makes_exactly_the_updates_the_replay_ratio_allows() {
    // 16 samples per segment: far more updates than this learner makes beside PointGoal's
    // envs when neither waits, so the actor must wait for it.
    let mut cfg = quickstart(8_192);
    cfg.buffer.replay_ratio = 16.0;
    let dir = tempfile::tempdir().unwrap();
    let summary = train_in(cfg.clone(), dir.path(), false, 600.0);
    // Every batch of 16 segments is learned from before the run ends: 8,192 steps are 256
    // segments, so 16 · 256 / 32 = 128 updates of 32 segments.
    let produced = summary.agent_steps / cfg.model.segment_len as u64;
    let expected =
        (cfg.buffer.replay_ratio * produced as f64) as u64 / cfg.buffer.batch_segments as u64;
    assert_eq!(summary.updates, expected);
    assert_eq!(summary.replay_ratio, 16.0);
    let waited = metrics_records(dir.path())
        .iter()
        .filter_map(|r| r.get("train/actor_wait_s")?.as_f64())
        .fold(0.0, f64::max);
    assert!(waited > 0.0, "the actor never waited for the learner");
}
