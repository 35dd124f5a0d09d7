//! Gaussian policy head and the diagonal-Gaussian maths V-MPO needs.

use tch::Tensor;
use tch::nn::{self, Module};

use crate::model::dense::{Dense, MatmulDtype};

/// Linear(d → hidden) → ReLU → Linear(hidden → 2A); mean = tanh, std = softplus + floor.
#[derive(Debug)]
pub struct PolicyHead {
    hidden: Dense,
    out: Dense,
    action_dim: i64,
    min_std: f64,
}

impl PolicyHead {
    pub fn new(
        p: nn::Path,
        d: i64,
        hidden: i64,
        action_dim: i64,
        min_std: f64,
        dtype: MatmulDtype,
    ) -> Self {
        Self {
            hidden: Dense::new(&p / "hidden", d, hidden, Default::default(), dtype),
            out: Dense::new(
                &p / "out",
                hidden,
                2 * action_dim,
                Default::default(),
                dtype,
            ),
            action_dim,
            min_std,
        }
    }

    /// `(mean, std)`, each `[..., A]`.
    pub fn forward(&self, core: &Tensor) -> (Tensor, Tensor) {
        let out = self.out.forward(&self.hidden.forward(core).relu());
        let mean = out.narrow(-1, 0, self.action_dim).tanh();
        let std = out.narrow(-1, self.action_dim, self.action_dim).softplus() + self.min_std;
        (mean, std)
    }
}

/// Draws `mean + std · ε`. The unclipped sample is what is stored and scored; clip it to the
/// action space only when sending it to the environment.
pub fn sample_actions(mean: &Tensor, std: &Tensor) -> Tensor {
    mean + std * mean.randn_like()
}

/// log N(a; mean, diag(std²)) summed over the last dimension.
pub fn gaussian_log_prob(mean: &Tensor, std: &Tensor, action: &Tensor) -> Tensor {
    let z = (action - mean) / std;
    let log_2pi = (2.0 * std::f64::consts::PI).ln();
    (z.square() * -0.5 - std.log() - 0.5 * log_2pi).sum_dim_intlist(-1, false, z.kind())
}
