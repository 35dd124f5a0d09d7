//! Learner → actor weight hand-over: the learner publishes a deep copy of its variables
//! (network, Pop-Art layer and statistics) every `T_target` updates; the actor copies the
//! newest one into its own store at a segment boundary.

use std::collections::HashMap;
use std::sync::Mutex;

use tch::Tensor;
use tch::nn::VarStore;

#[derive(Default)]
pub struct WeightBoard {
    slot: Mutex<Option<(u64, HashMap<String, Tensor>)>>,
}

impl WeightBoard {
    /// Publishes a copy of `vs` as `version`.
    pub fn publish(&self, version: u64, vs: &VarStore) {
        let copy: HashMap<String, Tensor> = tch::no_grad(|| {
            vs.variables()
                .into_iter()
                .map(|(k, v)| (k, v.detach().copy()))
                .collect()
        });
        *self.slot.lock().expect("weight board lock") = Some((version, copy));
    }

    /// Copies the newest weights into `actor` when they are newer than `have`; returns the
    /// version the actor holds afterwards.
    pub fn refresh(&self, have: u64, actor: &mut VarStore) -> u64 {
        let guard = self.slot.lock().expect("weight board lock");
        let Some((version, weights)) = guard.as_ref() else {
            return have;
        };
        if *version <= have {
            return have;
        }
        tch::no_grad(|| {
            for (name, mut var) in actor.variables() {
                if let Some(src) = weights.get(&name) {
                    var.copy_(&src.to_device(var.device()));
                }
            }
        });
        *version
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
