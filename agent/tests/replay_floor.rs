//! `buffer.min_replay_ratio`: a short real quickstart run (local env server, libtorch) whose
//! envs outpace its learner keeps its replay ratio at the floor by holding the actor.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use million::run_config::RunConfig;
use million::train::session::{TrainOptions, train};

#[test]
fn the_actor_waits_for_the_learner_at_the_replay_floor() {
    let mut cfg = RunConfig::from_file(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/quickstart.toml"),
    )
    .unwrap();
    cfg.train.total_agent_steps = 8_192;
    cfg.train.log_interval = 1_024;
    cfg.train.eval_interval = 0;
    cfg.train.checkpoint_interval = 0;
    // 16 samples per segment: 16 updates of 32 segments per 1,024 agent steps, more than
    // this learner keeps up with beside PointGoal's envs.
    cfg.buffer.replay_ratio = 16.0;
    cfg.buffer.min_replay_ratio = 16.0;
    let dir = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let summary = rt
        .block_on(train(TrainOptions {
            config: cfg,
            servers: vec![],
            env_access: Default::default(),
            run_dir: Some(dir.path().to_owned()),
            resume: false,
            progress: false,
            max_seconds: Some(600.0),
            evaluate: false,
            interrupt: Arc::new(AtomicBool::new(false)),
        }))
        .expect("training runs");
    // The last round's 32 segments may still wait for their updates: 16 · (256 - 32) / 256 = 14.
    assert!(
        summary.replay_ratio >= 13.0,
        "replay ratio {} under the floor 16",
        summary.replay_ratio
    );
    let metrics = std::fs::read_to_string(dir.path().join("metrics.jsonl")).unwrap();
    let waited = metrics
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|r| r.get("train/actor_wait_s")?.as_f64())
        .fold(0.0, f64::max);
    assert!(waited > 0.0, "the actor never waited:\n{metrics}");
}
