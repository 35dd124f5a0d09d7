//! `million bench script NAME [ARGS]...`: the env server's Python benchmarks (bench/env/),
//! so that every benchmark starts from `million bench`. Each is a standalone script with its
//! own arguments and output; this runs it with the repository's Python, passes ARGS through
//! untouched and exits with its status, so a script behaves as if run by hand.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use anyhow::Context;
use clap::{Args, Subcommand};
use million_env::find_in_repository;

#[derive(Debug, Args)]
#[command(
    disable_help_subcommand = true,
    subcommand_value_name = "NAME",
    subcommand_help_heading = "Benchmarks"
)]
pub struct ScriptBench {
    /// Python that runs the script (default: the repository's .venv, else python3); before
    /// NAME, since everything after NAME is the script's.
    #[arg(long)]
    pub python: Option<PathBuf>,
    #[command(subcommand)]
    pub script: Script,
}

/// The script's own arguments. Its name takes no help flag of its own, so that `NAME
/// --help` reaches the script and prints its options.
#[derive(Debug, Args)]
#[command(disable_help_flag = true)]
pub struct ScriptArgs {
    #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
    pub args: Vec<String>,
}

#[derive(Debug, Subcommand)]
pub enum Script {
    /// Peak memory per env slot of one env server, builds and XML compiles per episode
    /// (bench/env/server_memory.py).
    ServerMemory(ScriptArgs),
    /// Meta-World's step and reset with and without the server's fast paths, per task class
    /// (bench/env/fast_paths.py).
    FastPaths(ScriptArgs),
    /// Agent steps/s of million/ML10-train against raw Meta-World on the same tasks: the
    /// protocol's cost (bench/env/million_steprate.py).
    MillionSteprate(ScriptArgs),
    /// The same envs as a server serves, stepped in-process: `bench env`'s yardstick
    /// (bench/env/inprocess_rate.py).
    InprocessRate(ScriptArgs),
    /// Served (Python client: unary Step and the Session stream) against in-process steps/s
    /// on Meta-World reach-v3 (bench/env/step_rate.py).
    StepRate(ScriptArgs),
}

impl Script {
    /// The script's path in the repository and its arguments.
    fn parts(&self) -> (&'static str, &[String]) {
        match self {
            Script::ServerMemory(a) => ("bench/env/server_memory.py", &a.args),
            Script::FastPaths(a) => ("bench/env/fast_paths.py", &a.args),
            Script::MillionSteprate(a) => ("bench/env/million_steprate.py", &a.args),
            Script::InprocessRate(a) => ("bench/env/inprocess_rate.py", &a.args),
            Script::StepRate(a) => ("bench/env/step_rate.py", &a.args),
        }
    }
}

pub fn run(b: &ScriptBench) -> anyhow::Result<ExitCode> {
    let (rel, args) = b.script.parts();
    let script = find_in_repository(Path::new(rel))
        .with_context(|| format!("{rel} not found (set MILLION_ROOT)"))?;
    let python = super::python(b.python.as_deref());
    let status = Command::new(&python)
        .arg(&script)
        .args(args)
        .status()
        .with_context(|| format!("cannot run {} (pass --python)", python.display()))?;
    // A script killed by a signal has no code; it failed all the same.
    Ok(match status.code() {
        Some(0) => ExitCode::SUCCESS,
        Some(code) => ExitCode::from(u8::try_from(code).unwrap_or(1)),
        None => ExitCode::FAILURE,
    })
}
