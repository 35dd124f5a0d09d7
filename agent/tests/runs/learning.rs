//! The learning test: `configs/quickstart.toml` (million/PointGoal, 4 goals named only in the
//! instruction) reaches >= 90% deterministic trial success within its agent-step budget, while
//! the same run without instructions (configs/experiments/quickstart-no-instructions.toml: only
//! `instructions = false` differs), given the same number of agent steps, stays near chance on
//! first trials: the words reach the policy through the memory.
//!
//! Real parts throughout: a local million-env-server, the gRPC env pool, libtorch. Lockstep
//! pacing makes the run the same at any speed and load, so the budget is in agent steps; the wall
//! time is only a guard against a hung run. Runs alone (nextest test group `learning`).

use std::path::Path;

use crate::common::{shipped_config, train_in};
use million::run_config::RunConfig;
use million::train::session::TrainSummary;

/// A guard against a hung run, far above the ~5 minutes the run takes on 2 idle cores.
const WALL_GUARD_S: f64 = 3_600.0;

fn run(cfg: RunConfig, run_dir: &Path) -> TrainSummary {
    train_in(cfg, run_dir, true, WALL_GUARD_S)
}

fn split<'a>(s: &'a TrainSummary, name: &str) -> &'a million::train::eval::EvalReport {
    s.final_eval
        .iter()
        .find(|r| r.split == name)
        .unwrap_or_else(|| panic!("no {name} eval in {s:?}"))
}

#[test]
fn quickstart_learns_to_follow_instructions_and_the_ablation_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let quick = run(
        shipped_config("quickstart.toml"),
        &dir.path().join("quickstart"),
    );
    for p in &quick.curve {
        eprintln!(
            "quickstart {:>8} steps {:>6.1} s  {:<5} success {:.3}  first trials {:.3}",
            p.agent_steps, p.wall_s, p.split, p.success, p.first_trial
        );
    }
    eprintln!(
        "quickstart: {} steps in {:.0} s, {:.0} steps/s, {} updates",
        quick.agent_steps, quick.wall_s, quick.agent_steps_per_s, quick.updates
    );
    let train_split = split(&quick, "train");
    assert!(
        train_split.mean >= 0.9,
        "quickstart reached only {:.3} trial success in {} agent steps",
        train_split.mean,
        quick.agent_steps
    );
    assert!(
        quick.wall_s < WALL_GUARD_S,
        "the run hit the wall-time guard"
    );
    assert!(
        train_split.first_trial >= 0.8,
        "first trials follow the words: {:.3}",
        train_split.first_trial
    );
    assert!(train_split.trials >= 64, "{train_split:?}");
    // The held-out sentences name the same goals with unseen templates.
    assert!(
        split(&quick, "test").mean >= 0.6,
        "{:?}",
        split(&quick, "test")
    );
    // The final checkpoint exists and carries the run config for `million eval`.
    let ckpt = quick.final_checkpoint.as_ref().expect("final checkpoint");
    let meta = million::checkpoint::read_meta(ckpt).unwrap();
    assert!(
        meta.extra
            .contains_key(million::train::session::RUN_CONFIG_KEY)
    );
    assert_eq!(meta.counters.agent_steps, quick.agent_steps);

    let mut ablation = shipped_config("experiments/quickstart-no-instructions.toml");
    ablation.train.total_agent_steps = quick.agent_steps;
    ablation.train.eval_interval = 0;
    let blind = run(ablation, &dir.path().join("no-instructions"));
    let blind_train = split(&blind, "train");
    eprintln!(
        "no instructions after {} steps: success {:.3}, first trials {:.3}",
        blind.agent_steps, blind_train.mean, blind_train.first_trial
    );
    assert!(blind.agent_steps >= quick.agent_steps);
    // Without words the goal of a first trial is a guess among 4 (chance 0.25; a fixed
    // direction scores the share of its goal among the eval episodes).
    assert!(
        blind_train.first_trial < 0.6 && blind_train.first_trial <= train_split.first_trial - 0.3,
        "first trials without instructions {:.3} vs with {:.3}",
        blind_train.first_trial,
        train_split.first_trial
    );
    assert!(
        blind_train.mean < 0.6 && blind_train.mean <= train_split.mean - 0.3,
        "without instructions {:.3} vs with {:.3}",
        blind_train.mean,
        train_split.mean
    );
}
