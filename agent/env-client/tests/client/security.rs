//! TLS and the shared token end to end: a real server started with
//! `--tls-cert/--tls-key` and `MILLION_ENV_TOKEN`, reached by the Rust client.

use std::time::Duration;

use crate::common::{init_tracing, make_certs};
use million_env::{
    ActionSampler, AutoresetMode, ClientConfig, EnvClient, EnvError, EnvPool, LocalServer,
    LocalServerOptions, PoolConfig, RetryPolicy, TOKEN_ENV_VAR, TlsOptions, Token,
    default_server_binary,
};
use tonic::Code;
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint};
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};

const TOKEN: &str = "s3cret-token-for-tests";

struct Guarded {
    server: LocalServer,
    tls: TlsOptions,
    _dir: tempfile::TempDir,
}

fn client(tls: Option<&TlsOptions>, token: Option<&str>) -> ClientConfig {
    ClientConfig {
        tls: tls.cloned(),
        token: token.map(|t| Token::new(t).unwrap()),
        // A refused TLS handshake is "unreachable": give up quickly.
        retry: RetryPolicy {
            max_elapsed: Duration::from_secs(2),
            ..RetryPolicy::default()
        },
        ..ClientConfig::default()
    }
}

async fn guarded_server() -> Guarded {
    let dir = tempfile::tempdir().unwrap();
    let (ca, cert, key) = make_certs(dir.path());
    let tls = TlsOptions::from_ca_file(&ca).unwrap();
    let options = LocalServerOptions {
        extra_args: vec![
            "--tls-cert".into(),
            cert.display().to_string(),
            "--tls-key".into(),
            key.display().to_string(),
        ],
        env: vec![(TOKEN_ENV_VAR.into(), TOKEN.into())],
        client: client(Some(&tls), Some(TOKEN)),
        ..LocalServerOptions::default()
    };
    let binary = default_server_binary().expect("million-env-server installed (make setup)");
    let server = LocalServer::start(&binary, options)
        .await
        .expect("a TLS server starts");
    Guarded {
        server,
        tls,
        _dir: dir,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_and_token_end_to_end() {
    init_tracing();
    let g = guarded_server().await;
    let addr = g.server.addr();

    // Unary calls and a pool's Session streams carry the token over TLS.
    let good = client(Some(&g.tls), Some(TOKEN));
    let c = EnvClient::connect(addr, good.clone())
        .await
        .expect("connects");
    assert!(!c.list_envs().await.unwrap().is_empty());
    let mut config = PoolConfig::new(vec![addr.to_owned()], "Pendulum-v1", 4);
    config.groups = 2;
    config.autoreset = AutoresetMode::SameStep;
    config.client = good;
    let mut pool = EnvPool::connect(config).await.expect("pool over TLS");
    let mut sampler = ActionSampler::new(&pool.spec().action_space, 1).unwrap();
    pool.reset_all().await.unwrap();
    for g in 0..2 {
        pool.send(g, &sampler.sample(2)).unwrap();
    }
    for g in 0..2 {
        assert_eq!(pool.recv(g).await.unwrap().reward.len(), 2);
    }
    pool.close().await.unwrap();

    // A wrong or missing token: UNAUTHENTICATED, at once (not retried).
    for token in [Some("wrong"), None] {
        let err = EnvClient::connect(addr, client(Some(&g.tls), token))
            .await
            .expect_err("refused");
        assert_eq!(err.code(), Some(Code::Unauthenticated), "{err}");
        assert!(matches!(err, EnvError::Rpc { .. }), "{err}");
    }

    // Plaintext to a TLS server does not get through.
    let err = EnvClient::connect(addr, client(None, Some(TOKEN)))
        .await
        .expect_err("plaintext refused");
    assert!(
        matches!(err, EnvError::Unreachable { .. } | EnvError::Rpc { .. }),
        "{err}"
    );

    // Health is open without a token (for probes), over TLS.
    let channel = Endpoint::from_shared(format!("https://{addr}"))
        .unwrap()
        .tls_config(ClientTlsConfig::new().ca_certificate(Certificate::from_pem(&g.tls.ca_pem)))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let status = HealthClient::new(channel)
        .check(HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap()
        .into_inner()
        .status;
    assert_eq!(status, ServingStatus::Serving as i32);
}

#[test]
fn token_debug_never_shows_the_secret() {
    let config = client(None, Some(TOKEN));
    assert!(!format!("{config:?}").contains(TOKEN));
    assert!(Token::new("  ").is_err());
    assert!(Token::new("tab\there").is_err());
}
