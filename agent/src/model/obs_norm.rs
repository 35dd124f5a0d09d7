//! Per-feature observation normalisation of chosen fields (not in the paper; `model.obs_norm`).
//!
//! Meta-World's coordinates vary over a few centimetres to decimetres (reach goals: x within
//! ±0.1 m), and the token's LayerNorm scales a token as a whole, so a feature that barely
//! varies stays barely visible to the first linear layer. This keeps the running mean and
//! variance of every token feature over all observations the learner has seen (Chan's
//! parallel merge of each batch, in f64) and feeds (x − μ) / σ, clipped to ±`CLIP`, to the
//! network — as PPO implementations do (`VecNormalize`).
//!
//! The statistics are non-trainable variables of the model's store: they travel to the actors
//! and the target network with the weights and are saved in checkpoints. They start as the
//! identity (μ = 0, σ = 1). The learner observes every batch after its optimiser step but
//! commits the moments only when it syncs its target network (every `buffer.target_period`
//! updates): the statistics then change for the learner, the target and the actors at once,
//! so the KL between the learner and its target measures changed weights only. (Moving them
//! every update let the KL terms see changes the weights cannot undo; α_Σ then grew to 1e23.)

use tch::nn;
use tch::{Kind, Tensor};

/// Normalised features are clipped to ±CLIP (a feature that was constant so far and then
/// moves would otherwise be divided by ~0).
pub const CLIP: f64 = 10.0;
/// Added to the variance before the square root.
const EPS: f64 = 1e-8;

#[derive(Debug)]
pub struct ObsNorm {
    mean: Tensor,
    var: Tensor,
    count: Tensor,
    /// `[obs]` bool: the features that are normalised (the others pass unchanged).
    applied: Tensor,
    /// Rows observed since the last commit: count, sum and sum of squares per feature (f64).
    pending: (f64, Tensor, Tensor),
}

impl ObsNorm {
    /// Statistics for every feature of the token; `applied[i]` says whether feature i is
    /// normalised.
    pub fn new(p: nn::Path, applied: &[bool]) -> Self {
        let device = p.device();
        let obs_dim = applied.len() as i64;
        let full = |v: f64, shape: &[i64]| Tensor::full(shape, v, (Kind::Double, device));
        Self {
            mean: p.add("mean", full(0.0, &[obs_dim]), false),
            var: p.add("var", full(1.0, &[obs_dim]), false),
            count: p.add("count", full(0.0, &[1]), false),
            applied: Tensor::from_slice(applied).to_device(device),
            pending: (0.0, full(0.0, &[obs_dim]), full(0.0, &[obs_dim])),
        }
    }

    /// `[..., obs]` → normalised `[..., obs]` in the input's kind.
    pub fn forward(&self, obs: &Tensor) -> Tensor {
        let kind = obs.kind();
        let scale = (&self.var + EPS).rsqrt().to_kind(kind);
        ((obs - self.mean.to_kind(kind)) * scale)
            .clamp(-CLIP, CLIP)
            .where_self(&self.applied, obs)
    }

    /// Adds every row of `obs` `[..., obs]` to the pending moments; the statistics in use
    /// change only at [`ObsNorm::commit`].
    pub fn observe(&mut self, obs: &Tensor) {
        tch::no_grad(|| {
            let dim = *obs.size().last().expect("obs has a feature axis");
            let x = obs
                .detach()
                .reshape([-1, dim])
                .to_device(self.mean.device())
                .to_kind(Kind::Double);
            let (n, sum, sum_sq) = &mut self.pending;
            *n += x.size()[0] as f64;
            *sum += x.sum_dim_intlist(0, false, Kind::Double);
            *sum_sq += x.square().sum_dim_intlist(0, false, Kind::Double);
        })
    }

    /// Merges the pending moments into the running statistics (Chan's parallel update).
    pub fn commit(&mut self) {
        let (n, sum, sum_sq) = &mut self.pending;
        if *n == 0.0 {
            return;
        }
        tch::no_grad(|| {
            let batch_mean = &*sum / *n;
            let batch_var = (&*sum_sq / *n - batch_mean.square()).clamp_min(0.0);
            let seen = self.count.double_value(&[0]);
            let total = seen + *n;
            let delta = &batch_mean - &self.mean;
            let mean = &self.mean + &delta * (*n / total);
            // M2 = var·count; the initial identity variance carries no weight (count 0).
            let m2 = &self.var * seen + &batch_var * *n + delta.square() * (seen * *n / total);
            self.mean.copy_(&mean);
            self.var.copy_(&(m2 / total));
            let _ = self.count.fill_(total);
            *n = 0.0;
            let _ = sum.zero_();
            let _ = sum_sq.zero_();
        })
    }

    pub fn mean(&self) -> &Tensor {
        &self.mean
    }

    pub fn var(&self) -> &Tensor {
        &self.var
    }

    pub fn count(&self) -> f64 {
        self.count.double_value(&[0])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, nn::VarStore};

    #[test]
    fn starts_as_the_identity_and_merges_batches_like_one_big_batch() {
        let vs = VarStore::new(Device::Cpu);
        let mut norm = ObsNorm::new(vs.root() / "obs_norm", &[true; 3]);
        let x = Tensor::from_slice(&[0.5f32, -2.0, 3.0]).view([1, 3]);
        assert!(norm.forward(&x).allclose(&x, 0.0, 1e-6, false));

        tch::manual_seed(0);
        let a = Tensor::randn([4, 5, 3], (Kind::Float, Device::Cpu)) * 0.1 + 0.8;
        let b = Tensor::randn([7, 3], (Kind::Float, Device::Cpu)) * 0.3 - 0.2;
        norm.observe(&a);
        assert!(
            norm.forward(&x).allclose(&x, 0.0, 1e-6, false),
            "pending until commit"
        );
        norm.observe(&b);
        norm.commit();
        let all = Tensor::cat(&[a.reshape([-1, 3]), b.shallow_clone()], 0).to_kind(Kind::Double);
        let mean = all.mean_dim(0, false, Kind::Double);
        let var = (&all - &mean).square().mean_dim(0, false, Kind::Double);
        assert!(norm.mean().allclose(&mean, 1e-9, 1e-12, false));
        assert!(norm.var().allclose(&var, 1e-9, 1e-12, false));
        assert_eq!(norm.count(), 27.0);

        // After normalisation the data seen so far has mean 0 and variance 1 per feature.
        let z = norm
            .forward(&all.to_kind(Kind::Float))
            .to_kind(Kind::Double);
        let zmean = z.mean_dim(0, false, Kind::Double);
        let zvar = (&z - &zmean).square().mean_dim(0, false, Kind::Double);
        assert!(zmean.abs().max().double_value(&[]) < 1e-5);
        assert!((zvar - 1.0).abs().max().double_value(&[]) < 1e-4);
    }

    #[test]
    fn a_feature_constant_so_far_is_clipped_when_it_moves() {
        let vs = VarStore::new(Device::Cpu);
        let mut norm = ObsNorm::new(vs.root() / "obs_norm", &[true]);
        norm.observe(&Tensor::from_slice(&[2.0f32, 2.0, 2.0]).view([3, 1]));
        norm.commit();
        let out = norm.forward(&Tensor::from_slice(&[3.0f32]).view([1, 1]));
        assert_eq!(out.double_value(&[0, 0]), CLIP);
    }

    #[test]
    fn features_not_chosen_pass_unchanged() {
        let vs = VarStore::new(Device::Cpu);
        let mut norm = ObsNorm::new(vs.root() / "obs_norm", &[true, false]);
        norm.observe(&Tensor::from_slice(&[1.0f32, 5.0, 3.0, 7.0]).view([2, 2]));
        norm.commit();
        let out = norm.forward(&Tensor::from_slice(&[3.0f32, 7.0]).view([1, 2]));
        assert_eq!(
            Vec::<f32>::try_from(out.flatten(0, -1)).unwrap(),
            vec![1.0, 7.0]
        );
    }
}
