//! Turning an agent's actions into the tensor the API expects, and random actions.
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use crate::error::EnvError;
use crate::observation::batched;
use crate::space::Space;
use crate::tensor::{DType, Tensor, numel};

/// A batch of actions, row-major `[rows, *action shape]`, in whatever element
/// type the caller has; `encode_actions` converts it to the space's dtype.
#[derive(Clone, Copy, Debug)]
pub enum Actions<'a> {
    F32(&'a [f32]),
    F64(&'a [f64]),
    I64(&'a [i64]),
    /// Already a tensor of the right dtype and shape `[rows, *shape]`.
    Tensor(&'a Tensor),
}

impl<'a> From<&'a [f32]> for Actions<'a> {
    fn from(v: &'a [f32]) -> Self {
        Actions::F32(v)
    }
}
impl<'a> From<&'a Vec<f32>> for Actions<'a> {
    fn from(v: &'a Vec<f32>) -> Self {
        Actions::F32(v)
    }
}
impl<'a> From<&'a [f64]> for Actions<'a> {
    fn from(v: &'a [f64]) -> Self {
        Actions::F64(v)
    }
}
impl<'a> From<&'a Vec<f64>> for Actions<'a> {
    fn from(v: &'a Vec<f64>) -> Self {
        Actions::F64(v)
    }
}
impl<'a> From<&'a [i64]> for Actions<'a> {
    fn from(v: &'a [i64]) -> Self {
        Actions::I64(v)
    }
}
impl<'a> From<&'a Vec<i64>> for Actions<'a> {
    fn from(v: &'a Vec<i64>) -> Self {
        Actions::I64(v)
    }
}
impl<'a> From<&'a Tensor> for Actions<'a> {
    fn from(t: &'a Tensor) -> Self {
        Actions::Tensor(t)
    }
}

/// Encodes `rows` actions for `space`, checking length, finiteness and, for
/// integer spaces, integrality and range, so a bad batch is refused before any
/// part of it reaches a server.
pub fn encode_actions(
    space: &Space,
    rows: usize,
    actions: Actions<'_>,
) -> Result<Tensor, EnvError> {
    let (dtype, shape) = space
        .leaf_layout()
        .ok_or_else(|| EnvError::InvalidInput("Dict action spaces are not supported".into()))?;
    let want = batched(rows, &shape);
    let per_row = numel(&shape);
    let invalid = EnvError::InvalidInput;
    let tensor = match actions {
        Actions::Tensor(t) => {
            if t.dtype() != dtype || t.shape() != want.as_slice() {
                return Err(invalid(format!(
                    "action tensor is {} {:?}; the space needs {dtype} {want:?}",
                    t.dtype(),
                    t.shape()
                )));
            }
            t.clone()
        }
        other => {
            let values: Vec<f64> = match other {
                Actions::F32(v) => v.iter().map(|&x| f64::from(x)).collect(),
                Actions::F64(v) => v.to_vec(),
                Actions::I64(v) => v.iter().map(|&x| x as f64).collect(),
                Actions::Tensor(_) => unreachable!("handled above"),
            };
            if values.len() != rows * per_row {
                return Err(invalid(format!(
                    "{} action values for {rows} envs of {per_row} each",
                    values.len()
                )));
            }
            from_values(dtype, want, &values, other).map_err(invalid)?
        }
    };
    check_values(space, &tensor).map_err(invalid)?;
    Ok(tensor)
}

fn from_values(
    dtype: DType,
    shape: Vec<usize>,
    values: &[f64],
    src: Actions<'_>,
) -> Result<Tensor, String> {
    match (dtype, src) {
        // Keep the caller's exact bits when no conversion is needed.
        (DType::Float32, Actions::F32(v)) => Tensor::from_f32(shape, v),
        (DType::Float64, Actions::F64(v)) => Tensor::from_f64(shape, v),
        (DType::Int64, Actions::I64(v)) => Tensor::from_i64(shape, v),
        (DType::Float32, _) => {
            Tensor::from_f32(shape, &values.iter().map(|&x| x as f32).collect::<Vec<_>>())
        }
        (DType::Float64, _) => Tensor::from_f64(shape, values),
        (DType::Int64 | DType::Int8, _) => {
            let ints = values
                .iter()
                .map(|&x| {
                    if x.is_finite() && x.fract() == 0.0 {
                        Ok(x as i64)
                    } else {
                        Err(format!("action {x} is not an integer"))
                    }
                })
                .collect::<Result<Vec<_>, _>>()?;
            if dtype == DType::Int8 {
                let small = ints
                    .iter()
                    .map(|&i| i8::try_from(i).map_err(|_| format!("action {i} does not fit int8")))
                    .collect::<Result<Vec<_>, _>>()?;
                Tensor::from_i8(shape, &small)
            } else {
                Tensor::from_i64(shape, &ints)
            }
        }
        (other, _) => Err(format!("action dtype {other} is not supported")),
    }
}

fn check_values(space: &Space, t: &Tensor) -> Result<(), String> {
    match space {
        Space::Box(_) => {
            if let Some(bad) = t.to_f64_vec()?.into_iter().find(|v| !v.is_finite()) {
                return Err(format!("action value {bad} is not finite"));
            }
            Ok(())
        }
        Space::Discrete { n, start } => {
            for v in t.to_i64_vec()? {
                if v < *start || v >= start + n {
                    return Err(format!(
                        "action {v} outside Discrete [{start}, {})",
                        start + n
                    ));
                }
            }
            Ok(())
        }
        Space::MultiBinary { .. } => {
            if t.to_i64_vec()?.iter().any(|v| *v != 0 && *v != 1) {
                return Err("MultiBinary action other than 0/1".into());
            }
            Ok(())
        }
        Space::MultiDiscrete { nvec, start, .. } => {
            for (i, v) in t.to_i64_vec()?.into_iter().enumerate() {
                let j = i % nvec.len();
                if v < start[j] || v >= start[j] + nvec[j] {
                    return Err(format!("action element {i} = {v} outside its range"));
                }
            }
            Ok(())
        }
        Space::Dict(_) => Err("Dict action spaces are not supported".into()),
    }
}

/// Uniform random actions of a space, reproducible from a seed. Unbounded Box
/// sides are sampled within [-1, 1].
#[derive(Debug)]
pub struct ActionSampler {
    space: Space,
    rng: StdRng,
}

impl ActionSampler {
    pub fn new(space: &Space, seed: u64) -> Result<Self, EnvError> {
        if space.leaf_layout().is_none() {
            return Err(EnvError::InvalidInput(
                "Dict action spaces are not supported".into(),
            ));
        }
        Ok(ActionSampler {
            space: space.clone(),
            rng: StdRng::seed_from_u64(seed),
        })
    }

    /// Actions for `rows` envs, already encoded in the space's dtype.
    pub fn sample(&mut self, rows: usize) -> Tensor {
        let (dtype, shape) = self.space.leaf_layout().expect("checked in new");
        let shape = batched(rows, &shape);
        let n = numel(&shape);
        let rng = &mut self.rng;
        let result = match &self.space {
            Space::Box(b) => {
                let per = b.low.len().max(1);
                let values: Vec<f64> = (0..n)
                    .map(|i| {
                        let lo = if b.low[i % per].is_finite() {
                            b.low[i % per]
                        } else {
                            -1.0
                        };
                        let hi = if b.high[i % per].is_finite() {
                            b.high[i % per]
                        } else {
                            1.0
                        };
                        let x = lo + (hi - lo) * rng.random::<f64>();
                        // float32 rounding must not push a sample past the bound.
                        x.clamp(lo, hi)
                    })
                    .collect();
                match dtype {
                    DType::Float32 => {
                        let v: Vec<f32> = values
                            .iter()
                            .enumerate()
                            .map(|(i, &x)| {
                                (x as f32).clamp(b.low[i % per] as f32, b.high[i % per] as f32)
                            })
                            .collect();
                        Tensor::from_f32(shape, &v)
                    }
                    DType::Float64 => Tensor::from_f64(shape, &values),
                    _ => {
                        let ints: Vec<i64> = values.iter().map(|x| x.round() as i64).collect();
                        Tensor::from_i64(shape, &ints)
                    }
                }
            }
            Space::Discrete { n: k, start } => {
                let v: Vec<i64> = (0..n).map(|_| start + rng.random_range(0..*k)).collect();
                Tensor::from_i64(shape, &v)
            }
            Space::MultiBinary { .. } => {
                let v: Vec<i8> = (0..n).map(|_| i8::from(rng.random::<bool>())).collect();
                Tensor::from_i8(shape, &v)
            }
            Space::MultiDiscrete { nvec, start, .. } => {
                let v: Vec<i64> = (0..n)
                    .map(|i| {
                        let j = i % nvec.len();
                        start[j] + rng.random_range(0..nvec[j])
                    })
                    .collect();
                Tensor::from_i64(shape, &v)
            }
            Space::Dict(_) => unreachable!("checked in new"),
        };
        result.expect("sampled values match the layout")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::BoxSpace;

    fn pendulum_action() -> Space {
        Space::Box(BoxSpace {
            shape: vec![1],
            dtype: DType::Float32,
            low: vec![-2.0],
            high: vec![2.0],
        })
    }

    #[test]
    fn encodes_f32_without_conversion_and_refuses_bad_batches() {
        let space = pendulum_action();
        let t = encode_actions(&space, 2, Actions::F32(&[0.5, -1.0])).unwrap();
        assert_eq!(t.shape(), &[2, 1]);
        assert_eq!(t.dtype(), DType::Float32);
        let err = encode_actions(&space, 3, Actions::F32(&[0.5, -1.0])).unwrap_err();
        assert!(
            err.to_string().contains("2 action values for 3 envs"),
            "{err}"
        );
        let err = encode_actions(&space, 1, Actions::F32(&[f32::NAN])).unwrap_err();
        assert!(err.to_string().contains("not finite"), "{err}");
    }

    #[test]
    fn discrete_actions_must_be_integral_and_in_range() {
        let space = Space::Discrete { n: 2, start: 0 };
        let t = encode_actions(&space, 2, Actions::F32(&[1.0, 0.0])).unwrap();
        assert_eq!(t.to_i64_vec().unwrap(), vec![1, 0]);
        assert!(encode_actions(&space, 1, Actions::F32(&[0.5])).is_err());
        assert!(encode_actions(&space, 1, Actions::I64(&[2])).is_err());
    }

    #[test]
    fn sampler_is_reproducible_and_within_bounds() {
        let space = pendulum_action();
        let a = ActionSampler::new(&space, 7).unwrap().sample(64);
        let b = ActionSampler::new(&space, 7).unwrap().sample(64);
        assert_eq!(a, b);
        assert!(
            a.to_f64_vec()
                .unwrap()
                .iter()
                .all(|v| (-2.0..=2.0).contains(v))
        );
        encode_actions(&space, 64, Actions::Tensor(&a)).unwrap();
        let d = ActionSampler::new(&Space::Discrete { n: 3, start: 1 }, 1)
            .unwrap()
            .sample(50);
        assert!(d.to_i64_vec().unwrap().iter().all(|v| (1..4).contains(v)));
    }
}
