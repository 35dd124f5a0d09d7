//! A server killed and restarted on the same port mid-run: the pool reconnects,
//! re-makes and resets its envs, and reports the cut episodes as truncated with
//! their last observation, while envs on the other server carry on untouched.

use crate::common;

use std::time::Duration;

use crate::common::init_tracing;
use million_env::{
    ActionSampler, AutoresetMode, EnvPool, FLAT_FIELD, PoolConfig, RetryPolicy, StepBatch, Tensor,
};

fn patient_config(servers: Vec<String>, autoreset: AutoresetMode) -> PoolConfig {
    let mut c = PoolConfig::new(servers, "Pendulum-v1", 4);
    c.groups = 2;
    c.seed = Some(5);
    c.autoreset = autoreset;
    // The Python server needs a few seconds to come back.
    c.client.retry = RetryPolicy {
        max_attempts: 1_000,
        max_elapsed: Duration::from_secs(90),
        ..RetryPolicy::default()
    };
    c
}

fn row(t: &Tensor, i: usize) -> Vec<u8> {
    t.slice_rows(i..i + 1).unwrap().data().to_vec()
}

async fn step_all(pool: &mut EnvPool, sampler: &mut ActionSampler) -> Vec<StepBatch> {
    for g in 0..2 {
        pool.send(g, &sampler.sample(2)).unwrap();
    }
    let mut out = Vec::new();
    for g in 0..2 {
        out.push(pool.recv(g).await.unwrap());
    }
    out
}

/// Two fresh servers and a pool of 4 envs in 2 groups over them: envs 0 and 3 live on the
/// first server, envs 1 and 2 on the second, so each group has one env on each.
async fn pool_over_two_servers() -> (common::Server, common::Server, EnvPool) {
    let (a, b) = tokio::join!(common::start_server(), common::start_server());
    let pool = EnvPool::connect(patient_config(
        vec![a.addr().to_owned(), b.addr().to_owned()],
        AutoresetMode::SameStep,
    ))
    .await
    .unwrap();
    (a, b, pool)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn restarted_server_cuts_its_episodes_and_the_pool_goes_on() {
    init_tracing();
    let (_a, mut b, mut pool) = pool_over_two_servers().await;
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 3).unwrap();
    pool.reset_all().await.unwrap();
    let mut last = Vec::new();
    for _ in 0..5 {
        last = step_all(&mut pool, &mut sampler).await;
    }
    b.restart().await.expect("server restarts");

    let after = step_all(&mut pool, &mut sampler).await;
    // Row (group, index) of each env on b, and of each env on a.
    for (g, cut_row, kept_row) in [(0, 1, 0), (1, 0, 1)] {
        let batch = &after[g];
        let before = last[g].obs.get(FLAT_FIELD).unwrap();
        assert!(
            batch.cut[cut_row],
            "group {g}: the env on the restarted server was cut"
        );
        assert!(batch.truncated[cut_row] && !batch.terminated[cut_row]);
        assert_eq!(batch.reward[cut_row], 0.0);
        let fin = batch
            .final_obs
            .as_ref()
            .expect("a final observation for the cut row");
        let fin = fin.get(FLAT_FIELD).unwrap();
        assert_eq!(
            row(fin, cut_row),
            row(before, cut_row),
            "group {g}: the cut episode ends on its last observation"
        );
        let now = batch.obs.get(FLAT_FIELD).unwrap();
        assert_ne!(
            row(now, cut_row),
            row(before, cut_row),
            "a new episode began"
        );

        assert!(
            !batch.cut[kept_row] && !batch.truncated[kept_row],
            "group {g}: the env on a goes on"
        );
        assert!(
            fin.slice_rows(kept_row..kept_row + 1)
                .unwrap()
                .data()
                .iter()
                .all(|b| *b == 0)
        );
    }
    assert_eq!(pool.stats().rebuilds, 2);
    assert_eq!(pool.stats().cut_episodes, 2);

    for _ in 0..3 {
        let batches = step_all(&mut pool, &mut sampler).await;
        for b in &batches {
            assert_eq!(b.cut, vec![false, false]);
            assert_eq!(b.truncated, vec![false, false]);
        }
    }
    pool.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn next_step_mode_shows_the_cut_then_the_reset() {
    init_tracing();
    let mut server = common::start_server().await;
    let mut pool = EnvPool::connect(patient_config(
        vec![server.addr().to_owned()],
        AutoresetMode::NextStep,
    ))
    .await
    .unwrap();
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 4).unwrap();
    pool.reset_all().await.unwrap();
    let last = step_all(&mut pool, &mut sampler).await;
    server.restart().await.expect("server restarts");
    let cut = step_all(&mut pool, &mut sampler).await;
    let reset = step_all(&mut pool, &mut sampler).await;
    for g in 0..2 {
        assert_eq!(cut[g].cut, vec![true, true]);
        assert_eq!(cut[g].truncated, vec![true, true]);
        // NEXT_STEP: the ending step shows the final observation itself...
        assert_eq!(
            cut[g].obs.get(FLAT_FIELD).unwrap().data(),
            last[g].obs.get(FLAT_FIELD).unwrap().data()
        );
        // ...and the next one the new episode's first, with reward 0.
        assert_eq!(reset[g].reward, vec![0.0, 0.0]);
        assert_eq!(reset[g].truncated, vec![false, false]);
        assert_eq!(reset[g].cut, vec![false, false]);
        assert_ne!(
            reset[g].obs.get(FLAT_FIELD).unwrap().data(),
            cut[g].obs.get(FLAT_FIELD).unwrap().data()
        );
    }
    let next = step_all(&mut pool, &mut sampler).await;
    assert!(
        next.iter().all(|b| b.reward.iter().all(|r| *r < 0.0)),
        "stepping for real again"
    );
    pool.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn closing_after_a_restart_is_no_error() {
    // The restarted server no longer knows the pool's handle (NOT_FOUND): its envs are gone
    // already, which is what Close asks for. A run that lost a server while stopping used
    // to fail here before writing its final checkpoint.
    init_tracing();
    let mut server = common::start_server().await;
    let mut pool = EnvPool::connect(patient_config(
        vec![server.addr().to_owned()],
        AutoresetMode::SameStep,
    ))
    .await
    .unwrap();
    pool.reset_all().await.unwrap();
    server.restart().await.expect("server restarts");
    pool.close()
        .await
        .expect("a handle the server forgot is closed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_seeded_reset_that_loses_its_server_begins_the_episodes_it_asked_for() {
    // An evaluation resets to its first episodes before each attempt. If the server is lost
    // during that reset, the rebuilt envs must begin those same episodes, not new ones.
    init_tracing();
    let (_a, mut b, mut pool) = pool_over_two_servers().await;
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 3).unwrap();
    let first: Vec<Tensor> = pool
        .reset_all()
        .await
        .unwrap()
        .iter()
        .map(|r| r.obs.get(FLAT_FIELD).unwrap().clone())
        .collect();
    for _ in 0..3 {
        step_all(&mut pool, &mut sampler).await;
    }
    b.restart().await.expect("server restarts");
    for (g, first) in first.iter().enumerate() {
        let again = pool.reset_to_first_episodes(g).await.unwrap();
        let again = again.obs.get(FLAT_FIELD).unwrap();
        for i in 0..2 {
            assert_eq!(
                row(again, i),
                row(first, i),
                "group {g}, row {i}: the episode begins as it first did"
            );
        }
    }
    // b held one env of each group, so each group's reset rebuilt it.
    assert_eq!(pool.stats().rebuilds, 2);
    pool.close().await.unwrap();
}
