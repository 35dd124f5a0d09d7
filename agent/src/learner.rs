//! One V-MPO update: forward the sampled segments from their stored memory, n-step returns,
//! Pop-Art update, the V-MPO losses of ALGORITHM.md §4, one Adam step over everything.

use serde::Serialize;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use crate::algo::buffer::SegmentBatch;
use crate::algo::returns::bootstrapped_returns;
use crate::algo::vmpo;
use crate::config::AgentConfig;
use crate::model::Model;
use crate::model::policy::gaussian_log_prob;
use crate::optim::Adam;

/// The Lagrange multipliers η, α_μ, α_Σ: trainable scalars, projected back to at least
/// `vmpo.min_multiplier` after every step.
#[derive(Debug)]
pub struct Multipliers {
    pub eta: Tensor,
    pub alpha_mu: Tensor,
    pub alpha_sigma: Tensor,
}

/// Scalars of one update, for logs.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct UpdateMetrics {
    pub loss: f64,
    pub policy_loss: f64,
    pub temperature_loss: f64,
    pub alpha_mu_loss: f64,
    pub alpha_sigma_loss: f64,
    pub value_loss: f64,
    pub eta: f64,
    pub alpha_mu: f64,
    pub alpha_sigma: f64,
    pub kl_mu: f64,
    pub kl_sigma: f64,
    pub mean_return: f64,
    pub mean_advantage: f64,
    pub policy_steps: i64,
    pub selected_steps: i64,
    pub value_steps: i64,
    pub popart_mean_sigma: f64,
    pub mean_std: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    #[error("batch shape mismatch: {0}")]
    Shape(String),
    #[error("non-finite loss ({0}); the update was skipped")]
    NonFinite(f64),
}

pub struct Learner {
    cfg: AgentConfig,
    vs: VarStore,
    model: Model,
    multipliers: Multipliers,
    adam: Adam,
    updates: u64,
}

impl Learner {
    pub fn new(cfg: AgentConfig, device: Device) -> Self {
        let vs = VarStore::new(device);
        let model = Model::new(&vs.root(), &cfg.model, &cfg.popart);
        let p = vs.root() / "vmpo";
        let scalar = |name: &str, v: f64| p.var(name, &[], tch::nn::Init::Const(v));
        let multipliers = Multipliers {
            eta: scalar("eta", cfg.vmpo.init_eta),
            alpha_mu: scalar("alpha_mu", cfg.vmpo.init_alpha_mu),
            alpha_sigma: scalar("alpha_sigma", cfg.vmpo.init_alpha_sigma),
        };
        let adam = Adam::new(&vs, cfg.optim.clone());
        Self {
            cfg,
            vs,
            model,
            multipliers,
            adam,
            updates: 0,
        }
    }

    pub fn config(&self) -> &AgentConfig {
        &self.cfg
    }

    pub fn model(&self) -> &Model {
        &self.model
    }

    pub fn var_store(&self) -> &VarStore {
        &self.vs
    }

    pub fn var_store_mut(&mut self) -> &mut VarStore {
        &mut self.vs
    }

    pub fn multipliers(&self) -> &Multipliers {
        &self.multipliers
    }

    pub fn optimiser(&self) -> &Adam {
        &self.adam
    }

    pub fn optimiser_mut(&mut self) -> &mut Adam {
        &mut self.adam
    }

    pub fn updates(&self) -> u64 {
        self.updates
    }

    pub fn set_updates(&mut self, updates: u64) {
        self.updates = updates;
    }

    /// Copies the learner's network weights (and Pop-Art statistics) into an actor's store.
    pub fn copy_weights_to(&self, actor: &mut VarStore) -> Result<(), tch::TchError> {
        tch::no_grad(|| actor.copy(&self.vs))
    }

    pub fn update(&mut self, batch: &SegmentBatch) -> Result<UpdateMetrics, LearnerError> {
        let device = self.vs.device();
        let b = batch.to_device(device);
        let cfg = &self.cfg;
        let (n_seg, t_len, _) = b
            .obs
            .size3()
            .map_err(|e| LearnerError::Shape(format!("obs: {e}")))?;
        if t_len != cfg.model.segment_len as i64 || b.obs.size()[2] != cfg.model.obs_dim() as i64 {
            return Err(LearnerError::Shape(format!(
                "obs is {:?}, the model takes [b, {}, {}]",
                b.obs.size(),
                cfg.model.segment_len,
                cfg.model.obs_dim()
            )));
        }
        let out = self
            .model
            .forward_segment(&b.obs, &b.episode_start, &b.memory, &b.memory_len);
        let values = tch::no_grad(|| self.model.value(&out.value_features, &b.task));
        let returns = bootstrapped_returns(
            &b.rewards,
            &values,
            &b.terminated,
            &b.truncated,
            cfg.vmpo.gamma,
        );

        let n = n_seg * t_len;
        let task = b.task.reshape([n]);
        let g = returns.returns.reshape([n]);
        let value_valid = returns.trainable.reshape([n]);
        let policy_valid = value_valid.logical_and(&b.instruction.reshape([n]).logical_not());
        let popart = self.model.popart_mut().update(&g, &task, &value_valid);
        let target = self.model.popart().normalise_targets(&g, &task);
        let hidden = *out.value_features.size().last().expect("value features");
        let predicted = self
            .model
            .popart()
            .normalised(&out.value_features.reshape([n, hidden]), &task);
        let clip = cfg.vmpo.advantage_clip;
        let advantages = (&target - predicted.detach()).clamp(-clip, clip);

        let value_w = value_valid.to_kind(Kind::Float);
        let value_steps = value_w.sum(Kind::Float).clamp_min(1.0);
        let value_loss =
            ((&predicted - &target).square() * &value_w).sum(Kind::Float) / &value_steps * 0.5;

        let a_dim = cfg.model.action_dim as i64;
        let mean = out.mean.reshape([n, a_dim]);
        let std = out.std.reshape([n, a_dim]);
        let old_mean = b.behaviour_mean.reshape([n, a_dim]);
        let old_std = b.behaviour_std.reshape([n, a_dim]);
        let m = &self.multipliers;
        let (policy_loss, temperature_loss, selected) =
            match vmpo::top_advantages(&advantages, &policy_valid, cfg.vmpo.top_fraction) {
                Some(idx) => {
                    let top = advantages.index_select(0, &idx);
                    let psi = vmpo::psi_weights(&top, &m.eta);
                    let log_prob = gaussian_log_prob(
                        &mean.index_select(0, &idx),
                        &std.index_select(0, &idx),
                        &b.actions.reshape([n, a_dim]).index_select(0, &idx),
                    );
                    (
                        -(psi * log_prob).sum(Kind::Float),
                        vmpo::temperature_loss(&m.eta, &top, cfg.vmpo.eps_eta),
                        idx.size()[0],
                    )
                }
                None => (
                    Tensor::zeros([], (Kind::Float, device)),
                    Tensor::zeros([], (Kind::Float, device)),
                    0,
                ),
            };
        let kl_mu = vmpo::kl_mean(&mean, &old_mean, &old_std);
        let kl_sigma = vmpo::kl_std(&std, &old_std);
        let alpha_mu_loss =
            vmpo::multiplier_loss(&m.alpha_mu, &kl_mu, cfg.vmpo.eps_alpha_mu, &policy_valid);
        let alpha_sigma_loss = vmpo::multiplier_loss(
            &m.alpha_sigma,
            &kl_sigma,
            cfg.vmpo.eps_alpha_sigma,
            &policy_valid,
        );
        let loss =
            &policy_loss + &temperature_loss + &alpha_mu_loss + &alpha_sigma_loss + &value_loss;
        let loss_value = loss.double_value(&[]);
        if !loss_value.is_finite() {
            return Err(LearnerError::NonFinite(loss_value));
        }
        self.adam.zero_grad();
        loss.backward();
        self.adam.step();
        let floor = cfg.vmpo.min_multiplier;
        tch::no_grad(|| {
            for t in [&m.eta, &m.alpha_mu, &m.alpha_sigma] {
                let _ = t.shallow_clone().clamp_min_(floor);
            }
        });
        self.updates += 1;

        let pw = policy_valid.to_kind(Kind::Float);
        let policy_steps = pw.sum(Kind::Float).double_value(&[]);
        let masked_mean = |x: &Tensor, w: &Tensor, count: f64| {
            (x.detach() * w).sum(Kind::Float).double_value(&[]) / count.max(1.0)
        };
        let value_count = value_w.sum(Kind::Float).double_value(&[]);
        Ok(UpdateMetrics {
            loss: loss_value,
            policy_loss: policy_loss.double_value(&[]),
            temperature_loss: temperature_loss.double_value(&[]),
            alpha_mu_loss: alpha_mu_loss.double_value(&[]),
            alpha_sigma_loss: alpha_sigma_loss.double_value(&[]),
            value_loss: value_loss.double_value(&[]),
            eta: m.eta.double_value(&[]),
            alpha_mu: m.alpha_mu.double_value(&[]),
            alpha_sigma: m.alpha_sigma.double_value(&[]),
            kl_mu: masked_mean(&kl_mu, &pw, policy_steps),
            kl_sigma: masked_mean(&kl_sigma, &pw, policy_steps),
            mean_return: masked_mean(&g, &value_w, value_count),
            mean_advantage: masked_mean(&advantages, &pw, policy_steps),
            policy_steps: policy_steps as i64,
            selected_steps: selected,
            value_steps: value_count as i64,
            popart_mean_sigma: popart.mean_sigma,
            mean_std: masked_mean(&std.mean_dim(-1, false, Kind::Float), &pw, policy_steps),
        })
    }
}
