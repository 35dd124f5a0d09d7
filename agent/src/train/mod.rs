//! The training runtime: acting over the env pool, the learner thread, evaluation.
//!
//! - [`session::train`]: one run end to end (servers, pool, actor loop, learner thread,
//!   logs, evaluation, checkpoints).
//! - [`actor::GroupActor`]: acting and recording for one pool group.
//! - [`learner_loop::run_learner`]: the learner thread (buffer, throttle, updates, weights).
//! - [`eval::Evaluator`]: deterministic evaluation of a split.
//! - [`tokens`] (with [`instruction_slots`]), [`outcomes`], [`weights`], [`servers`]: the
//!   small pieces they share.
pub mod actor;
pub mod eval;
pub mod instruction_slots;
pub mod learner_loop;
pub mod outcomes;
pub mod servers;
pub mod session;
pub mod tokens;
pub mod weights;
