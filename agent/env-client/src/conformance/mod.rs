//! The contract of the env API as checks run against a live server: the
//! `env-check` runner of `tests/contract/checks.toml`.
//!
//! The check list is compiled in from `checks.toml`, the single source of truth
//! shared with the pytest runner; a unit test fails when the checks implemented
//! here differ from the ones listed for `env-check`. Checks are generic over
//! env ids: flat and Dict observations, Box and Discrete actions.
mod checks_api;
mod checks_data;
mod checks_episodes;
mod ctx;

use std::fmt;
use std::time::{Duration, Instant};

use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};

use crate::client::{ClientConfig, EnvClient};
use crate::value::{Kwargs, Value};
use ctx::Ctx;

/// `tests/contract/checks.toml`, compiled in.
pub const CHECKS_TOML: &str = include_str!("../../../../tests/contract/checks.toml");

/// The name this runner has in `checks.toml`'s `runners` lists.
pub const RUNNER: &str = "env-check";

/// Env ids `million env-check` runs when none is given: a Box-action and a
/// Discrete-action env every Gymnasium install has.
pub const DEFAULT_ENV_IDS: [&str; 2] = ["Pendulum-v1", "CartPole-v1"];

/// One entry of `checks.toml`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct CheckDef {
    pub id: String,
    pub summary: String,
    #[serde(default)]
    pub runners: Option<Vec<String>>,
    #[serde(default)]
    pub status: Option<String>,
}

#[derive(Deserialize)]
struct CheckFile {
    check: Vec<CheckDef>,
}

/// Every check of `checks.toml`.
pub fn all_checks() -> Vec<CheckDef> {
    toml::from_str::<CheckFile>(CHECKS_TOML)
        .expect("checks.toml is valid (a unit test parses it)")
        .check
}

/// The checks this runner must implement, in file order.
pub fn listed_checks() -> Vec<CheckDef> {
    all_checks()
        .into_iter()
        .filter(|c| {
            c.runners
                .as_ref()
                .is_none_or(|r| r.iter().any(|r| r == RUNNER))
        })
        .collect()
}

/// How one check ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Pass,
    Fail,
    /// Not applicable to this env (e.g. non-finite actions of a Discrete space).
    Skip,
}

/// What a check returns when it did not fail.
#[derive(Debug)]
pub(crate) enum Outcome {
    Pass(String),
    Skip(String),
}

#[derive(Clone, Debug, Serialize)]
pub struct CheckResult {
    pub id: String,
    pub summary: String,
    pub status: Status,
    pub message: String,
    pub seconds: f64,
}

/// The result of a conformance run.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub server: String,
    pub env_id: String,
    pub kwargs: String,
    pub results: Vec<CheckResult>,
}

impl Report {
    /// True when no check failed (skipped ones do not count as failures).
    pub fn passed(&self) -> bool {
        self.results.iter().all(|r| r.status != Status::Fail)
    }

    pub fn failures(&self) -> impl Iterator<Item = &CheckResult> {
        self.results.iter().filter(|r| r.status == Status::Fail)
    }

    pub fn get(&self, id: &str) -> Option<&CheckResult> {
        self.results.iter().find(|r| r.id == id)
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a report serialises")
    }
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "env-check of {} on {}{}",
            self.env_id, self.server, self.kwargs
        )?;
        for r in &self.results {
            let tag = match r.status {
                Status::Pass => "PASS",
                Status::Fail => "FAIL",
                Status::Skip => "SKIP",
            };
            write!(f, "  {tag}  {:<32} {:>6.2}s", r.id, r.seconds)?;
            if !r.message.is_empty() {
                write!(f, "  {}", r.message)?;
            }
            writeln!(f)?;
        }
        let count = |s| self.results.iter().filter(|r| r.status == s).count();
        write!(
            f,
            "{} passed, {} failed, {} skipped",
            count(Status::Pass),
            count(Status::Fail),
            count(Status::Skip)
        )
    }
}

/// Settings of a run.
#[derive(Clone, Debug)]
pub struct ConformanceOptions {
    pub server: String,
    pub env_id: String,
    pub kwargs: Kwargs,
    /// Envs per handle in the checks (at least 3, so subsets can be reordered).
    pub num_envs: usize,
    pub seed: u64,
    pub client: ClientConfig,
    /// A check taking longer fails.
    pub check_timeout: Duration,
    /// Checks that need episodes to end step at most this many times (and are
    /// skipped for envs whose time limit is longer).
    pub max_steps: u64,
}

impl ConformanceOptions {
    pub fn new(server: impl Into<String>, env_id: impl Into<String>, kwargs: Kwargs) -> Self {
        let mut client = ClientConfig {
            client_name: concat!("million-env-check/", env!("CARGO_PKG_VERSION")).into(),
            ..ClientConfig::default()
        };
        // A server that is not up within this budget is reported, not awaited.
        client.retry.max_elapsed = Duration::from_secs(10);
        ConformanceOptions {
            server: server.into(),
            env_id: env_id.into(),
            kwargs,
            num_envs: 3,
            seed: 20_230_529,
            client,
            check_timeout: Duration::from_secs(300),
            max_steps: 20_000,
        }
    }
}

/// Runs every `env-check` check against `server` for `env_id`.
pub async fn run_conformance(server: &str, env_id: &str, kwargs: Kwargs) -> Report {
    run_conformance_with(ConformanceOptions::new(server, env_id, kwargs)).await
}

pub async fn run_conformance_with(opts: ConformanceOptions) -> Report {
    let kwargs = if opts.kwargs.is_empty() {
        String::new()
    } else {
        format!(" with {}", Value::Map(opts.kwargs.clone()))
    };
    let mut report = Report {
        server: opts.server.clone(),
        env_id: opts.env_id.clone(),
        kwargs,
        results: Vec::new(),
    };
    let listed = listed_checks();
    let client = match EnvClient::connect(&opts.server, opts.client.clone()).await {
        Ok(c) => c,
        Err(e) => {
            for def in listed {
                report.results.push(CheckResult {
                    id: def.id,
                    summary: def.summary,
                    status: Status::Fail,
                    message: format!("could not connect: {e}"),
                    seconds: 0.0,
                });
            }
            return report;
        }
    };
    let ctx = Ctx::new(client, &opts);
    // Bad-input checks run before the survival check, whatever the file order.
    let (last, first): (Vec<_>, Vec<_>) = listed
        .into_iter()
        .partition(|d| d.id == "server_survives_bad_input");
    for def in first.into_iter().chain(last) {
        let start = Instant::now();
        let (status, message) = match dispatch(&def.id, &ctx) {
            None => (Status::Fail, "not implemented by this runner".to_owned()),
            Some(fut) => match tokio::time::timeout(opts.check_timeout, fut).await {
                Ok(Ok(Outcome::Pass(m))) => (Status::Pass, m),
                Ok(Ok(Outcome::Skip(m))) => (Status::Skip, m),
                Ok(Err(e)) => (Status::Fail, format!("{e:#}")),
                Err(_) => (
                    Status::Fail,
                    format!("did not finish within {:?}", opts.check_timeout),
                ),
            },
        };
        ctx.close_opened().await;
        tracing::debug!(id = %def.id, ?status, %message, "check done");
        report.results.push(CheckResult {
            id: def.id,
            summary: def.summary,
            status,
            message,
            seconds: start.elapsed().as_secs_f64(),
        });
    }
    report
}

/// The implemented checks: one list gives both the dispatcher and the ids.
macro_rules! registry {
    ($($id:literal => $f:path),* $(,)?) => {
        /// Ids of the checks this runner implements.
        pub const IMPLEMENTED: &[&str] = &[$($id),*];

        fn dispatch<'a>(id: &str, ctx: &'a Ctx) -> Option<BoxFuture<'a, anyhow::Result<Outcome>>> {
            match id {
                $($id => Some(Box::pin($f(ctx))),)*
                _ => None,
            }
        }
    };
}

registry! {
    "handshake" => checks_api::handshake,
    "health" => checks_api::health,
    "list_envs" => checks_api::list_envs,
    "spec_matches_data" => checks_data::spec_matches_data,
    "reset_rows" => checks_data::reset_rows,
    "step_rows" => checks_data::step_rows,
    "terminated_truncated_distinct" => checks_episodes::terminated_truncated_distinct,
    "autoreset_next_step" => checks_episodes::autoreset_next_step,
    "autoreset_same_step" => checks_episodes::autoreset_same_step,
    "autoreset_disabled" => checks_episodes::autoreset_disabled,
    "seed_determinism" => checks_data::seed_determinism,
    "session_stream" => checks_data::session_stream,
    "concurrent_isolation" => checks_data::concurrent_isolation,
    "close_frees" => checks_api::close_frees,
    "error_wrong_action_shape" => checks_api::error_wrong_action_shape,
    "error_wrong_action_dtype" => checks_api::error_wrong_action_dtype,
    "error_nonfinite_action" => checks_api::error_nonfinite_action,
    "error_unknown_env_id" => checks_api::error_unknown_env_id,
    "error_bad_kwargs" => checks_api::error_bad_kwargs,
    "error_unknown_handle" => checks_api::error_unknown_handle,
    "error_closed_handle" => checks_api::error_closed_handle,
    "error_step_before_reset" => checks_api::error_step_before_reset,
    "error_oversized_batch" => checks_api::error_oversized_batch,
    "error_in_stream_continues" => checks_api::error_in_stream_continues,
    "server_survives_bad_input" => checks_api::server_survives_bad_input,
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;
    use crate::error::code_from_name;

    #[test]
    fn implemented_checks_are_exactly_the_listed_ones() {
        let listed: BTreeSet<String> = listed_checks().into_iter().map(|c| c.id).collect();
        let implemented: BTreeSet<String> = IMPLEMENTED.iter().map(|s| s.to_string()).collect();
        let missing: Vec<_> = listed.difference(&implemented).collect();
        let extra: Vec<_> = implemented.difference(&listed).collect();
        assert!(
            missing.is_empty() && extra.is_empty(),
            "checks.toml lists {missing:?} that env-check lacks; env-check has {extra:?} that checks.toml does not list for it"
        );
        assert_eq!(IMPLEMENTED.len(), listed.len(), "no id registered twice");
    }

    #[test]
    fn check_file_is_well_formed() {
        let all = all_checks();
        let ids: BTreeSet<&str> = all.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids.len(), all.len(), "check ids are unique");
        for c in &all {
            if let Some(s) = &c.status {
                assert!(code_from_name(s).is_some(), "{}: unknown status {s}", c.id);
            }
        }
        // The pytest-only check exists and is excluded from this runner.
        assert!(ids.contains("metaworld_in_process_equal"));
        assert!(
            !listed_checks()
                .iter()
                .any(|c| c.id == "metaworld_in_process_equal")
        );
    }

    #[test]
    fn report_prints_and_serialises() {
        let report = Report {
            server: "127.0.0.1:1".into(),
            env_id: "X-v0".into(),
            kwargs: String::new(),
            results: vec![
                CheckResult {
                    id: "health".into(),
                    summary: "s".into(),
                    status: Status::Pass,
                    message: String::new(),
                    seconds: 0.1,
                },
                CheckResult {
                    id: "handshake".into(),
                    summary: "s".into(),
                    status: Status::Fail,
                    message: "boom".into(),
                    seconds: 0.2,
                },
            ],
        };
        assert!(!report.passed());
        let text = report.to_string();
        assert!(
            text.contains("FAIL  handshake") && text.contains("1 passed, 1 failed"),
            "{text}"
        );
        let json: serde_json::Value = serde_json::from_str(&report.to_json()).unwrap();
        assert_eq!(json["results"][1]["status"], "fail");
    }
}
