//! The MILLION agent.
pub use million_env as env;
