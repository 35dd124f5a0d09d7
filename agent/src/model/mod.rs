//! The MILLION network: observation token → [running normalisation, `model.obs_norm`] →
//! LayerNorm → Linear [+ the instruction slots' pooling, `model.instruction_words`] → GTrXL →
//! policy head and Pop-Art value head (docs/ALGORITHM.md §2) [+ the goal head,
//! `model.goal_prediction`].

pub mod acting;
pub mod dense;
pub mod gtrxl;
pub mod instruction;
pub mod obs_norm;
pub mod policy;
pub mod popart;

use tch::nn::{self, LayerNorm, Linear, Module};
use tch::{Device, Tensor};

use crate::config::{GOAL_DIM, GoalPrediction, ModelConfig, PopArtConfig};
use dense::Dense;
use gtrxl::Gtrxl;
use instruction::InstructionPool;
use obs_norm::ObsNorm;
use policy::PolicyHead;
use popart::PopArt;

/// The network. Variables live in the `VarStore` it was built from; the Pop-Art statistics
/// are non-trainable variables of the same store, so they travel with the weights.
#[derive(Debug)]
pub struct Model {
    cfg: ModelConfig,
    /// Running normalisation of the chosen token fields (`model.obs_norm`; None = the paper).
    obs_norm: Option<ObsNorm>,
    input_norm: LayerNorm,
    input_proj: Dense,
    /// Attention pooling of the instruction slots (None = the paper).
    instruction: Option<InstructionPool>,
    core: Gtrxl,
    policy: PolicyHead,
    value_hidden: Dense,
    popart: PopArt,
    /// Core output → the task's goal (None = the paper; `model.goal_prediction`).
    goal: Option<Linear>,
    device: Device,
}

/// Outputs of a whole-segment forward pass.
#[derive(Debug)]
pub struct SegmentOutput {
    /// Policy mean and std, `[B, T, A]`.
    pub mean: Tensor,
    pub std: Tensor,
    /// Features entering the Pop-Art layer, `[B, T, value_hidden]`. The normalised value is
    /// taken from them only after the Pop-Art update, so its gradient is for the new weights.
    pub value_features: Tensor,
    /// Core output `[B, T, d]`, memory for the next segment `[L, B, m, d]` and its length `[B]`.
    pub core: gtrxl::CoreOutput,
}

impl Model {
    pub fn new(p: &nn::Path, cfg: &ModelConfig, popart: &PopArtConfig) -> Self {
        let d = cfg.d_model as i64;
        let obs = cfg.fields_dim() as i64;
        Self {
            obs_norm: (!cfg.obs_norm.is_empty())
                .then(|| ObsNorm::new(p / "obs_norm", &cfg.obs_norm_mask())),
            input_norm: nn::layer_norm(p / "input_norm", vec![obs], Default::default()),
            input_proj: Dense::new(
                p / "input_proj",
                obs,
                d,
                Default::default(),
                cfg.matmul_dtype,
            ),
            instruction: (cfg.instruction_words > 0).then(|| {
                InstructionPool::new(
                    &(p / "instruction"),
                    cfg.instruction_words,
                    cfg.instruction_queries,
                    cfg.word_dim(),
                    cfg.d_model,
                )
            }),
            core: Gtrxl::new(p / "core", cfg),
            policy: PolicyHead::new(
                p / "policy",
                d,
                cfg.policy_hidden as i64,
                cfg.action_dim as i64,
                cfg.min_std,
                cfg.matmul_dtype,
            ),
            value_hidden: Dense::new(
                p / "value_hidden",
                d,
                cfg.value_hidden as i64,
                Default::default(),
                cfg.matmul_dtype,
            ),
            popart: PopArt::new(
                p / "popart",
                cfg.value_hidden as i64,
                cfg.num_tasks as i64,
                popart.clone(),
            ),
            // Zero-initialised: the head draws no random numbers, so a probe run acts and
            // learns number for number as the same seed without it.
            goal: (cfg.goal_prediction != GoalPrediction::Off).then(|| {
                let zero = nn::LinearConfig {
                    ws_init: nn::Init::Const(0.0),
                    bs_init: Some(nn::Init::Const(0.0)),
                    bias: true,
                };
                nn::linear(p / "goal", d, GOAL_DIM as i64, zero)
            }),
            cfg: cfg.clone(),
            device: p.device(),
        }
    }

    pub fn config(&self) -> &ModelConfig {
        &self.cfg
    }

    pub fn device(&self) -> Device {
        self.device
    }

    pub fn core(&self) -> &Gtrxl {
        &self.core
    }

    pub fn popart(&self) -> &PopArt {
        &self.popart
    }

    pub fn popart_mut(&mut self) -> &mut PopArt {
        &mut self.popart
    }

    pub fn obs_norm_mut(&mut self) -> Option<&mut ObsNorm> {
        self.obs_norm.as_mut()
    }

    /// The configured fields of tokens `[..., obs]`: everything but the instruction slots and
    /// the goal to predict.
    pub fn fields(&self, obs: &Tensor) -> Tensor {
        obs.narrow(-1, 0, self.cfg.fields_dim() as i64)
    }

    /// Token `[..., obs]` → model input `[..., d]`.
    pub fn embed(&self, obs: &Tensor) -> Tensor {
        let fields = self.fields(obs);
        let fields = match &self.obs_norm {
            Some(norm) => norm.forward(&fields),
            None => fields,
        };
        let x = self.input_proj.forward(&self.input_norm.forward(&fields));
        match &self.instruction {
            Some(pool) => {
                let slots = obs.narrow(-1, self.cfg.fields_dim() as i64, pool.width());
                x + pool.forward(&slots)
            }
            None => x,
        }
    }

    pub fn policy(&self, core: &Tensor) -> (Tensor, Tensor) {
        self.policy.forward(core)
    }

    pub fn value_features(&self, core: &Tensor) -> Tensor {
        self.value_hidden.forward(core).relu()
    }

    /// The goal head's prediction `[..., 3]` from core outputs `[..., d]`, its gradient
    /// stopped at the core for `goal_prediction = "probe"`; None without a goal head.
    pub fn goal(&self, core: &Tensor) -> Option<Tensor> {
        let head = self.goal.as_ref()?;
        Some(match self.cfg.goal_prediction {
            GoalPrediction::Probe => head.forward(&core.detach()),
            _ => head.forward(core),
        })
    }

    /// The goal each token carries for the goal head to predict, `[..., 3]`.
    pub fn goal_target(&self, obs: &Tensor) -> Option<Tensor> {
        let (offset, width) = self.cfg.goal_span()?;
        Some(obs.narrow(-1, offset as i64, width as i64))
    }

    /// Unnormalised value `[...]` from value features `[..., H]` and task ids `[...]`.
    pub fn value(&self, features: &Tensor, task: &Tensor) -> Tensor {
        let shape = task.size();
        let h = features.size()[features.dim() - 1];
        let flat_task = task.flatten(0, -1);
        let n = self
            .popart
            .normalised(&features.reshape([-1, h]), &flat_task);
        self.popart
            .unnormalise(&n, &flat_task)
            .view(shape.as_slice())
    }

    /// The policy's mean and std `[B, T, A]` alone over a segment: all the target network is
    /// asked for (V-MPO's KL reference), so its value head is not computed.
    pub fn policy_segment(
        &self,
        obs: &Tensor,
        episode_start: &Tensor,
        memory: &Tensor,
        memory_len: &Tensor,
    ) -> (Tensor, Tensor) {
        let core = self
            .core
            .forward_segment(&self.embed(obs), episode_start, memory, memory_len);
        self.policy(&core.output)
    }

    /// Learning forward pass over `obs` `[B, T, obs]` with the memory stored at segment start.
    pub fn forward_segment(
        &self,
        obs: &Tensor,
        episode_start: &Tensor,
        memory: &Tensor,
        memory_len: &Tensor,
    ) -> SegmentOutput {
        let x = self.embed(obs);
        let core = self
            .core
            .forward_segment(&x, episode_start, memory, memory_len);
        let (mean, std) = self.policy(&core.output);
        let value_features = self.value_features(&core.output);
        SegmentOutput {
            mean,
            std,
            value_features,
            core,
        }
    }
}
