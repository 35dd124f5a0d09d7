//! `million config`: the run config a file resolves to, `base =` chain and defaults applied,
//! as the run would use it (and write to its run folder's config.toml).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;

use crate::run_config::RunConfig;

#[derive(Debug, Args)]
pub struct ConfigArgs {
    /// Run config (TOML), e.g. configs/ml10.toml.
    #[arg(long)]
    pub config: PathBuf,
}

pub fn run(args: ConfigArgs) -> anyhow::Result<ExitCode> {
    let cfg = RunConfig::from_file(&args.config)?;
    print!("{}", toml::to_string(&cfg)?);
    Ok(ExitCode::SUCCESS)
}
