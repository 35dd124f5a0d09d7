//! The instruction slots' path into the network (`model.instruction_words` = K > 0; not in
//! the paper). The token ends with K slots of [valid, word…] holding the latest instruction's
//! words (`train::instruction_slots` keeps them). Each of Q learned queries
//! (`model.instruction_queries`) attends over the valid slots; the Q pooled values, side by
//! side, join the token's embedding through one output layer:
//!
//! ```text
//! slots [.., K, 1+W] ─ words ─┬─ key   Linear(W→d) ─┐
//!                             │                     ├ softmax(q_i·k/√d over valid slots + null) ─ Σ ─┐
//!                             └─ value Linear(W→d) ─┘              for each query q_1 … q_Q         │
//!                                                       concatenated [.., Q·d] ─ Linear(Q·d→d) ─→ [.., d]
//! ```
//!
//! Why: in the paper a word reaches later steps only through the GTrXL memory, which the
//! learner treats as a constant (stop-gradient), so a trial step's loss trains the goal
//! word's encoding only when both lie in one 32-step segment. The slots are part of every
//! stored token, so every step's loss reaches the words. The pooling ignores word order (a
//! bag of words): enough to find a goal word, and the same for any paraphrase's length. A
//! null slot (score 0, value 0) makes an empty context add nothing instead of NaN. One query
//! must weigh the words that name the task against `goal_pos` in a single average; with
//! several, each can keep to its own word.

use tch::nn::{self, Linear, Module};
use tch::{Kind, Tensor};

#[derive(Debug)]
pub struct InstructionPool {
    slots: i64,
    word: i64,
    d: i64,
    queries: i64,
    /// `[d]` with one query (the variable of configs before several existed), `[Q, d]` else.
    query: Tensor,
    key: Linear,
    value: Linear,
    out: Linear,
}

impl InstructionPool {
    pub fn new(p: &nn::Path, slots: usize, queries: usize, word: usize, d: usize) -> Self {
        let (w, d, q) = (word as i64, d as i64, queries as i64);
        let shape: &[i64] = if q == 1 { &[d] } else { &[q, d] };
        Self {
            slots: slots as i64,
            word: w,
            d,
            queries: q,
            query: p.randn("query", shape, 0.0, 1.0 / (d as f64).sqrt()),
            key: nn::linear(p / "key", w, d, Default::default()),
            value: nn::linear(p / "value", w, d, Default::default()),
            out: nn::linear(p / "out", q * d, d, Default::default()),
        }
    }

    /// Width of the slots part of the token: K × (1 + W).
    pub fn width(&self) -> i64 {
        self.slots * (1 + self.word)
    }

    /// Slots `[..., K·(1+W)]` → `[..., d]`.
    pub fn forward(&self, slots: &Tensor) -> Tensor {
        let mut lead = slots.size();
        lead.pop();
        let s = slots.reshape([-1, self.slots, 1 + self.word]);
        let n = s.size()[0];
        let valid = s.narrow(2, 0, 1).squeeze_dim(2).gt(0.5); // [N, K]
        let words = s.narrow(2, 1, self.word);
        let keys = self.key.forward(&words); // [N, K, d]
        let values = self.value.forward(&words);
        let (q, d) = (self.queries, self.d);
        lead.push(d);
        if q == 1 {
            // One query: the arithmetic of the runs made before several existed, kept so that
            // their seeds repeat number for number.
            let scores = keys
                .matmul(&self.query.view([d, 1]))
                .squeeze_dim(2)
                .divide_scalar((d as f64).sqrt())
                .masked_fill(&valid.logical_not(), f64::NEG_INFINITY);
            let null = Tensor::zeros([n, 1], (Kind::Float, slots.device()));
            let weights = Tensor::cat(&[scores, null], 1)
                .softmax(1, Kind::Float)
                .narrow(1, 0, self.slots); // [N, K]
            let pooled = (weights.unsqueeze(2) * values).sum_dim_intlist(1, false, Kind::Float);
            return self.out.forward(&pooled).view(lead.as_slice());
        }
        let scores = keys
            .matmul(&self.query.view([q, d]).transpose(0, 1)) // [N, K, Q]
            .divide_scalar((d as f64).sqrt())
            .masked_fill(&valid.logical_not().unsqueeze(2), f64::NEG_INFINITY);
        let null = Tensor::zeros([n, 1, q], (Kind::Float, slots.device()));
        let weights = Tensor::cat(&[scores, null], 1)
            .softmax(1, Kind::Float)
            .narrow(1, 0, self.slots); // [N, K, Q]
        // Each query's weighted sum of the values, side by side: [N, Q, d] → [N, Q·d].
        let pooled = weights.transpose(1, 2).matmul(&values).reshape([n, q * d]);
        self.out.forward(&pooled).view(lead.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, nn::VarStore};

    fn slots(rows: &[(f32, [f32; 2])]) -> Tensor {
        let v: Vec<f32> = rows
            .iter()
            .flat_map(|(valid, w)| [*valid, w[0], w[1]])
            .collect();
        Tensor::from_slice(&v).view([1, -1])
    }

    #[test]
    fn empty_slots_add_the_bias_only_and_invalid_slots_are_ignored() {
        for queries in [1, 3] {
            empty_and_invalid_slots(queries);
        }
    }

    fn empty_and_invalid_slots(queries: usize) {
        let vs = VarStore::new(Device::Cpu);
        let pool = InstructionPool::new(&vs.root(), 3, queries, 2, 8);
        let empty = pool.forward(&slots(&[(0.0, [0.0; 2]); 3]));
        assert_eq!(empty.size(), vec![1, 8]);
        assert!(bool::try_from(empty.isfinite().all()).unwrap());
        let bias = pool.out.bs.as_ref().unwrap().view([1, 8]);
        assert!(empty.allclose(&bias, 1e-6, 1e-6, false));
        // An invalid slot's content changes nothing; a valid one does.
        let one = pool.forward(&slots(&[
            (1.0, [0.3, -0.2]),
            (0.0, [0.0; 2]),
            (0.0, [0.0; 2]),
        ]));
        let junk = pool.forward(&slots(&[
            (1.0, [0.3, -0.2]),
            (0.0, [5.0, 5.0]),
            (0.0, [0.0; 2]),
        ]));
        assert!(one.allclose(&junk, 1e-6, 1e-6, false));
        assert!(!one.allclose(&empty, 1e-4, 1e-4, false));
    }

    #[test]
    fn pooling_ignores_slot_order_and_keeps_leading_dimensions() {
        for queries in [1, 3] {
            slot_order_and_leading_dimensions(queries);
        }
    }

    fn slot_order_and_leading_dimensions(queries: usize) {
        let vs = VarStore::new(Device::Cpu);
        let pool = InstructionPool::new(&vs.root(), 2, queries, 2, 4);
        let a = pool.forward(&slots(&[(1.0, [0.1, 0.9]), (1.0, [-0.5, 0.2])]));
        let b = pool.forward(&slots(&[(1.0, [-0.5, 0.2]), (1.0, [0.1, 0.9])]));
        assert!(a.allclose(&b, 1e-6, 1e-6, false));
        let rows: Vec<Tensor> = (0..6)
            .map(|_| slots(&[(1.0, [0.1, 0.9]), (0.0, [0.0; 2])]))
            .collect();
        let batch = Tensor::cat(&rows, 0).view([2, 3, 6]);
        assert_eq!(pool.forward(&batch).size(), vec![2, 3, 4]);
    }

    #[test]
    fn each_query_reads_its_own_word() {
        // Keys copy the word into the first two of d = 4 dimensions; query 0 looks along the
        // first, query 1 along the second, each strongly enough to hold all its weight on
        // one word. Then the reader's output is the output layer applied to the two words'
        // values side by side, whatever other words the slots hold.
        let vs = VarStore::new(Device::Cpu);
        let pool = InstructionPool::new(&vs.root(), 3, 2, 2, 4);
        tch::no_grad(|| {
            let mut key = pool.key.ws.shallow_clone();
            key.copy_(&Tensor::from_slice(&[1f32, 0., 0., 1., 0., 0., 0., 0.]).view([4, 2]));
            let _ = pool.key.bs.as_ref().unwrap().shallow_clone().zero_();
            let mut query = pool.query.shallow_clone();
            query.copy_(&Tensor::from_slice(&[80f32, 0., 0., 0., 0., 80., 0., 0.]).view([2, 4]));
        });
        let (first, second, other) = ([1f32, 0.], [0f32, 1.], [-1f32, -1.]);
        let got = pool.forward(&slots(&[(1.0, other), (1.0, second), (1.0, first)]));
        let word = |w: [f32; 2]| pool.value.forward(&Tensor::from_slice(&w).view([1, 2]));
        let expected = pool
            .out
            .forward(&Tensor::cat(&[word(first), word(second)], 1));
        assert!(
            got.allclose(&expected, 1e-5, 1e-5, false),
            "{got} {expected}"
        );
    }
}
