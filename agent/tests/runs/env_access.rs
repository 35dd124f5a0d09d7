//! `million env-check` through `--env-tls-ca` and the token (flag or
//! MILLION_ENV_TOKEN) against a server with TLS and a token: the flags reach the
//! client, a wrong token is refused as UNAUTHENTICATED.
use crate::env_common;

use std::process::Command;

use million_env::{
    ClientConfig, LocalServer, LocalServerOptions, TOKEN_ENV_VAR, TlsOptions, Token,
    default_server_binary,
};

const TOKEN: &str = "agent-cli-test-token";

fn env_check(addr: &str, ca: &std::path::Path) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_million"));
    cmd.args([
        "env-check",
        "--env-server",
        addr,
        "--env",
        "million/PointGoal",
    ])
    .arg("--env-tls-ca")
    .arg(ca)
    .env_remove(TOKEN_ENV_VAR);
    cmd
}

#[test]
fn env_check_over_tls_with_a_token() {
    let dir = tempfile::tempdir().unwrap();
    let (ca, cert, key) = env_common::make_certs(dir.path());
    let options = LocalServerOptions {
        extra_args: vec![
            "--tls-cert".into(),
            cert.display().to_string(),
            "--tls-key".into(),
            key.display().to_string(),
        ],
        env: vec![(TOKEN_ENV_VAR.into(), TOKEN.into())],
        client: ClientConfig {
            tls: Some(TlsOptions::from_ca_file(&ca).unwrap()),
            token: Some(Token::new(TOKEN).unwrap()),
            ..ClientConfig::default()
        },
        ..LocalServerOptions::default()
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let binary = default_server_binary().expect("million-env-server installed (make setup)");
    let server = rt.block_on(LocalServer::start(&binary, options)).unwrap();

    let ok = env_check(server.addr(), &ca)
        .env(TOKEN_ENV_VAR, TOKEN)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&ok.stdout);
    assert!(ok.status.success(), "env-check passes over TLS: {text}");

    let refused = env_check(server.addr(), &ca)
        .args(["--env-token", "wrong"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&refused.stdout);
    assert!(!refused.status.success());
    assert!(text.contains("UNAUTHENTICATED"), "{text}");
    drop(server);
}
