//! The env client against real env servers: the API contract, discovery, local and
//! supervised servers, the env pool on Pendulum and Meta-World, reconnection, TLS and tokens.
//! One test binary instead of one per file, so the workspace links fewer.
#[path = "../common/mod.rs"]
mod common;

mod conformance;
mod discovery;
mod local_server;
mod pool_metaworld;
mod pool_pendulum;
mod reconnect;
mod security;
mod supervised;
