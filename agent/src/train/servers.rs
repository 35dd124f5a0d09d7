//! Env servers for a run: local `million-env-server` processes (killed when dropped) and the
//! client settings the pool uses for them.

use anyhow::Context;
use million_env::{ClientConfig, LocalServer, LocalServerOptions, default_server_binary};

use crate::run_config::RunConfig;

/// Starts `count` local env servers from the repository's `.venv`.
pub async fn start_local_servers(count: usize) -> anyhow::Result<Vec<LocalServer>> {
    let binary = default_server_binary().context(
        "no --env-server given and no local million-env-server found (run `make setup`)",
    )?;
    tracing::info!(count, binary = %binary.display(), "starting local env servers");
    LocalServer::start_many(&binary, LocalServerOptions::default(), count)
        .await
        .context("starting local env servers")
}

/// Client settings: the config's Make deadline, defaults otherwise.
pub fn client_config(cfg: &RunConfig) -> ClientConfig {
    let mut client = ClientConfig::default();
    client.timeouts.make = std::time::Duration::from_secs(cfg.env.make_timeout_s);
    client
}
