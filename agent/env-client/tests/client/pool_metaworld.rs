//! The pool on a Meta-World task (`Meta-World/MT1`, reach-v3): float64
//! observations, float32 actions, declared info fields, and the same
//! trajectories from one server or two.

use crate::common;

use crate::common::{Server, init_tracing};
use million_env::{
    ActionSampler, DType, EnvPool, FLAT_FIELD, Kwargs, PoolConfig, Space, StepBatch, Value,
};

fn reach(servers: &[&Server], groups: usize) -> PoolConfig {
    let mut c = PoolConfig::new(
        servers.iter().map(|s| s.addr().to_owned()).collect(),
        "Meta-World/MT1",
        4,
    );
    let mut kwargs = Kwargs::new();
    kwargs.insert("env_name".into(), Value::from("reach-v3"));
    // The goal set of Meta-World's own id is drawn at construction unless seeded.
    kwargs.insert("seed".into(), Value::Int(1));
    c.kwargs = kwargs;
    c.groups = groups;
    c.seed = Some(21);
    c
}

fn check(b: &StepBatch, low: &[f64], high: &[f64]) {
    let obs = b.obs.get(FLAT_FIELD).unwrap();
    assert_eq!(
        (obs.dtype(), obs.shape()),
        (DType::Float64, &[2usize, 39][..])
    );
    for (i, v) in obs.to_f64_vec().unwrap().iter().enumerate() {
        let (lo, hi) = (low[i % 39], high[i % 39]);
        assert!(
            v.is_finite() && *v >= lo - 1e-9 && *v <= hi + 1e-9,
            "obs[{i}] = {v} not in [{lo}, {hi}]"
        );
    }
    assert_eq!(
        b.terminated,
        vec![false, false],
        "Meta-World only truncates"
    );
    assert!(b.reward.iter().all(|r| r.is_finite() && *r >= 0.0));
    let success = b.info.get("success").expect("success is declared");
    assert_eq!(success.present, vec![true, true]);
    assert!(
        success
            .value
            .to_f64_vec()
            .unwrap()
            .iter()
            .all(|s| *s == 0.0 || *s == 1.0)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reach_batches_are_typed_and_reproducible_over_one_or_two_servers() {
    init_tracing();
    let (a, b) = tokio::join!(common::start_server(), common::start_server());
    let (one, two) = tokio::join!(
        EnvPool::connect(reach(&[&a], 1)),
        EnvPool::connect(reach(&[&a, &b], 2))
    );
    let (mut one, mut two) = (one.unwrap(), two.unwrap());
    let spec = one.spec().clone();
    assert_eq!(spec.max_episode_steps, 500);
    let Space::Box(obs_space) = &spec.observation_space else {
        panic!(
            "MT1 observations are a Box, got {:?}",
            spec.observation_space
        )
    };
    let Space::Box(act) = &spec.action_space else {
        panic!("MT1 actions are a Box")
    };
    assert_eq!(
        (act.dtype, act.shape.as_slice()),
        (DType::Float32, &[4usize][..])
    );
    assert!(spec.info_field("success").is_some());

    let r1 = one.reset_all().await.unwrap();
    let r2 = two.reset_all().await.unwrap();
    let first1 = r1[0].obs.get(FLAT_FIELD).unwrap();
    let mut first2 = r2[0].obs.get(FLAT_FIELD).unwrap().data().to_vec();
    first2.extend_from_slice(r2[1].obs.get(FLAT_FIELD).unwrap().data());
    assert_eq!(first1.data().to_vec(), first2);
    let declared: Vec<&str> = spec.info_fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(
        r1[0].info.names().collect::<Vec<_>>(),
        declared,
        "reset info has the declared fields"
    );

    let mut sampler = ActionSampler::new(&spec.action_space, 8).unwrap();
    for t in 0..25 {
        let actions = sampler.sample(4).to_f32_vec().unwrap();
        let b1 = one.step(0, &actions).await.unwrap();
        two.send(0, &actions[..8]).unwrap();
        two.send(1, &actions[8..]).unwrap();
        let (b20, b21) = (two.recv(0).await.unwrap(), two.recv(1).await.unwrap());
        check(&b20, &obs_space.low, &obs_space.high);
        check(&b21, &obs_space.low, &obs_space.high);
        let mut joined = b20.obs.get(FLAT_FIELD).unwrap().data().to_vec();
        joined.extend_from_slice(b21.obs.get(FLAT_FIELD).unwrap().data());
        assert_eq!(
            b1.obs.get(FLAT_FIELD).unwrap().data().to_vec(),
            joined,
            "step {t}"
        );
        assert_eq!(b1.reward, [b20.reward, b21.reward].concat(), "step {t}");
    }
    one.close().await.unwrap();
    two.close().await.unwrap();
}
