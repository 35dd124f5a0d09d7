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
//!
//! For an agent, the pool is the whole API:
//!
//! ```no_run
//! # async fn demo() -> million_env::Result<()> {
//! use million_env::{AutoresetMode, EnvPool, FLAT_FIELD, PoolConfig};
//! let mut config = PoolConfig::new(vec!["127.0.0.1:50051".into()], "Pendulum-v1", 8);
//! config.groups = 2; // double buffering: step one group while acting for the other
//! config.seed = Some(1); // env i gets seed 1 + i, whatever server it lands on
//! config.autoreset = AutoresetMode::SameStep;
//! let mut pool = EnvPool::connect(config).await?;
//! let first = pool.reset_all().await?;
//! pool.send(0, &vec![0.0f32; 4])?; // group 0: 4 envs x 1 action value
//! pool.send(1, &vec![0.0f32; 4])?;
//! let batch = pool.recv(0).await?; // obs of the next step, reward, flags, final_obs
//! let obs = batch.obs.get(FLAT_FIELD).unwrap();
//! // Raw little-endian bytes, shape and dtype: e.g. tch::Tensor::from_data_size(
//! // obs.data(), &shape_i64, Kind::Float) copies once, straight into a tensor.
//! let (_bytes, _shape) = (obs.data(), obs.shape());
//! # let _ = first;
//! pool.close().await
//! # }
//! ```

/// Messages and the gRPC client generated from `proto/million/env/v1/env.proto`.
// The generated code carries the proto's comments verbatim; its oneofs hold
// messages inline (a SessionResponse's MakeResponse is large, but rare).
#[allow(
    clippy::doc_lazy_continuation,
    clippy::doc_overindented_list_items,
    clippy::large_enum_variant
)]
pub mod proto {
    tonic::include_proto!("million.env.v1");
}

pub mod access;
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
pub mod supervised;
pub mod tensor;
pub mod value;

pub use access::{AccessError, TOKEN_ENV_VAR, TlsOptions, Token};
pub use action::{ActionSampler, Actions, encode_actions};
pub use client::{
    API_VERSION, ClientConfig, EnvClient, FEATURE_RENDER, Frames, MAX_MESSAGE_BYTES, RetryPolicy,
    ServerInfo, Timeouts,
};
pub use conformance::{Report, run_conformance};
pub use error::{EnvError, Result};
pub use local_server::{
    LocalServer, LocalServerError, LocalServerOptions, default_server_binary, find_in_repository,
};
pub use observation::{FLAT_FIELD, Fields, InfoBatch, InfoField, Observation};
pub use pool::{
    DnsResolver, EnvPool, PoolConfig, PoolStats, ResetBatch, Resolve, ResolveFuture, StepBatch,
};
pub use reply::{ResetResult, StepResult};
pub use session::{Session, SessionReply};
pub use space::{AutoresetMode, BoxSpace, EnvSpec, InfoFieldSpec, Space};
pub use supervised::{RestartPolicy, SupervisedServer};
pub use tensor::{DType, Tensor};
pub use value::{Kwargs, Value, parse_env_case, parse_kwarg, parse_kwargs};
