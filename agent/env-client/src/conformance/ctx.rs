//! Shared state and helpers of the conformance checks.
use std::sync::Mutex;

use anyhow::{Context, anyhow, bail};
use prost::Message;
use tonic::Code;

use crate::action::ActionSampler;
use crate::client::{ClientConfig, EnvClient};
use crate::error::{EnvError, code_name};
use crate::proto;
use crate::reply::StepResult;
use crate::space::{AutoresetMode, EnvSpec};
use crate::tensor::Tensor;
use crate::value::Kwargs;

use super::ConformanceOptions;

pub(crate) struct Ctx {
    pub client: EnvClient,
    pub env_id: String,
    pub kwargs: Kwargs,
    pub num_envs: usize,
    pub seed: u64,
    pub max_steps: u64,
    pub client_config: ClientConfig,
    /// Handles made by the running check, closed after it whatever its outcome.
    opened: Mutex<Vec<(EnvClient, String)>>,
}

impl Ctx {
    pub fn new(client: EnvClient, opts: &ConformanceOptions) -> Self {
        Ctx {
            client,
            env_id: opts.env_id.clone(),
            kwargs: opts.kwargs.clone(),
            num_envs: opts.num_envs.max(3),
            seed: opts.seed,
            max_steps: opts.max_steps,
            client_config: opts.client.clone(),
            opened: Mutex::new(Vec::new()),
        }
    }

    pub fn addr(&self) -> &str {
        self.client.addr()
    }

    /// Makes `n` envs of the env under test on `client` and remembers the handle.
    pub async fn make_on(
        &self,
        client: &EnvClient,
        n: usize,
        mode: AutoresetMode,
    ) -> anyhow::Result<(String, EnvSpec)> {
        let (handle, spec) = client
            .make(&self.env_id, &self.kwargs, n, mode)
            .await
            .with_context(|| format!("Make {} x{n} ({mode})", self.env_id))?;
        self.track(client, &handle);
        Ok((handle, spec))
    }

    pub async fn make(&self, n: usize, mode: AutoresetMode) -> anyhow::Result<(String, EnvSpec)> {
        self.make_on(&self.client, n, mode).await
    }

    pub fn track(&self, client: &EnvClient, handle: &str) {
        self.opened
            .lock()
            .expect("no check panics while holding the lock")
            .push((client.clone(), handle.to_owned()));
    }

    /// Closes what the last check opened; handles it closed itself are NOT_FOUND, which is fine.
    pub async fn close_opened(&self) {
        let opened = std::mem::take(&mut *self.opened.lock().expect("lock not poisoned"));
        for (client, handle) in opened {
            if let Err(e) = client.close(&handle).await
                && e.code() != Some(Code::NotFound)
            {
                tracing::warn!(%handle, %e, "closing a handle after a check");
            }
        }
    }

    /// Seeds `seed + base + i` for `n` envs.
    pub fn seeds(&self, base: u64, n: usize) -> Vec<i64> {
        (0..n)
            .map(|i| (self.seed + base + i as u64) as i64)
            .collect()
    }

    pub fn sampler(&self, spec: &EnvSpec, salt: u64) -> anyhow::Result<ActionSampler> {
        Ok(ActionSampler::new(&spec.action_space, self.seed ^ salt)?)
    }

    /// A second, independent connection (a second client).
    pub async fn second_client(&self) -> anyhow::Result<EnvClient> {
        Ok(EnvClient::connect(self.addr(), self.client_config.clone()).await?)
    }

    /// Steps budget for checks that wait for an episode to end.
    pub fn episode_budget(&self, spec: &EnvSpec) -> Option<u64> {
        match spec.max_episode_steps {
            0 => Some(self.max_steps.min(2_000)),
            t if t < self.max_steps => Some(t + 1),
            _ => None,
        }
    }
}

/// Fails unless `result` is an error with status `code`.
pub(crate) fn expect_code<T: std::fmt::Debug>(
    result: Result<T, EnvError>,
    code: Code,
    what: &str,
) -> anyhow::Result<()> {
    match result {
        Ok(v) => Err(anyhow!(
            "{what}: expected {}, the call succeeded ({})",
            code_name(code),
            short_debug(&v)
        )),
        Err(e) if e.code() == Some(code) => Ok(()),
        Err(e) => Err(anyhow!("{what}: expected {}, got: {e}", code_name(code))),
    }
}

fn short_debug<T: std::fmt::Debug>(v: &T) -> String {
    let s = format!("{v:?}");
    if s.len() > 120 {
        format!("{}...", &s[..s.floor_char_boundary(120)])
    } else {
        s
    }
}

/// A step request for `handle` carrying `action`.
pub(crate) fn step_request(handle: &str, action: proto::Tensor) -> proto::StepRequest {
    proto::StepRequest {
        handle: handle.to_owned(),
        action: Some(action),
    }
}

/// Steps and converts, failing with the step number in the message.
pub(crate) async fn step(
    client: &EnvClient,
    handle: &str,
    action: &Tensor,
    t: u64,
) -> anyhow::Result<StepResult> {
    client
        .step(handle, action)
        .await
        .with_context(|| format!("step {t}"))
}

/// Canonical bytes of a message, for byte-identical comparisons.
pub(crate) fn bytes_of<M: Message>(m: &M) -> Vec<u8> {
    m.encode_to_vec()
}

/// Compares two trajectories of raw step replies bit for bit: observation,
/// reward, flags and final observation.
pub(crate) fn same_steps(
    a: &[proto::StepResponse],
    b: &[proto::StepResponse],
    what: &str,
) -> anyhow::Result<()> {
    if a.len() != b.len() {
        bail!("{what}: {} vs {} steps", a.len(), b.len());
    }
    for (t, (x, y)) in a.iter().zip(b).enumerate() {
        if bytes_of(&x.observation.clone().unwrap_or_default())
            != bytes_of(&y.observation.clone().unwrap_or_default())
        {
            bail!("{what}: observations differ at step {t}");
        }
        let bits = |r: &[f64]| r.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        if bits(&x.reward) != bits(&y.reward) {
            bail!(
                "{what}: rewards differ at step {t}: {:?} vs {:?}",
                x.reward,
                y.reward
            );
        }
        if x.terminated != y.terminated || x.truncated != y.truncated {
            bail!("{what}: terminated/truncated differ at step {t}");
        }
        if x.final_observation.as_ref().map(bytes_of) != y.final_observation.as_ref().map(bytes_of)
        {
            bail!("{what}: final observations differ at step {t}");
        }
    }
    Ok(())
}
