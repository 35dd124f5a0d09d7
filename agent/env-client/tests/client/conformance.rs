//! `million env-check` (the conformance library) passes against the bundled
//! server, for a Box-action env, a Discrete-action env and a Meta-World env.

use crate::common;

use crate::common::init_tracing;
use million_env::conformance::{IMPLEMENTED, Status, listed_checks};
use million_env::{AutoresetMode, ClientConfig, EnvClient, Kwargs, Space, Value, run_conformance};

/// Runs env-check and asserts it passes; returns the env's observation space.
async fn passes(env_id: &str, kwargs: Kwargs) -> Space {
    init_tracing();
    let server = common::start_server().await;
    let report = run_conformance(server.addr(), env_id, kwargs.clone()).await;
    println!("{report}");
    let ran: Vec<&str> = report.results.iter().map(|r| r.id.as_str()).collect();
    assert_eq!(ran.len(), listed_checks().len(), "every listed check ran");
    assert_eq!(ran.len(), IMPLEMENTED.len());
    assert!(report.passed(), "{report}");
    // Only checks that genuinely cannot apply may be skipped.
    for r in &report.results {
        if r.status == Status::Skip {
            assert!(
                ["error_nonfinite_action", "terminated_truncated_distinct"]
                    .contains(&r.id.as_str()),
                "{} skipped: {}",
                r.id,
                r.message
            );
        }
    }
    let json: serde_json::Value = serde_json::from_str(&report.to_json()).unwrap();
    assert_eq!(json["env_id"], env_id);
    let client = EnvClient::connect(server.addr(), ClientConfig::default())
        .await
        .unwrap();
    let (handle, spec) = client
        .make(env_id, &kwargs, 1, AutoresetMode::SameStep)
        .await
        .unwrap();
    client.close(&handle).await.unwrap();
    spec.observation_space
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pendulum_conforms() {
    let space = passes("Pendulum-v1", Kwargs::new()).await;
    assert!(matches!(space, Space::Box(_)));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cartpole_conforms() {
    passes("CartPole-v1", Kwargs::new()).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metaworld_reach_conforms() {
    let mut kwargs = Kwargs::new();
    kwargs.insert("env_name".into(), Value::from("reach-v3"));
    // Meta-World's own id draws its goal set at construction; the seed kwarg fixes it.
    kwargs.insert("seed".into(), Value::Int(1));
    passes("Meta-World/MT1", kwargs).await;
}

/// A MILLION protocol env: Dict observations (state, instruction words, time...).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn million_pointgoal_with_dict_observations_conforms() {
    let space = passes("million/PointGoal", Kwargs::new()).await;
    assert!(
        matches!(space, Space::Dict(_)),
        "PointGoal observes a Dict: {space}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unreachable_server_fails_every_check_with_the_reason() {
    let port = common::free_port();
    let mut opts = million_env::conformance::ConformanceOptions::new(
        format!("127.0.0.1:{port}"),
        "Pendulum-v1",
        Kwargs::new(),
    );
    opts.client.retry.max_elapsed = std::time::Duration::from_millis(500);
    let report = million_env::conformance::run_conformance_with(opts).await;
    assert!(!report.passed());
    assert!(report.results.iter().all(|r| r.status == Status::Fail));
    let msg = &report.results[0].message;
    assert!(
        msg.contains("unreachable") && msg.contains(&port.to_string()),
        "{msg}"
    );
}
