//! `million bench learner --reference` on small configs: the PyTorch reference
//! (bench/learner_reference.py) must compute the same loss terms as the Rust learner, before,
//! in and after one update. Once with the quickstart config (the original's forms: n-step
//! returns, clamp-form multipliers, KL from the behaviour policy) and once with every other
//! form the config can select. One timed update per side; timings are never asserted.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common::repo;
use serde_json::Value;

const TERMS: [&str; 6] = [
    "loss",
    "policy_loss",
    "temperature_loss",
    "alpha_mu_loss",
    "alpha_sigma_loss",
    "value_loss",
];

/// Quickstart with the state field normalised, λ-returns, debiased Pop-Art over 3 tasks, log-form multipliers with their
/// own step size, a target network synced after every update, and the last step learned from.
fn variant_config(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(repo().join("configs/quickstart.toml")).unwrap();
    let mut cfg: toml::Table = text.parse().unwrap();
    let mut set = |section: &str, key: &str, value: toml::Value| {
        cfg[section]
            .as_table_mut()
            .unwrap()
            .insert(key.into(), value);
    };
    set("model", "num_tasks", 3.into());
    set(
        "model",
        "obs_norm",
        toml::Value::Array(vec!["state".into()]),
    );
    set("popart", "debias", true.into());
    set("vmpo", "lambda", 0.9.into());
    set("vmpo", "learn_last_step", true.into());
    set("vmpo", "multiplier_form", "log".into());
    set("vmpo", "multiplier_lr", 0.01.into());
    set("vmpo", "kl_reference", "target".into());
    set("buffer", "target_period", 1.into());
    set("buffer", "min_segments", 32.into());
    let path = dir.join("variant.toml");
    std::fs::write(&path, toml::to_string(&cfg).unwrap()).unwrap();
    path
}

fn check(config: &Path) {
    let out = Command::new(env!("CARGO_BIN_EXE_million"))
        .args(["bench", "learner", "--config"])
        .arg(config)
        .args([
            "--reference",
            "--iters",
            "1",
            "--rounds",
            "1",
            "--threads",
            "1",
        ])
        .arg("--json")
        .env("RUST_LOG", "warn")
        .output()
        .expect("million runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{}: bench learner --reference failed:\n{stderr}",
        config.display()
    );
    let report: Value = serde_json::from_slice(&out.stdout).expect("JSON on stdout");
    let check = &report["check"];
    assert_eq!(check["passed"], Value::Bool(true), "{report:#}");
    let values = check["values"].as_array().expect("compared values");
    for stage in ["before", "update", "after"] {
        for term in TERMS {
            let v = values
                .iter()
                .find(|v| v["stage"] == stage && v["term"] == term)
                .unwrap_or_else(|| panic!("{stage} {term} not compared: {report:#}"));
            let (rust, pytorch) = (v["rust"].as_f64().unwrap(), v["pytorch"].as_f64().unwrap());
            let diff = (rust - pytorch).abs();
            // The same losses on the same weights and batch to 1e-5; after one Adam step,
            // which moves a weight by ± its step size however small its gradient, to 1e-3
            // (`AFTER_STEP_TOLERANCE` of `million bench learner --reference`).
            let tol = if stage == "after" { 1e-3 } else { 1e-5 };
            assert!(
                rust.is_finite() && (diff <= tol || diff <= tol * rust.abs()),
                "{}: {stage} {term}: rust {rust}, pytorch {pytorch}",
                config.display()
            );
        }
    }
    let timing = report["timing"].as_array().expect("timing rows");
    assert_eq!(timing.len(), 1, "{report:#}");
}

#[test]
fn pytorch_reference_matches_the_learner_with_the_original_forms() {
    check(&repo().join("configs/quickstart.toml"));
}

#[test]
fn pytorch_reference_matches_the_learner_with_every_other_form() {
    let dir = tempfile::tempdir().unwrap();
    check(&variant_config(dir.path()));
}
