//! Runs the real Python env server for the integration tests: a free port,
//! wait for health, kill on drop.
#![allow(dead_code)] // each test binary uses a different part

use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use million_env::{ClientConfig, EnvClient, RetryPolicy};

/// The repository root: $MILLION_ROOT, else two levels above this crate.
pub fn repo_root() -> PathBuf {
    std::env::var_os("MILLION_ROOT")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.."))
}

pub fn server_binary() -> PathBuf {
    let bin = repo_root().join(".venv/bin/million-env-server");
    assert!(
        bin.exists(),
        "{} is missing: run `make setup` first",
        bin.display()
    );
    bin
}

pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free local port")
        .port()
}

/// Spawns the server; its "listening on HOST:PORT" line arrives on the channel
/// (the rest of its stdout is drained so the pipe never fills).
fn launch(addr: &str) -> (Child, mpsc::Receiver<String>) {
    let mut child = Command::new(server_binary())
        .args(["--address", addr, "--log-level", "WARNING"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .expect("million-env-server starts");
    let stdout = child.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if line.starts_with("listening on ") {
                let _ = tx.send(line);
            }
        }
    });
    (child, rx)
}

/// A running `million-env-server`, killed when dropped.
pub struct Server {
    pub port: u16,
    pub addr: String,
    child: Option<Child>,
}

impl Server {
    /// Starts a server on a port it picks itself and waits until it answers.
    /// (Letting the server bind port 0 avoids two parallel tests racing for one
    /// "free" port; gRPC's SO_REUSEPORT would let both bind it.)
    pub async fn start() -> Server {
        let (mut child, lines) = launch("127.0.0.1:0");
        let port = tokio::task::spawn_blocking(move || {
            lines
                .recv_timeout(Duration::from_secs(120))
                .ok()
                .and_then(|line| line.rsplit(':').next()?.trim().parse::<u16>().ok())
        })
        .await
        .unwrap();
        let Some(port) = port else {
            let _ = child.kill();
            let _ = child.wait();
            panic!("million-env-server did not report its port");
        };
        let server = Server {
            port,
            addr: format!("127.0.0.1:{port}"),
            child: Some(child),
        };
        server.wait_ready().await;
        server
    }

    /// Starts a server on `port` without waiting for it.
    pub fn spawn(port: u16) -> Server {
        let addr = format!("127.0.0.1:{port}");
        let (child, _) = launch(&addr);
        Server {
            port,
            addr,
            child: Some(child),
        }
    }

    /// Waits for the handshake and grpc.health to answer SERVING.
    pub async fn wait_ready(&self) {
        let start = Instant::now();
        let config = ClientConfig {
            retry: RetryPolicy {
                max_attempts: 1_000,
                max_elapsed: Duration::from_secs(90),
                ..RetryPolicy::default()
            },
            ..ClientConfig::default()
        };
        let client = EnvClient::connect(&self.addr, config)
            .await
            .unwrap_or_else(|e| panic!("server on {} never came up: {e}", self.addr));
        loop {
            if let Ok(tonic_health::pb::health_check_response::ServingStatus::Serving) =
                client.health().await
            {
                return;
            }
            assert!(
                start.elapsed() < Duration::from_secs(90),
                "server not healthy"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    /// Kills the process (SIGKILL: no goodbye to its clients).
    pub fn kill(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    /// Kills the server and starts a new one on the same port (without waiting).
    pub fn restart(&mut self) {
        self.kill();
        *self = Server::spawn(self.port);
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Client logs on stderr (shown for failing tests), filtered by RUST_LOG.
pub fn init_tracing() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "million_env=info".into()),
        )
        .with_test_writer()
        .try_init();
}
