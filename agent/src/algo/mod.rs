//! V-MPO with Pop-Art targets and the FIFO segment buffer (docs/ALGORITHM.md §3–§5).

pub mod buffer;
pub mod returns;
pub mod rollout;
pub mod vmpo;
