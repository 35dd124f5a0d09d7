//! One pool target standing for several replicas (a scaled Docker service, a
//! Kubernetes headless Service): every address it resolves to gets envs, and when a
//! replica is lost the target is resolved again, so its envs move to a live replica,
//! a new one under a new address included. Real servers; the name is resolved by a
//! fake resolver whose answer the test changes, as DNS changes when a replica is
//! replaced.

use crate::common;

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::common::init_tracing;
use million_env::{
    ActionSampler, AutoresetMode, EnvPool, PoolConfig, Resolve, ResolveFuture, RetryPolicy,
    StepBatch,
};

const NAME: &str = "env-server.test:50051";

#[derive(Debug, Default)]
struct FakeDns {
    answers: Mutex<HashMap<String, Vec<String>>>,
}

impl FakeDns {
    fn set(&self, name: &str, addrs: &[&str]) {
        self.answers.lock().unwrap().insert(
            name.to_owned(),
            addrs.iter().map(|a| (*a).to_owned()).collect(),
        );
    }
}

impl Resolve for FakeDns {
    fn resolve<'a>(&'a self, target: &'a str) -> ResolveFuture<'a> {
        let answer = self.answers.lock().unwrap().get(target).cloned();
        Box::pin(async move {
            answer.ok_or_else(|| std::io::Error::other(format!("{target}: no such name")))
        })
    }
}

fn config(dns: &Arc<FakeDns>) -> PoolConfig {
    let mut c = PoolConfig::new(vec![NAME.to_owned()], "Pendulum-v1", 4);
    c.groups = 2;
    c.seed = Some(5);
    c.autoreset = AutoresetMode::SameStep;
    c.resolver = dns.clone();
    c.client.retry = RetryPolicy {
        max_attempts: 1_000,
        max_elapsed: Duration::from_secs(60),
        ..RetryPolicy::default()
    };
    c
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

fn cut_envs(batches: &[StepBatch]) -> BTreeSet<usize> {
    batches
        .iter()
        .flat_map(|b| {
            b.cut
                .iter()
                .enumerate()
                .filter(|(_, c)| **c)
                .map(|(i, _)| b.env_offset + i)
        })
        .collect()
}

fn envs_on(pool: &EnvPool, addr: &str) -> BTreeSet<usize> {
    let addrs = pool.env_addresses();
    (0..addrs.len()).filter(|&i| addrs[i] == addr).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_replica_gets_envs_and_a_replaced_one_is_found_under_its_new_address() {
    init_tracing();
    let (mut a, b) = tokio::join!(common::start_server(), common::start_server());
    let dns = Arc::new(FakeDns::default());
    dns.set(NAME, &[a.addr(), b.addr()]);
    let mut pool = EnvPool::connect(config(&dns)).await.unwrap();
    let on_a = envs_on(&pool, a.addr());
    let on_b = envs_on(&pool, b.addr());
    assert_eq!(on_a.len(), 2, "one name, two replicas: both get envs");
    assert_eq!(on_b.len(), 2);

    let mut sampler = ActionSampler::new(&pool.spec().action_space, 3).unwrap();
    pool.reset_all().await.unwrap();
    for _ in 0..3 {
        step_all(&mut pool, &mut sampler).await;
    }

    // Replica a dies and is replaced under a new address; DNS now lists b and c.
    a.kill().await;
    let c = common::start_server().await;
    dns.set(NAME, &[b.addr(), c.addr()]);
    let after = step_all(&mut pool, &mut sampler).await;
    assert_eq!(cut_envs(&after), on_a, "a's envs were cut, b's went on");
    assert_eq!(envs_on(&pool, c.addr()), on_a, "a's envs now run on c");
    assert_eq!(envs_on(&pool, b.addr()), on_b);
    assert_eq!(pool.stats().rebuilds, 2);

    for _ in 0..3 {
        let batches = step_all(&mut pool, &mut sampler).await;
        assert!(cut_envs(&batches).is_empty());
    }
    pool.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_replica_still_listed_is_skipped_for_a_live_one() {
    init_tracing();
    let (mut a, b) = tokio::join!(common::start_server(), common::start_server());
    let dns = Arc::new(FakeDns::default());
    dns.set(NAME, &[a.addr(), b.addr()]);
    let mut pool = EnvPool::connect(config(&dns)).await.unwrap();
    let on_a = envs_on(&pool, a.addr());
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 3).unwrap();
    pool.reset_all().await.unwrap();
    step_all(&mut pool, &mut sampler).await;

    // Stale DNS: a is gone but still listed. Its envs are tried there briefly, then
    // rebuilt on b.
    a.kill().await;
    let after = step_all(&mut pool, &mut sampler).await;
    assert_eq!(cut_envs(&after), on_a);
    assert_eq!(
        envs_on(&pool, b.addr()).len(),
        4,
        "every env on the live replica"
    );
    let batches = step_all(&mut pool, &mut sampler).await;
    assert!(cut_envs(&batches).is_empty());
    pool.close().await.unwrap();
}
