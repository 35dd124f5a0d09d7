//! Typed spaces and the environment spec (`proto::Space`, `proto::EnvSpec`).
use std::fmt;

use crate::proto;
use crate::tensor::{DType, Tensor, numel};
use crate::value::{Kwargs, kwargs_from_proto};

/// How a batch continues after an episode ends (Gymnasium 1.x vector env modes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub enum AutoresetMode {
    /// The step after the end resets the env (its action ignored, reward 0).
    NextStep,
    /// The ending step already carries the next episode's first observation; the
    /// ending one is in `final_obs`. What a learner that bootstraps wants.
    SameStep,
    /// Ended envs must be reset by the client.
    Disabled,
}

impl AutoresetMode {
    pub fn to_proto(self) -> proto::AutoresetMode {
        match self {
            AutoresetMode::NextStep => proto::AutoresetMode::NextStep,
            AutoresetMode::SameStep => proto::AutoresetMode::SameStep,
            AutoresetMode::Disabled => proto::AutoresetMode::Disabled,
        }
    }

    /// `UNSPECIFIED` means NEXT_STEP, as the API defines.
    pub fn from_proto(value: i32) -> Result<Self, String> {
        match proto::AutoresetMode::try_from(value) {
            Ok(proto::AutoresetMode::Unspecified | proto::AutoresetMode::NextStep) => {
                Ok(AutoresetMode::NextStep)
            }
            Ok(proto::AutoresetMode::SameStep) => Ok(AutoresetMode::SameStep),
            Ok(proto::AutoresetMode::Disabled) => Ok(AutoresetMode::Disabled),
            Err(_) => Err(format!("unknown autoreset mode {value}")),
        }
    }
}

impl fmt::Display for AutoresetMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            AutoresetMode::NextStep => "NEXT_STEP",
            AutoresetMode::SameStep => "SAME_STEP",
            AutoresetMode::Disabled => "DISABLED",
        })
    }
}

/// gymnasium.spaces.Box.
#[derive(Clone, Debug, PartialEq)]
pub struct BoxSpace {
    pub shape: Vec<usize>,
    pub dtype: DType,
    /// Elementwise bounds with the space's shape (±inf where unbounded).
    pub low: Vec<f64>,
    pub high: Vec<f64>,
}

/// A Gymnasium space, one environment's worth (no batch dimension).
#[derive(Clone, Debug, PartialEq)]
pub enum Space {
    Box(BoxSpace),
    Discrete {
        n: i64,
        start: i64,
    },
    MultiBinary {
        shape: Vec<usize>,
    },
    MultiDiscrete {
        nvec: Vec<i64>,
        shape: Vec<usize>,
        start: Vec<i64>,
    },
    /// Named subspaces in the environment's declared order.
    Dict(Vec<(String, Space)>),
}

impl Space {
    pub fn from_proto(space: &proto::Space) -> Result<Self, String> {
        use proto::space::Kind;
        Ok(match space.kind.as_ref().ok_or("space without a kind")? {
            Kind::Box(b) => {
                let shape = dims(&b.shape)?;
                let dtype = DType::from_proto(b.dtype)?;
                let bound = |t: &Option<proto::Tensor>, which: &str| -> Result<Vec<f64>, String> {
                    let t = Tensor::from_proto(
                        t.clone()
                            .ok_or_else(|| format!("Box space without {which}"))?,
                    )?;
                    if t.shape() != shape.as_slice() {
                        return Err(format!(
                            "Box {which} has shape {:?}, the space {shape:?}",
                            t.shape()
                        ));
                    }
                    t.to_f64_vec()
                };
                Space::Box(BoxSpace {
                    low: bound(&b.low, "low")?,
                    high: bound(&b.high, "high")?,
                    shape,
                    dtype,
                })
            }
            Kind::Discrete(d) => {
                if d.n < 1 {
                    return Err(format!("Discrete space with n = {}", d.n));
                }
                Space::Discrete {
                    n: d.n,
                    start: d.start,
                }
            }
            Kind::MultiBinary(m) => Space::MultiBinary {
                shape: dims(&m.shape)?,
            },
            Kind::MultiDiscrete(m) => {
                let shape = dims(&m.shape)?;
                if m.nvec.len() != numel(&shape) {
                    return Err("MultiDiscrete nvec does not match its shape".into());
                }
                let start = if m.start.is_empty() {
                    vec![0; m.nvec.len()]
                } else {
                    m.start.clone()
                };
                Space::MultiDiscrete {
                    nvec: m.nvec.clone(),
                    shape,
                    start,
                }
            }
            Kind::Dict(d) => Space::Dict(
                d.entries
                    .iter()
                    .map(|e| {
                        let s = e
                            .space
                            .as_ref()
                            .ok_or_else(|| format!("Dict entry {} without a space", e.name))?;
                        Ok((e.name.clone(), Space::from_proto(s)?))
                    })
                    .collect::<Result<_, String>>()?,
            ),
        })
    }

    /// Dtype and shape of one environment's value of a non-Dict space, as it
    /// travels in a tensor (Discrete as an int64 scalar, MultiBinary as int8).
    pub fn leaf_layout(&self) -> Option<(DType, Vec<usize>)> {
        match self {
            Space::Box(b) => Some((b.dtype, b.shape.clone())),
            Space::Discrete { .. } => Some((DType::Int64, Vec::new())),
            Space::MultiBinary { shape } => Some((DType::Int8, shape.clone())),
            Space::MultiDiscrete { shape, .. } => Some((DType::Int64, shape.clone())),
            Space::Dict(_) => None,
        }
    }

    /// Leaves of the space by path (`a/b` for nested Dicts; see `Observation::fields`).
    pub fn leaves(&self) -> Vec<(String, &Space)> {
        let mut out = Vec::new();
        collect_leaves(self, "", &mut out);
        out
    }

    /// Number of scalars in one environment's value (all leaves together).
    pub fn flat_size(&self) -> usize {
        self.leaves()
            .iter()
            .map(|(_, s)| s.leaf_layout().map_or(0, |(_, shape)| numel(&shape)))
            .sum()
    }
}

impl fmt::Display for Space {
    /// A one-line summary: `Box(float32, [3])`, `Discrete(2)`, `Dict{a: ..., b: ...}`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Space::Box(b) => write!(f, "Box({}, {:?})", b.dtype, b.shape),
            Space::Discrete { n, start: 0 } => write!(f, "Discrete({n})"),
            Space::Discrete { n, start } => write!(f, "Discrete({n}, start={start})"),
            Space::MultiBinary { shape } => write!(f, "MultiBinary({shape:?})"),
            Space::MultiDiscrete { nvec, .. } => write!(f, "MultiDiscrete({nvec:?})"),
            Space::Dict(entries) => {
                f.write_str("Dict{")?;
                for (i, (name, s)) in entries.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{name}: {s}")?;
                }
                f.write_str("}")
            }
        }
    }
}

fn collect_leaves<'a>(space: &'a Space, prefix: &str, out: &mut Vec<(String, &'a Space)>) {
    match space {
        Space::Dict(entries) => {
            for (name, sub) in entries {
                let path = if prefix.is_empty() {
                    name.clone()
                } else {
                    format!("{prefix}/{name}")
                };
                collect_leaves(sub, &path, out);
            }
        }
        leaf => {
            let name = if prefix.is_empty() {
                crate::observation::FLAT_FIELD.to_owned()
            } else {
                prefix.to_owned()
            };
            out.push((name, leaf));
        }
    }
}

fn dims(shape: &[i64]) -> Result<Vec<usize>, String> {
    shape
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| format!("negative dimension in {shape:?}")))
        .collect()
}

/// One declared info field.
#[derive(Clone, Debug, PartialEq)]
pub struct InfoFieldSpec {
    pub name: String,
    pub dtype: DType,
    /// Shape of one environment's value; empty for a scalar.
    pub shape: Vec<usize>,
    pub description: String,
}

/// Everything a client needs to know about one environment of a batch.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvSpec {
    pub env_id: String,
    pub num_envs: usize,
    pub observation_space: Space,
    pub action_space: Space,
    pub info_fields: Vec<InfoFieldSpec>,
    pub autoreset: AutoresetMode,
    /// Time limit in steps; 0 = none.
    pub max_episode_steps: u64,
    /// The kwargs after the server applied its defaults.
    pub kwargs: Kwargs,
}

impl EnvSpec {
    pub fn from_proto(spec: &proto::EnvSpec) -> Result<Self, String> {
        let observation_space = Space::from_proto(
            spec.observation_space
                .as_ref()
                .ok_or("spec without an observation space")?,
        )
        .map_err(|e| format!("observation space: {e}"))?;
        let action_space = Space::from_proto(
            spec.action_space
                .as_ref()
                .ok_or("spec without an action space")?,
        )
        .map_err(|e| format!("action space: {e}"))?;
        if matches!(action_space, Space::Dict(_)) {
            return Err("Dict action spaces are not supported by this client".into());
        }
        let info_fields = spec
            .info_fields
            .iter()
            .map(|f| {
                Ok(InfoFieldSpec {
                    name: f.name.clone(),
                    dtype: DType::from_proto(f.dtype)
                        .map_err(|e| format!("info field {}: {e}", f.name))?,
                    shape: dims(&f.shape)?,
                    description: f.description.clone(),
                })
            })
            .collect::<Result<_, String>>()?;
        Ok(EnvSpec {
            env_id: spec.env_id.clone(),
            num_envs: spec.num_envs as usize,
            observation_space,
            action_space,
            info_fields,
            autoreset: AutoresetMode::from_proto(spec.autoreset_mode)?,
            max_episode_steps: spec.max_episode_steps,
            kwargs: kwargs_from_proto(&spec.kwargs)?,
        })
    }

    pub fn info_field(&self, name: &str) -> Option<&InfoFieldSpec> {
        self.info_fields.iter().find(|f| f.name == name)
    }
}
