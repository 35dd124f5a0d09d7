//! Incremental acting: one step for all B env slots at a time. Per layer it caches the keys
//! and values of the memory and of the segment's steps so far, and the segment's normalised
//! layer inputs (the next memory), so a step costs one token per slot instead of re-running
//! the window. All slots advance together; segment boundaries are every T steps and episode
//! boundaries are per slot, through the same `valid_from` rule as `Gtrxl::forward_segment`.

use tch::{Kind, Tensor};

use super::Model;
use super::gtrxl::last_rows;

/// Per-slot recurrent state of the actor.
#[derive(Debug)]
pub struct ActingState {
    batch: i64,
    step: i64,
    memory: Tensor,
    memory_len: Tensor,
    valid_from: Tensor,
    keys: Vec<Tensor>,
    values: Vec<Tensor>,
    inputs: Vec<Tensor>,
    caches_ready: bool,
}

/// Behaviour distribution of one step, `[B, A]` each.
#[derive(Debug)]
pub struct ActOutput {
    pub mean: Tensor,
    pub std: Tensor,
}

impl ActingState {
    pub fn batch(&self) -> i64 {
        self.batch
    }

    /// Steps already taken in the current segment (0 = at a segment start).
    pub fn segment_step(&self) -> i64 {
        self.step
    }

    /// Memory `[L, B, m, d]` and its valid length `[B]` at the start of the current segment:
    /// exactly what the learner must be given with this segment.
    pub fn segment_start_memory(&self) -> (Tensor, Tensor) {
        (self.memory.shallow_clone(), self.memory_len.shallow_clone())
    }
}

impl Model {
    /// Fresh state for `batch` slots: zero memory, at a segment start.
    pub fn acting_state(&self, batch: i64) -> ActingState {
        let (memory, memory_len) = self.core().empty_memory(batch, self.device());
        ActingState {
            batch,
            step: 0,
            valid_from: memory_len.shallow_clone(),
            memory,
            memory_len,
            keys: vec![],
            values: vec![],
            inputs: vec![],
            caches_ready: false,
        }
    }

    /// One step for every slot. `obs` `[B, obs]`; `episode_start` `[B]` bool marks slots whose
    /// observation is the first of a new episode (their earlier steps become invisible).
    pub fn act(&self, state: &mut ActingState, obs: &Tensor, episode_start: &Tensor) -> ActOutput {
        tch::no_grad(|| self.act_no_grad(state, obs, episode_start))
    }

    fn act_no_grad(
        &self,
        state: &mut ActingState,
        obs: &Tensor,
        episode_start: &Tensor,
    ) -> ActOutput {
        let core = self.core();
        let m = core.memory_len();
        let t_len = self.config().segment_len as i64;
        let device = self.device();
        assert_eq!(
            obs.size()[0],
            state.batch,
            "observation batch does not match the acting state"
        );
        if !state.caches_ready {
            self.start_segment(state);
        }
        let t = state.step;
        let episode_start = episode_start.to_device(device).to_kind(Kind::Bool);
        state.valid_from = Tensor::full([state.batch], m + t, (Kind::Int64, device))
            .where_self(&episode_start, &state.valid_from);
        let k_len = m + t + 1;
        let key_idx = Tensor::arange(k_len, (Kind::Int64, device)).unsqueeze(0);
        let allowed = key_idx.ge_tensor(&state.valid_from.unsqueeze(1)); // [B, K']
        let mask = Tensor::zeros([state.batch, 1, 1, k_len], (Kind::Float, device)).masked_fill(
            &allowed.logical_not().view([state.batch, 1, 1, k_len]),
            f64::NEG_INFINITY,
        );
        let distance = (-key_idx + (m + t)).view([1, k_len]);
        let mut x = self.embed(&obs.to_device(device)).unsqueeze(1);
        for (l, layer) in core.layers().iter().enumerate() {
            let x_norm = layer.normalise_input(&x);
            state.inputs[l].narrow(1, t, 1).copy_(&x_norm);
            let (k, v) = layer.keys_values(&x_norm);
            state.keys[l].narrow(2, m + t, 1).copy_(&k);
            state.values[l].narrow(2, m + t, 1).copy_(&v);
            let bias = &mask + layer.relative_bias(&distance).unsqueeze(0);
            x = layer.attend_and_gate(
                &x,
                &x_norm,
                &state.keys[l].narrow(2, 0, k_len),
                &state.values[l].narrow(2, 0, k_len),
                &bias,
            );
        }
        let (mean, std) = self.policy(&x.squeeze_dim(1));
        state.step += 1;
        if state.step == t_len {
            Self::finish_segment(state, m, t_len);
        }
        ActOutput { mean, std }
    }

    fn start_segment(&self, state: &mut ActingState) {
        let core = self.core();
        let m = core.memory_len();
        let t_len = self.config().segment_len as i64;
        let d = core.d_model();
        let device = self.device();
        state.keys.clear();
        state.values.clear();
        state.inputs.clear();
        for (l, layer) in core.layers().iter().enumerate() {
            let (k, v) = layer.keys_values(&state.memory.get(l as i64));
            let mut shape = k.size();
            shape[2] = m + t_len;
            let keys = Tensor::zeros(shape.as_slice(), (Kind::Float, device));
            let values = Tensor::zeros(shape.as_slice(), (Kind::Float, device));
            keys.narrow(2, 0, m).copy_(&k);
            values.narrow(2, 0, m).copy_(&v);
            state.keys.push(keys);
            state.values.push(values);
            state.inputs.push(Tensor::zeros(
                [state.batch, t_len, d],
                (Kind::Float, device),
            ));
        }
        state.valid_from = -&state.memory_len + m;
        state.caches_ready = true;
    }

    /// The window's valid rows become the next segment's memory; keys and values are recomputed
    /// at the next step because the weights may be refreshed between segments.
    fn finish_segment(state: &mut ActingState, m: i64, t_len: i64) {
        let next_len = (-&state.valid_from + (m + t_len)).clamp_max(m);
        let layers: Vec<Tensor> = state
            .inputs
            .iter()
            .enumerate()
            .map(|(l, inputs)| {
                let rows = Tensor::cat(&[state.memory.get(l as i64), inputs.shallow_clone()], 1);
                last_rows(&rows, m, &next_len)
            })
            .collect();
        state.memory = Tensor::stack(&layers, 0);
        state.memory_len = next_len;
        state.step = 0;
        state.caches_ready = false;
    }
}
