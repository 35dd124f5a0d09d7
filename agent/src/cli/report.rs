use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;

use crate::report::write_report;

#[derive(Debug, Args)]
pub struct ReportArgs {
    /// Run directories (each with metrics.jsonl); several are overlaid in the curves.
    #[arg(required = true)]
    pub runs: Vec<PathBuf>,
    /// Output directory (default: RUN_DIR/report of the first run).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(a: ReportArgs) -> anyhow::Result<ExitCode> {
    let out = a.out.unwrap_or_else(|| a.runs[0].join("report"));
    let report = write_report(&a.runs, &out)?;
    for run in &report.runs {
        if run.skipped_lines > 0 {
            eprintln!(
                "warning: {}: skipped {} unreadable line(s) of metrics.jsonl",
                run.dir.display(),
                run.skipped_lines
            );
        }
    }
    println!("{}", report.markdown.display());
    for f in &report.figures {
        println!("{}", f.display());
    }
    Ok(ExitCode::SUCCESS)
}
