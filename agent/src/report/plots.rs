//! The report's PNG figures, drawn with plotters' bitmap backend and the embedded font.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::font::{FAMILY, ensure_registered};
use crate::report::reference::{self, References};
use crate::report::runs::RunData;

/// Distinct line colours (matplotlib's tab10), one per run.
pub const RUN_COLOURS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];
const REFERENCE_COLOUR: RGBColor = RGBColor(60, 60, 60);

fn colour(i: usize) -> RGBColor {
    RUN_COLOURS[i % RUN_COLOURS.len()]
}

type DrawResult<T> = Result<T, Box<dyn std::error::Error>>;

fn err(e: Box<dyn std::error::Error>) -> anyhow::Error {
    anyhow::anyhow!("drawing failed: {e}")
}

/// "1.5k", "20M", "400M": agent steps for axis labels.
pub fn format_steps(steps: f64) -> String {
    let (value, unit) = if steps >= 1e9 {
        (steps / 1e9, "G")
    } else if steps >= 1e6 {
        (steps / 1e6, "M")
    } else if steps >= 1e3 {
        (steps / 1e3, "k")
    } else {
        (steps, "")
    };
    let text = if (value - value.round()).abs() < 0.05 {
        format!("{value:.0}")
    } else {
        format!("{value:.1}")
    };
    format!("{text}{unit}")
}

/// How the step axis is drawn: linear, or log10 when reference points lie far beyond the
/// runs (a short run next to the 400M-step references would otherwise be a dot).
#[derive(Debug, Clone, Copy)]
struct StepAxis {
    log: bool,
    lo: f64,
    hi: f64,
}

impl StepAxis {
    fn new(run_steps: &[u64], reference_steps: &[u64]) -> Self {
        let run_max = run_steps.iter().copied().max().unwrap_or(1).max(1) as f64;
        let run_min = run_steps
            .iter()
            .copied()
            .filter(|&s| s > 0)
            .min()
            .unwrap_or(1) as f64;
        let ref_max = reference_steps.iter().copied().max().unwrap_or(0) as f64;
        if ref_max > 10.0 * run_max {
            let lo = run_min.min(ref_max).log10().floor();
            Self {
                log: true,
                lo,
                hi: ref_max.log10() + 0.15,
            }
        } else {
            Self {
                log: false,
                lo: 0.0,
                hi: run_max.max(ref_max) * 1.03,
            }
        }
    }

    fn x(&self, step: u64) -> f64 {
        if self.log {
            (step.max(1) as f64).log10()
        } else {
            step as f64
        }
    }

    fn label(&self, x: f64) -> String {
        if self.log {
            format_steps(10f64.powf(x))
        } else {
            format_steps(x)
        }
    }

    fn description(&self) -> &'static str {
        if self.log {
            "agent steps (log scale)"
        } else {
            "agent steps"
        }
    }
}

/// The learning-curve figure: one row per split, success and first-trial success side by
/// side, every run overlaid in its colour, and the ML10/ML45 references on success panels.
pub fn draw_curves(runs: &[RunData], path: &Path) -> anyhow::Result<()> {
    ensure_registered();
    let mut splits: Vec<String> = vec!["train".into()];
    for run in runs {
        for s in run.splits() {
            if !splits.iter().any(|x| x == s) {
                splits.push(s.to_owned());
            }
        }
    }
    let refs: Vec<&References> = {
        let mut r: Vec<&References> = runs
            .iter()
            .filter_map(|run| reference::for_benchmark(run.benchmark()?))
            .collect();
        r.dedup_by_key(|x| x.benchmark);
        r
    };
    let run_steps: Vec<u64> = runs
        .iter()
        .flat_map(|r| r.curves.values().flatten().map(|p| p.step))
        .chain(runs.iter().map(|r| r.last_step))
        .collect();
    let ref_steps: Vec<u64> = refs
        .iter()
        .flat_map(|r| {
            r.logged
                .iter()
                .flat_map(|l| l.points.iter().map(|p| p.step))
        })
        .collect();
    let axis = StepAxis::new(&run_steps, &ref_steps);
    let (w, h) = (1400u32, 460 * splits.len() as u32 + 60);
    let root = BitMapBackend::new(path, (w, h)).into_drawing_area();
    (|| -> DrawResult<()> {
        root.fill(&WHITE)?;
        let title = format!(
            "Deterministic evaluation: {}",
            runs.iter()
                .map(|r| r.name.as_str())
                .collect::<Vec<_>>()
                .join(" vs ")
        );
        let root = root.titled(&title, (FAMILY, 26).into_font())?;
        let panels = root.split_evenly((splits.len(), 2));
        for (row, split) in splits.iter().enumerate() {
            for (col, first_trial) in [false, true].into_iter().enumerate() {
                let area = &panels[row * 2 + col];
                curve_panel(area, runs, split, first_trial, &refs, axis)?;
            }
        }
        root.present()?;
        Ok(())
    })()
    .map_err(err)
}

fn curve_panel(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    runs: &[RunData],
    split: &str,
    first_trial: bool,
    refs: &[&References],
    axis: StepAxis,
) -> DrawResult<()> {
    let what = if first_trial {
        "first-trial success"
    } else {
        "success (all trials)"
    };
    let mut chart = ChartBuilder::on(area)
        .caption(format!("{split} split: {what}"), (FAMILY, 20))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(axis.lo..axis.hi, 0f64..1.02f64)?;
    chart
        .configure_mesh()
        .x_desc(axis.description())
        .y_desc(if first_trial {
            "first-trial success rate"
        } else {
            "trial success rate"
        })
        .x_label_formatter(&|x| axis.label(*x))
        .y_label_formatter(&|y| format!("{y:.1}"))
        .label_style((FAMILY, 14))
        .axis_desc_style((FAMILY, 16))
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    let mut any = false;
    for (i, run) in runs.iter().enumerate() {
        let points: Vec<(f64, f64)> = run
            .curves
            .get(split)
            .into_iter()
            .flatten()
            .filter_map(|p| {
                let y = if first_trial {
                    p.first_trial?
                } else {
                    p.success
                };
                Some((axis.x(p.step), y))
            })
            .collect();
        if points.is_empty() {
            continue;
        }
        any = true;
        let c = colour(i);
        chart
            .draw_series(LineSeries::new(points.clone(), c.stroke_width(2)))?
            .label(run.name.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], c.stroke_width(3)));
        chart.draw_series(
            points
                .iter()
                .map(|&(x, y)| Circle::new((x, y), 3, c.filled())),
        )?;
    }
    if !first_trial {
        for r in refs {
            for (k, fin) in r.finals.iter().enumerate() {
                let Some(y) = fin.value(split) else { continue };
                let style = REFERENCE_COLOUR.mix(if k == 0 { 0.9 } else { 0.5 });
                chart
                    .draw_series(DashedLineSeries::new(
                        [(axis.lo, y), (axis.hi, y)],
                        8,
                        5,
                        style.stroke_width(2),
                    ))?
                    .label(format!("{} {} (final)", r.benchmark, fin.label))
                    .legend(move |(x, y)| {
                        PathElement::new([(x, y), (x + 20, y)], style.stroke_width(2))
                    });
            }
            for (k, logged) in r.logged.iter().enumerate() {
                let pts: Vec<(f64, f64)> = logged
                    .points
                    .iter()
                    .filter_map(|p| Some((axis.x(p.step), p.value(split)?)))
                    .collect();
                let style = REFERENCE_COLOUR;
                if k % 2 == 0 {
                    chart
                        .draw_series(
                            pts.iter()
                                .map(|&(x, y)| Cross::new((x, y), 6, style.stroke_width(2))),
                        )?
                        .label(format!("{} {}", r.benchmark, logged.label))
                        .legend(move |(x, y)| Cross::new((x + 10, y), 6, style.stroke_width(2)));
                } else {
                    chart
                        .draw_series(
                            pts.iter().map(|&(x, y)| {
                                TriangleMarker::new((x, y), 6, style.stroke_width(2))
                            }),
                        )?
                        .label(format!("{} {}", r.benchmark, logged.label))
                        .legend(move |(x, y)| {
                            TriangleMarker::new((x + 10, y), 6, style.stroke_width(2))
                        });
                }
            }
        }
    }
    if any || (!first_trial && !refs.is_empty()) {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font((FAMILY, 14))
            .draw()?;
    }
    if !any {
        area.draw(&Text::new(
            format!("no {split} evaluation recorded"),
            (
                area.dim_in_pixel().0 as i32 / 2 - 100,
                area.dim_in_pixel().1 as i32 / 2,
            ),
            (FAMILY, 18).into_font().color(&BLACK.mix(0.6)),
        ))?;
    }
    Ok(())
}

/// Height in pixels of the per-task panel of `tasks` tasks.
fn task_panel_height(tasks: usize) -> u32 {
    110 + 24 * tasks.max(1) as u32
}

/// Per-task success bars of one run's final evaluation: one panel per split (train above
/// test), one bar per task (alphabetical, top to bottom) with its value at the end. A panel
/// grows with its number of tasks, so one task and ML45's 45 train tasks both read well.
pub fn draw_task_bars(run: &RunData, path: &Path) -> anyhow::Result<()> {
    ensure_registered();
    let splits = run.final_evals();
    let longest = splits
        .iter()
        .flat_map(|(_, f)| f.per_task.keys().map(|k| k.chars().count()))
        .max()
        .unwrap_or(4);
    let title_h = 40u32;
    let w = 900u32;
    let h = title_h
        + splits
            .iter()
            .map(|(_, f)| task_panel_height(f.per_task.len()))
            .sum::<u32>()
            .max(task_panel_height(1));
    let root = BitMapBackend::new(path, (w, h)).into_drawing_area();
    (|| -> DrawResult<()> {
        root.fill(&WHITE)?;
        let mut rest = root.titled(
            &format!("{}: per-task success, final evaluation", run.name),
            (FAMILY, 22).into_font(),
        )?;
        if splits.is_empty() {
            rest.draw(&Text::new(
                "no evaluation recorded",
                (20, 40),
                (FAMILY, 18).into_font(),
            ))?;
        }
        for (split, fin) in &splits {
            let (area, below) = rest.split_vertically(task_panel_height(fin.per_task.len()));
            rest = below;
            let names: Vec<&String> = fin.per_task.keys().collect();
            let n = names.len().max(1);
            // Task i sits at y = n - 1 - i (the first name on top); labels only there.
            let y_of = |i: usize| (n - 1 - i) as f64;
            let mut chart = ChartBuilder::on(&area)
                .caption(
                    format!(
                        "{split} split at {} agent steps: mean success {:.2}, {} task{}",
                        format_steps(fin.step as f64),
                        fin.success,
                        names.len(),
                        if names.len() == 1 { "" } else { "s" }
                    ),
                    (FAMILY, 17),
                )
                .margin(10)
                .x_label_area_size(45)
                .y_label_area_size(20 + 8 * longest as u32)
                .build_cartesian_2d(0f64..1.12f64, -0.6f64..n as f64 - 0.4)?;
            chart
                .configure_mesh()
                .disable_y_mesh()
                .x_labels(7)
                .x_desc("trial success rate")
                .x_label_formatter(&|x| {
                    if *x <= 1.0 {
                        format!("{x:.1}")
                    } else {
                        String::new()
                    }
                })
                // Task names are drawn beside their bars below, not at "nice" numbers.
                .y_labels(1)
                .y_label_formatter(&|_| String::new())
                .label_style((FAMILY, 14))
                .axis_desc_style((FAMILY, 15))
                .draw()?;
            let right_centre = plotters::style::text_anchor::Pos::new(
                plotters::style::text_anchor::HPos::Right,
                plotters::style::text_anchor::VPos::Center,
            );
            for (i, name) in names.iter().enumerate() {
                let (px, py) = chart.backend_coord(&(0.0, y_of(i)));
                root.draw(&Text::new(
                    name.to_string(),
                    (px - 6, py),
                    TextStyle::from((FAMILY, 14).into_font()).pos(right_centre),
                ))?;
            }
            let c = colour(if *split == "test" { 1 } else { 0 });
            chart.draw_series(names.iter().enumerate().map(|(i, name)| {
                let v = fin.per_task[*name];
                Rectangle::new([(0.0, y_of(i) - 0.35), (v, y_of(i) + 0.35)], c.filled())
            }))?;
            chart.draw_series(names.iter().enumerate().map(|(i, name)| {
                let v = fin.per_task[*name];
                Text::new(
                    format!("{v:.2}"),
                    (v + 0.01, y_of(i)),
                    TextStyle::from((FAMILY, 13).into_font()).pos(
                        plotters::style::text_anchor::Pos::new(
                            plotters::style::text_anchor::HPos::Left,
                            plotters::style::text_anchor::VPos::Center,
                        ),
                    ),
                )
            }))?;
        }
        root.present()?;
        Ok(())
    })()
    .map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_formatted_for_axes() {
        assert_eq!(format_steps(0.0), "0");
        assert_eq!(format_steps(1500.0), "1.5k");
        assert_eq!(format_steps(2e6), "2M");
        assert_eq!(format_steps(4e8), "400M");
    }

    #[test]
    fn a_short_run_next_to_far_references_gets_a_log_axis() {
        let a = StepAxis::new(&[50_000, 100_000], &[10_000_000, 400_000_000]);
        assert!(a.log);
        assert!(a.lo <= 50_000f64.log10() && a.hi > 400e6f64.log10());
        let b = StepAxis::new(&[100_000_000, 300_000_000], &[400_000_000]);
        assert!(!b.log);
        assert!(b.hi >= 400e6);
    }
}
