//! Checkpoints: one safetensors file holding the weights (every variable of the learner's
//! store: network, Pop-Art layer and statistics, η/α), the Adam moments, and as metadata the
//! counters and the agent config (JSON). Written to a temporary file in the same directory,
//! synced, then renamed over the target, so a crash never leaves a half-written checkpoint.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::algo::buffer::BufferCounters;
use crate::config::AgentConfig;
use crate::learner::Learner;

const FORMAT: &str = "million-checkpoint-v1";
const WEIGHT_PREFIX: &str = "model.";

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("checkpoint {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("checkpoint {path}: invalid safetensors: {message}")]
    Format { path: PathBuf, message: String },
    #[error("checkpoint {path}: {message}")]
    Content { path: PathBuf, message: String },
}

/// Progress counters stored with the weights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Counters {
    pub updates: u64,
    pub adam_steps: i64,
    pub agent_steps: u64,
    pub buffer: BufferCounters,
}

/// What a checkpoint holds besides tensors.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointMeta {
    pub counters: Counters,
    pub config: AgentConfig,
    /// Free-form entries of the caller (e.g. the full run config), kept verbatim.
    pub extra: HashMap<String, String>,
}

fn dtype_of(kind: Kind) -> Option<Dtype> {
    match kind {
        Kind::Float => Some(Dtype::F32),
        Kind::Double => Some(Dtype::F64),
        Kind::Int64 => Some(Dtype::I64),
        _ => None,
    }
}

fn kind_of(dtype: Dtype) -> Option<Kind> {
    match dtype {
        Dtype::F32 => Some(Kind::Float),
        Dtype::F64 => Some(Kind::Double),
        Dtype::I64 => Some(Kind::Int64),
        _ => None,
    }
}

fn to_bytes(t: &Tensor) -> Vec<u8> {
    let t = t.detach().to_device(Device::Cpu).contiguous();
    let numel = t.numel();
    let mut buf = vec![0u8; numel * t.kind().elt_size_in_bytes()];
    t.copy_data_u8(&mut buf, numel);
    buf
}

/// Saves the learner's state atomically to `path`.
pub fn save(
    path: &Path,
    learner: &Learner,
    agent_steps: u64,
    buffer: BufferCounters,
    extra: &HashMap<String, String>,
) -> Result<(), CheckpointError> {
    let content = |message: String| CheckpointError::Content {
        path: path.to_owned(),
        message,
    };
    let mut named: Vec<(String, Tensor)> = learner
        .var_store()
        .variables()
        .into_iter()
        .map(|(k, v)| (format!("{WEIGHT_PREFIX}{k}"), v))
        .collect();
    named.extend(learner.optimiser().state());
    named.sort_by(|a, b| a.0.cmp(&b.0));
    let mut blobs = Vec::with_capacity(named.len());
    for (name, t) in &named {
        let dtype = dtype_of(t.kind())
            .ok_or_else(|| content(format!("{name}: unsupported kind {:?}", t.kind())))?;
        let shape: Vec<usize> = t.size().iter().map(|&s| s as usize).collect();
        blobs.push((name.clone(), dtype, shape, to_bytes(t)));
    }
    let views = blobs
        .iter()
        .map(|(name, dtype, shape, bytes)| {
            TensorView::new(*dtype, shape.clone(), bytes)
                .map(|v| (name.clone(), v))
                .map_err(|e| content(format!("{name}: {e}")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let counters = Counters {
        updates: learner.updates(),
        adam_steps: learner.optimiser().steps(),
        agent_steps,
        buffer,
    };
    let mut metadata = extra.clone();
    let json = |v: &dyn erased::Json| v.json().map_err(|e| content(e.to_string()));
    metadata.insert("format".into(), FORMAT.into());
    metadata.insert("counters".into(), json(&counters)?);
    metadata.insert("config".into(), json(learner.config())?);

    let bytes =
        safetensors::serialize(views, Some(metadata)).map_err(|e| CheckpointError::Format {
            path: path.to_owned(),
            message: e.to_string(),
        })?;
    let io = |source| CheckpointError::Io {
        path: path.to_owned(),
        source,
    };
    if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    crate::run_dir::write_atomically(path, &bytes).map_err(io)
}

mod erased {
    /// Object-safe JSON serialisation for the two metadata entries.
    pub trait Json {
        fn json(&self) -> serde_json::Result<String>;
    }
    impl<T: serde::Serialize> Json for T {
        fn json(&self) -> serde_json::Result<String> {
            serde_json::to_string(self)
        }
    }
}

/// Reads only the metadata (config and counters), e.g. to build a learner before [`load`].
pub fn read_meta(path: &Path) -> Result<CheckpointMeta, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.to_owned(),
        source,
    })?;
    meta_from_bytes(path, &bytes)
}

fn meta_from_bytes(path: &Path, bytes: &[u8]) -> Result<CheckpointMeta, CheckpointError> {
    let content = |message: String| CheckpointError::Content {
        path: path.to_owned(),
        message,
    };
    let (_, header) = SafeTensors::read_metadata(bytes).map_err(|e| CheckpointError::Format {
        path: path.to_owned(),
        message: e.to_string(),
    })?;
    let mut meta = header.metadata().clone().unwrap_or_default();
    if meta.remove("format").as_deref() != Some(FORMAT) {
        return Err(content(format!("not a {FORMAT} file")));
    }
    let mut take = |key: &str| {
        meta.remove(key)
            .ok_or_else(|| content(format!("metadata `{key}` missing")))
    };
    let counters: Counters =
        serde_json::from_str(&take("counters")?).map_err(|e| content(format!("counters: {e}")))?;
    let config: AgentConfig =
        serde_json::from_str(&take("config")?).map_err(|e| content(format!("config: {e}")))?;
    Ok(CheckpointMeta {
        counters,
        config,
        extra: meta,
    })
}

/// Restores weights, optimiser state and counters into `learner`, which must have been built
/// with the checkpoint's config. Returns the metadata.
pub fn load(path: &Path, learner: &mut Learner) -> Result<CheckpointMeta, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.to_owned(),
        source,
    })?;
    let meta = meta_from_bytes(path, &bytes)?;
    let content = |message: String| CheckpointError::Content {
        path: path.to_owned(),
        message,
    };
    if meta.config.model != learner.config().model {
        return Err(content(
            "the model config differs from the learner's".into(),
        ));
    }
    let st = SafeTensors::deserialize(&bytes).map_err(|e| CheckpointError::Format {
        path: path.to_owned(),
        message: e.to_string(),
    })?;
    let mut tensors = HashMap::new();
    for (name, view) in st.tensors() {
        let kind = kind_of(view.dtype())
            .ok_or_else(|| content(format!("{name}: unsupported dtype {:?}", view.dtype())))?;
        let shape: Vec<i64> = view.shape().iter().map(|&s| s as i64).collect();
        let t = Tensor::f_from_data_size(view.data(), &shape, kind)
            .map_err(|e| content(format!("{name}: {e}")))?;
        tensors.insert(name, t);
    }
    let device = learner.var_store().device();
    tch::no_grad(|| -> Result<(), CheckpointError> {
        for (name, mut var) in learner.var_store().variables() {
            let key = format!("{WEIGHT_PREFIX}{name}");
            let src = tensors
                .get(&key)
                .ok_or_else(|| content(format!("`{key}` missing")))?;
            if src.size() != var.size() || src.kind() != var.kind() {
                return Err(content(format!(
                    "`{key}` is {:?} {:?}, the model has {:?} {:?}",
                    src.kind(),
                    src.size(),
                    var.kind(),
                    var.size()
                )));
            }
            var.copy_(&src.to_device(device));
        }
        Ok(())
    })?;
    let moments: HashMap<String, Tensor> = tensors
        .into_iter()
        .filter(|(k, _)| k.starts_with("adam."))
        .map(|(k, v)| (k, v.to_device(device)))
        .collect();
    learner
        .optimiser_mut()
        .load_state(meta.counters.adam_steps, &moments)
        .map_err(|e| content(e.to_string()))?;
    learner.set_updates(meta.counters.updates);
    Ok(meta)
}
