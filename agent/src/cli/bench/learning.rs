//! `million bench learning`: does a config learn to its targets within a budget of agent steps?
//!
//! The learning targets (RESULTS.md; e.g. ML1-reach: train success ≥ 0.9 and held-out
//! success ≥ 0.8 within 2.5 M agent steps, first trials ≥ 0.3 above the no-instructions
//! ablation) take longer than CI allows, so they are a bench that is run and recorded
//! (RESULTS.md), not a test. It trains the config for `--steps` agent steps (default: the
//! config's `train.total_agent_steps`; lockstep pacing makes that the same run at any speed
//! and load; local env servers, deterministic
//! evaluations at the config's `eval_interval` and at the end), then, with `--ablation`, the
//! ablation config for the same agent steps, evaluated at the same steps. It reports when each
//! split first reached its target (agent steps, and minutes for information), each split's
//! best and last figures, and the first-trial gap to the ablation at every shared evaluation:
//! on first trials that succeeded at all, and on those that succeeded within each env-step
//! budget of the config's `eval.first_trial_within` (on ML1-reach a policy without the words
//! learns to sweep the goal box within a whole trial, so "at all" stops telling them apart).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use serde::Serialize;

use crate::run_config::RunConfig;
use crate::train::session::{CurvePoint, TrainOptions, TrainSummary, train};

/// Evaluations of the two runs count as at the same agent steps when they lie within this
/// fraction of the evaluation interval of each other.
const SAME_STEPS_FRACTION: u64 = 20;

#[derive(Debug, Args)]
pub struct LearningBench {
    /// Run config to train, e.g. configs/ml1-reach.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// The same run without what is tested (e.g.
    /// configs/experiments/ml1-reach-no-instructions.toml), trained for as many agent steps as
    /// the config reached.
    #[arg(long)]
    pub ablation: Option<PathBuf>,
    /// Budget of the config's training in agent steps (default: its train.total_agent_steps);
    /// the run is evaluated at its eval_interval and at the end.
    #[arg(long)]
    pub steps: Option<u64>,
    /// Replicate N (as `million train --seed`), for both runs.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Success to reach on the train split.
    #[arg(long, default_value_t = 0.9)]
    pub train_target: f64,
    /// Success to reach on the test split (held-out goals or sentences).
    #[arg(long, default_value_t = 0.8)]
    pub test_target: f64,
    /// How far the config's first-trial success must lie above the ablation's.
    #[arg(long, default_value_t = 0.3)]
    pub first_trial_gap: f64,
    /// Directory of the two runs (DIR/run, DIR/ablation); it must not exist yet. Default
    /// runs/bench-learning-<config name>[-seedN].
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// One JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// A split's figure at one evaluation.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Milestone {
    pub agent_steps: u64,
    pub minutes: f64,
    pub success: f64,
    pub first_trial: f64,
}

#[derive(Debug, Serialize)]
pub struct SplitResult {
    pub split: String,
    pub target: f64,
    /// The first evaluation at or above the target, if any.
    pub first_met: Option<Milestone>,
    pub best: Milestone,
    pub last: Milestone,
}

/// The config's first-trial success minus the ablation's, at one shared evaluation.
#[derive(Debug, Serialize)]
pub struct GapPoint {
    pub split: String,
    pub agent_steps: u64,
    pub with: f64,
    pub without: f64,
    pub gap: f64,
}

#[derive(Debug, Serialize)]
pub struct AblationResult {
    pub config: PathBuf,
    pub agent_steps: u64,
    pub minutes: f64,
    pub target_gap: f64,
    /// Gaps at every evaluation both runs made at the same agent steps.
    pub gaps: Vec<GapPoint>,
    /// Whether, on every split the config evaluated, both runs were evaluated at the config's
    /// final agent steps and the gap there reaches the target.
    pub final_gap_met: bool,
    /// The same for first trials that succeeded within k env steps, for each k of the
    /// config's `eval.first_trial_within`: how soon, where `gaps` compares only whether (an
    /// agent without the words can search the goal out in a whole trial, but not as soon as
    /// one that reads it). No gaps for a k the ablation's evaluations did not measure.
    pub within: Vec<WithinGaps>,
}

/// First-trial gaps on trials that succeeded within `env_steps` env steps.
#[derive(Debug, Serialize)]
pub struct WithinGaps {
    pub env_steps: u64,
    pub gaps: Vec<GapPoint>,
    pub final_gap_met: bool,
}

#[derive(Debug, Serialize)]
pub struct LearningReport {
    pub config: PathBuf,
    pub seed: Option<u64>,
    pub budget_agent_steps: u64,
    pub agent_steps: u64,
    pub minutes: f64,
    pub agent_steps_per_s: f64,
    pub replay_ratio: f64,
    pub run_dir: PathBuf,
    pub splits: Vec<SplitResult>,
    pub ablation: Option<AblationResult>,
}

pub fn run(b: &LearningBench) -> anyhow::Result<()> {
    let run_dir = b.run_dir.clone().unwrap_or_else(|| {
        crate::cli::train::default_run_dir("bench-learning-", &b.config, b.seed)
    });
    anyhow::ensure!(
        !run_dir.exists(),
        "{} exists: a learning bench starts from scratch (move it away or pass --run-dir)",
        run_dir.display()
    );
    let mut cfg = load(&b.config, b.seed)?;
    let budget = b.steps.unwrap_or(cfg.train.total_agent_steps);
    anyhow::ensure!(budget > 0, "--steps must be > 0");
    anyhow::ensure!(
        cfg.train.eval_interval > 0,
        "{}: train.eval_interval is 0, so there is no curve to read targets from",
        b.config.display()
    );
    let eval_interval = cfg.train.eval_interval;
    // Loaded now: a bad ablation config fails before the hour of training, not after it.
    let ablation_cfg = b
        .ablation
        .as_deref()
        .map(|path| load(path, b.seed).map(|cfg| (path, cfg)))
        .transpose()?;
    let budgets = cfg.eval.first_trial_within.clone();
    // The whole budget runs: an early stop would hide what comes after the target.
    cfg.train.total_agent_steps = budget;
    cfg.train.stop_at_success = 2.0;
    let main = train_run(cfg, &run_dir.join("run"))?;
    let splits = [("train", b.train_target), ("test", b.test_target)]
        .into_iter()
        .filter_map(|(split, target)| split_result(&main.curve, split, target))
        .collect();

    let ablation = match ablation_cfg {
        None => None,
        Some((path, mut cfg)) => {
            cfg.train.total_agent_steps = main.agent_steps;
            cfg.train.eval_interval = eval_interval;
            cfg.train.stop_at_success = 2.0;
            let blind = train_run(cfg, &run_dir.join("ablation"))?;
            let tolerance = eval_interval / SAME_STEPS_FRACTION;
            let gaps = first_trial_gaps(&main.curve, &blind.curve, tolerance, FirstTrial::Success);
            let met =
                |gaps: &[GapPoint]| final_gap_met(&main.curve, gaps, b.first_trial_gap, tolerance);
            let within = budgets
                .iter()
                .map(|&env_steps| {
                    let measure = FirstTrial::SuccessWithin(env_steps);
                    let gaps = first_trial_gaps(&main.curve, &blind.curve, tolerance, measure);
                    WithinGaps {
                        env_steps,
                        final_gap_met: met(&gaps),
                        gaps,
                    }
                })
                .collect();
            Some(AblationResult {
                config: path.to_owned(),
                agent_steps: blind.agent_steps,
                minutes: blind.wall_s / 60.0,
                target_gap: b.first_trial_gap,
                final_gap_met: met(&gaps),
                gaps,
                within,
            })
        }
    };
    let report = LearningReport {
        config: b.config.clone(),
        seed: b.seed,
        budget_agent_steps: budget,
        agent_steps: main.agent_steps,
        minutes: main.wall_s / 60.0,
        agent_steps_per_s: main.agent_steps_per_s,
        replay_ratio: main.replay_ratio,
        run_dir,
        splits,
        ablation,
    };
    if b.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report);
    }
    Ok(())
}

fn load(path: &Path, seed: Option<u64>) -> anyhow::Result<RunConfig> {
    let mut cfg = RunConfig::from_file(path)?;
    if let Some(n) = seed {
        cfg.env.replicate(n);
    }
    Ok(cfg)
}

fn train_run(cfg: RunConfig, dir: &Path) -> anyhow::Result<TrainSummary> {
    let rt = crate::cli::runtime(cfg.runtime.io_threads)?;
    rt.block_on(train(TrainOptions {
        run_dir: Some(dir.to_owned()),
        ..TrainOptions::local(cfg)
    }))
    .with_context(|| format!("training into {}", dir.display()))
}

fn milestones<'a>(curve: &'a [CurvePoint], split: &'a str) -> impl Iterator<Item = Milestone> + 'a {
    curve
        .iter()
        .filter(move |p| p.split == split)
        .map(|p| Milestone {
            agent_steps: p.agent_steps,
            minutes: p.wall_s / 60.0,
            success: p.success,
            first_trial: p.first_trial,
        })
}

/// The split's first evaluation at or above `target`, its best and its last; None when the
/// run has no evaluation of that split.
pub fn split_result(curve: &[CurvePoint], split: &str, target: f64) -> Option<SplitResult> {
    let points: Vec<Milestone> = milestones(curve, split).collect();
    let last = *points.last()?;
    // The earliest of equal bests.
    let best = points
        .iter()
        .copied()
        .reduce(|best, m| if m.success > best.success { m } else { best })
        .expect("not empty");
    Some(SplitResult {
        split: split.to_owned(),
        target,
        first_met: points.iter().find(|m| m.success >= target).copied(),
        best,
        last,
    })
}

/// What a first-trial gap compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FirstTrial {
    /// Whether first trials succeeded at all, within their whole length.
    Success,
    /// Whether they succeeded within this many env steps (`EvalReport::first_trial_within`).
    SuccessWithin(u64),
}

impl FirstTrial {
    /// The point's figure; None when the evaluation did not measure it.
    fn of(self, p: &CurvePoint) -> Option<f64> {
        match self {
            Self::Success => Some(p.first_trial),
            Self::SuccessWithin(k) => p.first_trial_within.get(&k).copied(),
        }
    }
}

/// First-trial gaps at the evaluations both runs made at the same agent steps (within
/// `tolerance` steps: runs with other env counts step in other increments). A run's final
/// evaluation may repeat its last periodic one's step; the later (final) figure is kept.
pub fn first_trial_gaps(
    with: &[CurvePoint],
    without: &[CurvePoint],
    tolerance: u64,
    measure: FirstTrial,
) -> Vec<GapPoint> {
    let mut gaps = vec![];
    for split in ["train", "test"] {
        let of_split = |curve: &[CurvePoint]| -> Vec<(u64, f64)> {
            curve
                .iter()
                .filter(|p| p.split == split)
                .filter_map(|p| Some((p.agent_steps, measure.of(p)?)))
                .collect()
        };
        let theirs = of_split(without);
        let mut split_gaps: Vec<GapPoint> = vec![];
        for (steps, mine) in of_split(with) {
            let Some(&(_, other)) = theirs
                .iter()
                .rev()
                .filter(|o| o.0.abs_diff(steps) <= tolerance)
                .min_by_key(|o| o.0.abs_diff(steps))
            else {
                continue;
            };
            split_gaps.retain(|g| g.agent_steps != steps);
            split_gaps.push(GapPoint {
                split: split.to_owned(),
                agent_steps: steps,
                with: mine,
                without: other,
                gap: mine - other,
            });
        }
        gaps.extend(split_gaps);
    }
    gaps
}

/// True when every split of `with` has a gap at its last evaluation's agent steps and that
/// gap reaches `target`: an ablation cut short, or a split it did not evaluate, is no pass.
pub fn final_gap_met(with: &[CurvePoint], gaps: &[GapPoint], target: f64, tolerance: u64) -> bool {
    let mut splits: Vec<&str> = with.iter().map(|p| p.split.as_str()).collect();
    splits.sort_unstable();
    splits.dedup();
    !splits.is_empty()
        && splits.iter().all(|split| {
            let last = milestones(with, split)
                .last()
                .expect("split from the curve");
            gaps.iter()
                .rev()
                .find(|g| g.split == *split)
                .is_some_and(|g| {
                    g.agent_steps.abs_diff(last.agent_steps) <= tolerance && g.gap >= target
                })
        })
}

fn print_report(r: &LearningReport) {
    println!(
        "{}: {} agent steps (budget {}) in {:.1} min ({:.0} steps/s, replay ratio {:.2}); runs in {}",
        r.config.display(),
        r.agent_steps,
        r.budget_agent_steps,
        r.minutes,
        r.agent_steps_per_s,
        r.replay_ratio,
        r.run_dir.display()
    );
    for s in &r.splits {
        let met = match &s.first_met {
            Some(m) => format!(
                "MET at {} steps, {:.1} min ({:.3})",
                m.agent_steps, m.minutes, m.success
            ),
            None => "NOT MET".into(),
        };
        println!(
            "  {:<5} success ≥ {:.2}: {met}; best {:.3} at {} steps, last {:.3} (first trials {:.3})",
            s.split,
            s.target,
            s.best.success,
            s.best.agent_steps,
            s.last.success,
            s.last.first_trial
        );
    }
    if let Some(a) = &r.ablation {
        println!(
            "  ablation {} ({} steps in {:.1} min): first-trial gap ≥ {:.2} at the end: {}",
            a.config.display(),
            a.agent_steps,
            a.minutes,
            a.target_gap,
            if a.final_gap_met { "MET" } else { "NOT MET" }
        );
        for g in &a.gaps {
            println!(
                "    {:<5} {:>9} steps: first trials {:.3} with, {:.3} without, gap {:+.3}",
                g.split, g.agent_steps, g.with, g.without, g.gap
            );
        }
        for w in &a.within {
            println!(
                "  first trials successful within {} env steps, gap ≥ {:.2} at the end: {}",
                w.env_steps,
                a.target_gap,
                match (w.gaps.is_empty(), w.final_gap_met) {
                    (true, _) => "not measured (the ablation's evaluations lack this budget)",
                    (false, true) => "MET",
                    (false, false) => "NOT MET",
                }
            );
            for g in &w.gaps {
                println!(
                    "    {:<5} {:>9} steps: {:.3} with, {:.3} without, gap {:+.3}",
                    g.split, g.agent_steps, g.with, g.without, g.gap
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(split: &str, agent_steps: u64, success: f64, first_trial: f64) -> CurvePoint {
        CurvePoint {
            agent_steps,
            wall_s: agent_steps as f64 / 100.0,
            split: split.into(),
            success,
            first_trial,
            // Half the first trials that succeeded did so within 100 env steps.
            first_trial_within: [(100, first_trial / 2.0)].into(),
        }
    }

    #[test]
    fn a_target_is_met_at_the_first_evaluation_reaching_it_and_the_earliest_best_is_kept() {
        let curve = [
            point("train", 100, 0.5, 0.0),
            point("test", 100, 0.1, 0.0),
            point("train", 200, 0.9, 0.0),
            point("train", 300, 0.95, 0.0),
            point("train", 400, 0.95, 0.0),
            point("train", 400, 0.7, 0.0),
        ];
        let r = split_result(&curve, "train", 0.9).unwrap();
        assert_eq!(r.first_met.unwrap().agent_steps, 200);
        assert_eq!(r.best.agent_steps, 300);
        assert_eq!((r.last.agent_steps, r.last.success), (400, 0.7));
        let t = split_result(&curve, "test", 0.8).unwrap();
        assert!(t.first_met.is_none());
        assert!(split_result(&curve, "other", 0.8).is_none());
    }

    #[test]
    fn gaps_pair_evaluations_at_the_same_steps_and_keep_the_final_figure() {
        let with = [
            point("train", 100, 0.0, 0.6),
            point("train", 200, 0.0, 0.8),
            // the final evaluation, at the last periodic one's steps
            point("train", 200, 0.0, 0.9),
        ];
        let without = [
            point("train", 100, 0.0, 0.3),
            point("train", 150, 0.0, 0.1),
            point("train", 203, 0.0, 0.4),
        ];
        let gaps = first_trial_gaps(&with, &without, 5, FirstTrial::Success);
        let got: Vec<(u64, f64)> = gaps.iter().map(|g| (g.agent_steps, g.without)).collect();
        assert_eq!(got, [(100, 0.3), (200, 0.4)]);
        assert!((gaps[1].gap - 0.5).abs() < 1e-12);
        assert!(final_gap_met(&with, &gaps, 0.5 - 1e-9, 5));
        assert!(!final_gap_met(&with, &gaps, 0.6, 5));
        // Within 100 env steps: the same pairs, the figures of that measure.
        let soon = first_trial_gaps(&with, &without, 5, FirstTrial::SuccessWithin(100));
        let got: Vec<(u64, f64)> = soon.iter().map(|g| (g.agent_steps, g.without)).collect();
        assert_eq!(got, [(100, 0.15), (200, 0.2)]);
        assert!((soon[1].gap - 0.25).abs() < 1e-12);
        // A budget the evaluations did not measure gives no gap, so no pass.
        let unmeasured = first_trial_gaps(&with, &without, 5, FirstTrial::SuccessWithin(50));
        assert!(unmeasured.is_empty());
        assert!(!final_gap_met(&with, &unmeasured, 0.0, 5));
    }

    #[test]
    fn an_ablation_cut_short_or_a_split_without_gaps_is_no_pass() {
        let with = [
            point("train", 100, 0.0, 0.9),
            point("train", 200, 0.0, 0.9),
            point("test", 200, 0.0, 0.9),
        ];
        let short = [point("train", 100, 0.0, 0.0)];
        let gaps = first_trial_gaps(&with, &short, 5, FirstTrial::Success);
        assert_eq!(gaps.len(), 1);
        assert!(!final_gap_met(&with, &gaps, 0.3, 5), "cut short");
        let train_only = [point("train", 100, 0.0, 0.0), point("train", 200, 0.0, 0.0)];
        let gaps = first_trial_gaps(&with, &train_only, 5, FirstTrial::Success);
        assert!(!final_gap_met(&with, &gaps, 0.3, 5), "no test gap");
        assert!(!final_gap_met(&[], &[], 0.3, 5));
    }
}
