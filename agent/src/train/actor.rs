//! Acting for one group of the env pool: turn the group's observations into tokens, act with
//! the incremental GTrXL state of its slots, send the (clipped) actions, and record what acted
//! into segments. Training samples from the behaviour policy; evaluation takes its mean.

use million_env::{EnvPool, Space, StepBatch};
use tch::{Device, Kind, Tensor};

use crate::algo::buffer::SegmentBatch;
use crate::algo::rollout::{NextObservation, RolloutCollector, StepRecord};
use crate::model::Model;
use crate::model::acting::ActingState;
use crate::model::policy::sample_actions;
use crate::train::tokens::{StepInputs, TokenBuilder};

/// Per-dimension action bounds of a Box action space, for clipping what the env receives.
#[derive(Debug)]
pub struct ActionBounds {
    low: Tensor,
    high: Tensor,
}

impl ActionBounds {
    pub fn from_space(space: &Space, action_dim: usize) -> anyhow::Result<Self> {
        let Space::Box(b) = space else {
            anyhow::bail!("the agent needs a Box action space, the env has {space:?}");
        };
        anyhow::ensure!(
            b.low.len() == action_dim,
            "the env's actions have {} dimensions, model.action_dim is {action_dim}",
            b.low.len()
        );
        let f = |v: &[f64]| Tensor::from_slice(&v.iter().map(|&x| x as f32).collect::<Vec<_>>());
        Ok(Self {
            low: f(&b.low),
            high: f(&b.high),
        })
    }

    /// Clips `[B, A]` actions to the bounds; row-major f32 values for the pool.
    pub fn clip(&self, actions: &Tensor) -> Vec<f32> {
        let a = actions
            .to_device(Device::Cpu)
            .to_kind(Kind::Float)
            .max_other(&self.low)
            .min_other(&self.high);
        Vec::<f32>::try_from(a.flatten(0, -1)).expect("f32 actions")
    }
}

struct Pending {
    inputs: StepInputs,
    episode_start: Tensor,
    action: Tensor,
    mean: Tensor,
    std: Tensor,
}

/// The acting side of one group.
pub struct GroupActor {
    pub group: usize,
    pub offset: usize,
    pub rows: usize,
    state: ActingState,
    collector: RolloutCollector,
    tokens: TokenBuilder,
    inputs: Option<StepInputs>,
    episode_start: Tensor,
    pending: Option<Pending>,
}

impl GroupActor {
    pub fn new(model: &Model, pool: &EnvPool, group: usize) -> Self {
        let envs = pool.group_envs(group);
        let rows = envs.len();
        Self {
            group,
            offset: envs.start,
            rows,
            state: model.acting_state(rows as i64),
            collector: RolloutCollector::new(model.config().segment_len),
            tokens: TokenBuilder::new(model.config(), rows),
            inputs: None,
            episode_start: Tensor::ones([rows as i64], (Kind::Bool, Device::Cpu)),
            pending: None,
        }
    }

    /// Steps taken in the current segment (0 = at a boundary, where weights may change).
    pub fn segment_step(&self) -> i64 {
        self.state.segment_step()
    }

    /// Takes the group's first observations (after a reset): every slot starts an episode.
    pub fn observe_reset(
        &mut self,
        model: &Model,
        obs: &million_env::Fields,
        info: &million_env::InfoBatch,
    ) -> anyhow::Result<()> {
        let starts = vec![true; self.rows];
        self.inputs = Some(
            self.tokens
                .step_inputs(model.config(), obs, Some(info), &starts)?,
        );
        self.episode_start = Tensor::from_slice(&starts);
        Ok(())
    }

    /// Acts on the current observations and sends the actions (`deterministic` = mean).
    pub fn act_and_send(
        &mut self,
        model: &Model,
        pool: &mut EnvPool,
        bounds: &ActionBounds,
        deterministic: bool,
    ) -> anyhow::Result<()> {
        let inputs = self
            .inputs
            .take()
            .ok_or_else(|| anyhow::anyhow!("group {} acted without an observation", self.group))?;
        if self.collector.is_at_segment_start() {
            let (memory, len) = self.state.segment_start_memory();
            self.collector.begin(memory, len);
        }
        let out = model.act(&mut self.state, &inputs.token, &self.episode_start);
        let action = if deterministic {
            out.mean.shallow_clone()
        } else {
            tch::no_grad(|| sample_actions(&out.mean, &out.std))
        };
        pool.send(self.group, &bounds.clip(&action))?;
        self.pending = Some(Pending {
            inputs,
            episode_start: self.episode_start.shallow_clone(),
            action,
            mean: out.mean,
            std: out.std,
        });
        Ok(())
    }

    /// Takes the reply to the last actions: records the step (when `record`) and returns a
    /// finished segment batch every T steps.
    pub fn observe_step(
        &mut self,
        model: &Model,
        step: &StepBatch,
        record: bool,
    ) -> anyhow::Result<Option<SegmentBatch>> {
        let p = self
            .pending
            .take()
            .ok_or_else(|| anyhow::anyhow!("group {} got a step it did not send", self.group))?;
        let ended = step.ended();
        let next_inputs =
            self.tokens
                .step_inputs(model.config(), &step.obs, Some(&step.info), &ended)?;
        let next_start = Tensor::from_slice(&ended);
        let mut batch = None;
        if record {
            batch = self.collector.push(
                StepRecord {
                    obs: p.inputs.token,
                    episode_start: p.episode_start,
                    action: p.action,
                    reward: Tensor::from_slice(&step.reward_f32()),
                    terminated: Tensor::from_slice(&step.terminated),
                    truncated: Tensor::from_slice(&step.truncated),
                    instruction: p.inputs.instruction,
                    task: p.inputs.task,
                    behaviour_mean: p.mean,
                    behaviour_std: p.std,
                },
                NextObservation {
                    obs: &next_inputs.token,
                    episode_start: &next_start,
                },
            )?;
        }
        self.inputs = Some(next_inputs);
        self.episode_start = next_start;
        Ok(batch)
    }
}
