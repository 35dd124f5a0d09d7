//! A supervised local server killed with SIGKILL (as by the OOM killer) comes
//! back on the same port, and a pool over it goes on: the cut episodes are
//! reported as truncated, and stepping continues.

use std::time::{Duration, Instant};

use crate::common::init_tracing;
use million_env::{
    ActionSampler, AutoresetMode, EnvPool, LocalServer, LocalServerOptions, PoolConfig,
    RestartPolicy, SupervisedServer, default_server_binary,
};

async fn wait_for(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < timeout, "{what} within {timeout:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn kill_9(pid: u32) {
    let status = std::process::Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success());
}

/// One step of both groups; returns how many rows were cut by a rebuild.
async fn step(pool: &mut EnvPool, sampler: &mut ActionSampler) -> usize {
    for g in 0..2 {
        pool.send(g, &sampler.sample(2)).unwrap();
    }
    let mut cut = 0;
    for g in 0..2 {
        let batch = pool.recv(g).await.expect("the pool goes on");
        for (i, &c) in batch.cut.iter().enumerate() {
            assert!(!c || (batch.truncated[i] && !batch.terminated[i]));
            cut += usize::from(c);
        }
    }
    cut
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_local_server_is_restarted_and_the_pool_goes_on() {
    init_tracing();
    let binary = default_server_binary().expect("million-env-server installed (make setup)");
    let server = LocalServer::start(&binary, LocalServerOptions::default())
        .await
        .unwrap();
    let port = server.port();
    let supervised = SupervisedServer::new(server, RestartPolicy::default());
    let mut config = PoolConfig::new(vec![supervised.addr().to_owned()], "Pendulum-v1", 4);
    config.groups = 2;
    config.seed = Some(3);
    config.autoreset = AutoresetMode::SameStep;
    // The pool's own reconnect budget (30 s by default) is what a run relies on.
    let mut pool = EnvPool::connect(config).await.unwrap();
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 2).unwrap();
    pool.reset_all().await.unwrap();
    for _ in 0..3 {
        assert_eq!(step(&mut pool, &mut sampler).await, 0);
    }

    let first = supervised.pid().expect("running");
    kill_9(first);
    wait_for("a restart", Duration::from_secs(120), || {
        supervised.restarts() == 1 && supervised.pid().is_some()
    })
    .await;
    assert_ne!(supervised.pid(), Some(first));
    assert!(
        supervised.addr().ends_with(&format!(":{port}")),
        "same port"
    );

    // Every env lived on the dead server: all 4 are cut once, then steps go on.
    let mut cut = 0;
    for _ in 0..3 {
        cut += step(&mut pool, &mut sampler).await;
    }
    assert_eq!(cut, 4);
    assert_eq!(pool.stats().rebuilds, 2, "both shards were rebuilt");
    assert_eq!(pool.stats().cut_episodes, 4);
    pool.close().await.unwrap();
}
