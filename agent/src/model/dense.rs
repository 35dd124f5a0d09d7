//! Linear layers whose matrix product runs at the configured precision (`model.matmul_dtype`).
//!
//! At the recipe's sizes about half of a learner update is matrix products, and this CPU's
//! bfloat16 products (AVX-512 BF16) run their shapes at about twice float32's rate. With
//! `bfloat16` a layer casts its input and weights to bfloat16, multiplies (accumulating in
//! float32 inside the kernel, the result rounded to bfloat16) and returns float32, as
//! PyTorch's CPU autocast does for `linear`. Weights, gradients, optimiser state and
//! everything element-wise stay float32. On the 2-core machine a whole update is no faster
//! for it (0.99–1.05×: the casts and their allocations take back what the products save;
//! BENCHMARKS.md, "The learner"), so float32 stays the default.

use tch::nn::{self, Linear, LinearConfig, Module};
use tch::{Kind, Tensor};

pub use crate::config::MatmulDtype;

/// `nn::Linear` (same variables, so checkpoints do not depend on the precision) whose
/// forward runs at a chosen precision.
#[derive(Debug)]
pub struct Dense {
    linear: Linear,
    dtype: MatmulDtype,
}

impl Dense {
    pub fn new(
        p: nn::Path,
        inputs: i64,
        outputs: i64,
        cfg: LinearConfig,
        dtype: MatmulDtype,
    ) -> Self {
        Self {
            linear: nn::linear(p, inputs, outputs, cfg),
            dtype,
        }
    }
}

impl Module for Dense {
    fn forward(&self, xs: &Tensor) -> Tensor {
        match self.dtype {
            MatmulDtype::Float32 => self.linear.forward(xs),
            MatmulDtype::Bfloat16 => {
                let bf16 = |t: &Tensor| t.to_kind(Kind::BFloat16);
                let bias = self.linear.bs.as_ref().map(bf16);
                xs.to_kind(Kind::BFloat16)
                    .linear(&bf16(&self.linear.ws), bias.as_ref())
                    .to_kind(Kind::Float)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, nn::VarStore};

    /// Both precisions read the same variables; bfloat16 agrees with float32 to its rounding
    /// (8 significant bits: relative error ~2⁻⁸ per rounding) and its gradients reach the
    /// float32 weights.
    #[test]
    fn bfloat16_layer_tracks_float32_on_the_same_weights() {
        tch::manual_seed(0);
        let vs = VarStore::new(Device::Cpu);
        let f32_layer = Dense::new(
            vs.root() / "l",
            64,
            192,
            Default::default(),
            MatmulDtype::Float32,
        );
        let bf16_layer = Dense {
            linear: Linear {
                ws: f32_layer.linear.ws.shallow_clone(),
                bs: f32_layer.linear.bs.as_ref().map(Tensor::shallow_clone),
            },
            dtype: MatmulDtype::Bfloat16,
        };
        let x = Tensor::randn([512, 64], (Kind::Float, Device::Cpu));
        let exact = f32_layer.forward(&x);
        let rounded = bf16_layer.forward(&x);
        assert_eq!(rounded.kind(), Kind::Float);
        let scale = exact.abs().mean(Kind::Float).double_value(&[]);
        let error = (&rounded - &exact)
            .abs()
            .mean(Kind::Float)
            .double_value(&[]);
        assert!(
            error > 0.0,
            "bfloat16 changed nothing: the cast is not taking effect"
        );
        assert!(
            error < 0.02 * scale,
            "mean error {error} against mean size {scale}"
        );

        rounded.sum(Kind::Float).backward();
        let grad = f32_layer.linear.ws.grad();
        assert_eq!(grad.kind(), Kind::Float);
        // d(sum)/dW[o, i] = Σ_rows x[:, i], the same for every output row.
        let expected = x
            .sum_dim_intlist(0, false, Kind::Float)
            .unsqueeze(0)
            .expand([192, 64], false);
        let grad_error = (&grad - &expected).abs().max().double_value(&[]);
        let grad_scale = expected.abs().max().double_value(&[]);
        assert!(
            grad_error < 0.02 * grad_scale,
            "gradient error {grad_error} of {grad_scale}"
        );
    }
}
