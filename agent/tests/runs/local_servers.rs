//! The local env servers `million train` and `million eval` start: what the config passes
//! to them reaches their command line. Real `million-env-server` processes.
use million::train::servers::start_local_servers;

/// `runtime.env_server_args` reach the local servers' command lines: a flag value the
/// server refuses stops it before it listens (argparse's exit status 2; the reason is on its
/// stderr), a good one serves.
#[tokio::test]
async fn runtime_env_server_args_reach_the_local_servers() {
    let bad = ["--idle-envs".to_owned(), "-1".to_owned()];
    let err = start_local_servers(1, &bad)
        .await
        .expect_err("the server refuses --idle-envs -1");
    let text = format!("{err:#}");
    assert!(
        text.contains("exited before it listened") && text.contains("exit status: 2"),
        "{text}"
    );
    let good = ["--compiled-models".to_owned(), "3".to_owned()];
    let servers = start_local_servers(1, &good)
        .await
        .expect("the server starts");
    assert_eq!(servers.len(), 1);
}
