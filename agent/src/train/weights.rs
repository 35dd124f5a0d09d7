//! Learner → actor weight hand-over: the learner copies its variables (network, Pop-Art
//! layer and statistics) every `T_target` updates into a snapshot it reports; the actor copies
//! a snapshot into its own store at a round's start.

use std::collections::HashMap;

use tch::Tensor;
use tch::nn::VarStore;

/// A deep copy of the learner's variables after `version` updates.
pub struct WeightSnapshot {
    pub version: u64,
    weights: HashMap<String, Tensor>,
}

impl WeightSnapshot {
    pub fn of(version: u64, vs: &VarStore) -> Self {
        let weights = tch::no_grad(|| {
            vs.variables()
                .into_iter()
                .map(|(k, v)| (k, v.detach().copy()))
                .collect()
        });
        Self { version, weights }
    }

    /// Copies the snapshot into `actor`'s variables of the same names.
    pub fn apply_to(&self, actor: &mut VarStore) {
        tch::no_grad(|| {
            for (name, mut var) in actor.variables() {
                if let Some(src) = self.weights.get(&name) {
                    var.copy_(&src.to_device(var.device()));
                }
            }
        });
    }
}

/// CPU time consumed so far by the calling thread, in seconds.
pub fn thread_cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec through a valid pointer.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return 0.0;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Lowers the calling thread's priority by `nice` (Linux applies nice per thread).
pub fn nice_current_thread(nice: i32) {
    if nice == 0 {
        return;
    }
    // SAFETY: plain syscalls on the calling thread's own id.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        if libc::setpriority(libc::PRIO_PROCESS, tid, nice) != 0 {
            tracing::warn!(nice, "could not lower the learner thread's priority");
        }
    }
}
