//! The conformance checks from the command line, as `million env-check` runs them:
//!
//! ```text
//! cargo run -p million-env --example env_check -- --env-server HOST:PORT \
//!     [--env ID[:key=value,...] ...] [--json]
//! ```
//! Without `--env`, runs the default env ids. Exits non-zero when a check fails.
use std::process::ExitCode;

use million_env::conformance::{DEFAULT_ENV_IDS, run_conformance};
use million_env::parse_env_case;

#[tokio::main]
async fn main() -> ExitCode {
    let mut server = None;
    let mut cases = Vec::new();
    let mut json = false;
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        match (flag.as_str(), flag.as_str() == "--json") {
            (_, true) => json = true,
            ("--env-server", _) => server = it.next(),
            ("--env", _) => match it.next().map(|c| parse_env_case(&c)) {
                Some(Ok(case)) => cases.push(case),
                Some(Err(e)) => {
                    eprintln!("{e}");
                    return ExitCode::from(2);
                }
                None => {
                    eprintln!("--env needs a value");
                    return ExitCode::from(2);
                }
            },
            _ => {
                eprintln!(
                    "usage: env_check --env-server HOST:PORT [--env ID[:k=v,...]]... [--json]"
                );
                return ExitCode::from(2);
            }
        }
    }
    let Some(server) = server else {
        eprintln!("--env-server HOST:PORT is required");
        return ExitCode::from(2);
    };
    if cases.is_empty() {
        cases = DEFAULT_ENV_IDS
            .iter()
            .map(|id| parse_env_case(id).expect("default ids parse"))
            .collect();
    }
    let mut ok = true;
    for (env_id, kwargs) in cases {
        let report = run_conformance(&server, &env_id, kwargs).await;
        ok &= report.passed();
        if json {
            println!("{}", report.to_json());
        } else {
            println!("{report}\n");
        }
    }
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
