//! Adam over named variables, with its moments exposed so checkpoints can save them (tch's
//! built-in optimiser keeps its state inside libtorch, out of reach).

use std::collections::HashMap;

use tch::Tensor;
use tch::nn::VarStore;

use crate::config::OptimConfig;

#[derive(Debug, thiserror::Error)]
pub enum OptimStateError {
    #[error("optimiser state has no `{0}`")]
    Missing(String),
    #[error("optimiser state `{name}` has shape {got:?}, the variable has {expected:?}")]
    Shape {
        name: String,
        got: Vec<i64>,
        expected: Vec<i64>,
    },
}

/// Adam with its moments and step sizes in flat buffers, one element per variable element:
/// an update is a dozen whole-buffer kernels plus one `sub_` per variable, where a loop over
/// the variables launched a dozen per variable (on a GPU, launch-bound at these sizes, the
/// loop made the update ~1.3x slower than PyTorch's fused Adam; BENCHMARKS.md, "GPU").
/// The formula is the loop's and PyTorch's (roundings may differ in the last bit).
#[derive(Debug)]
pub struct Adam {
    cfg: OptimConfig,
    params: Vec<(String, Tensor)>,
    /// (offset, length) of each variable in the flat buffers.
    spans: Vec<(i64, i64)>,
    /// Step size of each element (`cfg.lr` unless overridden by prefix).
    lr: Tensor,
    m: Tensor,
    v: Tensor,
    step: i64,
    /// Whether the slow path (a variable without a gradient) was reported already.
    warned_missing_grad: bool,
}

impl Adam {
    /// Optimises every trainable variable of `vs` (sorted by name for a stable order).
    pub fn new(vs: &VarStore, cfg: OptimConfig) -> Self {
        let mut params: Vec<(String, Tensor)> = vs
            .variables()
            .into_iter()
            .filter(|(_, t)| t.requires_grad())
            .collect();
        params.sort_by(|a, b| a.0.cmp(&b.0));
        let mut spans = Vec::with_capacity(params.len());
        let mut total = 0i64;
        for (_, p) in &params {
            let n = p.numel() as i64;
            spans.push((total, n));
            total += n;
        }
        let (kind, device) = params
            .first()
            .map_or((tch::Kind::Float, vs.device()), |(_, p)| {
                (p.kind(), p.device())
            });
        // One flat buffer needs one kind and one device (the agent's variables are all f32
        // on the run's device).
        assert!(
            params
                .iter()
                .all(|(_, p)| p.kind() == kind && p.device() == device),
            "Adam's variables must share one kind and device"
        );
        let zeros = || Tensor::zeros([total], (kind, device));
        Self {
            lr: Tensor::full([total], cfg.lr, (kind, device)),
            cfg,
            params,
            spans,
            m: zeros(),
            v: zeros(),
            step: 0,
            warned_missing_grad: false,
        }
    }

    /// Gives every variable whose name starts with `prefix` its own step size.
    pub fn set_lr_for_prefix(&mut self, prefix: &str, lr: f64) {
        for ((name, _), &(offset, len)) in self.params.iter().zip(&self.spans) {
            if name.starts_with(prefix) {
                let _ = self.lr.narrow(0, offset, len).fill_(lr);
            }
        }
    }

    pub fn steps(&self) -> i64 {
        self.step
    }

    pub fn zero_grad(&mut self) {
        for (_, p) in self.params.iter_mut() {
            p.zero_grad();
        }
    }

    /// One Adam step, unless a gradient is NaN or infinite (then nothing changes and it
    /// returns false). One device-to-host read decides, not one per variable.
    pub fn step_if_finite(&mut self) -> bool {
        if self.params.is_empty() {
            self.step += 1;
            return true;
        }
        tch::no_grad(|| {
            let grads: Vec<Tensor> = self.params.iter().map(|(_, p)| p.grad()).collect();
            if grads.iter().all(Tensor::defined) {
                let flat: Vec<Tensor> = grads.iter().map(|g| g.reshape([-1])).collect();
                let g = Tensor::cat(&flat, 0);
                // Summed in f64 (which no sum of f32 values overflows), the total is finite
                // exactly when every element is: one pass instead of isfinite's four.
                if !g.sum(tch::Kind::Double).double_value(&[]).is_finite() {
                    return false;
                }
                self.apply(&g);
            } else {
                // A variable outside the loss (the agent has none): step the others,
                // one variable at a time (the old cost: a host read per variable).
                if !self.warned_missing_grad {
                    self.warned_missing_grad = true;
                    tracing::warn!("a trainable variable has no gradient; Adam steps per variable");
                }
                let finite = grads
                    .iter()
                    .filter(|g| g.defined())
                    .all(|g| g.isfinite().all().int64_value(&[]) == 1);
                if !finite {
                    return false;
                }
                self.apply_each(&grads);
            }
            true
        })
    }

    fn bias_corrections(&mut self) -> (f64, f64) {
        self.step += 1;
        let OptimConfig { beta1, beta2, .. } = self.cfg;
        (
            1.0 - beta1.powi(self.step as i32),
            1.0 - beta2.powi(self.step as i32),
        )
    }

    /// The step on the flat gradient of every variable.
    fn apply(&mut self, g: &Tensor) {
        let bias = self.bias_corrections();
        let update = adam_update(&self.cfg, bias, &mut self.m, &mut self.v, g, &self.lr);
        for ((_, p), &(offset, len)) in self.params.iter_mut().zip(&self.spans) {
            *p -= update.narrow(0, offset, len).view_(p.size());
        }
    }

    /// The step variable by variable, skipping those without a gradient.
    fn apply_each(&mut self, grads: &[Tensor]) {
        let bias = self.bias_corrections();
        for (((_, p), &(offset, len)), g) in self.params.iter_mut().zip(&self.spans).zip(grads) {
            if !g.defined() {
                continue;
            }
            let mut m = self.m.narrow(0, offset, len);
            let mut v = self.v.narrow(0, offset, len);
            let lr = self.lr.narrow(0, offset, len);
            let update = adam_update(&self.cfg, bias, &mut m, &mut v, &g.reshape([-1]), &lr);
            *p -= update.view_(p.size());
        }
    }

    /// A variable's slice of a flat buffer, in the variable's shape (a view: writes go through).
    fn slice(&self, buffer: &Tensor, i: usize) -> Tensor {
        let (offset, len) = self.spans[i];
        buffer.narrow(0, offset, len).view_(self.params[i].1.size())
    }

    /// Moments as named tensors (`adam.m.<var>`, `adam.v.<var>`).
    pub fn state(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.params.len());
        for (i, (name, _)) in self.params.iter().enumerate() {
            out.push((format!("adam.m.{name}"), self.slice(&self.m, i)));
            out.push((format!("adam.v.{name}"), self.slice(&self.v, i)));
        }
        out
    }

    pub fn load_state(
        &mut self,
        step: i64,
        state: &HashMap<String, Tensor>,
    ) -> Result<(), OptimStateError> {
        for (i, (name, p)) in self.params.iter().enumerate() {
            for (prefix, buffer) in [("adam.m.", &self.m), ("adam.v.", &self.v)] {
                let key = format!("{prefix}{name}");
                let src = state
                    .get(&key)
                    .ok_or_else(|| OptimStateError::Missing(key.clone()))?;
                if src.size() != p.size() {
                    return Err(OptimStateError::Shape {
                        name: key,
                        got: src.size(),
                        expected: p.size(),
                    });
                }
                let mut dst = self.slice(buffer, i);
                tch::no_grad(|| dst.copy_(src));
            }
        }
        self.step = step;
        Ok(())
    }
}

/// Adam's arithmetic on flat tensors of one length: updates the moments `m` and `v` in
/// place from the gradient `g` and returns the step to subtract (element-wise step sizes
/// `lr`; `bias` = (1 − β₁ᵗ, 1 − β₂ᵗ)). Both the flat and the per-variable path call this.
fn adam_update(
    cfg: &OptimConfig,
    (bc1, bc2): (f64, f64),
    m: &mut Tensor,
    v: &mut Tensor,
    g: &Tensor,
    lr: &Tensor,
) -> Tensor {
    let OptimConfig {
        beta1, beta2, eps, ..
    } = *cfg;
    *m *= beta1;
    *m += g * (1.0 - beta1);
    *v *= beta2;
    let _ = v.addcmul_(&(g * (1.0 - beta2)), g);
    let denom = v.sqrt() / bc2.sqrt() + eps;
    &*m / denom * lr / bc1
}

#[cfg(test)]
mod tests {
    use tch::nn::{Init, VarStore};
    use tch::{Device, Kind, Tensor};

    use super::*;

    /// Variables `a` and `b` (and, with `idle`, a variable `c` outside the loss), the same
    /// start values in every store.
    fn store(idle: bool) -> (VarStore, Tensor, Tensor) {
        let vs = VarStore::new(Device::Cpu);
        let root = vs.root();
        let a = root.var_copy("a", &Tensor::from_slice(&[0.5f32, -1.0, 2.0]));
        let b = root.var_copy("b", &Tensor::from_slice(&[1.5f32, 0.25]).view([2, 1]));
        if idle {
            let _ = root.var("c", &[4], Init::Const(1.0));
        }
        (vs, a, b)
    }

    /// Adam over `vs` with step size 0.1, and 0.05 for `b`.
    fn adam(vs: &VarStore) -> Adam {
        let cfg = OptimConfig {
            lr: 0.1,
            ..OptimConfig::default()
        };
        let mut adam = Adam::new(vs, cfg);
        adam.set_lr_for_prefix("b", 0.05);
        adam
    }

    fn train(idle: bool) -> (Tensor, Tensor) {
        let (vs, a, b) = store(idle);
        let mut adam = adam(&vs);
        for k in 0..4 {
            adam.zero_grad();
            let loss = (&a * (k as f64 + 1.0)).square().sum(Kind::Float)
                + (&b - 3.0).pow_tensor_scalar(3).sum(Kind::Float);
            loss.backward();
            assert!(adam.step_if_finite());
        }
        (a.detach().copy(), b.detach().copy())
    }

    #[test]
    fn the_per_variable_path_steps_as_the_flat_one() {
        // Without `c` every variable has a gradient: the flat path. With it, `c` gets none
        // and the per-variable path runs; `a` and `b` must end where the flat path left them.
        let (flat_a, flat_b) = train(false);
        let (each_a, each_b) = train(true);
        assert!(flat_a.allclose(&each_a, 1e-6, 1e-7, false));
        assert!(flat_b.allclose(&each_b, 1e-6, 1e-7, false));
        // And they moved.
        let (_, start_a, start_b) = store(false);
        assert!(!flat_a.allclose(&start_a, 1e-3, 1e-3, false));
        assert!(!flat_b.allclose(&start_b, 1e-2, 1e-2, false));
    }

    #[test]
    fn the_first_step_moves_each_element_by_its_step_size() {
        // Adam's first step is lr · sign(g) (up to eps): 0.1 for `a`, 0.05 for `b`.
        let (vs, a, b) = store(false);
        let mut adam = adam(&vs);
        let (a0, b0) = (a.detach().copy(), b.detach().copy());
        adam.zero_grad();
        (a.sum(Kind::Float) + b.sum(Kind::Float)).backward();
        assert!(adam.step_if_finite());
        assert!((&a0 - a.detach()).allclose(&a0.full_like(0.1), 1e-5, 1e-6, false));
        assert!((&b0 - b.detach()).allclose(&b0.full_like(0.05), 1e-5, 1e-6, false));
    }

    #[test]
    fn a_non_finite_gradient_changes_nothing() {
        // Both paths: every variable in the loss (flat), and `c` outside it (per variable).
        for idle in [false, true] {
            let (vs, a, b) = store(idle);
            let mut adam = Adam::new(&vs, OptimConfig::default());
            let (a0, b0) = (a.detach().copy(), b.detach().copy());
            adam.zero_grad();
            (a.sum(Kind::Float) * f64::NAN + b.sum(Kind::Float)).backward();
            assert!(!adam.step_if_finite());
            assert!(a.detach().equal(&a0) && b.detach().equal(&b0));
            assert_eq!(adam.steps(), 0);
        }
    }
}
