//! Segments and the FIFO segment buffer with replay-ratio accounting (docs/ALGORITHM.md §5).

use std::collections::VecDeque;

use rand::Rng;
use tch::{Device, Tensor};

/// One env slot's T steps plus what the learner needs to replay them exactly as they acted.
#[derive(Debug)]
pub struct Segment {
    /// `[T, obs]` observation tokens.
    pub obs: Tensor,
    /// `[T, A]` unclipped sampled actions.
    pub actions: Tensor,
    /// `[T]` rewards of the actions.
    pub rewards: Tensor,
    /// `[T]` bool, kept apart: truncation bootstraps, termination does not.
    pub terminated: Tensor,
    pub truncated: Tensor,
    /// `[T]` bool: the observation is the first of a new episode.
    pub episode_start: Tensor,
    /// `[T]` bool: instruction-phase step (no action effect, out of the policy losses).
    pub instruction: Tensor,
    /// `[T]` i64 task ids.
    pub task: Tensor,
    /// `[T, A]` behaviour distribution at acting time.
    pub behaviour_mean: Tensor,
    pub behaviour_std: Tensor,
    /// `[obs]` the observation after the last step (the next segment's first) and `[]` bool:
    /// it starts a new episode. The last step bootstraps from its value when
    /// `vmpo.learn_last_step` is on; otherwise it is unused.
    pub bootstrap_obs: Tensor,
    pub bootstrap_start: Tensor,
    /// `[L, m, d]` memory at the segment start and its valid length (i64 scalar).
    pub memory: Tensor,
    pub memory_len: Tensor,
}

/// `b` segments stacked: a leading batch dimension on every field except `memory`, which is
/// `[L, b, m, d]` as the model takes it.
#[derive(Debug)]
pub struct SegmentBatch {
    pub obs: Tensor,
    pub actions: Tensor,
    pub rewards: Tensor,
    pub terminated: Tensor,
    pub truncated: Tensor,
    pub episode_start: Tensor,
    pub instruction: Tensor,
    pub task: Tensor,
    pub behaviour_mean: Tensor,
    pub behaviour_std: Tensor,
    pub bootstrap_obs: Tensor,
    pub bootstrap_start: Tensor,
    pub memory: Tensor,
    pub memory_len: Tensor,
}

impl SegmentBatch {
    pub fn len(&self) -> i64 {
        self.obs.size()[0]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn stack(segments: &[&Segment]) -> Self {
        let st = |f: fn(&Segment) -> &Tensor, dim: i64| {
            Tensor::stack(&segments.iter().map(|s| f(s)).collect::<Vec<_>>(), dim)
        };
        Self {
            obs: st(|s| &s.obs, 0),
            actions: st(|s| &s.actions, 0),
            rewards: st(|s| &s.rewards, 0),
            terminated: st(|s| &s.terminated, 0),
            truncated: st(|s| &s.truncated, 0),
            episode_start: st(|s| &s.episode_start, 0),
            instruction: st(|s| &s.instruction, 0),
            task: st(|s| &s.task, 0),
            behaviour_mean: st(|s| &s.behaviour_mean, 0),
            behaviour_std: st(|s| &s.behaviour_std, 0),
            bootstrap_obs: st(|s| &s.bootstrap_obs, 0),
            bootstrap_start: st(|s| &s.bootstrap_start, 0),
            memory: st(|s| &s.memory, 1),
            memory_len: st(|s| &s.memory_len, 0),
        }
    }

    /// One segment per slot (views into this batch's storage).
    pub fn split(&self) -> Vec<Segment> {
        (0..self.len())
            .map(|i| Segment {
                obs: self.obs.get(i),
                actions: self.actions.get(i),
                rewards: self.rewards.get(i),
                terminated: self.terminated.get(i),
                truncated: self.truncated.get(i),
                episode_start: self.episode_start.get(i),
                instruction: self.instruction.get(i),
                task: self.task.get(i),
                behaviour_mean: self.behaviour_mean.get(i),
                behaviour_std: self.behaviour_std.get(i),
                bootstrap_obs: self.bootstrap_obs.get(i),
                bootstrap_start: self.bootstrap_start.get(i),
                memory: self.memory.select(1, i),
                memory_len: self.memory_len.get(i),
            })
            .collect()
    }

    pub fn to_device(&self, device: Device) -> Self {
        let d = |t: &Tensor| t.to_device(device);
        Self {
            obs: d(&self.obs),
            actions: d(&self.actions),
            rewards: d(&self.rewards),
            terminated: d(&self.terminated),
            truncated: d(&self.truncated),
            episode_start: d(&self.episode_start),
            instruction: d(&self.instruction),
            task: d(&self.task),
            behaviour_mean: d(&self.behaviour_mean),
            behaviour_std: d(&self.behaviour_std),
            bootstrap_obs: d(&self.bootstrap_obs),
            bootstrap_start: d(&self.bootstrap_start),
            memory: d(&self.memory),
            memory_len: d(&self.memory_len),
        }
    }
}

/// First-in-first-out store of the newest `capacity` segments. The learner samples `batch`
/// segments uniformly (without replacement within a batch) and only while
/// (segments consumed + batch) ≤ replay_ratio · (segments produced).
#[derive(Debug)]
pub struct SegmentBuffer {
    segments: VecDeque<Segment>,
    capacity: usize,
    batch: usize,
    min_segments: usize,
    replay_ratio: f64,
    produced: u64,
    consumed: u64,
}

/// Produced/consumed counters, for logging and checkpoints.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, Default)]
pub struct BufferCounters {
    pub produced_segments: u64,
    pub consumed_segments: u64,
}

impl SegmentBuffer {
    pub fn new(cfg: &crate::config::BufferConfig) -> Self {
        Self {
            segments: VecDeque::with_capacity(cfg.capacity()),
            capacity: cfg.capacity(),
            batch: cfg.batch_segments,
            min_segments: cfg.min_segments.max(cfg.batch_segments),
            replay_ratio: cfg.replay_ratio,
            produced: 0,
            consumed: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.segments.len()
    }

    pub fn is_empty(&self) -> bool {
        self.segments.is_empty()
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    pub fn push(&mut self, segment: Segment) {
        if self.segments.len() == self.capacity {
            self.segments.pop_front();
        }
        self.segments.push_back(segment);
        self.produced += 1;
    }

    pub fn push_batch(&mut self, batch: &SegmentBatch) {
        for s in batch.split() {
            self.push(s);
        }
    }

    /// Whether the learner may take a batch now.
    pub fn ready(&self) -> bool {
        self.segments.len() >= self.min_segments
            && (self.consumed + self.batch as u64) as f64
                <= self.replay_ratio * self.produced as f64
    }

    /// (samples consumed) / (samples produced) so far.
    pub fn replay_ratio(&self) -> f64 {
        if self.produced == 0 {
            0.0
        } else {
            self.consumed as f64 / self.produced as f64
        }
    }

    /// A uniform batch, or `None` while not [`ready`](Self::ready).
    pub fn sample(&mut self, rng: &mut impl Rng) -> Option<SegmentBatch> {
        if !self.ready() {
            return None;
        }
        let idx = rand::seq::index::sample(rng, self.segments.len(), self.batch);
        let chosen: Vec<&Segment> = idx.iter().map(|i| &self.segments[i]).collect();
        let batch = SegmentBatch::stack(&chosen);
        self.consumed += self.batch as u64;
        Some(batch)
    }

    pub fn iter(&self) -> impl Iterator<Item = &Segment> {
        self.segments.iter()
    }

    pub fn counters(&self) -> BufferCounters {
        BufferCounters {
            produced_segments: self.produced,
            consumed_segments: self.consumed,
        }
    }

    /// Restores the counters after a resume (the segments themselves are not checkpointed).
    pub fn restore_counters(&mut self, c: BufferCounters) {
        self.produced = c.produced_segments;
        self.consumed = c.consumed_segments;
    }
}
