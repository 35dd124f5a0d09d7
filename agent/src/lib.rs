//! The MILLION agent: GTrXL memory, Gaussian policy, Pop-Art values, V-MPO with a FIFO
//! segment buffer (ALGORITHM.md §2–§6).
pub use million_env as env;

pub mod algo;
pub mod checkpoint;
pub mod config;
pub mod learner;
pub mod model;
pub mod optim;
