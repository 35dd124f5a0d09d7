use std::process::ExitCode;

use clap::Args;
use million_env::conformance::{ConformanceOptions, run_conformance_with};
use million_env::parse_env_case;

use crate::cli::access::EnvAccessArgs;

#[derive(Debug, Args)]
pub struct EnvCheckArgs {
    /// host:port of the env server to check.
    #[arg(long = "env-server")]
    pub env_server: String,
    /// Env id, optionally with kwargs as `ID:key=value,key=value` (as pytest tests/contract); repeatable.
    #[arg(long = "env", default_value = "million/PointGoal")]
    pub envs: Vec<String>,
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub access: EnvAccessArgs,
}

pub fn run(a: EnvCheckArgs) -> anyhow::Result<ExitCode> {
    let access = a.access.resolve()?;
    let rt = super::runtime(1)?;
    let mut all_passed = true;
    let mut reports = vec![];
    for case in &a.envs {
        let (env_id, kwargs) =
            parse_env_case(case).map_err(|e| anyhow::anyhow!("--env {case:?}: {e}"))?;
        let mut options = ConformanceOptions::new(&a.env_server, env_id, kwargs);
        options.client.token = access.token.clone();
        options.client.tls = access.tls.clone();
        let report = rt.block_on(run_conformance_with(options));
        all_passed &= report.passed();
        if a.json {
            reports.push(serde_json::from_str::<serde_json::Value>(
                &report.to_json(),
            )?);
        } else {
            println!("{report}");
        }
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
    }
    Ok(if all_passed {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
