//! Env servers for a run: local `million-env-server` processes (restarted on
//! their port when they die, killed when dropped) and the client settings the
//! pool uses for them.

use anyhow::Context;
use million_env::{
    ClientConfig, LocalServer, LocalServerOptions, RestartPolicy, SupervisedServer, TlsOptions,
    Token, default_server_binary,
};

use crate::run_config::RunConfig;

/// How to reach guarded env servers (`--env-token`, `--env-tls-ca`); local
/// servers listen on loopback only and need neither.
#[derive(Clone, Debug, Default)]
pub struct EnvAccess {
    pub token: Option<Token>,
    pub tls: Option<TlsOptions>,
}

/// Server options the agent owns for the servers it starts: it binds them to loopback and
/// talks to them without a token or TLS, so a config that set these would expose a server
/// or lock the agent out of it. The server refuses abbreviated options, so the exact names
/// (before any `=value`) are all there is to check.
const RESERVED_SERVER_ARGS: [&str; 4] = ["--address", "--token", "--tls-cert", "--tls-key"];

fn reserved_server_arg(arg: &str) -> bool {
    let name = arg.split_once('=').map_or(arg, |(name, _)| name);
    RESERVED_SERVER_ARGS.contains(&name)
}

/// Refuses extra arguments of local servers that would override what the agent owns (see
/// `RESERVED_SERVER_ARGS`), naming the argument and what to do instead.
pub fn check_local_server_args(args: &[String]) -> Result<(), String> {
    match args.iter().find(|a| reserved_server_arg(a)) {
        None => Ok(()),
        Some(arg) => Err(format!(
            "{arg:?} is set by the agent for the servers it starts (loopback address, no \
             token, no TLS); to serve elsewhere or guarded, start the servers yourself and \
             pass --env-server"
        )),
    }
}

/// Starts `count` local env servers from the repository's `.venv`, with `extra_args` on
/// their command lines (`runtime.env_server_args`); each is restarted on its port if its
/// process dies, so the pool reconnects to it.
pub async fn start_local_servers(
    count: usize,
    extra_args: &[String],
) -> anyhow::Result<Vec<SupervisedServer>> {
    let binary = default_server_binary().context(
        "no --env-server given and no local million-env-server found (run `make setup`)",
    )?;
    tracing::info!(count, binary = %binary.display(), ?extra_args, "starting local env servers");
    let options = LocalServerOptions {
        extra_args: extra_args.to_vec(),
        ..LocalServerOptions::default()
    };
    let servers = LocalServer::start_many(&binary, options, count)
        .await
        .context("starting local env servers")?;
    Ok(servers
        .into_iter()
        .map(|s| SupervisedServer::new(s, RestartPolicy::default()))
        .collect())
}

/// Client settings: the config's Make deadline and `access`, defaults otherwise.
pub fn client_config(cfg: &RunConfig, access: &EnvAccess) -> ClientConfig {
    let mut client = ClientConfig::default();
    client.timeouts.make = std::time::Duration::from_secs(cfg.env.make_timeout_s);
    client.token = access.token.clone();
    client.tls = access.tls.clone();
    client
}
