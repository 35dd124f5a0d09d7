//! Multi-task Pop-Art value output (docs/ALGORITHM.md §3): one normalised output row per task id
//! with its own running mean μ_k and scale σ_k. The statistics are kept in f64 because
//! ν − μ² cancels badly in f32 for returns in the hundreds.

use tch::nn;
use tch::{Kind, Tensor};

use crate::config::PopArtConfig;

#[derive(Debug)]
pub struct PopArt {
    weight: Tensor,
    bias: Tensor,
    mu: Tensor,
    nu: Tensor,
    sigma: Tensor,
    /// Updates in which each task was present (for debiased step sizes).
    updates: Tensor,
    cfg: PopArtConfig,
}

/// A copy of the statistics and the output layer, to undo an update.
#[derive(Debug)]
pub struct PopArtState(Vec<Tensor>);

/// Per-task statistics after an update, for logging.
#[derive(Debug, Clone, Copy)]
pub struct PopArtSummary {
    pub tasks_updated: i64,
    pub mean_sigma: f64,
}

impl PopArt {
    pub fn new(p: nn::Path, hidden: i64, num_tasks: i64, cfg: PopArtConfig) -> Self {
        let weight = p.var(
            "weight",
            &[num_tasks, hidden],
            nn::Init::Kaiming {
                dist: nn::init::NormalOrUniform::Uniform,
                fan: nn::init::FanInOut::FanIn,
                non_linearity: nn::init::NonLinearity::Linear,
            },
        );
        let bias = p.zeros("bias", &[num_tasks]);
        let device = p.device();
        let stat = |v: f64| Tensor::full([num_tasks], v, (Kind::Double, device));
        // σ = 1 and ν = σ² + μ² = 1 make the initial normalised and unnormalised outputs equal.
        let mu = p.add("mu", stat(0.0), false);
        let nu = p.add("nu", stat(1.0), false);
        let sigma = p.add("sigma", stat(1.0), false);
        let updates = p.add("updates", stat(0.0), false);
        Self {
            weight,
            bias,
            mu,
            nu,
            sigma,
            updates,
            cfg,
        }
    }

    /// Normalised output ñ `[N]` of features `[N, H]` at task ids `[N]`.
    pub fn normalised(&self, features: &Tensor, task: &Tensor) -> Tensor {
        let w = self.weight.index_select(0, task);
        (features * w).sum_dim_intlist(-1, false, features.kind()) + self.bias.index_select(0, task)
    }

    /// Unnormalised value σ_k ñ + μ_k `[N]`.
    pub fn unnormalise(&self, normalised: &Tensor, task: &Tensor) -> Tensor {
        let kind = normalised.kind();
        normalised * self.sigma.index_select(0, task).to_kind(kind)
            + self.mu.index_select(0, task).to_kind(kind)
    }

    /// (G − μ_k) / σ_k `[N]`.
    pub fn normalise_targets(&self, targets: &Tensor, task: &Tensor) -> Tensor {
        let kind = targets.kind();
        (targets - self.mu.index_select(0, task).to_kind(kind))
            / self.sigma.index_select(0, task).to_kind(kind)
    }

    pub fn mu(&self) -> &Tensor {
        &self.mu
    }

    pub fn sigma(&self) -> &Tensor {
        &self.sigma
    }

    fn tensors(&self) -> [&Tensor; 6] {
        [
            &self.weight,
            &self.bias,
            &self.mu,
            &self.nu,
            &self.sigma,
            &self.updates,
        ]
    }

    /// A copy of everything `update` changes.
    pub fn snapshot(&self) -> PopArtState {
        PopArtState(self.tensors().iter().map(|t| t.detach().copy()).collect())
    }

    /// Puts back a snapshot taken by [`PopArt::snapshot`].
    pub fn restore(&mut self, state: &PopArtState) {
        tch::no_grad(|| {
            for (dst, src) in self.tensors().into_iter().zip(&state.0) {
                dst.shallow_clone().copy_(src);
            }
        });
    }

    /// Moves μ, ν, σ of every task present (where `valid`) towards its targets and rescales
    /// that task's output row so that the unnormalised outputs are unchanged. A no-op when
    /// Pop-Art is disabled (the ablation keeps μ = 0, σ = 1).
    pub fn update(&mut self, targets: &Tensor, task: &Tensor, valid: &Tensor) -> PopArtSummary {
        if !self.cfg.enabled {
            return PopArtSummary {
                tasks_updated: 0,
                mean_sigma: 1.0,
            };
        }
        tch::no_grad(|| {
            let k = self.mu.size()[0];
            let device = self.mu.device();
            let g = targets.detach().to_kind(Kind::Double);
            let w = valid.to_kind(Kind::Double);
            let zeros = Tensor::zeros([k], (Kind::Double, device));
            let count = zeros.index_add(0, task, &w);
            let sum = zeros.index_add(0, task, &(&g * &w));
            let sum_sq = zeros.index_add(0, task, &(g.square() * &w));
            let present = count.gt(0.0);
            let n = count.clamp_min(1.0);
            let updates = &self.updates + present.to_kind(Kind::Double);
            // β per task: the configured β, or max(β, 1/n_k) when debiased.
            let beta = if self.cfg.debias {
                updates.clamp_min(1.0).reciprocal().clamp_min(self.cfg.beta)
            } else {
                Tensor::full([k], self.cfg.beta, (Kind::Double, device))
            };
            let keep = 1.0 - &beta;
            let mu_new = (&self.mu * &keep + sum / &n * &beta).where_self(&present, &self.mu);
            let nu_new = (&self.nu * &keep + sum_sq / &n * &beta).where_self(&present, &self.nu);
            let sigma_new = (&nu_new - mu_new.square())
                .clamp_min(0.0)
                .sqrt()
                .clamp(self.cfg.sigma_min, self.cfg.sigma_max)
                .where_self(&present, &self.sigma);
            let kind = self.weight.kind();
            let scale = (&self.sigma / &sigma_new).to_kind(kind);
            let new_bias = ((&self.sigma * self.bias.to_kind(Kind::Double) + &self.mu - &mu_new)
                / &sigma_new)
                .to_kind(kind);
            self.weight.copy_(&(&self.weight * scale.unsqueeze(1)));
            self.bias.copy_(&new_bias);
            self.mu.copy_(&mu_new);
            self.nu.copy_(&nu_new);
            self.sigma.copy_(&sigma_new);
            self.updates.copy_(&updates);
            let tasks_updated = present.sum(Kind::Int64).int64_value(&[]);
            let shown = if tasks_updated > 0 {
                sigma_new.masked_select(&present)
            } else {
                sigma_new.shallow_clone()
            };
            PopArtSummary {
                tasks_updated,
                mean_sigma: shown.mean(Kind::Double).double_value(&[]),
            }
        })
    }
}
