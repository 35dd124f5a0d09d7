//! `LocalServer` against the real `million-env-server`.

use std::time::Duration;

use million_env::{
    ClientConfig, EnvClient, LocalServer, LocalServerError, LocalServerOptions, RetryPolicy,
    default_server_binary,
};

#[tokio::test]
async fn starts_servers_on_distinct_ports_and_kills_them() {
    let binary = default_server_binary().expect("make setup installed the server");
    let mut servers = LocalServer::start_many(&binary, LocalServerOptions::default(), 2)
        .await
        .expect("two servers start");
    assert_ne!(servers[0].port(), servers[1].port());
    for server in &servers {
        let client = EnvClient::connect(server.addr(), ClientConfig::default())
            .await
            .unwrap();
        assert!(!client.list_envs().await.unwrap().is_empty());
    }

    let addr = servers[0].addr().to_owned();
    servers[0].kill().await;
    let quick = ClientConfig {
        retry: RetryPolicy {
            max_attempts: 2,
            max_elapsed: Duration::from_millis(300),
            ..RetryPolicy::default()
        },
        ..ClientConfig::default()
    };
    assert!(
        EnvClient::connect(&addr, quick).await.is_err(),
        "a killed server must not answer"
    );
}

#[cfg(target_os = "linux")]
#[tokio::test]
async fn a_server_leads_its_own_process_group() {
    // A Ctrl-C in the agent's terminal signals the agent's process group; the servers must
    // not be in it, or they die before the agent's final evaluation and checkpoint.
    let binary = default_server_binary().expect("make setup installed the server");
    let server = LocalServer::start(&binary, LocalServerOptions::default())
        .await
        .expect("server starts");
    let pid = server.pid().expect("a running server has a pid") as libc::pid_t;
    // SAFETY: getpgid only reads the process table.
    let (group, ours) = unsafe { (libc::getpgid(pid), libc::getpgid(0)) };
    assert_eq!(group, pid, "the server leads its own group");
    assert_ne!(group, ours, "the server is outside the agent's group");
}

#[tokio::test]
async fn a_missing_binary_is_a_clear_error() {
    let missing = std::path::Path::new("/nonexistent/million-env-server");
    let err = LocalServer::start(missing, LocalServerOptions::default())
        .await
        .unwrap_err();
    assert!(matches!(err, LocalServerError::Spawn { .. }), "{err}");
    assert!(
        err.to_string().contains("/nonexistent/million-env-server"),
        "{err}"
    );
}
