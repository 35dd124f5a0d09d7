//! Collects the steps of all acting slots into segment batches of T steps.

use tch::{Device, Kind, Tensor};

use super::buffer::SegmentBatch;

/// Everything recorded for one step of all B slots (`[B, ...]` each).
#[derive(Debug)]
pub struct StepRecord {
    pub obs: Tensor,
    pub episode_start: Tensor,
    pub action: Tensor,
    pub reward: Tensor,
    pub terminated: Tensor,
    pub truncated: Tensor,
    pub instruction: Tensor,
    pub task: Tensor,
    pub behaviour_mean: Tensor,
    pub behaviour_std: Tensor,
}

/// The observation a step led to (after an autoreset, the next episode's first) and whether it
/// starts a new episode, `[B, obs]` and `[B]`. Kept for the segment's last step: its value is
/// what that step bootstraps from (`vmpo.learn_last_step`).
#[derive(Debug)]
pub struct NextObservation<'a> {
    pub obs: &'a Tensor,
    pub episode_start: &'a Tensor,
}

/// Accumulates T steps after `begin` (called with the acting state's segment-start memory) and
/// returns the finished batch on CPU.
#[derive(Debug)]
pub struct RolloutCollector {
    segment_len: usize,
    steps: Vec<StepRecord>,
    memory: Option<(Tensor, Tensor)>,
}

#[derive(Debug, thiserror::Error)]
pub enum RolloutError {
    #[error("a step was pushed before the segment's start memory was given")]
    NotStarted,
}

impl RolloutCollector {
    pub fn new(segment_len: usize) -> Self {
        Self {
            segment_len,
            steps: Vec::with_capacity(segment_len),
            memory: None,
        }
    }

    pub fn is_at_segment_start(&self) -> bool {
        self.steps.is_empty()
    }

    /// Memory `[L, B, m, d]` and length `[B]` at the start of the segment being collected.
    pub fn begin(&mut self, memory: Tensor, memory_len: Tensor) {
        self.steps.clear();
        self.memory = Some((memory, memory_len));
    }

    pub fn push(
        &mut self,
        step: StepRecord,
        next: NextObservation<'_>,
    ) -> Result<Option<SegmentBatch>, RolloutError> {
        if self.memory.is_none() {
            return Err(RolloutError::NotStarted);
        }
        self.steps.push(step);
        if self.steps.len() < self.segment_len {
            return Ok(None);
        }
        let steps = std::mem::take(&mut self.steps);
        let (memory, memory_len) = self.memory.take().ok_or(RolloutError::NotStarted)?;
        let col = |f: fn(&StepRecord) -> &Tensor, kind: Kind| {
            let cols: Vec<Tensor> = steps
                .iter()
                .map(|s| f(s).to_device(Device::Cpu).to_kind(kind))
                .collect();
            Tensor::stack(&cols, 1)
        };
        Ok(Some(SegmentBatch {
            obs: col(|s| &s.obs, Kind::Float),
            actions: col(|s| &s.action, Kind::Float),
            rewards: col(|s| &s.reward, Kind::Float),
            terminated: col(|s| &s.terminated, Kind::Bool),
            truncated: col(|s| &s.truncated, Kind::Bool),
            episode_start: col(|s| &s.episode_start, Kind::Bool),
            instruction: col(|s| &s.instruction, Kind::Bool),
            task: col(|s| &s.task, Kind::Int64),
            behaviour_mean: col(|s| &s.behaviour_mean, Kind::Float),
            behaviour_std: col(|s| &s.behaviour_std, Kind::Float),
            bootstrap_obs: next.obs.to_device(Device::Cpu).to_kind(Kind::Float),
            bootstrap_start: next
                .episode_start
                .to_device(Device::Cpu)
                .to_kind(Kind::Bool),
            memory: memory.to_device(Device::Cpu),
            memory_len: memory_len.to_device(Device::Cpu),
        }))
    }
}
