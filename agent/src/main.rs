//! `million`: the MILLION agent's command line. Subcommands are added as the training loop,
//! evaluation and env checks land.

use clap::Parser;

#[derive(Debug, Parser)]
#[command(name = "million", version, about = "The MILLION meta-RL agent")]
struct Cli {
    /// Agent config (TOML) to validate and print.
    #[arg(long)]
    check_config: Option<std::path::PathBuf>,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    if let Some(path) = cli.check_config {
        let cfg = million::config::AgentConfig::from_file(&path)?;
        println!("{cfg:#?}");
    }
    Ok(())
}
