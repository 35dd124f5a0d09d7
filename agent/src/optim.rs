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

#[derive(Debug)]
pub struct Adam {
    cfg: OptimConfig,
    params: Vec<(String, Tensor)>,
    /// Step size of each parameter (`cfg.lr` unless overridden by prefix).
    lrs: Vec<f64>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    step: i64,
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
        let m = params.iter().map(|(_, p)| p.zeros_like()).collect();
        let v = params.iter().map(|(_, p)| p.zeros_like()).collect();
        let lrs = vec![cfg.lr; params.len()];
        Self {
            cfg,
            params,
            lrs,
            m,
            v,
            step: 0,
        }
    }

    /// Gives every variable whose name starts with `prefix` its own step size.
    pub fn set_lr_for_prefix(&mut self, prefix: &str, lr: f64) {
        for ((name, _), l) in self.params.iter().zip(self.lrs.iter_mut()) {
            if name.starts_with(prefix) {
                *l = lr;
            }
        }
    }

    /// True when every gradient present is finite (an update with a NaN or infinite gradient
    /// must not be applied).
    pub fn gradients_finite(&self) -> bool {
        tch::no_grad(|| {
            self.params.iter().all(|(_, p)| {
                let g = p.grad();
                !g.defined() || g.isfinite().all().int64_value(&[]) == 1
            })
        })
    }

    pub fn steps(&self) -> i64 {
        self.step
    }

    pub fn zero_grad(&mut self) {
        for (_, p) in self.params.iter_mut() {
            p.zero_grad();
        }
    }

    pub fn step(&mut self) {
        let OptimConfig {
            beta1, beta2, eps, ..
        } = self.cfg;
        self.step += 1;
        let bc1 = 1.0 - beta1.powi(self.step as i32);
        let bc2 = 1.0 - beta2.powi(self.step as i32);
        tch::no_grad(|| {
            for (((_, p), lr), (m, v)) in self
                .params
                .iter_mut()
                .zip(self.lrs.iter())
                .zip(self.m.iter_mut().zip(self.v.iter_mut()))
            {
                let lr = *lr;
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                *m *= beta1;
                *m += &g * (1.0 - beta1);
                *v *= beta2;
                let _ = v.addcmul_(&(&g * (1.0 - beta2)), &g);
                let denom = v.sqrt() / bc2.sqrt() + eps;
                *p -= &*m / denom * (lr / bc1);
            }
        });
    }

    /// Moments as named tensors (`adam.m.<var>`, `adam.v.<var>`).
    pub fn state(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.params.len());
        for ((name, _), (m, v)) in self.params.iter().zip(self.m.iter().zip(self.v.iter())) {
            out.push((format!("adam.m.{name}"), m.shallow_clone()));
            out.push((format!("adam.v.{name}"), v.shallow_clone()));
        }
        out
    }

    pub fn load_state(
        &mut self,
        step: i64,
        state: &HashMap<String, Tensor>,
    ) -> Result<(), OptimStateError> {
        for ((name, p), (m, v)) in self
            .params
            .iter()
            .zip(self.m.iter_mut().zip(self.v.iter_mut()))
        {
            for (prefix, dst) in [("adam.m.", m), ("adam.v.", v)] {
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
                tch::no_grad(|| dst.copy_(src));
            }
        }
        self.step = step;
        Ok(())
    }
}
