//! Runs the real Python env server for the integration tests through the
//! library's `LocalServer` (the server picks its own port; killed on drop).
#![allow(dead_code)] // each test binary uses a different part

use std::net::TcpListener;

pub use million_env::LocalServer as Server;
use million_env::{LocalServerOptions, default_server_binary};

/// Starts a server and waits until it is healthy.
pub async fn start_server() -> Server {
    let binary = default_server_binary().expect("million-env-server installed (make setup)");
    Server::start(&binary, LocalServerOptions::default())
        .await
        .expect("million-env-server starts")
}

/// A loopback port nobody listens on (for unreachable-server tests).
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free local port")
        .port()
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
