//! Every run config shipped in configs/ parses, validates, and builds a model of its sizes.

use std::path::{Path, PathBuf};

use million::run_config::RunConfig;

fn config_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("configs/ exists") {
        let path = entry.expect("dir entry").path();
        if path.is_dir() {
            config_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "toml") {
            out.push(path);
        }
    }
}

fn configs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs")
}

#[test]
fn every_shipped_config_is_valid() {
    let mut files = vec![];
    config_files(&configs_dir(), &mut files);
    files.sort();
    let names: Vec<String> = files
        .iter()
        .map(|p| p.strip_prefix(configs_dir()).unwrap().display().to_string())
        .collect();
    for required in [
        "base.toml",
        "mt1-reach.toml",
        "ml1-reach.toml",
        "ml10.toml",
        "ml45.toml",
        "quickstart.toml",
        "paper/ml10.toml",
        "paper/ml45.toml",
        "paper/ml1-reach.toml",
        "experiments/ml10-no-popart.toml",
        "experiments/ml10-no-instructions.toml",
        "experiments/ml10-full-time-obs.toml",
        "experiments/quickstart-no-instructions.toml",
    ] {
        assert!(
            names.iter().any(|n| n == required),
            "{required} missing: {names:?}"
        );
    }
    for path in &files {
        let cfg = RunConfig::from_file(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        // The sizes build a working model: one acting step gives actions of the right shape.
        let vs = tch::nn::VarStore::new(tch::Device::Cpu);
        let model = million::model::Model::new(&vs.root(), &cfg.model, &cfg.popart);
        let mut state = model.acting_state(2);
        let obs = tch::Tensor::zeros([2, cfg.model.obs_dim() as i64], tch::kind::FLOAT_CPU);
        let out = model.act(&mut state, &obs, &tch::Tensor::from_slice(&[true, true]));
        assert_eq!(
            out.mean.size(),
            [2, cfg.model.action_dim as i64],
            "{}",
            path.display()
        );
        assert!(!cfg.eval_splits().unwrap().is_empty());
    }
}

#[test]
fn paper_ml10_holds_the_paper_defaults_and_ablations_differ_where_they_should() {
    let load = |name: &str| RunConfig::from_file(&configs_dir().join(name)).unwrap();
    let paper = load("paper/ml10.toml");
    // The paper's values are the defaults, with the original's trial_success flag in the token.
    let mut expected = million::config::AgentConfig::default();
    expected
        .model
        .observation
        .push(million::config::ObsField::new("trial_success", 1));
    assert_eq!(paper.agent(), expected);
    assert_eq!(paper.env.id, "million/ML10-train");
    assert_eq!(paper.train.total_agent_steps, 400_000_000);

    // Each ablation changes its shipped config where it says and nowhere else in the agent.
    let ml10 = load("ml10.toml");
    let no_popart = load("experiments/ml10-no-popart.toml");
    assert!(ml10.popart.enabled && !no_popart.popart.enabled);
    let mut agent = no_popart.agent();
    agent.popart.enabled = true;
    assert_eq!(agent, ml10.agent());
    let noi = load("experiments/ml10-no-instructions.toml");
    assert_eq!(
        noi.env_kwargs().unwrap()["instructions"],
        million::env::Value::Bool(false)
    );
    assert_eq!(noi.model.observation.last().unwrap().key, "prev_reward");
    let ft = load("experiments/ml10-full-time-obs.toml");
    assert_eq!(
        ft.env_kwargs().unwrap()["time_obs"],
        million::env::Value::String("episode".into())
    );
}

#[test]
fn a_bad_config_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, "[env]\nnum_env = 3\n").unwrap();
    let err = RunConfig::from_file(&path).unwrap_err().to_string();
    assert!(err.contains("bad.toml") && err.contains("num_env"), "{err}");
    let err = RunConfig::from_file(&dir.path().join("missing.toml"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("missing.toml"), "{err}");

    // obs_norm may only name fields of the observation token.
    std::fs::write(&path, "[model]\nobs_norm = [\"sate\"]\n").unwrap();
    let err = RunConfig::from_file(&path).unwrap_err().to_string();
    assert!(err.contains("obs_norm") && err.contains("sate"), "{err}");
}
