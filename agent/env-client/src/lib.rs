//! Client side of the MILLION environment API (`proto/million/env/v1/env.proto`).
//!
//! - [`EnvClient`]: one server; every call under a deadline, connection with
//!   bounded exponential backoff, the version handshake, the [`Session`] stream.
//! - [`EnvPool`]: N envs over many servers in G independently stepped groups,
//!   pipelined over Session streams, rebuilt when a server restarts.
//! - [`conformance`]: the API's contract checks (`tests/contract/checks.toml`)
//!   as a library, for `million env-check`.
//! - Typed data: [`Tensor`] (payload kept as `bytes::Bytes`), [`Space`],
//!   [`EnvSpec`], [`Observation`] / [`Fields`], [`InfoBatch`].

/// Messages and the gRPC client generated from `proto/million/env/v1/env.proto`.
// The generated code carries the proto's comments verbatim.
#[allow(clippy::doc_lazy_continuation, clippy::doc_overindented_list_items)]
pub mod proto {
    tonic::include_proto!("million.env.v1");
}

pub mod action;
pub mod client;
pub mod conformance;
pub mod error;
pub mod local_server;
pub mod observation;
pub mod pool;
pub mod reply;
pub mod session;
pub mod space;
pub mod tensor;
pub mod value;

pub use action::{ActionSampler, Actions, encode_actions};
pub use client::{API_VERSION, ClientConfig, EnvClient, RetryPolicy, ServerInfo, Timeouts};
pub use conformance::{Report, run_conformance};
pub use error::{EnvError, Result};
pub use local_server::{LocalServer, LocalServerError, LocalServerOptions, default_server_binary};
pub use observation::{FLAT_FIELD, Fields, InfoBatch, InfoField, Observation};
pub use pool::{EnvPool, PoolConfig, PoolStats, ResetBatch, StepBatch};
pub use reply::{ResetResult, StepResult};
pub use session::{Session, SessionReply};
pub use space::{AutoresetMode, BoxSpace, EnvSpec, InfoFieldSpec, Space};
pub use tensor::{DType, Tensor};
pub use value::{Kwargs, Value, parse_env_case, parse_kwarg, parse_kwargs};
