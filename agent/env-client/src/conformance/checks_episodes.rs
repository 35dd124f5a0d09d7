//! Checks of episode ends: the time limit and the three autoreset modes. The
//! autoreset checks replay the same seeds and actions on a DISABLED handle,
//! whose manual resets show what the autoreset must have produced.
use anyhow::{Context, bail, ensure};
use tonic::Code;

use super::Outcome;
use super::ctx::{Ctx, bytes_of, expect_code, step};
use crate::observation::Observation;
use crate::reply::StepResult;
use crate::space::{AutoresetMode, EnvSpec};

fn row(obs: &Observation, i: usize) -> anyhow::Result<Vec<u8>> {
    Ok(bytes_of(
        &obs.slice_rows(i..i + 1)
            .map_err(anyhow::Error::msg)?
            .to_proto(),
    ))
}

fn row_is_zero(obs: &Observation, i: usize) -> anyhow::Result<bool> {
    let r = obs.slice_rows(i..i + 1).map_err(anyhow::Error::msg)?;
    Ok(r.fields()
        .iter()
        .all(|(_, t)| t.data().iter().all(|b| *b == 0) && t.strings().iter().all(String::is_empty)))
}

fn ended_rows(s: &StepResult) -> Vec<usize> {
    (0..s.rows())
        .filter(|&i| s.terminated[i] || s.truncated[i])
        .collect()
}

fn budget(ctx: &Ctx, spec: &EnvSpec) -> Result<u64, Outcome> {
    ctx.episode_budget(spec).ok_or_else(|| {
        Outcome::Skip(format!(
            "time limit {} exceeds the step budget {}",
            spec.max_episode_steps, ctx.max_steps
        ))
    })
}

/// Same observations and flags on two handles that should be in lockstep.
fn lockstep(a: &StepResult, b: &StepResult, rows: &[usize], t: u64) -> anyhow::Result<()> {
    for &i in rows {
        ensure!(
            row(&a.obs, i)? == row(&b.obs, i)?
                && a.terminated[i] == b.terminated[i]
                && a.truncated[i] == b.truncated[i],
            "step {t}, env {i}: the autoreset handle and a DISABLED handle with the same seeds and actions disagree"
        );
    }
    Ok(())
}

pub(crate) async fn terminated_truncated_distinct(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let (handle, spec) = ctx.make(n, AutoresetMode::SameStep).await?;
    let limit = spec.max_episode_steps;
    if limit == 0 {
        return Ok(Outcome::Skip("the spec declares no time limit".into()));
    }
    if limit >= ctx.max_steps {
        return Ok(Outcome::Skip(format!(
            "time limit {limit} exceeds the step budget {}",
            ctx.max_steps
        )));
    }
    ctx.client
        .reset(&handle, &[], &ctx.seeds(0, n))
        .await
        .context("Reset")?;
    let mut sampler = ctx.sampler(&spec, 20)?;
    let mut age = vec![0u64; n];
    let (mut truncations, mut terminations) = (0, 0);
    for t in 0..=limit {
        let s = step(&ctx.client, &handle, &sampler.sample(n), t).await?;
        for (i, age) in age.iter_mut().enumerate() {
            *age += 1;
            let (term, trunc) = (s.terminated[i], s.truncated[i]);
            if trunc && *age != limit {
                bail!("env {i} truncated after {age} steps; the time limit is {limit}");
            }
            if !term && !trunc && *age >= limit {
                bail!("env {i} reached the time limit of {limit} steps and was not truncated");
            }
            if term || trunc {
                truncations += usize::from(trunc && !term);
                terminations += usize::from(term);
                *age = 0;
            }
        }
    }
    Ok(Outcome::Pass(format!(
        "{truncations} episodes truncated at exactly {limit} steps, {terminations} terminated"
    )))
}

/// A handle in `mode` and a DISABLED twin, both reset with the same seeds: stepped
/// with the same actions, the twin's manual resets show what the autoreset must
/// produce. `Err` is the skip when the time limit exceeds the step budget.
struct Paired {
    h: String,
    d: String,
    spec: EnvSpec,
    steps: u64,
    sampler: crate::action::ActionSampler,
}

async fn paired(
    ctx: &Ctx,
    mode: AutoresetMode,
    salt: u64,
) -> anyhow::Result<Result<Paired, Outcome>> {
    let n = ctx.num_envs;
    let (h, spec) = ctx.make(n, mode).await?;
    let (d, _) = ctx.make(n, AutoresetMode::Disabled).await?;
    ensure!(spec.autoreset == mode, "spec autoreset {}", spec.autoreset);
    let steps = match budget(ctx, &spec) {
        Ok(b) => b,
        Err(skip) => return Ok(Err(skip)),
    };
    let seeds = ctx.seeds(0, n);
    ctx.client.reset(&h, &[], &seeds).await.context("Reset")?;
    ctx.client
        .reset(&d, &[], &seeds)
        .await
        .context("Reset of the DISABLED handle")?;
    let sampler = ctx.sampler(&spec, salt)?;
    Ok(Ok(Paired {
        h,
        d,
        spec,
        steps,
        sampler,
    }))
}

pub(crate) async fn autoreset_same_step(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let Paired {
        h,
        d,
        spec,
        steps,
        mut sampler,
    } = match paired(ctx, AutoresetMode::SameStep, 21).await? {
        Ok(p) => p,
        Err(skip) => return Ok(skip),
    };
    let all: Vec<usize> = (0..n).collect();
    for t in 0..steps {
        let action = sampler.sample(n);
        let s = step(&ctx.client, &h, &action, t).await?;
        let r = step(&ctx.client, &d, &action, t)
            .await
            .context("DISABLED handle")?;
        let ended = ended_rows(&s);
        if ended.is_empty() {
            lockstep(&s, &r, &all, t)?;
            continue;
        }
        let running: Vec<usize> = all.iter().copied().filter(|i| !ended.contains(i)).collect();
        lockstep(&s, &r, &running, t)?;
        let fin = s.final_obs.as_ref().with_context(|| {
            format!("step {t}: envs {ended:?} ended without a final_observation")
        })?;
        fin.conforms_to_layout(&spec.observation_space, n)
            .map_err(anyhow::Error::msg)?;
        for &i in &ended {
            ensure!(
                row(fin, i)? == row(&r.obs, i)?,
                "step {t}, env {i}: final_observation is not the ending observation"
            );
            ensure!(
                s.terminated[i] == r.terminated[i] && s.truncated[i] == r.truncated[i],
                "step {t}, env {i}: flags differ from the DISABLED replay"
            );
        }
        for &i in &running {
            ensure!(
                row_is_zero(fin, i)?,
                "step {t}, env {i} did not end but its final_observation row is not zero"
            );
        }
        if !spec.info_fields.is_empty() {
            let fi = s
                .final_info
                .as_ref()
                .with_context(|| format!("step {t}: envs ended without final_info"))?;
            for f in &fi.0 {
                for &i in &running {
                    ensure!(
                        !f.present[i],
                        "step {t}: final_info {} present for env {i}, which did not end",
                        f.name
                    );
                }
            }
        }
        // The reply's observation must be the next episode's first one.
        let idx: Vec<u32> = ended.iter().map(|&i| i as u32).collect();
        let fresh = ctx
            .client
            .reset(&d, &idx, &[])
            .await
            .context("manual reset of the DISABLED handle")?;
        for (k, &i) in ended.iter().enumerate() {
            ensure!(
                row(&s.obs, i)? == row(&fresh.obs, k)?,
                "step {t}, env {i}: the observation after the end is not the next episode's first observation"
            );
        }
        return Ok(Outcome::Pass(format!(
            "envs {ended:?} ended at step {t}; final and first observations match a manual reset"
        )));
    }
    Ok(Outcome::Skip(format!(
        "no episode ended within {steps} steps"
    )))
}

pub(crate) async fn autoreset_next_step(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let Paired {
        h,
        d,
        spec,
        steps,
        mut sampler,
    } = match paired(ctx, AutoresetMode::NextStep, 22).await? {
        Ok(p) => p,
        Err(skip) => return Ok(skip),
    };
    let all: Vec<usize> = (0..n).collect();
    for t in 0..steps {
        let action = sampler.sample(n);
        let s = step(&ctx.client, &h, &action, t).await?;
        let r = step(&ctx.client, &d, &action, t)
            .await
            .context("DISABLED handle")?;
        // The ending step itself carries the final observation.
        lockstep(&s, &r, &all, t)?;
        let ended = ended_rows(&s);
        if ended.is_empty() {
            continue;
        }
        for &i in &ended {
            s.obs
                .slice_rows(i..i + 1)
                .map_err(anyhow::Error::msg)?
                .conforms_to(&spec.observation_space, 1)
                .map_err(|e| anyhow::anyhow!("step {t}, env {i}: final observation: {e}"))?;
        }
        let idx: Vec<u32> = ended.iter().map(|&i| i as u32).collect();
        let fresh = ctx
            .client
            .reset(&d, &idx, &[])
            .await
            .context("manual reset of the DISABLED handle")?;
        let action = sampler.sample(n);
        let s2 = step(&ctx.client, &h, &action, t + 1).await?;
        let r2 = step(&ctx.client, &d, &action, t + 1)
            .await
            .context("DISABLED handle")?;
        for (k, &i) in ended.iter().enumerate() {
            ensure!(
                s2.reward[i] == 0.0,
                "step {}, env {i}: reward {} on the reset step",
                t + 1,
                s2.reward[i]
            );
            ensure!(
                !s2.terminated[i] && !s2.truncated[i],
                "step {}, env {i}: terminated/truncated set on the reset step",
                t + 1
            );
            ensure!(
                row(&s2.obs, i)? == row(&fresh.obs, k)?,
                "step {}, env {i}: the reset step's observation is not the next episode's first observation",
                t + 1
            );
            ensure!(
                row(&s2.obs, i)? != row(&s.obs, i)?,
                "step {}, env {i}: the reset step repeats the final observation",
                t + 1
            );
        }
        let running: Vec<usize> = all.iter().copied().filter(|i| !ended.contains(i)).collect();
        lockstep(&s2, &r2, &running, t + 1)?;
        return Ok(Outcome::Pass(format!(
            "envs {ended:?} ended at step {t} and were reset on the next step"
        )));
    }
    Ok(Outcome::Skip(format!(
        "no episode ended within {steps} steps"
    )))
}

pub(crate) async fn autoreset_disabled(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let n = ctx.num_envs;
    let (h, spec) = ctx.make(n, AutoresetMode::Disabled).await?;
    ensure!(
        spec.autoreset == AutoresetMode::Disabled,
        "spec autoreset {}",
        spec.autoreset
    );
    let steps = match budget(ctx, &spec) {
        Ok(b) => b,
        Err(skip) => return Ok(skip),
    };
    ctx.client
        .reset(&h, &[], &ctx.seeds(0, n))
        .await
        .context("Reset")?;
    let mut sampler = ctx.sampler(&spec, 23)?;
    for t in 0..steps {
        let s = step(&ctx.client, &h, &sampler.sample(n), t).await?;
        let ended = ended_rows(&s);
        if ended.is_empty() {
            continue;
        }
        for attempt in 0..2 {
            expect_code(
                ctx.client.step(&h, &sampler.sample(n)).await,
                Code::FailedPrecondition,
                &format!("step {attempt} after envs {ended:?} ended"),
            )?;
        }
        let idx: Vec<u32> = ended.iter().map(|&i| i as u32).collect();
        let fresh = ctx
            .client
            .reset(&h, &idx, &[])
            .await
            .context("Reset of the ended envs")?;
        ensure!(
            fresh.env_indices == idx,
            "reset of {idx:?} answered for {:?}",
            fresh.env_indices
        );
        step(&ctx.client, &h, &sampler.sample(n), t + 1)
            .await
            .context("step after resetting the ended envs")?;
        return Ok(Outcome::Pass(format!(
            "envs {ended:?} ended at step {t}; stepping was refused until reset"
        )));
    }
    Ok(Outcome::Skip(format!(
        "no episode ended within {steps} steps"
    )))
}
