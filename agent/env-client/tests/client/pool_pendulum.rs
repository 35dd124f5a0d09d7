//! The pool on Pendulum-v1 against the real server: batch shapes with double
//! buffering, time-limit truncation under SAME_STEP, determinism by seed across
//! server counts, and clear errors for bad input.

use crate::common;

use std::time::Duration;

use crate::common::{Server, free_port, init_tracing};
use million_env::{
    ActionSampler, AutoresetMode, ClientConfig, DType, EnvClient, EnvError, EnvPool, FLAT_FIELD,
    Kwargs, PoolConfig, RetryPolicy, StepBatch, Tensor,
};
use tonic::Code;

fn config(servers: &[&Server], num_envs: usize, groups: usize, seed: u64) -> PoolConfig {
    let mut c = PoolConfig::new(
        servers.iter().map(|s| s.addr().to_owned()).collect(),
        "Pendulum-v1",
        num_envs,
    );
    c.groups = groups;
    c.seed = Some(seed);
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn double_buffered_groups_have_batch_shapes_and_truncate_at_the_limit() {
    init_tracing();
    let server = common::start_server().await;
    let mut pool = EnvPool::connect(config(&[&server], 6, 2, 7)).await.unwrap();
    let spec = pool.spec().clone();
    assert_eq!(spec.num_envs, 6);
    assert_eq!(spec.max_episode_steps, 200);
    assert_eq!(spec.autoreset, AutoresetMode::SameStep);
    assert_eq!(pool.group_envs(0), 0..3);
    assert_eq!(pool.group_envs(1), 3..6);

    let resets = pool.reset_all().await.unwrap();
    for (g, r) in resets.iter().enumerate() {
        assert_eq!(r.group, g);
        assert_eq!(r.env_offset, 3 * g);
        let obs = r.obs.get(FLAT_FIELD).unwrap();
        assert_eq!(
            (obs.dtype(), obs.shape()),
            (DType::Float32, &[3usize, 3][..])
        );
    }
    let mut last: Vec<Tensor> = resets
        .iter()
        .map(|r| r.obs.get(FLAT_FIELD).unwrap().clone())
        .collect();

    let mut sampler = ActionSampler::new(&spec.action_space, 1).unwrap();
    pool.send(0, &sampler.sample(3)).unwrap();
    for t in 1..=201 {
        // Group 1 goes out while group 0 is still on the server, and vice versa.
        pool.send(1, &sampler.sample(3)).unwrap();
        let b0 = pool.recv(0).await.unwrap();
        if t < 201 {
            pool.send(0, &sampler.sample(3)).unwrap();
        }
        let b1 = pool.recv(1).await.unwrap();
        for (g, b) in [(0, &b0), (1, &b1)] {
            check_batch(b, g, t, &last[g]);
            last[g] = b.obs.get(FLAT_FIELD).unwrap().clone();
        }
    }
    assert_eq!(pool.stats().rebuilds, 0);
    pool.close().await.unwrap();
}

fn check_batch(b: &StepBatch, g: usize, t: usize, previous: &Tensor) {
    assert_eq!(b.group, g);
    assert_eq!(b.rows(), 3);
    let obs = b.obs.get(FLAT_FIELD).unwrap();
    assert_eq!(obs.shape(), &[3, 3]);
    assert_eq!(b.terminated, vec![false; 3], "Pendulum never terminates");
    assert_eq!(b.cut, vec![false; 3]);
    // All envs of a group started together, so the time limit hits them together.
    assert_eq!(b.truncated, vec![t == 200; 3], "step {t}");
    if t == 200 {
        let fin = b
            .final_obs
            .as_ref()
            .expect("final observations of the truncated rows");
        let fin = fin.get(FLAT_FIELD).unwrap();
        assert_eq!(fin.shape(), &[3, 3]);
        assert_ne!(
            fin.data(),
            obs.data(),
            "the new episode starts from a reset observation"
        );
        // cos/sin of the angle stay on the unit circle in the final observation.
        let v = fin.to_f64_vec().unwrap();
        for row in v.chunks(3) {
            assert!(
                (row[0] * row[0] + row[1] * row[1] - 1.0).abs() < 1e-4,
                "{row:?}"
            );
        }
    } else {
        assert!(b.final_obs.is_none(), "step {t}: no row ended");
        assert_ne!(obs.data(), previous.data(), "step {t}: the envs moved");
    }
    assert!(b.reward.iter().all(|r| r.is_finite() && *r <= 0.0));
}

/// Steps a pool `steps` times with actions from a fixed seed; returns every
/// observation and reward batch, concatenated over groups.
async fn trajectory(pool: &mut EnvPool, steps: usize) -> (Vec<Vec<u8>>, Vec<Vec<f64>>) {
    let n = pool.num_envs();
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 99).unwrap();
    let mut obs = Vec::new();
    let mut rewards = Vec::new();
    let mut first = Vec::new();
    for r in pool.reset_all().await.unwrap() {
        first.extend_from_slice(r.obs.get(FLAT_FIELD).unwrap().data());
    }
    obs.push(first);
    for _ in 0..steps {
        let all = sampler.sample(n).to_f32_vec().unwrap();
        let mut o = Vec::new();
        let mut r = Vec::new();
        for g in 0..pool.num_groups() {
            let envs = pool.group_envs(g);
            pool.send(g, &all[envs.start..envs.end]).unwrap();
        }
        for g in 0..pool.num_groups() {
            let b = pool.recv(g).await.unwrap();
            o.extend_from_slice(b.obs.get(FLAT_FIELD).unwrap().data());
            r.extend_from_slice(&b.reward);
        }
        obs.push(o);
        rewards.push(r);
    }
    (obs, rewards)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn seeds_decide_trajectories_whatever_the_server_count() {
    init_tracing();
    let (a, b) = tokio::join!(common::start_server(), common::start_server());
    let mut one = EnvPool::connect(config(&[&a], 5, 1, 11)).await.unwrap();
    let mut two = EnvPool::connect(config(&[&a, &b], 5, 2, 11)).await.unwrap();
    let mut other_seed = EnvPool::connect(config(&[&b], 5, 1, 12)).await.unwrap();
    let (obs1, rew1) = trajectory(&mut one, 30).await;
    let (obs2, rew2) = trajectory(&mut two, 30).await;
    let (obs3, _) = trajectory(&mut other_seed, 30).await;
    assert_eq!(
        obs1, obs2,
        "1 server vs 2 servers and 2 groups: same observations"
    );
    assert_eq!(rew1, rew2);
    assert_ne!(obs1[0], obs3[0], "another seed, another start");
    for p in [one, two, other_seed] {
        p.close().await.unwrap();
    }
}

fn code<T>(r: Result<T, EnvError>) -> Option<Code> {
    r.map(|_| ()).unwrap_err().code()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_status_codes_and_clear_errors() {
    init_tracing();
    let server = common::start_server().await;
    let client = EnvClient::connect(server.addr(), ClientConfig::default())
        .await
        .unwrap();

    let unknown = client
        .make("NoSuchEnv-v0", &Kwargs::new(), 1, AutoresetMode::SameStep)
        .await;
    assert_eq!(code(unknown), Some(Code::InvalidArgument));
    let (handle, spec) = client
        .make("Pendulum-v1", &Kwargs::new(), 2, AutoresetMode::SameStep)
        .await
        .unwrap();
    let good = ActionSampler::new(&spec.action_space, 0).unwrap().sample(2);
    assert_eq!(
        code(client.step(&handle, &good).await),
        Some(Code::FailedPrecondition)
    );
    client.reset(&handle, &[], &[1, 2]).await.unwrap();
    let wrong_rows = Tensor::from_f32(vec![3, 1], &[0.0; 3]).unwrap();
    let err = client.step(&handle, &wrong_rows).await.unwrap_err();
    assert_eq!(err.code(), Some(Code::InvalidArgument));
    assert!(err.to_string().contains("INVALID_ARGUMENT"), "{err}");
    let nan = Tensor::from_f32(vec![2, 1], &[0.0, f32::NAN]).unwrap();
    assert_eq!(
        code(client.step(&handle, &nan).await),
        Some(Code::InvalidArgument)
    );
    assert_eq!(
        code(client.reset(&handle, &[0], &[1, 2]).await),
        Some(Code::InvalidArgument)
    );
    assert_eq!(
        code(client.reset(&handle, &[5], &[]).await),
        Some(Code::InvalidArgument)
    );
    client
        .step(&handle, &good)
        .await
        .expect("the handle survives bad requests");
    client.close(&handle).await.unwrap();
    assert_eq!(
        code(client.step(&handle, &good).await),
        Some(Code::NotFound)
    );

    // The pool refuses malformed batches before they reach any server.
    let mut pool = EnvPool::connect(config(&[&server], 4, 2, 3)).await.unwrap();
    let refused = |r: Result<(), EnvError>, what: &str| match r {
        Err(EnvError::InvalidInput(m)) => assert!(m.contains(what), "{m}"),
        other => panic!("expected InvalidInput({what}), got {other:?}"),
    };
    refused(pool.send(0, &[0.0f32, 0.0][..]), "reset");
    pool.reset(0).await.unwrap();
    refused(pool.send(0, &[0.0f32; 3][..]), "3 action values for 2 envs");
    refused(pool.send(0, &[0.0f32, f32::INFINITY][..]), "not finite");
    refused(pool.send(5, &[0.0f32; 2][..]), "group 5 out of 0..2");
    assert!(
        matches!(pool.recv(0).await, Err(EnvError::InvalidInput(_))),
        "nothing in flight"
    );
    pool.send(0, &[0.5f32, -0.5][..]).unwrap();
    refused(pool.send(0, &[0.5f32, -0.5][..]), "in flight");
    assert!(
        matches!(pool.reset_all().await, Err(EnvError::InvalidInput(m)) if m.contains("in flight")),
        "no reset while a step is in flight"
    );
    let b = pool.recv(0).await.unwrap();
    assert_eq!(b.rows(), 2);
    pool.close().await.unwrap();

    let bad_pool = |f: fn(&mut PoolConfig)| {
        let mut c = config(&[&server], 4, 1, 0);
        f(&mut c);
        c
    };
    for (c, what) in [
        (bad_pool(|c| c.groups = 5), "groups"),
        (bad_pool(|c| c.num_envs = 0), "num_envs"),
        (bad_pool(|c| c.servers.clear()), "at least one"),
        (
            bad_pool(|c| c.autoreset = AutoresetMode::Disabled),
            "DISABLED",
        ),
    ] {
        match EnvPool::connect(c).await {
            Err(EnvError::InvalidInput(m)) => assert!(m.contains(what), "{m}"),
            other => panic!("expected InvalidInput({what}), got {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn version_mismatch_and_unreachable_servers_are_clear_errors() {
    init_tracing();
    let server = common::start_server().await;
    let newer = ClientConfig {
        api_version: (2, 0),
        ..ClientConfig::default()
    };
    match EnvClient::connect(server.addr(), newer).await {
        Err(e @ EnvError::VersionMismatch { .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains("version mismatch") && msg.contains("2.0"),
                "{msg}"
            );
        }
        other => panic!("expected a version mismatch, got {other:?}"),
    }

    let nobody = format!("127.0.0.1:{}", free_port());
    let quick = ClientConfig {
        retry: RetryPolicy {
            initial_backoff: Duration::from_millis(20),
            max_backoff: Duration::from_millis(100),
            max_attempts: 4,
            max_elapsed: Duration::from_secs(5),
        },
        ..ClientConfig::default()
    };
    let mut c = PoolConfig::new(
        vec![server.addr().to_owned(), nobody.clone()],
        "Pendulum-v1",
        2,
    );
    c.client = quick;
    match EnvPool::connect(c).await {
        Err(e @ EnvError::Unreachable { attempts: 4, .. }) => {
            assert!(e.to_string().contains(&nobody), "{e}");
        }
        other => panic!("expected Unreachable after 4 attempts, got {other:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn closing_or_dropping_a_pool_frees_its_envs() {
    init_tracing();
    let server = common::start_server().await;
    let client = EnvClient::connect(server.addr(), ClientConfig::default())
        .await
        .unwrap();
    let alive = async || client.stats().await.unwrap()["envs_alive"];
    let pool = EnvPool::connect(config(&[&server], 3, 1, 0)).await.unwrap();
    assert_eq!(alive().await, 3.0);
    pool.close().await.unwrap();
    assert_eq!(alive().await, 0.0);

    let pool = EnvPool::connect(config(&[&server], 5, 2, 0)).await.unwrap();
    assert_eq!(alive().await, 5.0);
    drop(pool);
    let start = std::time::Instant::now();
    while alive().await != 0.0 {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "a dropped pool's envs stay alive"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}
