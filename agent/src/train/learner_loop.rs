//! The learner thread: drains finished segments into the FIFO buffer, samples `b` of them
//! whenever the replay-ratio throttle allows, runs `Learner::update`, publishes the weights
//! for the actor every `T_target` updates, and writes checkpoints when asked.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, TryRecvError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rand::SeedableRng;
use rand::rngs::StdRng;

use crate::algo::buffer::{BufferCounters, ReplayFloor, SegmentBatch, SegmentBuffer};
use crate::checkpoint;
use crate::learner::{Learner, UpdateMetrics};
use crate::train::weights::{WeightBoard, nice_current_thread, thread_cpu_seconds};

/// What the learner reports to the rest of the run.
#[derive(Debug, Clone, Default)]
pub struct LearnerProgress {
    pub updates: u64,
    pub last: Option<UpdateMetrics>,
    pub replay_ratio: f64,
    pub buffer_counters: BufferCounters,
    pub buffer_len: usize,
    pub cpu_seconds: f64,
    pub skipped_updates: u64,
}

/// State shared between the actor (main thread) and the learner thread.
#[derive(Default)]
pub struct Shared {
    pub weights: WeightBoard,
    pub progress: Mutex<LearnerProgress>,
    pub agent_steps: AtomicU64,
    pub stop: AtomicBool,
    /// A checkpoint path the learner should write at its next iteration.
    pub checkpoint_request: Mutex<Option<PathBuf>>,
    pub checkpoint_error: Mutex<Option<String>>,
}

pub struct LearnerThreadArgs {
    pub learner: Learner,
    pub buffer: SegmentBuffer,
    pub segments: Receiver<SegmentBatch>,
    pub shared: Arc<Shared>,
    pub seed: u64,
    pub extra_meta: HashMap<String, String>,
}

/// What the thread hands back when it stops.
pub struct LearnerThreadResult {
    pub learner: Learner,
    pub buffer_counters: BufferCounters,
}

pub fn run_learner(args: LearnerThreadArgs) -> LearnerThreadResult {
    let LearnerThreadArgs {
        mut learner,
        mut buffer,
        segments,
        shared,
        seed,
        extra_meta,
    } = args;
    learner.config().runtime.apply();
    nice_current_thread(learner.config().runtime.learner_nice);
    let target_period = learner.config().buffer.target_period as u64;
    let mut rng = StdRng::seed_from_u64(seed ^ 0x5eed_1ea7);
    let mut skipped = 0;
    shared
        .weights
        .publish(learner.updates(), learner.var_store());
    let mut published = learner.updates();
    loop {
        let mut disconnected = false;
        loop {
            match segments.try_recv() {
                Ok(b) => buffer.push_batch(&b),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    disconnected = true;
                    break;
                }
            }
        }
        if shared.stop.load(Ordering::Relaxed) || disconnected {
            break;
        }
        if let Some(path) = shared.checkpoint_request.lock().expect("lock").take() {
            let steps = shared.agent_steps.load(Ordering::Relaxed);
            if let Err(e) = checkpoint::save(&path, &learner, steps, buffer.counters(), &extra_meta)
            {
                *shared.checkpoint_error.lock().expect("lock") = Some(e.to_string());
            }
        }
        let metrics = match buffer.sample(&mut rng) {
            Some(batch) => match learner.update(&batch) {
                Ok(m) => Some(m),
                Err(e) => {
                    skipped += 1;
                    tracing::warn!(%e, "learner update skipped");
                    None
                }
            },
            None => {
                match segments.recv_timeout(Duration::from_millis(20)) {
                    Ok(b) => buffer.push_batch(&b),
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
                None
            }
        };
        if learner.updates() >= published + target_period {
            published = learner.updates();
            shared.weights.publish(published, learner.var_store());
        }
        let mut p = shared.progress.lock().expect("lock");
        p.updates = learner.updates();
        if metrics.is_some() {
            p.last = metrics;
        }
        p.replay_ratio = buffer.replay_ratio();
        p.buffer_counters = buffer.counters();
        p.buffer_len = buffer.len();
        p.cpu_seconds = thread_cpu_seconds();
        p.skipped_updates = skipped;
    }
    LearnerThreadResult {
        buffer_counters: buffer.counters(),
        learner,
    }
}

/// Holds the actor while `floor` says the learner is behind (`buffer.min_replay_ratio`), or
/// until `learner_running` turns false; returns how long it waited.
pub async fn wait_for_learner(
    floor: &ReplayFloor,
    shared: &Shared,
    learner_running: impl Fn() -> bool,
) -> Duration {
    let start = std::time::Instant::now();
    loop {
        let (counters, len) = {
            let p = shared.progress.lock().expect("lock");
            (p.buffer_counters, p.buffer_len)
        };
        if !floor.holds_actor(counters, len) || !learner_running() {
            return start.elapsed();
        }
        // An update takes tens of milliseconds or more; a millisecond's poll costs nothing.
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
}
