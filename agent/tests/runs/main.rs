//! The agent with real env servers: training runs (lockstep, resume, learning), evaluation,
//! reports and videos, benchmarks, the env-check command. One test binary, so libtorch is
//! linked once.
#[path = "../common/mod.rs"]
mod common;
#[path = "../../env-client/tests/common/mod.rs"]
mod env_common;

mod bench_smoke;
mod env_access;
mod eval_lost_server;
mod goal_prediction;
mod learning;
mod local_servers;
mod lockstep;
mod report;
mod resume;
mod video;
