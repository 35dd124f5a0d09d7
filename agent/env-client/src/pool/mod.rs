//! `EnvPool`: N environments spread over several servers, stepped in batches,
//! in G groups that can be in flight independently.
//!
//! With G = 2 the agent double-buffers: `send(0, ..)`, then compute group 1's
//! actions while group 0's envs step on the servers, `send(1, ..)`, `recv(0)`,
//! and so on. With G = 1 it is plain batched stepping (`step`).
//!
//! Env `i` (global index) is seeded with `seed + i` on its group's first reset,
//! whichever server it lands on, so results do not depend on the server count.
//! When a server restarts mid-run, the affected envs are rebuilt and their cut
//! episodes reported as truncated (`cut` set, the last observation as final
//! observation), never glued to the new episodes. Envs rebuilt while stepping or
//! during an unseeded reset are reseeded with a shifted base; a seeded reset that
//! loses its server is rebuilt with the seeds it asked for.
//!
//! A server target that resolves to several addresses (a scaled Docker service, a
//! Kubernetes headless Service) counts as one server per address; a lost server's
//! target is resolved again, so its envs move to a live (or new) replica.
mod layout;
mod resolve;
mod shard;

use std::collections::HashMap;
use std::ops::Range;
use std::sync::Arc;

use futures::future::try_join_all;

use crate::action::{Actions, encode_actions};
use crate::client::ClientConfig;
use crate::error::{EnvError, Result};
use crate::observation::{Fields, InfoBatch, Observation};
use crate::reply::{ResetResult, StepResult};
use crate::space::{AutoresetMode, EnvSpec};
use crate::value::Kwargs;
pub use layout::{Block, layout, split_even};
pub use resolve::{DnsResolver, Resolve, ResolveFuture};
use shard::{MakeArgs, Shard, spec_difference};

/// What to run and where.
#[derive(Clone, Debug)]
pub struct PoolConfig {
    /// Every env server to use (at least one): `host:port` or a URI. A name that
    /// resolves to several addresses stands for all of them (one server each).
    pub servers: Vec<String>,
    pub env_id: String,
    pub kwargs: Kwargs,
    /// Total environments over all servers and groups.
    pub num_envs: usize,
    /// Independently stepped groups (1..=num_envs).
    pub groups: usize,
    /// Env i is reset with seed + i on its group's first reset; None = unseeded.
    pub seed: Option<u64>,
    /// SAME_STEP (what learners want) or NEXT_STEP; DISABLED needs per-env
    /// resets, which the `EnvClient` offers.
    pub autoreset: AutoresetMode,
    /// Deadlines and connection retries.
    pub client: ClientConfig,
    /// Full reconnect + re-make attempts for one lost server before giving up.
    pub recovery_attempts: u32,
    /// Turns `servers` into replica addresses, at connect and after a loss.
    pub resolver: Arc<dyn Resolve>,
}

impl PoolConfig {
    pub fn new(servers: Vec<String>, env_id: impl Into<String>, num_envs: usize) -> Self {
        PoolConfig {
            servers,
            env_id: env_id.into(),
            kwargs: Kwargs::new(),
            num_envs,
            groups: 1,
            seed: None,
            autoreset: AutoresetMode::SameStep,
            client: ClientConfig::default(),
            recovery_attempts: 3,
            resolver: Arc::new(DnsResolver),
        }
    }

    fn validate(&self) -> Result<()> {
        let invalid = |m: String| Err(EnvError::InvalidInput(m));
        if self.servers.is_empty() {
            return invalid("the pool needs at least one env server address".into());
        }
        if self.num_envs == 0 {
            return invalid("num_envs must be at least 1".into());
        }
        if self.groups == 0 || self.groups > self.num_envs {
            return invalid(format!(
                "groups must be in 1..={} (num_envs), got {}",
                self.num_envs, self.groups
            ));
        }
        if self.autoreset == AutoresetMode::Disabled {
            return invalid(
                "the pool runs SAME_STEP or NEXT_STEP autoreset; use EnvClient for DISABLED".into(),
            );
        }
        Ok(())
    }
}

/// Reply to a group's reset.
#[derive(Clone, Debug)]
pub struct ResetBatch {
    pub group: usize,
    /// Global index of row 0 (rows are consecutive envs).
    pub env_offset: usize,
    pub obs: Fields,
    pub info: InfoBatch,
}

/// Reply to a group's step, one row per env of the group.
#[derive(Clone, Debug)]
pub struct StepBatch {
    pub group: usize,
    /// Global index of row 0 (rows are consecutive envs).
    pub env_offset: usize,
    /// Under SAME_STEP, rows that ended already hold the next episode's first observation.
    pub obs: Fields,
    pub reward: Vec<f64>,
    pub terminated: Vec<bool>,
    pub truncated: Vec<bool>,
    /// Rows whose episode was cut because their server went away; `truncated`
    /// is set for them too and `final_obs` holds their last observation.
    pub cut: Vec<bool>,
    /// Info of the step (under SAME_STEP: the reset info for rows that ended).
    pub info: InfoBatch,
    /// When a row ended: every row, the ended ones holding the ending
    /// observation (others zero). Bootstrap truncated rows from it.
    pub final_obs: Option<Fields>,
    /// When a row ended: the ending step's info (others not present).
    pub final_info: Option<InfoBatch>,
}

impl StepBatch {
    pub fn rows(&self) -> usize {
        self.reward.len()
    }

    /// Rows whose episode ended at this step (terminated or truncated).
    pub fn ended(&self) -> Vec<bool> {
        self.terminated
            .iter()
            .zip(&self.truncated)
            .map(|(a, b)| *a || *b)
            .collect()
    }

    pub fn reward_f32(&self) -> Vec<f32> {
        self.reward.iter().map(|&r| r as f32).collect()
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum GroupState {
    NeedsReset,
    Resetting,
    Ready,
    Stepping,
}

#[derive(Debug)]
struct Group {
    envs: Range<usize>,
    shards: Vec<Shard>,
    state: GroupState,
    seeded: bool,
    /// Whether the reset in flight is seeded (begins the first episodes). A shard lost
    /// during it is rebuilt with those seeds, so the episodes begin as asked.
    seeded_reset_in_flight: bool,
}

/// Counters of the pool's fault handling.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoolStats {
    /// Times a handle was rebuilt after its server went away.
    pub rebuilds: u64,
    /// Episodes reported truncated because of a rebuild.
    pub cut_episodes: u64,
}

#[derive(Debug)]
pub struct EnvPool {
    spec: EnvSpec,
    args: MakeArgs,
    seed: Option<u64>,
    groups: Vec<Group>,
    stats: PoolStats,
}

impl EnvPool {
    /// Connects to every server, makes each block's envs (all in parallel) and
    /// checks that every server reports the same spec.
    pub async fn connect(config: PoolConfig) -> Result<Self> {
        config.validate()?;
        let args = MakeArgs {
            env_id: config.env_id.clone(),
            kwargs: config.kwargs.clone(),
            autoreset: config.autoreset,
            client: config.client.clone(),
            recovery_attempts: config.recovery_attempts,
            resolver: config.resolver.clone(),
        };
        // (target, address) of every replica, each once.
        let mut servers: Vec<(String, String)> = Vec::new();
        for target in &config.servers {
            let addrs =
                resolve::resolve_with_retry(config.resolver.as_ref(), target, &config.client.retry)
                    .await?;
            for addr in addrs {
                if !servers.iter().any(|(_, a)| *a == addr) {
                    servers.push((target.clone(), addr));
                }
            }
        }
        let plan = layout(config.num_envs, config.groups, servers.len());
        let opened = try_join_all(plan.iter().flat_map(|(_, blocks)| {
            blocks.iter().map(|b| {
                let (target, addr) = &servers[b.server];
                Shard::open(target, addr, b.envs.clone(), &args)
            })
        }))
        .await?;
        let mut opened = opened.into_iter();
        let mut spec: Option<EnvSpec> = None;
        let mut groups = Vec::with_capacity(plan.len());
        for (envs, blocks) in plan {
            let mut shards = Vec::with_capacity(blocks.len());
            for _ in blocks {
                let (shard, s) = opened.next().expect("one shard per block");
                match &spec {
                    None => spec = Some(s),
                    Some(first) => {
                        if let Some(diff) = spec_difference(first, &s) {
                            return Err(EnvError::protocol(
                                &shard.addr,
                                format!(
                                    "its {} spec differs from the first server's: {diff}",
                                    config.env_id
                                ),
                            ));
                        }
                    }
                }
                shards.push(shard);
            }
            groups.push(Group {
                envs,
                shards,
                state: GroupState::NeedsReset,
                seeded: false,
                seeded_reset_in_flight: false,
            });
        }
        let mut spec = spec.expect("at least one shard");
        spec.num_envs = config.num_envs;
        tracing::info!(
            env_id = %config.env_id,
            num_envs = config.num_envs,
            groups = config.groups,
            servers = %servers.iter().map(|(_, a)| a.as_str()).collect::<Vec<_>>().join(" "),
            "env pool ready"
        );
        Ok(EnvPool {
            spec,
            args,
            seed: config.seed,
            groups,
            stats: PoolStats::default(),
        })
    }

    /// The spec of one env (with `num_envs` the pool's total).
    pub fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    pub fn num_envs(&self) -> usize {
        self.spec.num_envs
    }

    pub fn num_groups(&self) -> usize {
        self.groups.len()
    }

    /// Global indices of group `g`'s envs (its rows, in order).
    pub fn group_envs(&self, g: usize) -> Range<usize> {
        self.groups[g].envs.clone()
    }

    pub fn stats(&self) -> PoolStats {
        self.stats
    }

    /// The server address of every env, by global index (where each env runs now).
    pub fn env_addresses(&self) -> Vec<String> {
        let mut out = vec![String::new(); self.num_envs()];
        for shard in self.groups.iter().flat_map(|g| &g.shards) {
            for i in shard.envs.clone() {
                out[i] = shard.addr.clone();
            }
        }
        out
    }

    /// Rows of this pool on each server address (`taken`: a group's shards held
    /// outside `groups` while it is received).
    fn load(&self, taken: &[Shard]) -> HashMap<String, usize> {
        let mut load = HashMap::new();
        for shard in self.groups.iter().flat_map(|g| &g.shards).chain(taken) {
            *load.entry(shard.addr.clone()).or_default() += shard.rows();
        }
        load
    }

    fn group_mut(&mut self, g: usize) -> Result<&mut Group> {
        let n = self.groups.len();
        self.groups
            .get_mut(g)
            .ok_or_else(|| EnvError::InvalidInput(format!("group {g} out of 0..{n}")))
    }

    fn seeds(&self, envs: Range<usize>, generation: u64) -> Vec<i64> {
        // A rebuild reseeds with a shifted base so the new episodes differ from
        // the first ones yet stay reproducible.
        self.seed.map_or_else(Vec::new, |s| {
            let shift = generation.wrapping_mul(self.spec.num_envs as u64);
            envs.map(|i| s.wrapping_add(i as u64).wrapping_add(shift) as i64)
                .collect()
        })
    }

    /// Resets every env of group `g` (seeded the first time when a seed is set).
    pub async fn reset(&mut self, g: usize) -> Result<ResetBatch> {
        self.send_reset(g)?;
        self.recv_reset(g).await
    }

    /// Resets every env of group `g` with the seeds of its first reset, so the episodes
    /// begin exactly as they began then (evaluation scores the same episodes each time).
    pub async fn reset_to_first_episodes(&mut self, g: usize) -> Result<ResetBatch> {
        self.group_mut(g)?.seeded = false;
        self.reset(g).await
    }

    /// Resets every group; one batch per group.
    pub async fn reset_all(&mut self) -> Result<Vec<ResetBatch>> {
        // Refuse before sending anything, so no group is left half-reset.
        if let Some(g) = self
            .groups
            .iter()
            .position(|g| matches!(g.state, GroupState::Stepping | GroupState::Resetting))
        {
            return Err(EnvError::InvalidInput(format!(
                "group {g} has a request in flight; recv it before resetting"
            )));
        }
        for g in 0..self.groups.len() {
            self.send_reset(g)?;
        }
        let mut out = Vec::with_capacity(self.groups.len());
        for g in 0..self.groups.len() {
            out.push(self.recv_reset(g).await?);
        }
        Ok(out)
    }

    fn send_reset(&mut self, g: usize) -> Result<()> {
        let seeded = self.group_mut(g)?.seeded;
        let group = &self.groups[g];
        if matches!(group.state, GroupState::Stepping | GroupState::Resetting) {
            return Err(EnvError::InvalidInput(format!(
                "group {g} has a request in flight; recv it before resetting"
            )));
        }
        let seeds: Vec<Vec<i64>> = group
            .shards
            .iter()
            .map(|s| {
                if seeded {
                    Vec::new()
                } else {
                    self.seeds(s.envs.clone(), 0)
                }
            })
            .collect();
        let group = &mut self.groups[g];
        for (shard, seeds) in group.shards.iter_mut().zip(&seeds) {
            shard.send_reset(seeds);
        }
        group.seeded_reset_in_flight = !seeded;
        group.seeded = true;
        group.state = GroupState::Resetting;
        Ok(())
    }

    async fn recv_reset(&mut self, g: usize) -> Result<ResetBatch> {
        let mut parts = Vec::new();
        let mut first_err = None;
        let shards = std::mem::take(&mut self.groups[g].shards);
        let seeded_reset = self.groups[g].seeded_reset_in_flight;
        let mut load = self.load(&shards);
        let mut kept = Vec::with_capacity(shards.len());
        for mut shard in shards {
            match shard.recv_reset().await {
                Ok(r) => parts.push(r),
                Err(e) if e.is_connection_loss() => {
                    // A seeded reset is rebuilt with its own seeds (an evaluation's reset
                    // to its first episodes begins them all the same); an unseeded one
                    // with shifted seeds, since the lost envs' generators are gone.
                    let generation = if seeded_reset { 0 } else { shard.restarts + 1 };
                    let seeds = self.seeds(shard.envs.clone(), generation);
                    match shard
                        .recover(&self.args, &self.spec, &seeds, &e, &mut load)
                        .await
                    {
                        Ok((r, _)) => {
                            self.stats.rebuilds += 1;
                            parts.push(r);
                        }
                        Err(e) => {
                            first_err.get_or_insert(e);
                        }
                    }
                }
                // The other shards' replies are still read so the streams stay in step.
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
            kept.push(shard);
        }
        let group = &mut self.groups[g];
        group.shards = kept;
        if let Some(e) = first_err {
            group.state = GroupState::NeedsReset;
            return Err(e);
        }
        group.state = GroupState::Ready;
        let obs =
            Observation::concat_rows(&parts.iter().map(|r| r.obs.clone()).collect::<Vec<_>>())
                .map_err(|e| EnvError::protocol("pool", e))?;
        let info = InfoBatch::concat_rows(
            &parts
                .iter()
                .map(|r| (r.obs.rows(), Some(&r.info)))
                .collect::<Vec<_>>(),
            &self.spec.info_fields,
        )
        .map_err(|e| EnvError::protocol("pool", e))?;
        Ok(ResetBatch {
            group: g,
            env_offset: group.envs.start,
            obs: obs.fields(),
            info,
        })
    }

    /// Sends one action per env of group `g` (row-major, `[group size, *action
    /// shape]`) without waiting for the reply; `recv(g)` collects it. The whole
    /// batch is checked first (length, finiteness, integer range), so a bad
    /// batch reaches no server.
    pub fn send<'a>(&mut self, g: usize, actions: impl Into<Actions<'a>>) -> Result<()> {
        let state = self.group_mut(g)?.state;
        match state {
            GroupState::Ready => {}
            GroupState::NeedsReset => {
                return Err(EnvError::InvalidInput(format!(
                    "group {g} must be reset before stepping"
                )));
            }
            GroupState::Stepping | GroupState::Resetting => {
                return Err(EnvError::InvalidInput(format!(
                    "group {g} already has a request in flight; recv it first"
                )));
            }
        }
        let group = &mut self.groups[g];
        let action = encode_actions(&self.spec.action_space, group.envs.len(), actions.into())?;
        for shard in &mut group.shards {
            let rows = shard.envs.start - group.envs.start..shard.envs.end - group.envs.start;
            let part = action.slice_rows(rows).map_err(EnvError::InvalidInput)?;
            shard.send_step(part);
        }
        group.state = GroupState::Stepping;
        Ok(())
    }

    /// Waits for group `g`'s step reply. A server lost meanwhile is rebuilt
    /// and its rows come back cut (truncated, `cut` set).
    pub async fn recv(&mut self, g: usize) -> Result<StepBatch> {
        if self.group_mut(g)?.state != GroupState::Stepping {
            return Err(EnvError::InvalidInput(format!(
                "group {g} has no step in flight"
            )));
        }
        let mut parts: Vec<(StepResult, bool)> = Vec::new();
        let mut first_err = None;
        let shards = std::mem::take(&mut self.groups[g].shards);
        let mut load = self.load(&shards);
        let mut kept = Vec::with_capacity(shards.len());
        for mut shard in shards {
            match shard.recv_step().await {
                Ok(s) => parts.push((s, false)),
                Err(e) if e.is_connection_loss() => {
                    let seeds = self.seeds(shard.envs.clone(), shard.restarts + 1);
                    match shard
                        .recover(&self.args, &self.spec, &seeds, &e, &mut load)
                        .await
                    {
                        Ok((reset, ending)) => {
                            self.stats.rebuilds += 1;
                            self.stats.cut_episodes += shard.rows() as u64;
                            parts.push((self.cut_step(&mut shard, reset, ending), true));
                        }
                        Err(e) => {
                            first_err.get_or_insert(e);
                        }
                    }
                }
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
            kept.push(shard);
        }
        let group = &mut self.groups[g];
        group.shards = kept;
        if let Some(e) = first_err {
            group.state = GroupState::NeedsReset;
            return Err(e);
        }
        group.state = GroupState::Ready;
        let env_offset = group.envs.start;
        assemble_step(&self.spec, g, env_offset, parts).map_err(|e| EnvError::protocol("pool", e))
    }

    /// `send` then `recv`.
    pub async fn step<'a>(
        &mut self,
        g: usize,
        actions: impl Into<Actions<'a>>,
    ) -> Result<StepBatch> {
        self.send(g, actions)?;
        self.recv(g).await
    }

    /// The reply standing in for a step of envs whose server was lost: their
    /// episodes end truncated on the last observation seen.
    fn cut_step(
        &self,
        shard: &mut Shard,
        reset: ResetResult,
        ending: Option<Observation>,
    ) -> StepResult {
        let n = shard.rows();
        let ending = ending.unwrap_or_else(|| Observation::zeros(&self.spec.observation_space, n));
        let flags = |v| vec![v; n];
        match self.spec.autoreset {
            AutoresetMode::NextStep => {
                // NEXT_STEP: this step shows the ending observation; the next
                // one hands out the reset (see `Shard::defer_reset`).
                let info = shard.absent_info(&self.spec);
                shard.defer_reset(reset);
                StepResult {
                    obs: ending,
                    reward: vec![0.0; n],
                    terminated: flags(false),
                    truncated: flags(true),
                    info,
                    final_obs: None,
                    final_info: None,
                }
            }
            _ => StepResult {
                obs: reset.obs,
                reward: vec![0.0; n],
                terminated: flags(false),
                truncated: flags(true),
                info: reset.info,
                final_obs: Some(ending),
                final_info: None,
            },
        }
    }

    /// Closes every handle; the first failure is returned after trying all. A handle the
    /// server no longer knows (NOT_FOUND: the server restarted, or its envs already ended)
    /// is closed already, so it is no failure: a run that lost a server while it stopped
    /// must still write its final checkpoint.
    pub async fn close(mut self) -> Result<()> {
        let mut first_err = None;
        for group in std::mem::take(&mut self.groups) {
            for shard in group.shards {
                match shard.client().close(shard.handle()).await {
                    Err(e) if e.code() == Some(tonic::Code::NotFound) => {
                        tracing::debug!(handle = shard.handle(), "closing: already gone");
                    }
                    Err(e) => {
                        first_err.get_or_insert(e);
                    }
                    Ok(()) => {}
                }
            }
        }
        first_err.map_or(Ok(()), Err)
    }
}

impl Drop for EnvPool {
    /// A pool dropped without `close` still frees its server-side envs when a
    /// tokio runtime is around to send the Close calls.
    fn drop(&mut self) {
        let open: Vec<_> = self
            .groups
            .iter()
            .flat_map(|g| {
                g.shards
                    .iter()
                    .map(|s| (s.client().clone(), s.handle().to_owned()))
            })
            .collect();
        if open.is_empty() {
            return;
        }
        if let Ok(rt) = tokio::runtime::Handle::try_current() {
            rt.spawn(async move {
                for (client, handle) in open {
                    if let Err(e) = client.close(&handle).await {
                        tracing::debug!(%handle, %e, "closing a dropped pool's handle");
                    }
                }
            });
        }
    }
}

fn assemble_step(
    spec: &EnvSpec,
    group: usize,
    env_offset: usize,
    parts: Vec<(StepResult, bool)>,
) -> std::result::Result<StepBatch, String> {
    let obs =
        Observation::concat_rows(&parts.iter().map(|(s, _)| s.obs.clone()).collect::<Vec<_>>())?;
    let mut reward = Vec::new();
    let mut terminated = Vec::new();
    let mut truncated = Vec::new();
    let mut cut = Vec::new();
    for (s, was_cut) in &parts {
        reward.extend_from_slice(&s.reward);
        terminated.extend_from_slice(&s.terminated);
        truncated.extend_from_slice(&s.truncated);
        cut.extend(std::iter::repeat_n(*was_cut, s.rows()));
    }
    let info = InfoBatch::concat_rows(
        &parts
            .iter()
            .map(|(s, _)| (s.rows(), Some(&s.info)))
            .collect::<Vec<_>>(),
        &spec.info_fields,
    )?;
    let final_obs = if parts.iter().any(|(s, _)| s.final_obs.is_some()) {
        let pieces: Vec<Observation> = parts
            .iter()
            .map(|(s, _)| {
                s.final_obs
                    .clone()
                    .unwrap_or_else(|| Observation::zeros(&spec.observation_space, s.rows()))
            })
            .collect();
        Some(Observation::concat_rows(&pieces)?.fields())
    } else {
        None
    };
    let final_info = if parts.iter().any(|(s, _)| s.final_info.is_some()) {
        Some(InfoBatch::concat_rows(
            &parts
                .iter()
                .map(|(s, _)| (s.rows(), s.final_info.as_ref()))
                .collect::<Vec<_>>(),
            &spec.info_fields,
        )?)
    } else {
        None
    };
    Ok(StepBatch {
        group,
        env_offset,
        obs: obs.fields(),
        reward,
        terminated,
        truncated,
        cut,
        info,
        final_obs,
        final_info,
    })
}
