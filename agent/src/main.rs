//! `million`: train, evaluate, benchmark and check env servers (see `million --help`).

use clap::Parser;

fn main() -> std::process::ExitCode {
    million::cli::init_tracing();
    let cli = million::cli::Cli::parse();
    match million::cli::run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
