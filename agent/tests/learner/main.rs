//! The agent's parts without env servers: the model, acting, the buffer, Pop-Art, the
//! learner (against the PyTorch reference too) and the shipped configs. One test binary, so
//! libtorch is linked once.
#[path = "../common/mod.rs"]
mod common;

mod acting;
mod bench_reference;
mod buffer;
mod configs;
mod learner;
mod model;
mod popart;
