//! An env server lost partway through a deterministic evaluation voids it. Before this
//! check, the trials that had ended by the loss (the short ones, often the successful
//! ones) were scored alone, and a split whose true rate was ~0.2 reported 1.00. Real env
//! server, `million/PointGoal` as the quickstart evaluates it, random actions.
use std::path::Path;
use std::time::Duration;

use million::run_config::RunConfig;
use million::train::eval::{EvalTally, Scoring};
use million::train::outcomes::text;
use million_env::{
    ActionSampler, AutoresetMode, EnvPool, LocalServer, LocalServerOptions, PoolConfig,
    RetryPolicy, default_server_binary,
};

const ENVS: usize = 4;

async fn eval_pool(server: &str) -> EnvPool {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let cfg = RunConfig::from_file(&repo.join("configs/quickstart.toml")).unwrap();
    let split = cfg.eval_splits().unwrap().remove(0);
    let mut pc = PoolConfig::new(vec![server.to_owned()], split.env_id.clone(), ENVS);
    pc.kwargs = split.kwargs;
    pc.seed = Some(7);
    pc.autoreset = AutoresetMode::SameStep;
    // The Python server needs a few seconds to come back.
    pc.client.retry = RetryPolicy {
        max_attempts: 1_000,
        max_elapsed: Duration::from_secs(90),
        ..RetryPolicy::default()
    };
    EnvPool::connect(pc).await.expect("pool connects")
}

/// Tasks of the rows at a reset, as the evaluator reads them.
fn tasks(info: &million_env::InfoBatch) -> Vec<String> {
    (0..ENVS)
        .map(|row| text(info, "task_name", row).unwrap_or_else(|| "none".into()))
        .collect()
}

/// What identifies the episodes of a reset: each row's task, sentence and goal.
fn episodes(info: &million_env::InfoBatch) -> (Vec<String>, Vec<Option<String>>, Vec<u8>) {
    let goal = info.get("goal").expect("a goal info field");
    (
        tasks(info),
        (0..ENVS)
            .map(|row| text(info, "instruction", row))
            .collect(),
        goal.value.data().to_vec(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_lost_mid_evaluation_voids_the_scores() {
    let binary = default_server_binary().expect("million-env-server installed (make setup)");
    let mut server = LocalServer::start(&binary, LocalServerOptions::default())
        .await
        .expect("server starts");
    let mut pool = eval_pool(server.addr()).await;
    let mut actions = ActionSampler::new(&pool.spec().action_space, 3).unwrap();

    // Uninterrupted, the tally runs to its end and scores every row.
    let reset = pool.reset_to_first_episodes(0).await.unwrap();
    let mut tally = EvalTally::new(&tasks(&reset.info), "none", &[5, 1_000]);
    let mut steps = 0;
    while !tally.finished() {
        let step = pool.step(0, &actions.sample(ENVS)).await.unwrap();
        assert_eq!(tally.observe(&step), Scoring::Going);
        steps += 1;
        assert!(steps < 10_000, "the episodes never ended");
    }
    let report = tally.report("train", "million/PointGoal".into());
    assert_eq!(report.episodes, ENVS);
    assert!(report.trials >= ENVS as u64, "every episode has trials");
    // Every trial but an episode's first follows a success or a failure of its episode.
    assert_eq!(
        report.after_success_trials + report.after_failure_trials,
        report.trials - ENVS as u64,
        "{report:?}"
    );
    // Random actions fail most trials, so later trials follow failures.
    assert!(report.after_failure_trials > 0, "{report:?}");
    assert!((0.0..=1.0).contains(&report.after_failure), "{report:?}");
    // First trials that succeeded within k env steps: the server reports how soon, and a
    // budget longer than any trial counts every success.
    let within = &report.first_trial_within;
    assert_eq!(within.keys().copied().collect::<Vec<_>>(), [5, 1_000]);
    assert!(within[&5] <= within[&1_000], "{report:?}");
    assert_eq!(within[&1_000], report.first_trial, "{report:?}");

    // The same episodes again, with the server killed and restarted a few steps in:
    // the cut step voids the tally instead of leaving it the trials ended so far.
    let reset = pool.reset_to_first_episodes(0).await.unwrap();
    let mut tally = EvalTally::new(&tasks(&reset.info), "none", &[5, 1_000]);
    for _ in 0..3 {
        let step = pool.step(0, &actions.sample(ENVS)).await.unwrap();
        assert_eq!(tally.observe(&step), Scoring::Going);
    }
    server.restart().await.expect("server restarts");
    let cut = pool.step(0, &actions.sample(ENVS)).await.unwrap();
    assert!(
        cut.cut.iter().all(|&c| c),
        "every row was cut: {:?}",
        cut.cut
    );
    assert_eq!(tally.observe(&cut), Scoring::Void);

    // The retry's reset on the rebuilt envs begins the very episodes of the first.
    let again = pool.reset_to_first_episodes(0).await.unwrap();
    assert_eq!(episodes(&again.info), episodes(&reset.info));
    pool.close().await.unwrap();
}
