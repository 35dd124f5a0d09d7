//! Checks of the service surface: handshake, health, discovery, handles, and
//! the error codes of bad input.
use std::collections::BTreeSet;

use anyhow::{Context, bail, ensure};
use tonic::Code;
use tonic_health::pb::health_check_response::ServingStatus;

use super::Outcome;
use super::ctx::{Ctx, expect_code, step_request};
use crate::client::API_VERSION;
use crate::error::code_name;
use crate::proto::{self, session_request::Request, session_response::Response};
use crate::space::{AutoresetMode, EnvSpec};
use crate::tensor::{DType, Tensor};
use crate::value::Value;

pub(crate) async fn handshake(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let reply = ctx
        .client
        .handshake_raw(proto::HandshakeRequest {
            client_version: Some(proto::ApiVersion {
                major: API_VERSION.0,
                minor: API_VERSION.1,
            }),
            client_name: "million-env-check".into(),
        })
        .await?;
    let version = reply.server_version.context("no server_version")?;
    ensure!(
        version.major == API_VERSION.0,
        "server major version {} (expected {})",
        version.major,
        API_VERSION.0
    );
    let caps = reply.capabilities.context("no capabilities")?;
    ensure!(caps.max_envs_per_handle >= 1, "max_envs_per_handle is 0");
    ensure!(caps.max_envs_total >= 1, "max_envs_total is 0");
    ensure!(
        !caps.autoreset_modes.is_empty(),
        "no autoreset modes declared"
    );
    for other in [0, API_VERSION.0 + 1] {
        let r = ctx
            .client
            .handshake_raw(proto::HandshakeRequest {
                client_version: Some(proto::ApiVersion {
                    major: other,
                    minor: 0,
                }),
                client_name: "million-env-check".into(),
            })
            .await;
        expect_code(
            r,
            Code::FailedPrecondition,
            &format!("handshake as major {other}"),
        )?;
    }
    Ok(Outcome::Pass(format!(
        "{} speaks {}.{}",
        reply.server_name, version.major, version.minor
    )))
}

pub(crate) async fn health(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let status = ctx.client.health().await?;
    ensure!(status == ServingStatus::Serving, "health status {status:?}");
    Ok(Outcome::Pass(String::new()))
}

pub(crate) async fn list_envs(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let envs = ctx.client.list_envs().await?;
    ensure!(!envs.is_empty(), "ListEnvs is empty");
    let mut seen = BTreeSet::new();
    for e in &envs {
        ensure!(!e.env_id.is_empty(), "an empty env id is listed");
        ensure!(
            seen.insert(e.env_id.as_str()),
            "{} is listed twice",
            e.env_id
        );
    }
    if seen.contains(ctx.env_id.as_str()) {
        return Ok(Outcome::Pass(format!("{} ids listed", envs.len())));
    }
    ctx.make(1, AutoresetMode::NextStep)
        .await
        .with_context(|| format!("{} is neither listed nor makeable", ctx.env_id))?;
    Ok(Outcome::Pass(format!(
        "{} ids listed; {} is not listed but makeable",
        envs.len(),
        ctx.env_id
    )))
}

pub(crate) async fn close_frees(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let alive = |c: &std::collections::HashMap<String, f64>| -> anyhow::Result<f64> {
        c.get("envs_alive")
            .copied()
            .context("GetStats has no envs_alive counter")
    };
    let n = ctx.num_envs;
    let (handle, spec) = ctx.make(n, AutoresetMode::NextStep).await?;
    let before = alive(&ctx.client.stats().await?)?;
    ensure!(
        before >= n as f64,
        "envs_alive is {before} with {n} envs just made"
    );
    ctx.client.close(&handle).await.context("Close")?;
    let after = alive(&ctx.client.stats().await?)?;
    ensure!(
        after <= before - n as f64,
        "envs_alive went from {before} to {after} on closing {n} envs"
    );
    let action = ctx.sampler(&spec, 1)?.sample(n);
    expect_code(
        ctx.client.step(&handle, &action).await,
        Code::NotFound,
        "Step after Close",
    )?;
    expect_code(
        ctx.client.reset(&handle, &[], &[]).await,
        Code::NotFound,
        "Reset after Close",
    )?;
    expect_code(
        ctx.client.close(&handle).await,
        Code::NotFound,
        "second Close",
    )?;
    Ok(Outcome::Pass(format!("envs_alive {before} -> {after}")))
}

/// A handle of the env under test, reset, ready for a bad step.
async fn ready_handle(ctx: &Ctx) -> anyhow::Result<(String, EnvSpec)> {
    let (handle, spec) = ctx.make(ctx.num_envs, AutoresetMode::SameStep).await?;
    ctx.client
        .reset(&handle, &[], &ctx.seeds(0, ctx.num_envs))
        .await
        .context("Reset")?;
    Ok((handle, spec))
}

/// After a refused request the handle must still step.
async fn still_steps(ctx: &Ctx, handle: &str, spec: &EnvSpec) -> anyhow::Result<()> {
    let action = ctx.sampler(spec, 99)?.sample(ctx.num_envs);
    ctx.client
        .step(handle, &action)
        .await
        .context("a valid step after the refused one")?;
    Ok(())
}

/// Sends each bad action and expects INVALID_ARGUMENT, then a valid step.
async fn refuse_actions(
    ctx: &Ctx,
    handle: &str,
    spec: &EnvSpec,
    bad: Vec<(String, proto::Tensor)>,
) -> anyhow::Result<Outcome> {
    let count = bad.len();
    for (what, tensor) in bad {
        let r = ctx.client.step_raw(step_request(handle, tensor)).await;
        expect_code(r, Code::InvalidArgument, &what)?;
        still_steps(ctx, handle, spec)
            .await
            .with_context(|| format!("after {what}"))?;
    }
    Ok(Outcome::Pass(format!("{count} bad actions refused")))
}

pub(crate) async fn error_wrong_action_shape(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let (handle, spec) = ready_handle(ctx).await?;
    let n = ctx.num_envs;
    let mut sampler = ctx.sampler(&spec, 2)?;
    let good = sampler.sample(n);
    let extra_row = sampler.sample(n + 1);
    let missing_row = sampler.sample(n - 1);
    let mut trailing = good.shape().to_vec();
    trailing.push(1);
    let extra_dim = good.clone().reshape(trailing).map_err(anyhow::Error::msg)?;
    refuse_actions(
        ctx,
        &handle,
        &spec,
        vec![
            (
                format!("action of shape {:?}", extra_row.shape()),
                extra_row.to_proto(),
            ),
            (
                format!("action of shape {:?}", missing_row.shape()),
                missing_row.to_proto(),
            ),
            (
                format!("action of shape {:?}", extra_dim.shape()),
                extra_dim.to_proto(),
            ),
        ],
    )
    .await
}

pub(crate) async fn error_wrong_action_dtype(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let (handle, spec) = ready_handle(ctx).await?;
    let n = ctx.num_envs;
    let good = ctx.sampler(&spec, 3)?.sample(n);
    let values = good.to_f64_vec().map_err(anyhow::Error::msg)?;
    let shape = good.shape().to_vec();
    let other = match good.dtype() {
        DType::Float64 => {
            Tensor::from_f32(shape, &values.iter().map(|&v| v as f32).collect::<Vec<_>>())
        }
        _ => Tensor::from_f64(shape, &values),
    }
    .map_err(anyhow::Error::msg)?;
    let mut short = good.to_proto();
    let item = good.dtype().item_size();
    short.data = short.data.slice(..short.data.len() - item);
    let mut unspecified = good.to_proto();
    unspecified.dtype = proto::DType::DtypeUnspecified as i32;
    refuse_actions(
        ctx,
        &handle,
        &spec,
        vec![
            (
                format!("{} action for a {} space", other.dtype(), good.dtype()),
                other.to_proto(),
            ),
            ("action data one element short".to_owned(), short),
            ("action of DTYPE_UNSPECIFIED".to_owned(), unspecified),
        ],
    )
    .await
}

pub(crate) async fn error_nonfinite_action(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let (handle, spec) = ready_handle(ctx).await?;
    let good = ctx.sampler(&spec, 4)?.sample(ctx.num_envs);
    if !good.dtype().is_float() {
        return Ok(Outcome::Skip(format!(
            "{} actions cannot be non-finite",
            good.dtype()
        )));
    }
    let mut bad = Vec::new();
    for (name, x) in [
        ("NaN", f64::NAN),
        ("+inf", f64::INFINITY),
        ("-inf", f64::NEG_INFINITY),
    ] {
        let mut values = good.to_f64_vec().map_err(anyhow::Error::msg)?;
        let last = values.len() - 1;
        values[last] = x;
        let shape = good.shape().to_vec();
        let t = match good.dtype() {
            DType::Float32 => {
                Tensor::from_f32(shape, &values.iter().map(|&v| v as f32).collect::<Vec<_>>())
            }
            _ => Tensor::from_f64(shape, &values),
        }
        .map_err(anyhow::Error::msg)?;
        bad.push((format!("action with {name}"), t.to_proto()));
    }
    refuse_actions(ctx, &handle, &spec, bad).await
}

pub(crate) async fn error_unknown_env_id(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let r = ctx
        .client
        .make(
            "MillionNoSuchEnv-v0",
            &Default::default(),
            1,
            AutoresetMode::NextStep,
        )
        .await;
    if let Ok((h, _)) = &r {
        ctx.track(&ctx.client, h);
    }
    expect_code(r, Code::InvalidArgument, "Make of an unknown env id")?;
    Ok(Outcome::Pass(String::new()))
}

pub(crate) async fn error_bad_kwargs(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let mut kwargs = ctx.kwargs.clone();
    kwargs.insert("million_no_such_kwarg".into(), Value::Int(1));
    let r = ctx
        .client
        .make(&ctx.env_id, &kwargs, 1, AutoresetMode::NextStep)
        .await;
    if let Ok((h, _)) = &r {
        ctx.track(&ctx.client, h);
    }
    expect_code(r, Code::InvalidArgument, "Make with an unknown kwarg")?;
    Ok(Outcome::Pass(String::new()))
}

pub(crate) async fn error_unknown_handle(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let handle = format!("million-no-such-handle-{:016x}", rand::random::<u64>());
    let action = Tensor::zeros(DType::Float32, vec![1, 1]);
    expect_code(
        ctx.client.reset(&handle, &[], &[]).await,
        Code::NotFound,
        "Reset",
    )?;
    expect_code(
        ctx.client.step(&handle, &action).await,
        Code::NotFound,
        "Step",
    )?;
    expect_code(ctx.client.close(&handle).await, Code::NotFound, "Close")?;
    Ok(Outcome::Pass(String::new()))
}

pub(crate) async fn error_closed_handle(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let (handle, spec) = ready_handle(ctx).await?;
    ctx.client.close(&handle).await.context("Close")?;
    let action = ctx.sampler(&spec, 5)?.sample(ctx.num_envs);
    expect_code(
        ctx.client.step(&handle, &action).await,
        Code::NotFound,
        "Step of a closed handle",
    )?;
    Ok(Outcome::Pass(String::new()))
}

pub(crate) async fn error_step_before_reset(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let (handle, spec) = ctx.make(ctx.num_envs, AutoresetMode::SameStep).await?;
    let action = ctx.sampler(&spec, 6)?.sample(ctx.num_envs);
    expect_code(
        ctx.client.step(&handle, &action).await,
        Code::FailedPrecondition,
        "Step before Reset",
    )?;
    ctx.client
        .reset(&handle, &[], &[])
        .await
        .context("Reset after the refused step")?;
    still_steps(ctx, &handle, &spec).await?;
    Ok(Outcome::Pass(String::new()))
}

pub(crate) async fn error_oversized_batch(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let request = |n: u32| proto::MakeRequest {
        env_id: ctx.env_id.clone(),
        kwargs: crate::value::kwargs_to_proto(&ctx.kwargs),
        num_envs: n,
        autoreset_mode: proto::AutoresetMode::SameStep as i32,
    };
    let zero = ctx.client.make_raw(request(0)).await;
    if let Ok(r) = &zero {
        ctx.track(&ctx.client, &r.handle);
    }
    expect_code(zero, Code::InvalidArgument, "Make with num_envs 0")?;
    let max = ctx.client.server().max_envs_per_handle;
    let Some(over) = max.checked_add(1) else {
        return Ok(Outcome::Pass(
            "num_envs 0 refused; max_envs_per_handle is u32::MAX, nothing is above it".into(),
        ));
    };
    let big = ctx.client.make_raw(request(over)).await;
    if let Ok(r) = &big {
        ctx.track(&ctx.client, &r.handle);
    }
    expect_code(
        big,
        Code::ResourceExhausted,
        &format!("Make with num_envs {over} (max {max})"),
    )?;
    Ok(Outcome::Pass(format!("max_envs_per_handle {max}")))
}

pub(crate) async fn error_in_stream_continues(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let (handle, spec) = ctx.make(ctx.num_envs, AutoresetMode::SameStep).await?;
    let n = ctx.num_envs;
    let mut sampler = ctx.sampler(&spec, 7)?;
    let bad = sampler.sample(n + 1).to_proto();
    let good = sampler.sample(n).to_proto();
    let unknown = format!("million-no-such-handle-{:016x}", rand::random::<u64>());
    let mut session = ctx.client.session();
    session.send_with_id(
        1,
        Request::Reset(crate::client::reset_request(&handle, &[], &[])),
    )?;
    session.send_with_id(2, Request::Step(step_request(&handle, bad.clone())))?;
    session.send_with_id(3, Request::Step(step_request(&handle, good.clone())))?;
    session.send_with_id(4, Request::Step(step_request(&unknown, good.clone())))?;
    session.send_with_id(5, Request::Step(step_request(&handle, good)))?;
    let mut replies = Vec::new();
    for _ in 0..5 {
        replies.push(session.recv_raw().await?);
    }
    let ids: Vec<u64> = replies.iter().map(|r| r.request_id).collect();
    ensure!(
        ids == [1, 2, 3, 4, 5],
        "request ids {ids:?}, expected [1, 2, 3, 4, 5]"
    );
    let unary_bad = ctx.client.step_raw(step_request(&handle, bad)).await;
    let unary_code = unary_bad
        .err()
        .and_then(|e| e.code())
        .context("the unary bad step succeeded")?;
    for (i, want) in [(1, unary_code), (3, Code::NotFound)] {
        match &replies[i].response {
            Some(Response::Error(e)) => ensure!(
                Code::from(e.code) == want,
                "request {}: in-stream error {} ({}), the unary call gives {}",
                i + 1,
                code_name(Code::from(e.code)),
                e.message,
                code_name(want)
            ),
            other => bail!("request {}: expected an error reply, got {other:?}", i + 1),
        }
    }
    ensure!(
        matches!(replies[0].response, Some(Response::Reset(_))),
        "request 1 was not answered by a reset"
    );
    for i in [2, 4] {
        ensure!(
            matches!(replies[i].response, Some(Response::Step(_))),
            "request {} after an error was not answered by a step: {:?}",
            i + 1,
            replies[i].response
        );
    }
    Ok(Outcome::Pass(format!(
        "in-stream error code {}",
        code_name(unary_code)
    )))
}

pub(crate) async fn server_survives_bad_input(ctx: &Ctx) -> anyhow::Result<Outcome> {
    let client = ctx
        .second_client()
        .await
        .context("reconnecting after the bad-input checks")?;
    let status = client.health().await?;
    ensure!(status == ServingStatus::Serving, "health {status:?}");
    let n = ctx.num_envs;
    let (handle, spec) = ctx.make_on(&client, n, AutoresetMode::SameStep).await?;
    let reset = client
        .reset(&handle, &[], &ctx.seeds(0, n))
        .await
        .context("Reset")?;
    reset
        .obs
        .conforms_to(&spec.observation_space, n)
        .map_err(anyhow::Error::msg)?;
    let mut sampler = ctx.sampler(&spec, 8)?;
    for t in 0..5 {
        let s = super::ctx::step(&client, &handle, &sampler.sample(n), t).await?;
        s.obs
            .conforms_to(&spec.observation_space, n)
            .map_err(anyhow::Error::msg)
            .with_context(|| format!("step {t}"))?;
    }
    Ok(Outcome::Pass(String::new()))
}
