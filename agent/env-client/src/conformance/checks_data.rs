//! Checks of the data: spec vs replies, row bookkeeping, determinism, the
//! Session stream and isolation between clients.
use anyhow::{Context, bail, ensure};

use super::Outcome;
use super::ctx::{Ctx, bytes_of, same_steps, step_request};
use crate::client::{EnvClient, reset_request};
use crate::observation::Observation;
use crate::proto::{self, session_request::Request, session_response::Response};
use crate::reply::StepResult;
use crate::space::{AutoresetMode, EnvSpec};
use crate::tensor::Tensor;

fn msg(e: String) -> anyhow::Error {
    anyhow::Error::msg(e)
}

/// The rows of `obs` listed in `rows`, each checked against the space (rows
/// that did not end hold zeros, which need not lie in the space).
fn check_rows(obs: &Observation, spec: &EnvSpec, rows: &[usize], what: &str) -> anyhow::Result<()> {
    for &r in rows {
        obs.slice_rows(r..r + 1)
            .map_err(msg)?
            .conforms_to(&spec.observation_space, 1)
            .map_err(|e| anyhow::anyhow!("{what} row {r}: {e}"))?;
    }
    Ok(())
}

fn check_step(s: &StepResult, spec: &EnvSpec, n: usize, t: u64) -> anyhow::Result<()> {
    let at = |e: String| anyhow::anyhow!("step {t}: {e}");
    s.obs.conforms_to(&spec.observation_space, n).map_err(at)?;
    s.info.conforms_to(&spec.info_fields, n).map_err(at)?;
    let ended: Vec<usize> = (0..n)
        .filter(|&i| s.terminated[i] || s.truncated[i])
        .collect();
    if let Some(f) = &s.final_obs {
        f.conforms_to_layout(&spec.observation_space, n)
            .map_err(at)?;
        check_rows(f, spec, &ended, &format!("step {t}: final observation"))?;
    }
    if let Some(fi) = &s.final_info {
        fi.conforms_to(&spec.info_fields, n).map_err(at)?;
    }
    Ok(())
}

pub(crate) async fn spec_matches_data(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let (handle, spec) = ctx.make(n, AutoresetMode::SameStep).await?;
    ensure!(
        spec.num_envs == n,
        "spec.num_envs {} for {n} envs",
        spec.num_envs
    );
    ensure!(
        spec.autoreset == AutoresetMode::SameStep,
        "spec autoreset {}",
        spec.autoreset
    );
    ensure!(spec.env_id == ctx.env_id, "spec env_id {:?}", spec.env_id);
    let reset = ctx
        .client
        .reset(&handle, &[], &ctx.seeds(0, n))
        .await
        .context("Reset")?;
    reset
        .obs
        .conforms_to(&spec.observation_space, n)
        .map_err(|e| anyhow::anyhow!("reset: {e}"))?;
    reset
        .info
        .conforms_to(&spec.info_fields, n)
        .map_err(|e| anyhow::anyhow!("reset: {e}"))?;
    let mut sampler = ctx.sampler(&spec, 10)?;
    let steps = 60;
    let mut ended = 0;
    for t in 0..steps {
        let s = super::ctx::step(&ctx.client, &handle, &sampler.sample(n), t).await?;
        check_step(&s, &spec, n, t)?;
        ended += s.ended().iter().filter(|e| **e).count();
    }
    Ok(Outcome::Pass(format!(
        "reset + {steps} steps of {n} envs conform ({} leaves, {} info fields, {ended} episodes ended)",
        spec.observation_space.leaves().len(),
        spec.info_fields.len()
    )))
}

pub(crate) async fn reset_rows(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let (handle, spec) = ctx.make(n, AutoresetMode::SameStep).await?;
    let seeds = ctx.seeds(0, n);
    let all = ctx
        .client
        .reset(&handle, &[], &seeds)
        .await
        .context("Reset of all")?;
    let want: Vec<u32> = (0..n as u32).collect();
    ensure!(all.obs.rows() == n, "{} rows for {n} envs", all.obs.rows());
    ensure!(
        all.env_indices == want,
        "env_indices {:?} for a reset of all",
        all.env_indices
    );
    let subset = [2u32, 0];
    let sub_seeds = [seeds[2], seeds[0]];
    let part = ctx
        .client
        .reset(&handle, &subset, &sub_seeds)
        .await
        .context("Reset of [2, 0]")?;
    ensure!(
        part.obs.rows() == 2,
        "{} rows for a reset of 2 envs",
        part.obs.rows()
    );
    ensure!(
        part.env_indices == subset,
        "env_indices {:?} for [2, 0]",
        part.env_indices
    );
    part.obs
        .conforms_to(&spec.observation_space, 2)
        .map_err(msg)?;
    part.info.conforms_to(&spec.info_fields, 2).map_err(msg)?;
    // Seeded the same, each row must be its env's: the order is the request's.
    for (k, &i) in subset.iter().enumerate() {
        let a = all
            .obs
            .slice_rows(i as usize..i as usize + 1)
            .map_err(msg)?;
        let b = part.obs.slice_rows(k..k + 1).map_err(msg)?;
        ensure!(
            bytes_of(&a.to_proto()) == bytes_of(&b.to_proto()),
            "row {k} of the reset of [2, 0] is not env {i}'s observation for seed {}",
            sub_seeds[k]
        );
    }
    let unseeded = ctx
        .client
        .reset(&handle, &[1], &[])
        .await
        .context("Reset of [1] unseeded")?;
    ensure!(
        unseeded.env_indices == [1] && unseeded.obs.rows() == 1,
        "reset of [1]: indices {:?}",
        unseeded.env_indices
    );
    Ok(Outcome::Pass(String::new()))
}

pub(crate) async fn step_rows(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let (handle, spec) = ctx.make(n, AutoresetMode::SameStep).await?;
    ctx.client.reset(&handle, &[], &[]).await.context("Reset")?;
    let action = ctx.sampler(&spec, 11)?.sample(n);
    let raw = ctx
        .client
        .step_raw(step_request(&handle, action.to_proto()))
        .await
        .context("Step")?;
    ensure!(
        raw.reward.len() == n,
        "{} rewards for {n} envs",
        raw.reward.len()
    );
    ensure!(
        raw.terminated.len() == n,
        "{} terminated flags for {n} envs",
        raw.terminated.len()
    );
    ensure!(
        raw.truncated.len() == n,
        "{} truncated flags for {n} envs",
        raw.truncated.len()
    );
    let obs = Observation::from_proto(raw.observation.context("no observation")?).map_err(msg)?;
    for (name, t) in obs.fields().iter() {
        ensure!(
            t.rows() == n && !t.shape().is_empty(),
            "observation {name} has shape {:?} for {n} envs",
            t.shape()
        );
    }
    Ok(Outcome::Pass(String::new()))
}

/// Reset with `seeds`, then step with `actions`, all unary; raw replies.
async fn run_unary(
    client: &EnvClient,
    handle: &str,
    seeds: &[i64],
    actions: &[Tensor],
) -> anyhow::Result<(proto::ResetResponse, Vec<proto::StepResponse>)> {
    let reset = client
        .reset_raw(reset_request(handle, &[], seeds))
        .await
        .context("Reset")?;
    let mut steps = Vec::with_capacity(actions.len());
    for (t, a) in actions.iter().enumerate() {
        steps.push(
            client
                .step_raw(step_request(handle, a.to_proto()))
                .await
                .with_context(|| format!("step {t}"))?,
        );
    }
    Ok((reset, steps))
}

fn actions(
    ctx: &Ctx,
    spec: &EnvSpec,
    salt: u64,
    n: usize,
    steps: usize,
) -> anyhow::Result<Vec<Tensor>> {
    let mut sampler = ctx.sampler(spec, salt)?;
    Ok((0..steps).map(|_| sampler.sample(n)).collect())
}

pub(crate) async fn seed_determinism(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let (a, spec) = ctx.make(n, AutoresetMode::SameStep).await?;
    let (b, _) = ctx.make(n, AutoresetMode::SameStep).await?;
    let acts = actions(ctx, &spec, 12, n, 30)?;
    let seeds = ctx.seeds(0, n);
    let (ra, sa) = run_unary(&ctx.client, &a, &seeds, &acts).await?;
    let (rb, sb) = run_unary(&ctx.client, &b, &seeds, &acts).await?;
    ensure!(
        ra.observation.as_ref().map(bytes_of) == rb.observation.as_ref().map(bytes_of),
        "two handles reset with the same seeds gave different first observations"
    );
    same_steps(&sa, &sb, "same seeds and actions on two handles")?;

    // Different seeds must change the first observation, unless reset is not random.
    let (c, _) = ctx.make(n, AutoresetMode::SameStep).await?;
    let other = ctx
        .client
        .reset_raw(reset_request(&c, &[], &ctx.seeds(1_000, n)))
        .await?;
    let first = |r: &proto::ResetResponse| -> anyhow::Result<Observation> {
        Observation::from_proto(r.observation.clone().context("no observation")?).map_err(msg)
    };
    let (fa, fc) = (first(&ra)?, first(&other)?);
    let differs = (0..n).any(|i| {
        let row = |o: &Observation| o.slice_rows(i..i + 1).map(|r| bytes_of(&r.to_proto()));
        row(&fa).ok() != row(&fc).ok()
    });
    if differs {
        return Ok(Outcome::Pass(
            "different seeds give different first observations".into(),
        ));
    }
    let mut previous = fc;
    for k in 0..3 {
        let again = ctx
            .client
            .reset(&c, &[], &[])
            .await
            .context("unseeded Reset")?;
        if bytes_of(&again.obs.to_proto()) != bytes_of(&previous.to_proto()) {
            bail!(
                "different seeds gave identical first observations, yet unseeded reset {k} changed them: the seed is ignored"
            );
        }
        previous = again.obs;
    }
    Ok(Outcome::Pass(
        "same seeds reproduce; this env's reset is not random, so different seeds may agree".into(),
    ))
}

pub(crate) async fn session_stream(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let (a, spec) = ctx.make(n, AutoresetMode::SameStep).await?;
    let (b, _) = ctx.make(n, AutoresetMode::SameStep).await?;
    let steps = 20;
    let acts = actions(ctx, &spec, 13, n, steps)?;
    let seeds = ctx.seeds(0, n);
    // Everything is queued before the first reply is read: pipelined.
    let mut session = ctx.client.session();
    let base = 1_000_u64;
    session.send_with_id(base, Request::Reset(reset_request(&a, &[], &seeds)))?;
    for (t, act) in acts.iter().enumerate() {
        session.send_with_id(
            base + 1 + t as u64,
            Request::Step(step_request(&a, act.to_proto())),
        )?;
    }
    let mut stream_reset = None;
    let mut stream_steps = Vec::new();
    for k in 0..=steps as u64 {
        let reply = session
            .recv_raw()
            .await
            .with_context(|| format!("reply {k}"))?;
        ensure!(
            reply.request_id == base + k,
            "reply {k} carries request_id {}, expected {}",
            reply.request_id,
            base + k
        );
        match (k, reply.response) {
            (0, Some(Response::Reset(r))) => stream_reset = Some(r),
            (_, Some(Response::Step(s))) if k > 0 => stream_steps.push(s),
            (_, other) => bail!("reply {k} is not the expected kind: {other:?}"),
        }
    }
    let stream_reset = stream_reset.context("no reset reply")?;
    let (unary_reset, unary_steps) = run_unary(&ctx.client, &b, &seeds, &acts).await?;
    ensure!(
        stream_reset.observation.as_ref().map(bytes_of)
            == unary_reset.observation.as_ref().map(bytes_of),
        "the stream's reset differs from the unary reset"
    );
    same_steps(&stream_steps, &unary_steps, "stream vs unary")?;
    for (t, (x, y)) in stream_steps.iter().zip(&unary_steps).enumerate() {
        ensure!(
            x.info.as_ref().map(bytes_of) == y.info.as_ref().map(bytes_of),
            "the stream's info differs from the unary info at step {t}"
        );
    }
    Ok(Outcome::Pass(format!("{} pipelined requests", steps + 1)))
}

pub(crate) async fn concurrent_isolation(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let other_client = ctx.second_client().await?;
    let (a, spec) = ctx.make_on(&ctx.client, n, AutoresetMode::SameStep).await?;
    let (b, _) = ctx
        .make_on(&other_client, n, AutoresetMode::SameStep)
        .await?;
    let steps = 20;
    let acts_a = actions(ctx, &spec, 14, n, steps)?;
    let acts_b = actions(ctx, &spec, 15, n, steps)?;
    let (seeds_a, seeds_b) = (ctx.seeds(0, n), ctx.seeds(500, n));
    // Interleaved: both clients' requests in flight at once, step by step.
    let (ra, rb) = tokio::join!(
        ctx.client.reset_raw(reset_request(&a, &[], &seeds_a)),
        other_client.reset_raw(reset_request(&b, &[], &seeds_b))
    );
    let (ra, rb) = (ra?, rb?);
    let mut sa = Vec::new();
    let mut sb = Vec::new();
    for t in 0..steps {
        let (x, y) = tokio::join!(
            ctx.client.step_raw(step_request(&a, acts_a[t].to_proto())),
            other_client.step_raw(step_request(&b, acts_b[t].to_proto()))
        );
        sa.push(x.with_context(|| format!("client 1 step {t}"))?);
        sb.push(y.with_context(|| format!("client 2 step {t}"))?);
    }
    // Alone: fresh handles, one after the other.
    let (a2, _) = ctx.make_on(&ctx.client, n, AutoresetMode::SameStep).await?;
    let (alone_ra, alone_sa) = run_unary(&ctx.client, &a2, &seeds_a, &acts_a).await?;
    let (b2, _) = ctx
        .make_on(&other_client, n, AutoresetMode::SameStep)
        .await?;
    let (alone_rb, alone_sb) = run_unary(&other_client, &b2, &seeds_b, &acts_b).await?;
    ensure!(
        ra.observation.as_ref().map(bytes_of) == alone_ra.observation.as_ref().map(bytes_of)
            && rb.observation.as_ref().map(bytes_of) == alone_rb.observation.as_ref().map(bytes_of),
        "a reset interleaved with another client differs from the same reset alone"
    );
    same_steps(&sa, &alone_sa, "client 1 interleaved vs alone")?;
    same_steps(&sb, &alone_sb, "client 2 interleaved vs alone")?;
    Ok(Outcome::Pass(String::new()))
}
