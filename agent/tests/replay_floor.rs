//! `buffer.min_replay_ratio`: a short real quickstart run (local env server, libtorch) whose
//! envs outpace its learner keeps its replay ratio at the floor by holding the actor.

mod common;

use common::{metrics_records, shipped_config, train_in};

#[test]
fn the_actor_waits_for_the_learner_at_the_replay_floor() {
    let mut cfg = shipped_config("quickstart.toml");
    cfg.train.total_agent_steps = 8_192;
    cfg.train.log_interval = 1_024;
    cfg.train.eval_interval = 0;
    cfg.train.checkpoint_interval = 0;
    // 16 samples per segment: 16 updates of 32 segments per 1,024 agent steps, more than
    // this learner keeps up with beside PointGoal's envs.
    cfg.buffer.replay_ratio = 16.0;
    cfg.buffer.min_replay_ratio = 16.0;
    let dir = tempfile::tempdir().unwrap();
    let summary = train_in(cfg, dir.path(), false, 600.0);
    // The last round's 32 segments may still wait for their updates: 16 · (256 - 32) / 256 = 14.
    assert!(
        summary.replay_ratio >= 13.0,
        "replay ratio {} under the floor 16",
        summary.replay_ratio
    );
    let waited = metrics_records(dir.path())
        .iter()
        .filter_map(|r| r.get("train/actor_wait_s")?.as_f64())
        .fold(0.0, f64::max);
    assert!(waited > 0.0, "the actor never waited for the learner");
}
