//! A run config: the agent's sections ([`AgentConfig`]) plus what to train on ([env]), for
//! how long and how often to evaluate, checkpoint and log ([train]), and where to evaluate
//! ([eval]). One TOML file; unknown keys are errors.
//!
//! A file may start from another: `base = "../ml1-reach.toml"` (relative to the file) reads
//! that config first and merges this file into it, table by table and key by key (so
//! `[vmpo]\neps_eta = 0.05` changes one value and an inline table such as `kwargs` gains or
//! changes keys); any other value replaces the base's. Bases may have bases.

use std::path::Path;

use million_env::{Kwargs, Value};
use serde::{Deserialize, Serialize};

use crate::config::{
    AgentConfig, BufferConfig, ConfigError, ModelConfig, OptimConfig, PopArtConfig, RuntimeConfig,
    VmpoConfig, read_config_file,
};
use crate::train::servers::check_local_server_args;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    pub model: ModelConfig,
    pub popart: PopArtConfig,
    pub vmpo: VmpoConfig,
    pub buffer: BufferConfig,
    pub optim: OptimConfig,
    pub runtime: RuntimeConfig,
    pub env: EnvConfig,
    pub train: TrainConfig,
    pub eval: EvalConfig,
}

/// The training environments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvConfig {
    pub id: String,
    /// Keyword arguments of the env (TOML values: bool, int, float, string, arrays, tables).
    pub kwargs: toml::Table,
    /// Environments over all servers.
    pub num_envs: usize,
    /// Independently stepped groups (2 = acting overlaps env stepping).
    pub groups: usize,
    /// Env i is seeded with seed + i.
    pub seed: u64,
    /// Seed of the agent's own randomness (weights, action noise, buffer sampling).
    pub agent_seed: u64,
    /// Deadline of Make calls in seconds (building ML45 takes about a minute).
    pub make_timeout_s: u64,
}

/// Env seeds of replicate n start at n · REPLICATE_SEED_STRIDE, so replicates of a run with
/// fewer envs than this never share an env seed.
pub const REPLICATE_SEED_STRIDE: u64 = 10_000;

impl EnvConfig {
    /// Makes this config replicate `n` of a run (`million train --seed n`): the agent's seed
    /// is n and env i is seeded with n · REPLICATE_SEED_STRIDE + i. Replicate 0 is the config
    /// as shipped (seed 0, agent_seed 0). The evaluation seeds stay: every replicate is
    /// scored on the same episodes.
    pub fn replicate(&mut self, n: u64) {
        self.agent_seed = n;
        self.seed = n * REPLICATE_SEED_STRIDE;
    }

    /// The first env seed of a leg that starts at `agent_steps`: `seed` for a new run. A
    /// resumed leg draws new episodes from `seed` plus 2^40 plus a 40-bit hash of its step,
    /// where no replicate's first leg seeds and two legs practically never meet; a plain
    /// `seed + agent_steps` made replicate n resumed at step s draw replicate m's episodes
    /// whenever s = (m - n) · REPLICATE_SEED_STRIDE, or another leg's at such a distance.
    pub fn seed_at(&self, agent_steps: u64) -> u64 {
        if agent_steps == 0 {
            return self.seed;
        }
        // splitmix64's finaliser, kept to 40 bits: seeds stay far below the proto's int64.
        let mut z = agent_steps.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        self.seed.wrapping_add((1 << 40) + (z >> 24))
    }
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            id: "million/ML10-train".into(),
            kwargs: toml::Table::new(),
            num_envs: 64,
            groups: 2,
            seed: 0,
            agent_seed: 0,
            make_timeout_s: 600,
        }
    }
}

/// Budget and intervals, all in agent steps (steps summed over all envs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    pub total_agent_steps: u64,
    /// 0 = no evaluation during training.
    pub eval_interval: u64,
    /// 0 = only the final checkpoint.
    pub checkpoint_interval: u64,
    pub log_interval: u64,
    /// Stop early once the mean train-split eval success reaches this (> 1 = never); the
    /// evaluated weights are then the run's result (final checkpoint and evaluation).
    pub stop_at_success: f64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            total_agent_steps: 400_000_000,
            eval_interval: 5_000_000,
            checkpoint_interval: 5_000_000,
            log_interval: 100_000,
            stop_at_success: 2.0,
        }
    }
}

/// Deterministic evaluation (mean actions).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    pub train_id: String,
    pub train_kwargs: toml::Table,
    /// Empty = no test split.
    pub test_id: String,
    pub test_kwargs: toml::Table,
    /// Episodes per split (one per env, run in one batch).
    pub episodes: usize,
    /// Env-step budgets k: each evaluation also reports the share of first trials that
    /// succeeded within k env steps (`eval/<split>/first_trial_success_within/<k>`).
    pub first_trial_within: Vec<u64>,
    pub seed: u64,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            train_id: "million/ML10-train".into(),
            train_kwargs: toml::Table::new(),
            test_id: "million/ML10-test".into(),
            test_kwargs: toml::Table::new(),
            episodes: 50,
            first_trial_within: vec![50, 100],
            seed: 1_000_000,
        }
    }
}

/// One evaluation split: its name, env id and kwargs.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalSplit {
    pub name: String,
    pub env_id: String,
    pub kwargs: Kwargs,
}

impl RunConfig {
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        let cfg: RunConfig = toml::from_str(text)?;
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let parse = || -> Result<Self, ConfigError> {
            let cfg: RunConfig = toml::Value::Table(read_layered(path, 0)?).try_into()?;
            cfg.validate()?;
            Ok(cfg)
        };
        parse().map_err(|e| match e {
            ConfigError::Parse(p) => ConfigError::Invalid(format!("{}: {p}", path.display())),
            ConfigError::Invalid(m) => ConfigError::Invalid(format!("{}: {m}", path.display())),
            other => other,
        })
    }

    /// Where a leg that stops at `until` (None: the budget) ends, in agent steps.
    pub fn leg_end(&self, until: Option<u64>) -> u64 {
        until.map_or(self.train.total_agent_steps, |u| {
            u.min(self.train.total_agent_steps)
        })
    }

    /// The agent's sections.
    pub fn agent(&self) -> AgentConfig {
        AgentConfig {
            model: self.model.clone(),
            popart: self.popart.clone(),
            vmpo: self.vmpo.clone(),
            buffer: self.buffer.clone(),
            optim: self.optim.clone(),
            runtime: self.runtime.clone(),
        }
    }

    pub fn env_kwargs(&self) -> Result<Kwargs, ConfigError> {
        kwargs_from_toml(&self.env.kwargs, "env.kwargs")
    }

    /// The configured evaluation splits (train, then test when set).
    pub fn eval_splits(&self) -> Result<Vec<EvalSplit>, ConfigError> {
        let mut out = vec![EvalSplit {
            name: "train".into(),
            env_id: self.eval.train_id.clone(),
            kwargs: kwargs_from_toml(&self.eval.train_kwargs, "eval.train_kwargs")?,
        }];
        if !self.eval.test_id.is_empty() {
            out.push(EvalSplit {
                name: "test".into(),
                env_id: self.eval.test_id.clone(),
                kwargs: kwargs_from_toml(&self.eval.test_kwargs, "eval.test_kwargs")?,
            });
        }
        Ok(out)
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        self.agent().validate()?;
        let bad = |m: String| Err(ConfigError::Invalid(m));
        if self.env.id.is_empty() || self.eval.train_id.is_empty() {
            return bad("env.id and eval.train_id must be set".into());
        }
        if self.env.num_envs == 0 || self.env.groups == 0 || self.env.groups > self.env.num_envs {
            return bad(format!(
                "env: need num_envs >= groups >= 1, got num_envs {} and groups {}",
                self.env.num_envs, self.env.groups
            ));
        }
        if self.eval.episodes == 0 {
            return bad("eval.episodes must be > 0".into());
        }
        let budgets = &self.eval.first_trial_within;
        if budgets.contains(&0) || (1..budgets.len()).any(|i| budgets[..i].contains(&budgets[i])) {
            return bad(format!(
                "eval.first_trial_within: budgets must be distinct and > 0 env steps, got {budgets:?}"
            ));
        }
        if self.train.log_interval == 0 {
            return bad("train.log_interval must be > 0".into());
        }
        if self.runtime.env_servers == 0 {
            return bad("runtime.env_servers must be > 0".into());
        }
        if let Err(e) = check_local_server_args(&self.runtime.env_server_args) {
            return bad(format!("runtime.env_server_args: {e}"));
        }
        self.env_kwargs()?;
        self.eval_splits()?;
        Ok(())
    }
}

/// Bases deeper than this are refused (a cycle of `base` keys would never end).
const MAX_BASE_DEPTH: usize = 8;

/// The TOML table of `path` with its `base` chain resolved (see the module docs).
fn read_layered(path: &Path, depth: usize) -> Result<toml::Table, ConfigError> {
    if depth > MAX_BASE_DEPTH {
        return Err(ConfigError::Invalid(format!(
            "{}: config bases nest more than {MAX_BASE_DEPTH} deep (a cycle?)",
            path.display()
        )));
    }
    let mut table: toml::Table = toml::from_str(&read_config_file(path)?)?;
    match table.remove("base") {
        None => Ok(table),
        Some(toml::Value::String(rel)) => {
            let base_path = path.parent().unwrap_or(Path::new(".")).join(rel);
            let mut base = read_layered(&base_path, depth + 1)?;
            merge_into(&mut base, table);
            Ok(base)
        }
        Some(other) => Err(ConfigError::Invalid(format!(
            "base must be the path of another config, got {other}"
        ))),
    }
}

/// Merges `over` into `base`: tables key by key (recursively), anything else replaced.
fn merge_into(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_into(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

fn kwargs_from_toml(table: &toml::Table, what: &str) -> Result<Kwargs, ConfigError> {
    table
        .iter()
        .map(|(k, v)| Ok((k.clone(), value_from_toml(v, &format!("{what}.{k}"))?)))
        .collect()
}

fn value_from_toml(v: &toml::Value, what: &str) -> Result<Value, ConfigError> {
    Ok(match v {
        toml::Value::Boolean(b) => Value::Bool(*b),
        toml::Value::Integer(i) => Value::Int(*i),
        toml::Value::Float(f) => Value::Float(*f),
        toml::Value::String(s) => Value::String(s.clone()),
        toml::Value::Array(a) => Value::List(
            a.iter()
                .map(|x| value_from_toml(x, what))
                .collect::<Result<_, _>>()?,
        ),
        toml::Value::Table(t) => Value::Map(kwargs_from_toml(t, what)?),
        toml::Value::Datetime(_) => {
            return Err(ConfigError::Invalid(format!(
                "{what}: dates are not env kwargs"
            )));
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replicates_differ_in_every_seed_but_the_evaluation_ones() {
        let base = RunConfig::from_toml_str("").unwrap();
        let mut zero = base.clone();
        zero.env.replicate(0);
        assert_eq!(zero, base, "replicate 0 is the shipped config");
        let mut two = base.clone();
        two.env.replicate(2);
        assert_eq!((two.env.agent_seed, two.env.seed), (2, 20_000));
        assert_eq!(two.eval, base.eval);
    }

    #[test]
    fn resumed_legs_never_draw_another_legs_episodes() {
        // 20 replicates of a 64-env run, resumed at every multiple of 10,000 steps to 2.5 M:
        // with `seed + steps` replicate 1 at 10,000 steps drew replicate 2's first episodes.
        let num_envs = 64;
        let mut first_seeds = vec![];
        for n in 0..20 {
            let mut env = RunConfig::from_toml_str("").unwrap().env;
            env.replicate(n);
            assert_eq!(env.seed_at(0), env.seed, "a new run keeps its seeds");
            for steps in (0..=2_500_000).step_by(10_000) {
                first_seeds.push(env.seed_at(steps));
            }
        }
        first_seeds.sort_unstable();
        for pair in first_seeds.windows(2) {
            assert!(
                pair[1] - pair[0] >= num_envs,
                "env seeds {} and {} overlap",
                pair[0],
                pair[1]
            );
        }
        assert!(*first_seeds.last().unwrap() < 1 << 62);
    }

    #[test]
    fn kwargs_keep_their_types() {
        let cfg = RunConfig::from_toml_str(
            "[env]\nid = \"million/PointGoal\"\nkwargs = { num_goals = 4, instructions = false, time_obs = \"trial\" }\n",
        )
        .unwrap();
        let kw = cfg.env_kwargs().unwrap();
        assert_eq!(kw["num_goals"], Value::Int(4));
        assert_eq!(kw["instructions"], Value::Bool(false));
        assert_eq!(kw["time_obs"], Value::String("trial".into()));
    }

    #[test]
    fn a_config_with_a_base_overrides_it_key_by_key() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        std::fs::write(
            dir.path().join("base.toml"),
            "[env]\nid = \"million/PointGoal\"\nkwargs = { num_goals = 4, trial_len = 8 }\n\
             [vmpo]\neps_eta = 0.2\ngamma = 0.9\n",
        )
        .unwrap();
        let child = dir.path().join("sub/child.toml");
        std::fs::write(
            &child,
            "base = \"../base.toml\"\n[env]\nkwargs = { num_goals = 2 }\n[vmpo]\ngamma = 0.5\n",
        )
        .unwrap();
        let cfg = RunConfig::from_file(&child).unwrap();
        assert_eq!(cfg.env.id, "million/PointGoal");
        let kw = cfg.env_kwargs().unwrap();
        assert_eq!(kw["num_goals"], Value::Int(2));
        assert_eq!(kw["trial_len"], Value::Int(8));
        assert_eq!((cfg.vmpo.eps_eta, cfg.vmpo.gamma), (0.2, 0.5));
        // A cycle is refused with a clear error, not a stack overflow.
        std::fs::write(&child, "base = \"child.toml\"\n").unwrap();
        let err = RunConfig::from_file(&child).unwrap_err().to_string();
        assert!(err.contains("nest more than"), "{err}");
        // A missing base names the file.
        std::fs::write(&child, "base = \"nowhere.toml\"\n").unwrap();
        let err = RunConfig::from_file(&child).unwrap_err().to_string();
        assert!(err.contains("nowhere.toml"), "{err}");
    }

    #[test]
    fn server_args_the_agent_owns_are_refused() {
        for arg in [
            "--address",
            "--token=s3cret",
            "--tls-cert",
            "--tls-key=k.pem",
        ] {
            let toml = format!("[runtime]\nenv_server_args = [{arg:?}, \"x\"]\n");
            let err = RunConfig::from_toml_str(&toml).unwrap_err().to_string();
            assert!(err.contains(arg) && err.contains("--env-server"), "{err}");
        }
        let ok = "[runtime]\nenv_server_args = [\"--idle-envs\", \"4\", \"--log-level=DEBUG\"]\n";
        assert!(RunConfig::from_toml_str(ok).is_ok());
    }

    #[test]
    fn bad_sections_are_named() {
        let err = RunConfig::from_toml_str("[env]\nnum_envs = 1\ngroups = 2\n").unwrap_err();
        assert!(err.to_string().contains("groups"), "{err}");
        let err = RunConfig::from_toml_str("[train]\ntotal_steps = 3\n").unwrap_err();
        assert!(err.to_string().contains("total_steps"), "{err}");
        for budgets in ["[0]", "[50, 50]"] {
            let text = format!("[eval]\nfirst_trial_within = {budgets}\n");
            let err = RunConfig::from_toml_str(&text).unwrap_err();
            assert!(err.to_string().contains("first_trial_within"), "{err}");
        }
    }
}
