//! Shared helpers: a small model config so tests stay fast on 2 cores, and short real
//! training runs of a shipped config (local env servers, libtorch).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use million::config::{AgentConfig, ModelConfig, ObsField};
use million::run_config::RunConfig;
use million::train::session::{TrainOptions, TrainSummary, train};
use tch::{Kind, Tensor};

/// The repository's root, where `configs/` lives.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A config shipped under `configs/`, e.g. `"quickstart.toml"` or `"experiments/…"`.
pub fn shipped_config(name: &str) -> RunConfig {
    RunConfig::from_file(&repo().join("configs").join(name)).expect("shipped config")
}

/// The tokio runtime `million` builds: `threads` workers for the gRPC streams.
pub fn runtime(threads: usize) -> tokio::runtime::Runtime {
    million::cli::runtime(threads).expect("a tokio runtime")
}

/// Trains `cfg` into `run_dir` with its own local env servers, for at most `max_seconds`,
/// with (`evaluate`) or without evaluations, as `million train` would.
pub fn train_in(cfg: RunConfig, run_dir: &Path, evaluate: bool, max_seconds: f64) -> TrainSummary {
    runtime(cfg.runtime.io_threads)
        .block_on(train(TrainOptions {
            run_dir: Some(run_dir.to_owned()),
            max_seconds: Some(max_seconds),
            evaluate,
            ..TrainOptions::local(cfg)
        }))
        .expect("training runs")
}

/// Every record of a run's `metrics.jsonl`, in order; each line must be a JSON object.
pub fn metrics_records(run_dir: &Path) -> Vec<serde_json::Map<String, serde_json::Value>> {
    let path = run_dir.join("metrics.jsonl");
    std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .map(|l| match serde_json::from_str(l) {
            Ok(serde_json::Value::Object(m)) => m,
            other => panic!("{}: not a JSON object: {l} ({other:?})", path.display()),
        })
        .collect()
}

pub fn small_model(segment_len: usize, memory_len: usize) -> ModelConfig {
    ModelConfig {
        observation: vec![
            ObsField::new("state", 5),
            ObsField::new("word", 3),
            ObsField::new("time", 1),
            ObsField::new("phase", 1),
        ],
        action_dim: 2,
        num_tasks: 3,
        layers: 2,
        d_model: 16,
        heads: 2,
        ff_dim: 32,
        segment_len,
        memory_len,
        policy_hidden: 16,
        value_hidden: 16,
        ..ModelConfig::default()
    }
}

pub fn small_agent(segment_len: usize, memory_len: usize, batch: usize) -> AgentConfig {
    let mut cfg = AgentConfig {
        model: small_model(segment_len, memory_len),
        ..AgentConfig::default()
    };
    cfg.buffer.batch_segments = batch;
    cfg.buffer.min_segments = batch;
    cfg.buffer.target_period = 4;
    cfg.validate().expect("small config is valid");
    cfg
}

/// Overwrites every relative-position bias with random values so tests exercise the distance
/// indexing (they start at zero).
pub fn randomise_relative_bias(vs: &tch::nn::VarStore) {
    tch::no_grad(|| {
        for (name, mut t) in vs.variables() {
            if name.ends_with("rel_bias") {
                t.copy_(&(t.randn_like() * 0.5));
            }
        }
    });
}

pub fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    (a - b).abs().max().to_kind(Kind::Double).double_value(&[])
}

/// Random episode starts `[B, T]` with probability `p`, as bool.
pub fn random_starts(b: i64, t: i64, p: f64) -> Tensor {
    Tensor::rand([b, t], (Kind::Float, tch::Device::Cpu)).lt(p)
}
