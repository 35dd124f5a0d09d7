//! One V-MPO update: forward the sampled segments from their stored memory, n-step returns,
//! Pop-Art update, the V-MPO losses of docs/ALGORITHM.md §4, one Adam step over everything.

use std::collections::BTreeMap;

use serde::Serialize;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use crate::algo::buffer::SegmentBatch;
use crate::algo::returns::bootstrapped_returns;
use crate::algo::vmpo;
use crate::config::{AgentConfig, KlReference, MultiplierForm, VmpoConfig};
use crate::model::policy::gaussian_log_prob;
use crate::model::popart::{PopArtState, PopArtSummary};
use crate::model::{Model, SegmentOutput};
use crate::optim::Adam;

/// The Lagrange multipliers η, α_μ, α_Σ as trainable scalars. In clamp form the variables are
/// the multipliers; in log form they are the logarithms, so the multipliers are positive by
/// construction. Either way they are projected into [`vmpo.min_multiplier`,
/// `vmpo.max_multiplier`] after every step.
#[derive(Debug)]
pub struct Multipliers {
    form: MultiplierForm,
    raw_eta: Tensor,
    raw_alpha_mu: Tensor,
    raw_alpha_sigma: Tensor,
}

impl Multipliers {
    fn new(p: &tch::nn::Path, v: &VmpoConfig) -> Self {
        let form = v.multiplier_form;
        let scalar = |name: &str, init: f64| {
            let raw = match form {
                MultiplierForm::Clamp => init,
                MultiplierForm::Log => init.ln(),
            };
            p.var(name, &[], tch::nn::Init::Const(raw))
        };
        Self {
            form,
            raw_eta: scalar("eta", v.init_eta),
            raw_alpha_mu: scalar("alpha_mu", v.init_alpha_mu),
            raw_alpha_sigma: scalar("alpha_sigma", v.init_alpha_sigma),
        }
    }

    fn value(&self, raw: &Tensor) -> Tensor {
        match self.form {
            MultiplierForm::Clamp => raw.shallow_clone(),
            MultiplierForm::Log => raw.exp(),
        }
    }

    /// η (differentiable with respect to its variable).
    pub fn eta(&self) -> Tensor {
        self.value(&self.raw_eta)
    }

    pub fn alpha_mu(&self) -> Tensor {
        self.value(&self.raw_alpha_mu)
    }

    pub fn alpha_sigma(&self) -> Tensor {
        self.value(&self.raw_alpha_sigma)
    }

    /// Keeps the multipliers within [floor, ceiling] after a step.
    fn project(&self, floor: f64, ceiling: f64) {
        let (low, high) = match self.form {
            MultiplierForm::Clamp => (floor, ceiling),
            MultiplierForm::Log => (floor.ln(), ceiling.ln()),
        };
        tch::no_grad(|| {
            for t in [&self.raw_eta, &self.raw_alpha_mu, &self.raw_alpha_sigma] {
                let _ = t.shallow_clone().clamp_(low, high);
            }
        });
    }
}

/// Name of the target network's part of the store.
const TARGET: &str = "target";
const TARGET_PREFIX: &str = "target.";

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
    /// Task id → Σ ψ over that task's selected steps (tasks with policy steps in the batch).
    pub task_psi_mass: BTreeMap<i64, f64>,
    /// Task id → the policy's mean std over that task's policy steps: whether one task's
    /// exploration collapses while another's stays wide.
    pub task_mean_std: BTreeMap<i64, f64>,
    /// Task id → the mean KL of the mean over that task's policy steps: which tasks spend
    /// the batch-wide trust region (ε_αμ bounds the batch's mean).
    pub task_kl_mu: BTreeMap<i64, f64>,
    /// The goal head's loss (its weight included) and its root mean squared error in metres
    /// over the batch's policy steps, overall and per task id (`model.goal_prediction`; absent
    /// without a goal head).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub goal_loss: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub goal_error: Option<f64>,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub task_goal_error: BTreeMap<i64, f64>,
}

/// The loss terms of one batch (steps 1–6 of an update) and what the metrics need.
struct Losses {
    loss: Tensor,
    policy_loss: Tensor,
    temperature_loss: Tensor,
    alpha_mu_loss: Tensor,
    alpha_sigma_loss: Tensor,
    value_loss: Tensor,
    /// The goal head's weighted loss and each step's squared error `[n]` (None without one).
    goal: Option<(Tensor, Tensor)>,
    kl_mu: Tensor,
    kl_sigma: Tensor,
    returns: Tensor,
    advantages: Tensor,
    std: Tensor,
    policy_mask: Tensor,
    value_w: Tensor,
    selected: i64,
    /// Each step's task id, Σ ψ per task id `[num_tasks]`, and each task's policy steps.
    task: Tensor,
    psi_mass: Tensor,
    task_policy_steps: Tensor,
    popart: PopArtSummary,
    /// The Pop-Art statistics and output layer before the update moved them.
    popart_before: PopArtState,
}

#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    #[error("batch shape mismatch: {0}")]
    Shape(String),
    #[error("non-finite loss ({0}); the update was skipped")]
    NonFinite(f64),
    #[error("non-finite gradient (loss {0}); the update was skipped")]
    NonFiniteGradient(f64),
}

pub struct Learner {
    cfg: AgentConfig,
    vs: VarStore,
    model: Model,
    /// V-MPO's π_old when `vmpo.kl_reference = "target"`: a frozen copy of the network under
    /// `target.` in the same store (so checkpoints keep it), synced every T_target updates.
    target: Option<Model>,
    multipliers: Multipliers,
    adam: Adam,
    updates: u64,
}

impl Learner {
    pub fn new(cfg: AgentConfig, device: Device) -> Self {
        let vs = VarStore::new(device);
        let model = Model::new(&vs.root(), &cfg.model, &cfg.popart);
        let multipliers = Multipliers::new(&(vs.root() / "vmpo"), &cfg.vmpo);
        let target = (cfg.vmpo.kl_reference == KlReference::Target)
            .then(|| Model::new(&(vs.root() / TARGET), &cfg.model, &cfg.popart));
        for (name, var) in vs.variables() {
            if name.starts_with(TARGET_PREFIX) {
                let _ = var.set_requires_grad(false);
            }
        }
        let mut adam = Adam::new(&vs, cfg.optim.clone());
        if let Some(lr) = cfg.vmpo.multiplier_lr {
            adam.set_lr_for_prefix("vmpo.", lr);
        }
        let learner = Self {
            cfg,
            vs,
            model,
            target,
            multipliers,
            adam,
            updates: 0,
        };
        learner.sync_target();
        learner
    }

    /// Copies the network into the target copy (when there is one).
    fn sync_target(&self) {
        if self.target.is_none() {
            return;
        }
        let vars = self.vs.variables();
        tch::no_grad(|| {
            for (name, var) in &vars {
                if let Some(source) = name.strip_prefix(TARGET_PREFIX) {
                    var.shallow_clone().copy_(&vars[source]);
                }
            }
        });
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

    /// The reverse of [`Learner::copy_weights_to`]: takes an actor's network weights (and
    /// Pop-Art statistics) as the learner's own, the target copy included. The optimiser's
    /// moments and the multipliers stay as they are. Used when a run stops because an
    /// evaluation of the actor's weights reached the target: those weights, not the newer
    /// ones the learner went on to, are the run's result.
    pub fn load_network_from(&mut self, actor: &VarStore) -> Result<(), tch::TchError> {
        let source = actor.variables();
        let mut vars = self.vs.variables();
        for (name, from) in &source {
            let to = vars.get_mut(name).ok_or_else(|| {
                tch::TchError::Torch(format!("the learner has no variable {name}"))
            })?;
            tch::no_grad(|| to.copy_(from));
        }
        self.sync_target();
        Ok(())
    }

    /// One V-MPO update on `b` segments of `T` steps. Read top to bottom:
    ///
    /// ```text
    ///  stored at segment start          the segment (T steps)
    ///  memory M_l, per layer, m rows    t = 0   1   …   T-2   T-1
    ///  ────────────────────────────     ─────────────────────────
    ///  keys of step t:  [sg(M_l) ; x̃_0 … x̃_t], minus every key before the start of t's
    ///                   own episode (episode_start), so no step attends across episodes
    ///  returns:         G_t = r_t + γ (1 − terminated_t) [(1 − λ) V(s_{t+1}) + λ G_{t+1}],
    ///                   G_{T-1} := V(s_{T-1})   (λ = 1: the original's n-step returns)
    ///                   with learn_last_step, s_T (stored after the segment) runs as one
    ///                   more step and G_{T-1} = r_{T-1} + γ (1 − terminated) V(s_T)
    ///                   a truncated step t (final obs not in the segment): G_t := V(s_t)
    ///  value_mask:      every step but T-1 (unless learn_last_step) and truncated ones
    ///                   (they only bootstrap)
    ///  policy_mask:     value_mask minus instruction-phase steps (no reward, action ignored)
    /// ```
    ///
    /// The value loss uses `value_mask`; the policy, temperature and KL terms `policy_mask`.
    /// Nothing is changed (Pop-Art statistics included) when the loss or a gradient is not finite.
    pub fn update(&mut self, batch: &SegmentBatch) -> Result<UpdateMetrics, LearnerError> {
        let l = self.losses(batch)?;

        // 7. One Adam step over network, Pop-Art layer and multipliers.
        let loss_value = l.loss.double_value(&[]);
        if !loss_value.is_finite() {
            self.model.popart_mut().restore(&l.popart_before);
            return Err(LearnerError::NonFinite(loss_value));
        }
        self.adam.zero_grad();
        l.loss.backward();
        if !self.adam.step_if_finite() {
            self.adam.zero_grad();
            self.model.popart_mut().restore(&l.popart_before);
            return Err(LearnerError::NonFiniteGradient(loss_value));
        }
        let v = &self.cfg.vmpo;
        self.multipliers.project(v.min_multiplier, v.max_multiplier);
        // 8. Normalised observations: the batch joins the pending moments, which the
        // statistics take in when the target is synced (model::obs_norm says why).
        let sync = (self.updates + 1).is_multiple_of(self.cfg.buffer.target_period as u64);
        let fields = self.model.fields(&batch.obs);
        if let Some(norm) = self.model.obs_norm_mut() {
            norm.observe(&fields);
            if sync {
                norm.commit();
            }
        }
        self.updates += 1;
        if sync {
            self.sync_target();
        }
        Ok(self.metrics(&l, loss_value))
    }

    /// The metrics an update on `batch` would report, computed without changing anything: no
    /// step, and the Pop-Art statistics the loss needs moved are put back (the multipliers
    /// are the current ones). For checks against other implementations of the same loss.
    pub fn loss_terms(&mut self, batch: &SegmentBatch) -> Result<UpdateMetrics, LearnerError> {
        let l = tch::no_grad(|| self.losses(batch))?;
        self.model.popart_mut().restore(&l.popart_before);
        let loss_value = l.loss.double_value(&[]);
        Ok(self.metrics(&l, loss_value))
    }

    /// The segment forward of step 1. With `vmpo.learn_last_step` the stored observation after
    /// the segment runs as step T, whose value features come back apart (`[B, H]`); the
    /// outputs are those of steps 0..T, which the extra step cannot change (it is later). Its
    /// farthest memory row lies at distance m + T, one past the relative bias table, and
    /// shares the bias of m + T − 1 (`TransformerLayer::relative_bias` clamps).
    fn forward_learning(&self, b: &SegmentBatch, t_len: i64) -> (SegmentOutput, Option<Tensor>) {
        if !self.cfg.vmpo.learn_last_step {
            let out =
                self.model
                    .forward_segment(&b.obs, &b.episode_start, &b.memory, &b.memory_len);
            return (out, None);
        }
        let obs = Tensor::cat(&[&b.obs, &b.bootstrap_obs.unsqueeze(1)], 1);
        let starts = Tensor::cat(&[&b.episode_start, &b.bootstrap_start.unsqueeze(1)], 1);
        let out = self
            .model
            .forward_segment(&obs, &starts, &b.memory, &b.memory_len);
        let steps = |t: &Tensor| t.narrow(1, 0, t_len);
        let bootstrap = out.value_features.select(1, t_len);
        let out = SegmentOutput {
            mean: steps(&out.mean),
            std: steps(&out.std),
            value_features: steps(&out.value_features),
            core: out.core,
        };
        (out, Some(bootstrap))
    }

    /// Steps 1–6 of [`Learner::update`]: the loss terms, with the Pop-Art statistics moved.
    fn losses(&mut self, batch: &SegmentBatch) -> Result<Losses, LearnerError> {
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
        let n = n_seg * t_len;
        let a_dim = cfg.model.action_dim as i64;
        let flat = |t: &Tensor| t.reshape([n]);
        let flat_actions = |t: &Tensor| t.reshape([n, a_dim]);

        // 1. Forward every step from the memory stored at its segment's start (and, with
        //    `learn_last_step`, the observation after the segment, for its value alone).
        let (out, bootstrap_features) = self.forward_learning(&b, t_len);
        let hidden = *out.value_features.size().last().expect("value features");
        let features = out.value_features.reshape([n, hidden]);
        let task = flat(&b.task);

        // 2. Targets: n-step (λ = 1) or λ-returns bootstrapped from the current value.
        let values = tch::no_grad(|| {
            let values = self.model.value(&out.value_features, &b.task);
            match &bootstrap_features {
                // The state after the segment continues the last step's episode (and task)
                // whenever its value is used: otherwise the last step ended its episode.
                Some(f) => {
                    let last_task = b.task.select(1, t_len - 1);
                    let after = self.model.value(f, &last_task).unsqueeze(1);
                    Tensor::cat(&[values, after], 1)
                }
                None => values,
            }
        });
        let returns = bootstrapped_returns(
            &b.rewards,
            &values,
            &b.terminated,
            &b.truncated,
            cfg.vmpo.gamma,
            cfg.vmpo.lambda,
        );
        let g = flat(&returns.returns);
        let value_mask = flat(&returns.trainable);
        // Trial steps: the policy learns on them, and the goal head (7.) is scored on them.
        let trial = flat(&b.instruction).logical_not();
        let policy_mask = value_mask.logical_and(&trial);

        // 3. Pop-Art: move the task statistics (undone below if the loss is not finite), then
        //    normalised targets Ĝ and advantages Â = clip(Ĝ − sg(ñ)).
        let popart_before = self.model.popart().snapshot();
        let popart = self.model.popart_mut().update(&g, &task, &value_mask);
        let target = self.model.popart().normalise_targets(&g, &task);
        let predicted = self.model.popart().normalised(&features, &task);
        let clip = cfg.vmpo.advantage_clip;
        let advantages = (&target - predicted.detach()).clamp(-clip, clip);

        // 4. Value loss ½ mean (ñ − Ĝ)² over value_mask.
        let value_w = value_mask.to_kind(Kind::Float);
        let value_count = value_w.sum(Kind::Float).clamp_min(1.0);
        let value_loss =
            ((&predicted - &target).square() * &value_w).sum(Kind::Float) / &value_count * 0.5;

        // 5. Policy and temperature over the top half of policy_mask by advantage (over the
        //    whole batch, or within each task with `per_task_e_step`).
        let mean = flat_actions(&out.mean);
        let std = flat_actions(&out.std);
        let m = &self.multipliers;
        let eta = m.eta();
        let (frac, eps_eta) = (cfg.vmpo.top_fraction, cfg.vmpo.eps_eta);
        let e_step = if cfg.vmpo.per_task_e_step {
            vmpo::e_step_per_task(&advantages, &policy_mask, &task, frac, &eta, eps_eta)
        } else {
            vmpo::e_step(&advantages, &policy_mask, frac, &eta, eps_eta)
        };
        let num_tasks = cfg.model.num_tasks as i64;
        let zero = || Tensor::zeros([], (Kind::Float, device));
        let (policy_loss, temperature_loss, selected, psi_mass) = match e_step {
            Some(e) => {
                let log_prob = gaussian_log_prob(
                    &mean.index_select(0, &e.idx),
                    &std.index_select(0, &e.idx),
                    &flat_actions(&b.actions).index_select(0, &e.idx),
                );
                let psi_mass =
                    vmpo::psi_mass_per_task(&e.psi, &task.index_select(0, &e.idx), num_tasks);
                (
                    -(&e.psi * log_prob).sum(Kind::Float),
                    e.temperature_loss,
                    e.idx.size()[0],
                    psi_mass,
                )
            }
            None => (
                zero(),
                zero(),
                0,
                Tensor::zeros([num_tasks], (Kind::Float, device)),
            ),
        };
        let task_policy_steps = Tensor::zeros([num_tasks], (Kind::Float, device)).scatter_add(
            0,
            &task,
            &policy_mask.to_kind(Kind::Float),
        );

        // 6. Decoupled KL from π_old over policy_mask: the target network on the same inputs,
        //    or the behaviour distribution stored at acting time.
        let (old_mean, old_std) = match &self.target {
            Some(target) => tch::no_grad(|| {
                let (mean, std) =
                    target.policy_segment(&b.obs, &b.episode_start, &b.memory, &b.memory_len);
                (flat_actions(&mean), flat_actions(&std))
            }),
            None => (
                flat_actions(&b.behaviour_mean),
                flat_actions(&b.behaviour_std),
            ),
        };
        let kl_mu = vmpo::kl_mean(&mean, &old_mean, &old_std);
        let kl_sigma = vmpo::kl_std(&std, &old_std);
        let (alpha_mu, alpha_sigma) = (m.alpha_mu(), m.alpha_sigma());
        let alpha_mu_loss =
            vmpo::multiplier_loss(&alpha_mu, &kl_mu, cfg.vmpo.eps_alpha_mu, &policy_mask);
        let alpha_sigma_loss = vmpo::multiplier_loss(
            &alpha_sigma,
            &kl_sigma,
            cfg.vmpo.eps_alpha_sigma,
            &policy_mask,
        );

        // 7. The goal head (`model.goal_prediction`): ½ the squared distance (m²) to the env's
        //    goal, averaged over the trial steps, where the words may have told it.
        let goal = self
            .model
            .goal(&out.core.output.narrow(1, 0, t_len))
            .zip(self.model.goal_target(&b.obs))
            .map(|(predicted, target)| {
                let sq_error = (predicted - target)
                    .square()
                    .sum_dim_intlist(-1, false, Kind::Float)
                    .reshape([n]);
                let trial_w = trial.to_kind(Kind::Float);
                let goal_loss = (&sq_error * &trial_w).sum(Kind::Float)
                    / trial_w.sum(Kind::Float).clamp_min(1.0)
                    * (0.5 * cfg.model.goal_prediction_weight);
                (goal_loss, sq_error)
            });

        let mut loss =
            &policy_loss + &temperature_loss + &alpha_mu_loss + &alpha_sigma_loss + &value_loss;
        if let Some((goal_loss, _)) = &goal {
            loss += goal_loss;
        }
        Ok(Losses {
            loss,
            policy_loss,
            temperature_loss,
            alpha_mu_loss,
            alpha_sigma_loss,
            value_loss,
            goal,
            kl_mu,
            kl_sigma,
            returns: g,
            advantages,
            std,
            policy_mask,
            value_w,
            selected,
            task,
            psi_mass,
            task_policy_steps,
            popart,
            popart_before,
        })
    }

    /// The scalars of an update from its loss terms (multipliers as they are now).
    fn metrics(&self, l: &Losses, loss_value: f64) -> UpdateMetrics {
        let m = &self.multipliers;
        let pw = l.policy_mask.to_kind(Kind::Float);
        // The mean of a per-step value over each task's policy steps, `[num_tasks]`.
        let task_mean = |x: &Tensor| {
            let sums = l.task_policy_steps.zeros_like().scatter_add(
                0,
                &l.task,
                &(x.detach().to_kind(Kind::Float) * &pw),
            );
            sums / l.task_policy_steps.clamp_min(1.0)
        };
        let policy_steps = pw.sum(Kind::Float).double_value(&[]);
        let masked_mean = |x: &Tensor, w: &Tensor, count: f64| {
            (x.detach() * w).sum(Kind::Float).double_value(&[]) / count.max(1.0)
        };
        let value_steps = l.value_w.sum(Kind::Float).double_value(&[]);
        UpdateMetrics {
            loss: loss_value,
            policy_loss: l.policy_loss.double_value(&[]),
            temperature_loss: l.temperature_loss.double_value(&[]),
            alpha_mu_loss: l.alpha_mu_loss.double_value(&[]),
            alpha_sigma_loss: l.alpha_sigma_loss.double_value(&[]),
            value_loss: l.value_loss.double_value(&[]),
            eta: m.eta().double_value(&[]),
            alpha_mu: m.alpha_mu().double_value(&[]),
            alpha_sigma: m.alpha_sigma().double_value(&[]),
            kl_mu: masked_mean(&l.kl_mu, &pw, policy_steps),
            kl_sigma: masked_mean(&l.kl_sigma, &pw, policy_steps),
            mean_return: masked_mean(&l.returns, &l.value_w, value_steps),
            mean_advantage: masked_mean(&l.advantages, &pw, policy_steps),
            policy_steps: policy_steps as i64,
            selected_steps: l.selected,
            value_steps: value_steps as i64,
            popart_mean_sigma: l.popart.mean_sigma,
            mean_std: masked_mean(&l.std.mean_dim(-1, false, Kind::Float), &pw, policy_steps),
            task_psi_mass: per_task(&l.psi_mass, &l.task_policy_steps),
            task_mean_std: per_task(
                &task_mean(&l.std.mean_dim(-1, false, Kind::Float)),
                &l.task_policy_steps,
            ),
            task_kl_mu: per_task(&task_mean(&l.kl_mu), &l.task_policy_steps),
            goal_loss: l.goal.as_ref().map(|(loss, _)| loss.double_value(&[])),
            goal_error: l
                .goal
                .as_ref()
                .filter(|_| policy_steps > 0.0)
                .map(|(_, e)| masked_mean(e, &pw, policy_steps).sqrt()),
            task_goal_error: l.goal.as_ref().map_or_else(BTreeMap::new, |(_, e)| {
                per_task(&task_mean(e).sqrt(), &l.task_policy_steps)
            }),
        }
    }
}

/// The tasks with policy steps in the batch, each with its value in `per_task` `[num_tasks]`.
fn per_task(per_task: &Tensor, task_policy_steps: &Tensor) -> BTreeMap<i64, f64> {
    let values = Vec::<f64>::try_from(per_task.to_kind(Kind::Double).to_device(Device::Cpu))
        .expect("per-task values");
    let steps = Vec::<f64>::try_from(
        task_policy_steps
            .to_kind(Kind::Double)
            .to_device(Device::Cpu),
    )
    .expect("policy steps");
    (0i64..)
        .zip(values.into_iter().zip(steps))
        .filter(|(_, (_, n))| *n > 0.0)
        .map(|(id, (m, _))| (id, m))
        .collect()
}
