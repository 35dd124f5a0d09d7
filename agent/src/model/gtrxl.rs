//! The Gated Transformer-XL core (docs/ALGORITHM.md §2): pre-LayerNorm layers with GRU-type gates,
//! causal attention over `[sg(memory); segment]` with a learned relative-position bias per
//! head, and a per-layer memory of the previous segment's normalised layer inputs.
//!
//! Episode boundaries: every query step has a `valid_from` index into the concatenated key
//! sequence (memory rows `0..m`, segment rows `m..m+T`); keys before it belong to an earlier
//! episode and are masked. Learning (`forward_segment`) and acting (`crate::model::acting`)
//! derive it from the same rule, so both see exactly the same keys.

use tch::nn::{self, LayerNorm, Module};
use tch::{Device, Kind, Tensor};

use crate::config::{MatmulDtype, ModelConfig};
use crate::model::dense::Dense;

/// GRU-type gate of GTrXL: `out = (1 − z) ⊙ x + z ⊙ h`.
#[derive(Debug)]
pub struct Gate {
    /// W_r, W_z, W_g applied to y in one matrix product.
    w: Dense,
    /// U_r, U_z applied to x in one matrix product.
    u_rz: Dense,
    u_g: Dense,
    b_g: Tensor,
}

impl Gate {
    pub fn new(p: nn::Path, d: i64, bias_init: f64, dtype: MatmulDtype) -> Self {
        let no_bias = nn::LinearConfig {
            bias: false,
            ..Default::default()
        };
        Self {
            w: Dense::new(&p / "w", d, 3 * d, no_bias, dtype),
            u_rz: Dense::new(&p / "u_rz", d, 2 * d, no_bias, dtype),
            u_g: Dense::new(&p / "u_g", d, d, no_bias, dtype),
            b_g: p.var("b_g", &[d], nn::Init::Const(bias_init)),
        }
    }

    pub fn forward(&self, x: &Tensor, y: &Tensor) -> Tensor {
        self.forward_with_update_gate(x, y).0
    }

    /// The gate output and its update gate z (z ≈ 0 means the gate passes x through).
    pub fn forward_with_update_gate(&self, x: &Tensor, y: &Tensor) -> (Tensor, Tensor) {
        let d = self.b_g.size()[0];
        let wy = self.w.forward(y);
        // W_r y + U_r x and W_z y + U_z x in one addition; x + z ⊙ (h − x) in one lerp.
        let rz = wy.narrow(-1, 0, 2 * d) + self.u_rz.forward(x);
        let r = rz.narrow(-1, 0, d).sigmoid();
        let z = (rz.narrow(-1, d, d) - &self.b_g).sigmoid();
        let h = (wy.narrow(-1, 2 * d, d) + self.u_g.forward(&(&r * x))).tanh();
        (x.lerp_tensor(&h, &z), z)
    }
}

/// One GTrXL layer.
#[derive(Debug)]
pub struct GtrxlLayer {
    ln_attn: LayerNorm,
    q: Dense,
    kv: Dense,
    out: Dense,
    gate_attn: Gate,
    ln_ff: LayerNorm,
    ff1: Dense,
    ff2: Dense,
    gate_ff: Gate,
    /// Learned bias per head and relative distance (query index − key index), `[H, K]`.
    rel_bias: Tensor,
    heads: i64,
    d: i64,
}

impl GtrxlLayer {
    fn new(p: nn::Path, cfg: &ModelConfig, max_distance: i64) -> Self {
        let (d, heads, ff) = (cfg.d_model as i64, cfg.heads as i64, cfg.ff_dim as i64);
        let (gate_bias, dtype) = (cfg.gate_bias_init, cfg.matmul_dtype);
        Self {
            ln_attn: nn::layer_norm(&p / "ln_attn", vec![d], Default::default()),
            q: Dense::new(&p / "q", d, d, Default::default(), dtype),
            kv: Dense::new(&p / "kv", d, 2 * d, Default::default(), dtype),
            out: Dense::new(&p / "out", d, d, Default::default(), dtype),
            gate_attn: Gate::new(&p / "gate_attn", d, gate_bias, dtype),
            ln_ff: nn::layer_norm(&p / "ln_ff", vec![d], Default::default()),
            ff1: Dense::new(&p / "ff1", d, ff, Default::default(), dtype),
            ff2: Dense::new(&p / "ff2", ff, d, Default::default(), dtype),
            gate_ff: Gate::new(&p / "gate_ff", d, gate_bias, dtype),
            rel_bias: p.zeros("rel_bias", &[heads, max_distance]),
            heads,
            d,
        }
    }

    pub fn normalise_input(&self, x: &Tensor) -> Tensor {
        self.ln_attn.forward(x)
    }

    /// Keys and values `[B, H, N, d/H]` of normalised rows `[B, N, d]`.
    pub fn keys_values(&self, rows: &Tensor) -> (Tensor, Tensor) {
        let (b, n, _) = rows.size3().expect("rows are [B, N, d]");
        let kv = self.kv.forward(rows).chunk(2, -1);
        let split = |t: &Tensor| {
            t.view([b, n, self.heads, self.d / self.heads])
                .transpose(1, 2)
        };
        (split(&kv[0]), split(&kv[1]))
    }

    /// Relative bias `[H, Q, K]` for the given distance table `[Q, K]` (clamped to the table).
    pub fn relative_bias(&self, distance: &Tensor) -> Tensor {
        let (q, k) = distance.size2().expect("distance is [Q, K]");
        let max = self.rel_bias.size()[1];
        self.rel_bias
            .index_select(1, &distance.clamp(0, max - 1).flatten(0, -1))
            .view([self.heads, q, k])
    }

    /// Attention of normalised queries `[B, Q, d]` over keys/values, with an additive bias
    /// broadcastable to `[B, H, Q, K]`, followed by both gated sub-layers.
    pub fn attend_and_gate(
        &self,
        x: &Tensor,
        x_norm: &Tensor,
        k: &Tensor,
        v: &Tensor,
        bias: &Tensor,
    ) -> Tensor {
        let (b, q_len, _) = x_norm.size3().expect("x_norm is [B, Q, d]");
        let q = self
            .q
            .forward(x_norm)
            .view([b, q_len, self.heads, self.d / self.heads])
            .transpose(1, 2);
        // Plain matmul-softmax-matmul: with a bias that needs a gradient (the relative bias)
        // libtorch's fused attention falls back to a slower path with extra −∞ checks.
        let scale = 1.0 / ((self.d / self.heads) as f64).sqrt();
        let scores = (q * scale).matmul(&k.transpose(-2, -1)) + bias;
        let y = scores
            .softmax(-1, Kind::Float)
            .matmul(v)
            .transpose(1, 2)
            .reshape([b, q_len, self.d]);
        let y = self.out.forward(&y).relu();
        let x = self.gate_attn.forward(x, &y);
        let f = self
            .ff2
            .forward(&self.ff1.forward(&self.ln_ff.forward(&x)).relu())
            .relu();
        self.gate_ff.forward(&x, &f)
    }

    pub fn gate_attn(&self) -> &Gate {
        &self.gate_attn
    }
}

/// Output of the core over one segment.
#[derive(Debug)]
pub struct CoreOutput {
    /// `[B, T, d]`
    pub output: Tensor,
    /// Valid trailing rows of `next_memory()`, `[B]` (i64).
    pub next_memory_len: Tensor,
    /// Each layer's `[memory; normalised segment]` rows, `[B, m + T, d]`, from which the
    /// next memory is cut on demand: learning never asks for it, so it costs nothing there.
    rows: Vec<Tensor>,
    memory_len: i64,
}

impl CoreOutput {
    /// Memory for the next segment, `[L, B, m, d]` (detached, rows of ended episodes zeroed).
    pub fn next_memory(&self) -> Tensor {
        let layers: Vec<Tensor> = self
            .rows
            .iter()
            .map(|rows| last_rows(&rows.detach(), self.memory_len, &self.next_memory_len))
            .collect();
        Tensor::stack(&layers, 0)
    }
}

#[derive(Debug)]
pub struct Gtrxl {
    layers: Vec<GtrxlLayer>,
    memory_len: i64,
    d: i64,
}

impl Gtrxl {
    pub fn new(p: nn::Path, cfg: &ModelConfig) -> Self {
        let d = cfg.d_model as i64;
        let memory_len = cfg.memory_len as i64;
        let max_distance = memory_len + cfg.segment_len as i64;
        let layers = (0..cfg.layers)
            .map(|i| GtrxlLayer::new(&p / format!("layer{i}"), cfg, max_distance))
            .collect();
        Self {
            layers,
            memory_len,
            d,
        }
    }

    pub fn layers(&self) -> &[GtrxlLayer] {
        &self.layers
    }

    pub fn memory_len(&self) -> i64 {
        self.memory_len
    }

    pub fn d_model(&self) -> i64 {
        self.d
    }

    /// Zero memory `[L, B, m, d]` and length `[B]` for `batch` fresh slots.
    pub fn empty_memory(&self, batch: i64, device: Device) -> (Tensor, Tensor) {
        (
            Tensor::zeros(
                [self.layers.len() as i64, batch, self.memory_len, self.d],
                (Kind::Float, device),
            ),
            Tensor::zeros([batch], (Kind::Int64, device)),
        )
    }

    /// Whole-segment forward pass (learning). `x` `[B, T, d]`, `episode_start` `[B, T]` bool
    /// (the step is the first of a new episode), `memory` `[L, B, m, d]`, `memory_len` `[B]`.
    pub fn forward_segment(
        &self,
        x: &Tensor,
        episode_start: &Tensor,
        memory: &Tensor,
        memory_len: &Tensor,
    ) -> CoreOutput {
        let (_, t_len, _) = x.size3().expect("x is [B, T, d]");
        let m = self.memory_len;
        let device = x.device();
        let valid_from = segment_valid_from(episode_start, memory_len, m);
        let mask = key_mask(&valid_from, m, t_len).unsqueeze(1); // [B, 1, T, K]
        let distance = relative_distance(m, t_len, device);
        let mut x = x.shallow_clone();
        let mut layer_rows = Vec::with_capacity(self.layers.len());
        // The window's valid rows after this segment: everything from the last episode start.
        let last_valid_from = valid_from.select(1, t_len - 1);
        let next_len = (-&last_valid_from + (m + t_len)).clamp_max(m);
        for (l, layer) in self.layers.iter().enumerate() {
            let x_norm = layer.normalise_input(&x);
            let rows = Tensor::cat(&[memory.get(l as i64), x_norm.shallow_clone()], 1);
            let (k, v) = layer.keys_values(&rows);
            let bias = &mask + layer.relative_bias(&distance).unsqueeze(0);
            x = layer.attend_and_gate(&x, &x_norm, &k, &v, &bias);
            layer_rows.push(rows);
        }
        CoreOutput {
            output: x,
            next_memory_len: next_len,
            rows: layer_rows,
            memory_len: m,
        }
    }
}

/// The last `m` rows of `rows` `[B, N, d]` with rows older than the last `len[b]` zeroed, so a
/// new episode starts from zero memory.
pub fn last_rows(rows: &Tensor, m: i64, len: &Tensor) -> Tensor {
    let n = rows.size()[1];
    let kept = rows.narrow(1, n - m, m);
    let idx = Tensor::arange(m, (Kind::Int64, rows.device()));
    let keep = idx.unsqueeze(0).ge_tensor(&(-len.unsqueeze(1) + m)); // [B, m]
    kept * keep.unsqueeze(-1).to_kind(rows.kind())
}

/// For each step `[B, T]`: the first key index (into `[memory; segment]`) of its episode.
pub fn segment_valid_from(episode_start: &Tensor, memory_len: &Tensor, m: i64) -> Tensor {
    let (_, t_len) = episode_start.size2().expect("episode_start is [B, T]");
    let steps = Tensor::arange(t_len, (Kind::Int64, episode_start.device())) + m;
    let starts = steps.unsqueeze(0).where_self(
        episode_start,
        &Tensor::zeros([1], (Kind::Int64, episode_start.device())),
    );
    let (last_start, _) = starts.cummax(1);
    last_start.maximum(&(-memory_len.unsqueeze(1) + m))
}

/// Additive mask `[B, Q, K]`: 0 where query `i` (key index `m + i`) may see key `j`
/// (`valid_from ≤ j ≤ m + i`), −∞ elsewhere.
pub fn key_mask(valid_from: &Tensor, m: i64, q_len: i64) -> Tensor {
    let device = valid_from.device();
    let k_len = m + q_len;
    let keys = Tensor::arange(k_len, (Kind::Int64, device)).view([1, 1, k_len]);
    let query_pos = (Tensor::arange(q_len, (Kind::Int64, device)) + m).view([1, q_len, 1]);
    let allowed = keys
        .ge_tensor(&valid_from.unsqueeze(-1))
        .logical_and(&keys.le_tensor(&query_pos));
    Tensor::zeros(allowed.size(), (Kind::Float, device))
        .masked_fill(&allowed.logical_not(), f64::NEG_INFINITY)
}

/// Distance table `[T, m + T]`: query `i` to key `j` is `m + i − j` (negative = future, masked).
pub fn relative_distance(m: i64, q_len: i64, device: Device) -> Tensor {
    let keys = Tensor::arange(m + q_len, (Kind::Int64, device)).unsqueeze(0);
    let queries = (Tensor::arange(q_len, (Kind::Int64, device)) + m).unsqueeze(1);
    queries - keys
}
