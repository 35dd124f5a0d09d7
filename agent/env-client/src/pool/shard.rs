//! One block of a pool: a handle of consecutive envs on one server, driven over
//! its own Session stream, and able to rebuild itself when the server restarts.
use std::ops::Range;

use crate::client::{ClientConfig, EnvClient, reset_request};
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
}

#[derive(Debug)]
pub(crate) struct Shard {
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
    pub async fn open(addr: &str, envs: Range<usize>, args: &MakeArgs) -> Result<(Self, EnvSpec)> {
        let client = EnvClient::connect(addr, args.client.clone()).await?;
        let (handle, spec) = client
            .make(&args.env_id, &args.kwargs, envs.len(), args.autoreset)
            .await?;
        let session = client.session();
        tracing::debug!(addr, ?envs, handle, "made envs");
        Ok((
            Shard {
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
            SessionReply::Step(_) => Err(EnvError::protocol(&self.addr, "a step reply to a reset")),
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
            SessionReply::Reset(_) => {
                Err(EnvError::protocol(&self.addr, "a reset reply to a step"))
            }
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

    /// Rebuilds the envs after the server went away: reconnect (with the
    /// client's backoff), make, check the spec is unchanged, reset with `seeds`,
    /// open a fresh stream. Returns the reset and the observation the cut
    /// episodes ended on.
    pub async fn recover(
        &mut self,
        args: &MakeArgs,
        expected: &EnvSpec,
        seeds: &[i64],
        cause: &EnvError,
    ) -> Result<(ResetResult, Option<Observation>)> {
        tracing::warn!(addr = %self.addr, envs = ?self.envs, %cause, "env server lost; rebuilding its envs");
        let mut last_err = None;
        for attempt in 1..=args.recovery_attempts.max(1) {
            match self.rebuild(args, expected, seeds).await {
                Ok(reset) => {
                    self.restarts += 1;
                    let ending = self.last_obs.replace(reset.obs.clone());
                    tracing::info!(addr = %self.addr, attempt, "envs rebuilt");
                    return Ok((reset, ending));
                }
                Err(e) if e.is_connection_loss() => last_err = Some(e),
                Err(e) => return Err(e),
            }
        }
        Err(last_err.expect("at least one attempt ran"))
    }

    async fn rebuild(
        &mut self,
        args: &MakeArgs,
        expected: &EnvSpec,
        seeds: &[i64],
    ) -> Result<ResetResult> {
        let client = EnvClient::connect(&self.addr, args.client.clone()).await?;
        // The old handle is gone if the server restarted; if it merely stalled,
        // free it. Either answer is fine.
        if let Err(e) = client.close(&self.handle).await {
            tracing::debug!(addr = %self.addr, %e, "closing the old handle");
        }
        let (handle, spec) = client
            .make(&args.env_id, &args.kwargs, self.rows(), args.autoreset)
            .await?;
        if let Some(diff) = spec_difference(expected, &spec) {
            let _ = client.close(&handle).await;
            return Err(EnvError::protocol(
                &self.addr,
                format!("the server came back with a different spec: {diff}"),
            ));
        }
        let reset = client.reset(&handle, &[], seeds).await?;
        self.check_rows(reset.obs.rows())?;
        self.session = client.session();
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
