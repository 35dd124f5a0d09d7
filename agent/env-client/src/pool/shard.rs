//! One block of a pool: a handle of consecutive envs on one server, driven over
//! its own Session stream, and able to rebuild itself when the server restarts.
use std::collections::HashMap;
use std::ops::Range;
use std::sync::Arc;
use std::time::Duration;

use super::resolve::{Resolve, resolve_with_retry};
use crate::client::{ClientConfig, EnvClient, RetryPolicy, make_request, reset_request};
use crate::error::{EnvError, Result};
use crate::observation::{InfoBatch, Observation};
use crate::proto;
use crate::proto::session_request::Request;
use crate::reply::{ResetResult, StepResult};
use crate::session::{Session, SessionReply};
use crate::space::{AutoresetMode, EnvSpec};
use crate::tensor::Tensor;
use crate::value::Kwargs;

/// How to (re)make a shard's envs.
#[derive(Clone, Debug)]
pub(crate) struct MakeArgs {
    pub env_id: String,
    pub kwargs: Kwargs,
    pub autoreset: AutoresetMode,
    pub client: ClientConfig,
    /// Full-restart attempts (connect + make + reset) before a recovery fails.
    pub recovery_attempts: u32,
    /// Finds the replicas behind a target again when a server is lost.
    pub resolver: Arc<dyn Resolve>,
}

#[derive(Debug)]
pub(crate) struct Shard {
    /// What the user named (`--env-server`): re-resolved when the server is lost.
    pub target: String,
    /// The replica's address the envs are on now.
    pub addr: String,
    /// Global env indices of the rows.
    pub envs: Range<usize>,
    client: EnvClient,
    handle: String,
    session: Session,
    /// Latest observation of the rows: the final observation of episodes cut by a restart.
    last_obs: Option<Observation>,
    /// A send that could not be queued; the matching recv reports it.
    send_failed: Option<EnvError>,
    /// NEXT_STEP after a cut: the reset to hand out on the next step instead of stepping.
    deferred_reset: Option<ResetResult>,
    deferred_pending: bool,
    /// How many times the envs were rebuilt.
    pub restarts: u64,
}

impl Shard {
    pub async fn open(
        target: &str,
        addr: &str,
        envs: Range<usize>,
        args: &MakeArgs,
    ) -> Result<(Self, EnvSpec)> {
        let client = EnvClient::connect(addr, args.client.clone()).await?;
        let (session, handle, spec) = make_envs(&client, args, envs.len()).await?;
        tracing::debug!(addr, ?envs, handle, "made envs");
        Ok((
            Shard {
                target: target.to_owned(),
                addr: addr.to_owned(),
                envs,
                client,
                handle,
                session,
                last_obs: None,
                send_failed: None,
                deferred_reset: None,
                deferred_pending: false,
                restarts: 0,
            },
            spec,
        ))
    }

    pub fn rows(&self) -> usize {
        self.envs.len()
    }

    fn queue(&mut self, request: Request) {
        if self.send_failed.is_none()
            && let Err(e) = self.session.send(request)
        {
            self.send_failed = Some(e);
        }
    }

    pub fn send_reset(&mut self, seeds: &[i64]) {
        self.deferred_reset = None;
        let req = reset_request(&self.handle, &[], seeds);
        self.queue(Request::Reset(req));
    }

    pub fn send_step(&mut self, action: Tensor) {
        if self.deferred_reset.is_some() {
            self.deferred_pending = true;
            return;
        }
        let req = proto::StepRequest {
            handle: self.handle.clone(),
            action: Some(action.to_proto()),
        };
        self.queue(Request::Step(req));
    }

    async fn recv_reply(&mut self) -> Result<SessionReply> {
        if let Some(e) = self.send_failed.take() {
            return Err(e);
        }
        self.session.recv().await
    }

    pub async fn recv_reset(&mut self) -> Result<ResetResult> {
        match self.recv_reply().await? {
            SessionReply::Reset(r) => {
                self.check_rows(r.obs.rows())?;
                self.last_obs = Some(r.obs.clone());
                Ok(r)
            }
            _ => Err(EnvError::protocol(
                &self.addr,
                "a reply to a reset that is no reset",
            )),
        }
    }

    pub async fn recv_step(&mut self) -> Result<StepResult> {
        if self.deferred_pending {
            self.deferred_pending = false;
            let r = self
                .deferred_reset
                .take()
                .expect("deferred_pending implies a reset");
            return Ok(self.deferred_step(r));
        }
        match self.recv_reply().await? {
            SessionReply::Step(s) => {
                self.check_rows(s.rows())?;
                self.last_obs = Some(s.obs.clone());
                Ok(s)
            }
            _ => Err(EnvError::protocol(
                &self.addr,
                "a reply to a step that is no step",
            )),
        }
    }

    fn check_rows(&self, rows: usize) -> Result<()> {
        if rows != self.rows() {
            return Err(EnvError::protocol(
                &self.addr,
                format!("{rows} rows for a handle of {} envs", self.rows()),
            ));
        }
        Ok(())
    }

    /// The NEXT_STEP-mode step after a cut: the reset observation, reward 0, no flags.
    fn deferred_step(&mut self, r: ResetResult) -> StepResult {
        let n = self.rows();
        self.last_obs = Some(r.obs.clone());
        StepResult {
            obs: r.obs,
            reward: vec![0.0; n],
            terminated: vec![false; n],
            truncated: vec![false; n],
            info: r.info,
            final_obs: None,
            final_info: None,
        }
    }

    /// Rebuilds the envs after the server went away: re-resolve the target, then on
    /// the best replica (fewest rows of this pool in `load`, the current one on a tie)
    /// reconnect (with the client's backoff), make, check the spec is unchanged, reset
    /// with `seeds`, open a fresh stream. Returns the reset and the observation the cut
    /// episodes ended on; `load` is updated when the envs move.
    pub async fn recover(
        &mut self,
        args: &MakeArgs,
        expected: &EnvSpec,
        seeds: &[i64],
        cause: &EnvError,
        load: &mut HashMap<String, usize>,
    ) -> Result<(ResetResult, Option<Observation>)> {
        tracing::warn!(addr = %self.addr, envs = ?self.envs, %cause, "env server lost; rebuilding its envs");
        let mut last_err = None;
        let attempts = args.recovery_attempts.max(1);
        for attempt in 1..=attempts {
            let candidates = self.candidates(args, load).await;
            // With several replicas, a dead one is given a few seconds, not the full
            // connect budget, before the next is tried.
            let retry = if candidates.len() > 1 {
                quick_retry(&args.client.retry)
            } else {
                args.client.retry.clone()
            };
            for addr in candidates {
                match self.rebuild(&addr, args, expected, seeds, &retry).await {
                    Ok(reset) => {
                        self.restarts += 1;
                        if addr != self.addr {
                            tracing::info!(target = %self.target, from = %self.addr, to = %addr, "envs moved to another replica");
                            if let Some(n) = load.get_mut(&self.addr) {
                                *n = n.saturating_sub(self.rows());
                            }
                            *load.entry(addr.clone()).or_default() += self.rows();
                            self.addr = addr;
                        }
                        let ending = self.last_obs.replace(reset.obs.clone());
                        tracing::info!(addr = %self.addr, attempt, "envs rebuilt");
                        return Ok((reset, ending));
                    }
                    Err(e)
                        if e.is_connection_loss() || matches!(e, EnvError::Unreachable { .. }) =>
                    {
                        tracing::debug!(%addr, %e, "replica not usable");
                        last_err = Some(e);
                    }
                    Err(e) => return Err(e),
                }
            }
            if attempt < attempts {
                tokio::time::sleep(args.client.retry.max_backoff).await;
            }
        }
        Err(last_err.expect("at least one attempt ran"))
    }

    /// The target's replicas now, best first; the last known address when the name
    /// does not resolve (any more).
    async fn candidates(&self, args: &MakeArgs, load: &HashMap<String, usize>) -> Vec<String> {
        let mut addrs = match resolve_with_retry(
            args.resolver.as_ref(),
            &self.target,
            &args.client.retry,
        )
        .await
        {
            Ok(addrs) => addrs,
            Err(e) => {
                tracing::warn!(target = %self.target, %e, "keeping the last known address");
                vec![self.addr.clone()]
            }
        };
        let others = |a: &String| {
            let n = load.get(a).copied().unwrap_or(0);
            if *a == self.addr {
                n.saturating_sub(self.rows())
            } else {
                n
            }
        };
        // Stable sort: resolution order breaks the remaining ties.
        addrs.sort_by_key(|a| (others(a), *a != self.addr));
        addrs
    }

    async fn rebuild(
        &mut self,
        addr: &str,
        args: &MakeArgs,
        expected: &EnvSpec,
        seeds: &[i64],
        retry: &RetryPolicy,
    ) -> Result<ResetResult> {
        let mut config = args.client.clone();
        config.retry = retry.clone();
        let client = EnvClient::connect(addr, config).await?;
        // The old handle is gone if the server restarted; if it merely stalled,
        // free it. Either answer is fine.
        if addr == self.addr
            && let Err(e) = client.close(&self.handle).await
        {
            tracing::debug!(addr, %e, "closing the old handle");
        }
        let (session, handle, spec) = make_envs(&client, args, self.rows()).await?;
        if let Some(diff) = spec_difference(expected, &spec) {
            let _ = client.close(&handle).await;
            return Err(EnvError::protocol(
                addr,
                format!("the server came back with a different spec: {diff}"),
            ));
        }
        let reset = client.reset(&handle, &[], seeds).await?;
        self.check_rows(reset.obs.rows())?;
        self.session = session;
        self.client = client;
        self.handle = handle;
        self.send_failed = None;
        self.deferred_pending = false;
        self.deferred_reset = None;
        Ok(reset)
    }

    /// Keeps a reset to serve as the next step's reply (NEXT_STEP emulation).
    pub fn defer_reset(&mut self, reset: ResetResult) {
        self.deferred_reset = Some(reset);
    }

    pub fn client(&self) -> &EnvClient {
        &self.client
    }

    pub fn handle(&self) -> &str {
        &self.handle
    }

    pub fn absent_info(&self, spec: &EnvSpec) -> InfoBatch {
        InfoBatch::absent(&spec.info_fields, self.rows())
    }
}

/// Opens the shard's stream and makes its envs. On an API 1.1 server they are
/// made on the stream, so the server frees them as soon as the stream ends
/// (this process died or lost its connection), not after its idle timeout.
async fn make_envs(
    client: &EnvClient,
    args: &MakeArgs,
    rows: usize,
) -> Result<(Session, String, EnvSpec)> {
    let mut session = client.session();
    if !client.makes_on_streams() {
        let (handle, spec) = client
            .make(&args.env_id, &args.kwargs, rows, args.autoreset)
            .await?;
        return Ok((session, handle, spec));
    }
    let request = make_request(&args.env_id, &args.kwargs, rows, args.autoreset)?;
    session.send(Request::Make(request))?;
    match session.recv_within(client.config().timeouts.make).await? {
        SessionReply::Make(made) => {
            let (handle, spec) = client.parse_made(&args.env_id, rows, *made)?;
            Ok((session, handle, spec))
        }
        _ => Err(EnvError::protocol(
            client.addr(),
            "a reply to a make that is no make",
        )),
    }
}

/// A connect budget of a few seconds, for one replica among several.
fn quick_retry(full: &RetryPolicy) -> RetryPolicy {
    RetryPolicy {
        max_attempts: full.max_attempts.min(3),
        max_elapsed: full.max_elapsed.min(Duration::from_secs(3)),
        ..full.clone()
    }
}

/// What differs between two specs of the same env, ignoring the batch size.
pub(crate) fn spec_difference(a: &EnvSpec, b: &EnvSpec) -> Option<String> {
    if a.observation_space != b.observation_space {
        return Some("observation space".into());
    }
    if a.action_space != b.action_space {
        return Some("action space".into());
    }
    if a.info_fields != b.info_fields {
        return Some("info fields".into());
    }
    if a.max_episode_steps != b.max_episode_steps {
        return Some(format!(
            "max_episode_steps {} vs {}",
            a.max_episode_steps, b.max_episode_steps
        ));
    }
    if a.autoreset != b.autoreset {
        return Some(format!("autoreset {} vs {}", a.autoreset, b.autoreset));
    }
    None
}
