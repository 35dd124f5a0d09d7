//! A local env server kept alive: when its process dies (the OOM killer, a
//! crash), it is started again on the same port, so that the pool's reconnect
//! path (rebuild the envs, report the cut episodes as truncated) picks it up.
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::Duration;

use tokio::task::JoinHandle;

use crate::local_server::LocalServer;

/// How hard to try.
#[derive(Clone, Debug)]
pub struct RestartPolicy {
    /// Restarts over the server's lifetime before giving up on it (a server that
    /// dies at once every time has a problem a restart will not fix).
    pub max_restarts: u64,
    /// Start attempts for one restart, `backoff` apart.
    pub attempts: u32,
    pub backoff: Duration,
}

impl Default for RestartPolicy {
    fn default() -> Self {
        RestartPolicy {
            max_restarts: 100,
            attempts: 5,
            backoff: Duration::from_secs(1),
        }
    }
}

#[derive(Debug, Default)]
struct State {
    restarts: AtomicU64,
    /// 0 while no process runs.
    pid: AtomicU32,
}

/// A `LocalServer` watched by a task that restarts it; dropping this stops the
/// task and kills the process.
#[derive(Debug)]
pub struct SupervisedServer {
    addr: String,
    state: Arc<State>,
    task: JoinHandle<()>,
}

impl SupervisedServer {
    /// Watches `server` from now on (on the current tokio runtime).
    pub fn new(server: LocalServer, policy: RestartPolicy) -> Self {
        let state = Arc::new(State::default());
        state
            .pid
            .store(server.pid().unwrap_or(0), Ordering::Relaxed);
        let addr = server.addr().to_owned();
        let task = tokio::spawn(watch(server, policy, state.clone()));
        SupervisedServer { addr, state, task }
    }

    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// Restarts so far (each one logged with the reason the process ended).
    pub fn restarts(&self) -> u64 {
        self.state.restarts.load(Ordering::Relaxed)
    }

    /// The current process id; `None` while the server is down.
    pub fn pid(&self) -> Option<u32> {
        Some(self.state.pid.load(Ordering::Relaxed)).filter(|&p| p != 0)
    }
}

impl Drop for SupervisedServer {
    fn drop(&mut self) {
        // Dropping the task's future drops the LocalServer, whose child is
        // killed on drop.
        self.task.abort();
    }
}

async fn watch(mut server: LocalServer, policy: RestartPolicy, state: Arc<State>) {
    let addr = server.addr().to_owned();
    while let Some(status) = server.wait_exit().await {
        state.pid.store(0, Ordering::Relaxed);
        let reason = match status {
            Ok(status) => status.to_string(),
            Err(e) => format!("cannot tell how it ended: {e}"),
        };
        let restarts = state.restarts.load(Ordering::Relaxed);
        if restarts >= policy.max_restarts {
            tracing::error!(%addr, %reason, restarts, "local env server died; restart budget spent, giving up");
            return;
        }
        tracing::warn!(%addr, %reason, "local env server died; restarting it on the same port");
        if !restart(&mut server, &policy).await {
            tracing::error!(%addr, attempts = policy.attempts, "local env server could not be restarted");
            return;
        }
        state.restarts.fetch_add(1, Ordering::Relaxed);
        state
            .pid
            .store(server.pid().unwrap_or(0), Ordering::Relaxed);
        tracing::info!(%addr, restarts = restarts + 1, "local env server restarted");
    }
}

async fn restart(server: &mut LocalServer, policy: &RestartPolicy) -> bool {
    for attempt in 1..=policy.attempts.max(1) {
        match server.relaunch().await {
            Ok(()) => return true,
            Err(e) => {
                tracing::warn!(addr = %server.addr(), attempt, error = %e, "restart attempt failed");
                tokio::time::sleep(policy.backoff).await;
            }
        }
    }
    false
}
