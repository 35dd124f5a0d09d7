//! `million report`: figures and a markdown page from run directories.
//!
//! Written to the output directory:
//! - `curves.png`: deterministic-evaluation success and first-trial success against agent
//!   steps, one row per split, every run overlaid (and, for ML10/ML45 runs, the reference
//!   results of docs/ALGORITHM.md §7);
//! - `tasks-<run>.png`: per-task success of each run's final evaluation, one panel per split;
//! - `report.md`: a summary table, the figures, and the per-task values.
//!
//! Everything comes from the runs' own files (`metrics.jsonl`, `config.toml`; see
//! [`runs::read_run`]); nothing is re-evaluated.

pub mod plots;
pub mod reference;
pub mod runs;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;

pub use runs::{RunData, read_run};

/// What `write_report` wrote.
#[derive(Debug, Clone)]
pub struct Report {
    pub markdown: PathBuf,
    pub figures: Vec<PathBuf>,
    pub runs: Vec<RunData>,
}

/// A file-name-safe form of a name (runs here, tasks in the videos).
pub(crate) fn slug(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '-'
            }
        })
        .collect()
}

/// "1 h 02 min", "3 min 20 s", "42 s".
pub fn format_duration(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    if s >= 3600 {
        format!("{} h {:02} min", s / 3600, (s % 3600) / 60)
    } else if s >= 60 {
        format!("{} min {:02} s", s / 60, s % 60)
    } else {
        format!("{s} s")
    }
}

/// A success value as the report prints it (3 decimals; "–" when absent).
pub fn fmt_success(v: Option<f64>) -> String {
    v.map_or_else(|| "–".to_owned(), |v| format!("{v:.3}"))
}

/// Reads `run_dirs`, draws the figures into `out`, writes `out/report.md`.
pub fn write_report(run_dirs: &[PathBuf], out: &Path) -> anyhow::Result<Report> {
    anyhow::ensure!(!run_dirs.is_empty(), "name at least one run directory");
    let mut runs = run_dirs
        .iter()
        .map(|d| read_run(d).with_context(|| format!("run {}", d.display())))
        .collect::<anyhow::Result<Vec<_>>>()?;
    // Two runs with the same directory name (runs/a/x, runs/b/x) get their parent added.
    for i in 0..runs.len() {
        if runs.iter().filter(|r| r.name == runs[i].name).count() > 1 {
            let parent = runs[i]
                .dir
                .parent()
                .and_then(|p| p.file_name())
                .map(|p| p.to_string_lossy().into_owned())
                .unwrap_or_else(|| i.to_string());
            runs[i].name = format!("{parent}/{}", runs[i].name);
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut figures = vec![];
    let curves = out.join("curves.png");
    plots::draw_curves(&runs, &curves)?;
    figures.push(curves);
    let mut task_figures = vec![];
    for run in &runs {
        let path = out.join(format!("tasks-{}.png", slug(&run.name)));
        plots::draw_task_bars(run, &path)?;
        task_figures.push(path.clone());
        figures.push(path);
    }
    let markdown = out.join("report.md");
    std::fs::write(&markdown, markdown_text(&runs, &task_figures))
        .with_context(|| format!("cannot write {}", markdown.display()))?;
    Ok(Report {
        markdown,
        figures,
        runs,
    })
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Evaluations averaged for the summary's steadier figures.
const RECENT_EVALS: usize = 3;

fn markdown_text(runs: &[RunData], task_figures: &[PathBuf]) -> String {
    let mut md = String::new();
    let names: Vec<&str> = runs.iter().map(|r| r.name.as_str()).collect();
    let _ = writeln!(md, "# MILLION report: {}\n", names.join(", "));
    let _ = writeln!(
        md,
        "Success is the deterministic evaluation's trial success rate (mean over tasks of each \
         task's successful trials / trials; the policy's mean action). First-trial success \
         counts only the first of the three trials: following the words without trial and \
         error.\n"
    );
    let _ = writeln!(md, "## Summary\n");
    let _ = writeln!(
        md,
        "| run | env | agent steps | wall time | steps/s | train success | test success | \
         train first-trial | test first-trial | test split |"
    );
    let _ = writeln!(md, "|---|---|---:|---:|---:|---:|---:|---:|---:|---|");
    for r in runs {
        let fin = |split: &str| r.final_eval.get(split);
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.name,
            if r.env_id.is_empty() { "?" } else { &r.env_id },
            r.last_step,
            format_duration(r.wall_s),
            r.steps_per_s
                .map_or_else(|| "–".into(), |v| format!("{v:.0}")),
            fmt_success(fin("train").map(|f| f.success)),
            fmt_success(fin("test").map(|f| f.success)),
            fmt_success(fin("train").and_then(|f| f.first_trial)),
            fmt_success(fin("test").and_then(|f| f.first_trial)),
            r.test_split.as_deref().unwrap_or("none"),
        );
    }
    let _ = writeln!(
        md,
        "\nWall time spans the first to the last metrics record; steps/s is agent steps over \
         that span, evaluation included. Final values come from each split's last evaluation \
         record.\n"
    );
    let _ = writeln!(
        md,
        "Steadier figures: the mean of each split's last {RECENT_EVALS} evaluations that carry \
         the figure (the count is in brackets; fewer when fewer were made or recorded it).\n"
    );
    let _ = writeln!(
        md,
        "| run | train success | test success | train first-trial | test first-trial |\n\
         |---|---:|---:|---:|---:|"
    );
    for r in runs {
        let mean = |split: &str, first_trial: bool| {
            r.recent_mean(split, RECENT_EVALS, first_trial)
                .map_or_else(|| "–".into(), |(v, n)| format!("{v:.3} ({n})"))
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            r.name,
            mean("train", false),
            mean("test", false),
            mean("train", true),
            mean("test", true),
        );
    }
    let _ = writeln!(md);
    let _ = writeln!(md, "## Learning curves\n\n![learning curves](curves.png)\n");
    let mut benchmarks: Vec<&str> = runs.iter().filter_map(RunData::benchmark).collect();
    benchmarks.dedup();
    for b in benchmarks {
        let Some(refs) = reference::for_benchmark(b) else {
            continue;
        };
        let _ = writeln!(
            md,
            "Reference results for {b} (docs/ALGORITHM.md §7; dashed lines: final results, markers: \
             the original code's logged runs):\n"
        );
        let _ = writeln!(
            md,
            "| source | agent steps | train | test |\n|---|---:|---:|---:|"
        );
        for f in refs.finals {
            let _ = writeln!(
                md,
                "| {} (final) | – | {:.3} | {:.3} |",
                f.label, f.train, f.test
            );
        }
        for l in refs.logged {
            for p in l.points {
                let _ = writeln!(
                    md,
                    "| {} | {} | {:.2} | {:.2} |",
                    l.label,
                    plots::format_steps(p.step as f64),
                    p.train,
                    p.test
                );
            }
        }
        let _ = writeln!(md);
    }
    let _ = writeln!(md, "## Per-task success (final evaluation)\n");
    for (r, fig) in runs.iter().zip(task_figures) {
        let _ = writeln!(
            md,
            "### {}\n\n![per-task success of {}]({})\n",
            r.name,
            r.name,
            file_name(fig)
        );
        if r.final_eval.is_empty() {
            let _ = writeln!(md, "No evaluation recorded.\n");
            continue;
        }
        let _ = writeln!(
            md,
            "| split | task | success | at agent step |\n|---|---|---:|---:|"
        );
        for (split, fin) in r.final_evals() {
            for (task, v) in &fin.per_task {
                let _ = writeln!(md, "| {split} | {task} | {v:.3} | {} |", fin.step);
            }
        }
        let _ = writeln!(md);
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_well() {
        assert_eq!(format_duration(42.4), "42 s");
        assert_eq!(format_duration(200.0), "3 min 20 s");
        assert_eq!(format_duration(3720.0), "1 h 02 min");
        assert_eq!(fmt_success(None), "–");
        assert_eq!(fmt_success(Some(0.95)), "0.950");
    }
}
