//! Typed agent configuration. Every number of docs/ALGORITHM.md §2–§6 is a field here; the defaults
//! are the paper's ML10 run. Unknown keys are rejected so that a typo in a TOML file is an error
//! instead of a silently ignored setting.

use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("invalid agent config: {0}")]
    Parse(#[from] toml::de::Error),
    #[error("invalid agent config: {0}")]
    Invalid(String),
}

/// The agent's part of a run config: network, algorithm, buffer, optimiser and CPU threads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct AgentConfig {
    pub model: ModelConfig,
    pub popart: PopArtConfig,
    pub vmpo: VmpoConfig,
    pub buffer: BufferConfig,
    pub optim: OptimConfig,
    pub runtime: RuntimeConfig,
}

/// One named observation field and its length; the token is the fields concatenated in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObsField {
    pub key: String,
    pub size: usize,
    /// The field is one integer (a `task_id`), written into the token as a one-hot vector of
    /// `size` entries; an integer outside `0..size` is an error. Default false: the field's
    /// values as they come.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub one_hot: bool,
}

impl ObsField {
    /// A field taken as it comes (not one-hot).
    pub fn new(key: &str, size: usize) -> Self {
        Self {
            key: key.into(),
            size,
            one_hot: false,
        }
    }
}

/// Network shape (§2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// Observation fields concatenated into the token, in this order (state 39 · word 50 ·
    /// time 1 · phase 1 = 91). The no-instructions ablation appends `prev_reward` (1).
    pub observation: Vec<ObsField>,
    /// Action dimension (Meta-World: 4).
    pub action_dim: usize,
    /// Number of task ids = Pop-Art output rows (50 Meta-World tasks).
    pub num_tasks: usize,
    /// GTrXL layers.
    pub layers: usize,
    /// Model width.
    pub d_model: usize,
    /// Attention heads (must divide d_model).
    pub heads: usize,
    /// Feed-forward hidden width.
    pub ff_dim: usize,
    /// Initial value of the learnable gate bias b_g (GTrXL: 2.0 keeps gates near identity).
    pub gate_bias_init: f64,
    /// Segment length T (steps per stored segment and per learning sequence).
    pub segment_len: usize,
    /// Memory length (rows of the previous segment kept per layer).
    pub memory_len: usize,
    /// Hidden width of the policy head.
    pub policy_hidden: usize,
    /// Hidden width of the value head.
    pub value_hidden: usize,
    /// Floor added to the softplus standard deviation [S].
    pub min_std: f64,
    /// Observation fields (keys of `observation`) whose features are normalised by their
    /// running mean and variance before the token's LayerNorm (not in the paper; empty = the
    /// paper). See `model::obs_norm` and docs/experiments/2026-11-22-mt1-reach-update-regime.md
    /// (not adopted there). It applies to the fields, not to the
    /// words kept in the instruction slots.
    pub obs_norm: Vec<String>,
    /// Words of the latest instruction the agent keeps beside every token (0 = the paper: a
    /// word reaches later steps only through the GTrXL memory). With K > 0 the token ends with
    /// K slots of [valid, word…], and the network pools them by attention into its input, so
    /// every trial step has a gradient path to the goal word (not in the paper; see
    /// `model::instruction` and docs/experiments/2026-12-02-instruction-slots.md).
    pub instruction_words: usize,
    /// Learned queries of the instruction slots' pooling (with `instruction_words` > 0; not in
    /// the paper). Each query pools the slots by its own attention and the pooled values are
    /// concatenated before the output layer, so one query can keep to the verb that names the
    /// task while another keeps to `goal_pos`; 1 = a single bag-of-words average.
    pub instruction_queries: usize,
    /// Precision of the linear layers' matrix products: "float32" (the paper) or
    /// "bfloat16" (weights, gradients and optimiser state stay float32; no faster over a
    /// whole update on the 2-core machine, and no learning run has used it). See `model::dense`.
    pub matmul_dtype: MatmulDtype,
    /// A head that predicts the task's real goal (the env's `goal` info, metres) from the
    /// core's output at every trial step (not in the paper; "off" = the paper). "probe": its
    /// gradient stops at the core, so it only measures whether the network carries the goal
    /// (`learner/goal_error`, per task `learner/task_goal_error/<id>`); "auxiliary": its loss
    /// also trains the network, to make it read the goal in the words. The goal travels at
    /// the token's end, after the instruction slots, and the network never takes it as input.
    pub goal_prediction: GoalPrediction,
    /// Weight of the goal head's loss: ½ the squared distance (m²) between the predicted and
    /// the real goal, averaged over trial steps.
    pub goal_prediction_weight: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            observation: vec![
                ObsField::new("state", 39),
                ObsField::new("word", 50),
                ObsField::new("time", 1),
                ObsField::new("phase", 1),
            ],
            action_dim: 4,
            num_tasks: 50,
            layers: 6,
            d_model: 64,
            heads: 4,
            ff_dim: 256,
            gate_bias_init: 2.0,
            segment_len: 64,
            memory_len: 64,
            policy_hidden: 256,
            value_hidden: 256,
            min_std: 1e-4,
            obs_norm: vec![],
            instruction_words: 0,
            instruction_queries: 1,
            matmul_dtype: MatmulDtype::Float32,
            goal_prediction: GoalPrediction::Off,
            goal_prediction_weight: 1.0,
        }
    }
}

/// The observation field whose values are the instruction's words.
pub const WORD_FIELD: &str = "word";

impl ModelConfig {
    /// Length of the token: the configured fields, then the instruction slots, then the goal
    /// that `goal_prediction` learns to predict (not an input of the network).
    pub fn obs_dim(&self) -> usize {
        self.fields_dim() + self.instruction_dim() + self.goal_dim()
    }

    /// Width of the goal at the token's end: 3 with `goal_prediction`, else 0.
    pub fn goal_dim(&self) -> usize {
        match self.goal_prediction {
            GoalPrediction::Off => 0,
            GoalPrediction::Probe | GoalPrediction::Auxiliary => GOAL_DIM,
        }
    }

    /// Where the goal lies in the token: (offset, width); None without `goal_prediction`.
    pub fn goal_span(&self) -> Option<(usize, usize)> {
        (self.goal_dim() > 0).then(|| (self.fields_dim() + self.instruction_dim(), GOAL_DIM))
    }

    /// Length of the configured fields concatenated.
    pub fn fields_dim(&self) -> usize {
        self.observation.iter().map(|f| f.size).sum()
    }

    /// Width of one word (the `word` field's size; 0 without one).
    pub fn word_dim(&self) -> usize {
        self.word_span().map_or(0, |(_, width)| width)
    }

    /// Where the `word` field lies in the token: (offset, width); None without one.
    pub fn word_span(&self) -> Option<(usize, usize)> {
        let mut offset = 0;
        for f in &self.observation {
            if f.key == WORD_FIELD {
                return Some((offset, f.size));
            }
            offset += f.size;
        }
        None
    }

    /// Length of the instruction slots after the fields: K × (1 + word width).
    pub fn instruction_dim(&self) -> usize {
        self.instruction_words * (1 + self.word_dim())
    }

    /// Per token feature: whether `obs_norm` normalises it.
    pub fn obs_norm_mask(&self) -> Vec<bool> {
        self.observation
            .iter()
            .flat_map(|f| std::iter::repeat_n(self.obs_norm.contains(&f.key), f.size))
            .collect()
    }
}

/// Multi-task Pop-Art (§3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PopArtConfig {
    /// false = the "without Pop-Art" ablation: a plain, unnormalised value head.
    pub enabled: bool,
    /// Step size β of the running first and second moments.
    pub beta: f64,
    pub sigma_min: f64,
    pub sigma_max: f64,
    /// Debiased moments [S]: task k's step size is max(β, 1/n_k) after its n_k-th update, so
    /// the first update sets μ, σ to the batch's moments and the statistics are a plain
    /// running average until 1/n_k falls below β. With β = 1e-4 and undebiased moments
    /// (the paper), σ starts at 1 and needs ~10⁴ updates to reach the returns' scale, while
    /// the normalised advantages are too large by that factor; a run of a few thousand
    /// updates never gets there.
    pub debias: bool,
}

impl Default for PopArtConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            beta: 1e-4,
            sigma_min: 1e-2,
            sigma_max: 1e6,
            debias: false,
        }
    }
}

/// V-MPO losses (§4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VmpoConfig {
    pub gamma: f64,
    pub eps_eta: f64,
    pub eps_alpha_mu: f64,
    pub eps_alpha_sigma: f64,
    pub init_eta: f64,
    pub init_alpha_mu: f64,
    pub init_alpha_sigma: f64,
    /// Multipliers are projected back to at least this value after every step.
    pub min_multiplier: f64,
    /// ... and to at most this one (not in the paper; the default never binds there). In log
    /// form a violated bound grows a multiplier by a factor every update: without a ceiling
    /// α_Σ reached 1e23, after which its KL term outweighs every other loss
    /// (docs/experiments/2026-11-22-mt1-reach-update-regime.md).
    pub max_multiplier: f64,
    /// Normalised advantages are clipped to ±this.
    pub advantage_clip: f64,
    /// Fraction of valid steps kept for the policy loss (V-MPO: the top half).
    pub top_fraction: f64,
    /// How η, α_μ, α_Σ are kept positive: "clamp" (the original: the raw value, clamped at
    /// `min_multiplier` after each step) or "log" [S] (the variable is log η, so a step
    /// changes the multiplier by a factor, whatever its scale).
    pub multiplier_form: MultiplierForm,
    /// Adam step size of the multipliers; `None` = `optim.lr` (the original: one Adam over
    /// everything). With lr 1e-4 and clamp form a multiplier moves ~1e-4 per update, so in a
    /// few thousand updates η cannot follow the advantages' scale and the KL bounds are not
    /// enforced (docs/ALGORITHM.md §4.8 leaves the form open).
    pub multiplier_lr: Option<f64>,
    /// The policy the KL terms measure from: "behaviour" (the original: the distribution
    /// stored with each segment at acting time) or "target" (V-MPO's π_old [V]: a copy of the
    /// network, refreshed every `buffer.target_period` updates, evaluated on the batch). The
    /// FIFO buffer mixes segments of several actor versions, so no policy can be within a
    /// small ε of all their stored distributions at once: with enforced multipliers the
    /// behaviour form's constraint is infeasible and α grows without bound
    /// (docs/experiments/2026-11-22-mt1-reach-update-regime.md).
    pub kl_reference: KlReference,
    /// λ of the λ-return targets: 1 = the original's n-step returns to the segment's end;
    /// below 1 the advantages become GAE(λ), with less variance from later actions [S].
    pub lambda: f64,
    /// Learn from each segment's last step too [S]. Off (the original), step T−1 has no
    /// successor in the segment: it only bootstraps, and 1 in T of all transitions is never
    /// learned from. On, the learner runs one more step, the observation after the segment
    /// (stored with it), whose value step T−1 bootstraps from; that step enters no loss.
    pub learn_last_step: bool,
    /// Do V-MPO's E-step (top half and ψ) apart within each task of the batch [S]. Off (the
    /// original), the top half is ranked over every task at once, and a task whose
    /// normalised advantages are smaller than the others' gets little of the policy loss;
    /// `learner/task_psi_mass/<task id>` in the metrics says how much each task gets.
    pub per_task_e_step: bool,
}

/// Precision of the network's linear layers' matrix products.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MatmulDtype {
    /// Float32 throughout: the paper, and the only precision the PyTorch reference checks.
    #[default]
    Float32,
    /// Inputs and weights rounded to bfloat16 for the product; see `model::dense`.
    Bfloat16,
}

/// Values of the env's `goal` info: a position in metres.
pub const GOAL_DIM: usize = 3;
/// The info field `model.goal_prediction` predicts.
pub const GOAL_INFO: &str = "goal";

/// Whether and how the network predicts the task's goal (`model.goal_prediction`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum GoalPrediction {
    /// No goal head: the paper.
    #[default]
    Off,
    /// A goal head on the core's output with its gradient stopped: a measurement only.
    Probe,
    /// A goal head whose loss trains the network too.
    Auxiliary,
}

/// What the decoupled KL terms compare the learned policy with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum KlReference {
    #[default]
    Behaviour,
    Target,
}

/// Parameterisation of the Lagrange multipliers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MultiplierForm {
    #[default]
    Clamp,
    Log,
}

impl Default for VmpoConfig {
    fn default() -> Self {
        Self {
            gamma: 0.99,
            eps_eta: 0.1,
            eps_alpha_mu: 0.0075,
            eps_alpha_sigma: 1e-5,
            init_eta: 1.0,
            init_alpha_mu: 1.0,
            init_alpha_sigma: 1.0,
            min_multiplier: 1e-8,
            max_multiplier: 1e30,
            advantage_clip: 40.0,
            top_fraction: 0.5,
            multiplier_form: MultiplierForm::Clamp,
            multiplier_lr: None,
            kl_reference: KlReference::Behaviour,
            lambda: 1.0,
            learn_last_step: false,
            per_task_e_step: false,
        }
    }
}

/// FIFO segment buffer and learner pacing (§5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BufferConfig {
    /// Segments per update b.
    pub batch_segments: usize,
    /// Actor weights are refreshed every `target_period` updates; the buffer holds
    /// `batch_segments · target_period` segments.
    pub target_period: usize,
    /// (samples consumed) / (samples produced): what the learner makes under lockstep pacing,
    /// a ceiling under free pacing.
    pub replay_ratio: f64,
    /// How the learner keeps pace with the actors (train/learner_loop.rs). "lockstep": the
    /// learner makes exactly the updates `replay_ratio` allows after each batch of segments
    /// and the actors wait for it, one round of segments behind, so a seed's run is the same
    /// at any speed and load (number for number on one kind of CPU). "free": neither waits
    /// (speed benchmarks only; updates per agent step then follow the machine's load).
    pub pacing: Pacing,
    /// The learner starts once the buffer holds this many segments (at least `batch_segments`).
    pub min_segments: usize,
}

impl Default for BufferConfig {
    fn default() -> Self {
        Self {
            batch_segments: 128,
            target_period: 100,
            replay_ratio: 4.0,
            pacing: Pacing::Lockstep,
            min_segments: 128,
        }
    }
}

/// `buffer.pacing`: see [`BufferConfig::pacing`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Pacing {
    #[default]
    Lockstep,
    Free,
}

impl BufferConfig {
    pub fn capacity(&self) -> usize {
        self.batch_segments * self.target_period
    }
}

/// Adam (§4.8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OptimConfig {
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self {
            lr: 1e-4,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// CPU use: libtorch threads, local env servers, learner priority.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RuntimeConfig {
    /// libtorch intra-op threads (`tch::set_num_threads`) of the actor and of the learner
    /// thread each; on 2 cores leave one for the envs.
    pub intra_op_threads: usize,
    /// Local env servers `million train` starts when no `--env-server` is given.
    pub env_servers: usize,
    /// Tokio worker threads (gRPC streams of the env pool; acting runs on the main thread).
    pub io_threads: usize,
    /// Nice increment of the learner thread (Linux): > 0 lets actors and env servers take
    /// the CPU first, so a learner never starves them; the replay ratio bounds it anyway.
    pub learner_nice: i32,
    /// "cpu", "cuda" or "auto" (CUDA when available) for the learner and the actor.
    pub device: String,
    /// More command-line arguments of each local env server, e.g. `["--idle-envs", "4"]`
    /// (`million-env-server --help`); servers given with `--env-server` are not touched.
    pub env_server_args: Vec<String>,
}

impl Default for RuntimeConfig {
    fn default() -> Self {
        Self {
            intra_op_threads: 1,
            env_servers: 2,
            io_threads: 1,
            learner_nice: 0,
            device: "auto".into(),
            env_server_args: Vec::new(),
        }
    }
}

impl RuntimeConfig {
    /// Applies the thread setting to libtorch for the calling thread (OpenMP settings are
    /// per thread: call it in the actor and in the learner thread), and tunes the process's
    /// heap for tensor churn once ([`crate::heap`]).
    pub fn apply(&self) {
        crate::heap::keep_freed_memory();
        tch::set_num_threads(self.intra_op_threads.max(1) as i32);
    }

    pub fn device(&self) -> tch::Device {
        match self.device.as_str() {
            "cpu" => tch::Device::Cpu,
            "cuda" => tch::Device::Cuda(0),
            _ => tch::Device::cuda_if_available(),
        }
    }
}

/// The text of a config file, or a `Read` error naming it.
pub fn read_config_file(path: &Path) -> Result<String, ConfigError> {
    std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.display().to_string(),
        source,
    })
}

impl AgentConfig {
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        let cfg: AgentConfig = toml::from_str(text)?;
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        Self::from_toml_str(&read_config_file(path)?)
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        let m = &self.model;
        let bad = |msg: String| Err(ConfigError::Invalid(msg));
        if m.observation.is_empty() || m.observation.iter().any(|f| f.size == 0) {
            return bad("model.observation needs at least one field, each with size > 0".into());
        }
        if m.heads == 0 || !m.d_model.is_multiple_of(m.heads) {
            return bad(format!(
                "model.heads ({}) must divide model.d_model ({})",
                m.heads, m.d_model
            ));
        }
        for (name, v) in [
            ("model.action_dim", m.action_dim),
            ("model.num_tasks", m.num_tasks),
            ("model.layers", m.layers),
            ("model.ff_dim", m.ff_dim),
            ("model.segment_len", m.segment_len),
            ("model.policy_hidden", m.policy_hidden),
            ("model.value_hidden", m.value_hidden),
            ("buffer.batch_segments", self.buffer.batch_segments),
            ("buffer.target_period", self.buffer.target_period),
        ] {
            if v == 0 {
                return bad(format!("{name} must be > 0"));
            }
        }
        if m.segment_len < 2 {
            return bad("model.segment_len must be at least 2 (the last step bootstraps)".into());
        }
        if m.min_std <= 0.0 {
            return bad("model.min_std must be > 0".into());
        }
        if let Some(key) = m
            .obs_norm
            .iter()
            .find(|k| !m.observation.iter().any(|f| &f.key == *k))
        {
            return bad(format!(
                "model.obs_norm names `{key}`, which is not a field of model.observation"
            ));
        }
        if m.instruction_words > 0 && m.word_dim() == 0 {
            return bad(format!(
                "model.instruction_words = {} needs a `{WORD_FIELD}` field in model.observation \
                 (the words it keeps)",
                m.instruction_words
            ));
        }
        if m.instruction_queries == 0 {
            return bad("model.instruction_queries must be at least 1".into());
        }
        if !(m.goal_prediction_weight.is_finite() && m.goal_prediction_weight >= 0.0) {
            return bad("model.goal_prediction_weight must be finite and >= 0".into());
        }
        let p = &self.popart;
        if p.beta <= 0.0 || p.beta > 1.0 || p.sigma_min <= 0.0 || p.sigma_min >= p.sigma_max {
            return bad("popart: need 0 < beta <= 1 and 0 < sigma_min < sigma_max".into());
        }
        let v = &self.vmpo;
        if !(0.0..=1.0).contains(&v.gamma) {
            return bad("vmpo.gamma must be in [0, 1]".into());
        }
        if !(0.0..=1.0).contains(&v.lambda) {
            return bad("vmpo.lambda must be in [0, 1]".into());
        }
        if v.top_fraction <= 0.0 || v.top_fraction > 1.0 {
            return bad("vmpo.top_fraction must be in (0, 1]".into());
        }
        if v.min_multiplier <= 0.0
            || v.max_multiplier < v.min_multiplier
            || [v.init_eta, v.init_alpha_mu, v.init_alpha_sigma]
                .iter()
                .any(|&init| init > v.max_multiplier)
            || v.init_eta < v.min_multiplier
            || v.init_alpha_mu < v.min_multiplier
            || v.init_alpha_sigma < v.min_multiplier
        {
            return bad(
                "vmpo: need 0 < min_multiplier <= every initial multiplier <= max_multiplier"
                    .into(),
            );
        }
        if v.advantage_clip <= 0.0 {
            return bad("vmpo.advantage_clip must be > 0".into());
        }
        if self.buffer.replay_ratio <= 0.0 {
            return bad("buffer.replay_ratio must be > 0".into());
        }
        if self.buffer.min_segments > self.buffer.capacity() {
            return bad("buffer.min_segments exceeds the buffer capacity".into());
        }
        if !matches!(self.runtime.device.as_str(), "cpu" | "cuda" | "auto") {
            return bad(format!(
                "runtime.device must be \"cpu\", \"cuda\" or \"auto\", got {:?}",
                self.runtime.device
            ));
        }
        if self.runtime.io_threads == 0 {
            return bad("runtime.io_threads must be > 0".into());
        }
        if self.optim.lr <= 0.0 {
            return bad("optim.lr must be > 0".into());
        }
        if v.multiplier_lr.is_some_and(|lr| lr <= 0.0) {
            return bad("vmpo.multiplier_lr must be > 0".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_paper_values() {
        let c = AgentConfig::default();
        assert_eq!(c.model.obs_dim(), 91);
        assert_eq!(c.buffer.capacity(), 12_800);
        assert_eq!((c.model.layers, c.model.d_model, c.model.heads), (6, 64, 4));
        assert_eq!(c.vmpo.eps_eta, 0.1);
        c.validate().unwrap();
    }

    #[test]
    fn empty_toml_gives_defaults_and_partial_sections_merge() {
        assert_eq!(
            AgentConfig::from_toml_str("").unwrap(),
            AgentConfig::default()
        );
        let c = AgentConfig::from_toml_str("[vmpo]\neps_eta = 0.01\n").unwrap();
        assert_eq!(c.vmpo.eps_eta, 0.01);
        assert_eq!(c.vmpo.gamma, 0.99);
    }

    #[test]
    fn unknown_keys_are_rejected_with_their_name() {
        let err = AgentConfig::from_toml_str("[vmpo]\nepsilon_eta = 0.01\n").unwrap_err();
        assert!(err.to_string().contains("epsilon_eta"), "{err}");
        let err = AgentConfig::from_toml_str("[modle]\n").unwrap_err();
        assert!(err.to_string().contains("modle"), "{err}");
    }

    #[test]
    fn inconsistent_values_are_rejected() {
        let err = AgentConfig::from_toml_str("[model]\nheads = 5\n").unwrap_err();
        assert!(err.to_string().contains("heads"), "{err}");
    }

    #[test]
    fn instruction_slots_extend_the_token_and_need_a_word_field() {
        let c = AgentConfig::from_toml_str("[model]\ninstruction_words = 12\n").unwrap();
        assert_eq!(c.model.fields_dim(), 91);
        assert_eq!(c.model.obs_dim(), 91 + 12 * 51);
        // state (39) · word (50) · time · phase: the word follows the state.
        assert_eq!(c.model.word_span(), Some((39, 50)));
        let err = AgentConfig::from_toml_str(
            "[model]\ninstruction_words = 12\nobservation = [{ key = \"state\", size = 39 }]\n",
        )
        .unwrap_err();
        assert!(err.to_string().contains("needs a `word` field"), "{err}");
        let err = AgentConfig::from_toml_str(
            "[model]\ninstruction_words = 12\ninstruction_queries = 0\n",
        )
        .unwrap_err();
        assert!(err.to_string().contains("instruction_queries"), "{err}");
    }
}
