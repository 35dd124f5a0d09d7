//! The MILLION agent: GTrXL memory, Gaussian policy, Pop-Art values, V-MPO with a FIFO
//! segment buffer (docs/ALGORITHM.md §2–§6).
//!
//! How the pieces fit (one actor thread, one learner thread, `runtime.intra_op_threads` = 1):
//! - [`config::AgentConfig`]: every hyperparameter, paper defaults, unknown keys rejected;
//!   call `cfg.runtime.apply()` once at start-up.
//! - [`learner::Learner`] owns the trained [`model::Model`], η/α and Adam;
//!   `Learner::copy_weights_to` refreshes an actor's `VarStore` (do it between segments).
//! - Acting: `Model::acting_state(B)` then `Model::act(&mut state, obs [B, obs], episode_start
//!   [B])` → behaviour mean/std; sample with [`model::policy::sample_actions`] (store the
//!   unclipped sample, clip only for the env). At each segment start hand
//!   `state.segment_start_memory()` to [`algo::rollout::RolloutCollector::begin`], push one
//!   [`algo::rollout::StepRecord`] per step with the observation it led to
//!   ([`algo::rollout::NextObservation`]); every T steps it yields a
//!   [`algo::buffer::SegmentBatch`] for [`algo::buffer::SegmentBuffer::push_batch`].
//! - Learning: `SegmentBuffer::sample` (throttled by the replay ratio) → `Learner::update`;
//!   [`train::learner_loop`] paces it against the actors (`buffer.pacing`).
//! - [`checkpoint::save`] / [`checkpoint::load`]: one atomic safetensors file;
//!   [`run_dir`]: the run folder's layout and metric names.
//! - Looking at a run: [`report`] (figures and report.md from run directories), [`video`]
//!   (GIFs of deterministic episodes, frames from the env server's `Render`).
pub use million_env as env;

pub mod algo;
pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod font;
pub mod heap;
pub mod learner;
pub mod machine;
pub mod metrics;
pub mod model;
pub mod optim;
pub mod procstat;
pub mod report;
pub mod run_config;
pub mod run_dir;
pub mod train;
pub mod video;
