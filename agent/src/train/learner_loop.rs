//! The learner thread and its link with the actor (docs/ALGORITHM.md §5).
//!
//! The actor sends [`ToLearner`] messages (finished segment batches, checkpoint requests) in
//! order over one channel; the learner answers with a [`LearnerReport`] after each batch
//! (lockstep) or each update (free pacing), carrying its progress and, every `T_target`
//! updates, a copy of its weights. [`LearnerLink`] is the actor's end.
//!
//! Pacing (`buffer.pacing`):
//! - `lockstep`: after each batch arrives, the learner makes exactly the updates the replay
//!   ratio allows, no more and no fewer. At the start of each round of segments the actor
//!   waits until the learner has finished every update due for the rounds before the last
//!   one, and acts with the weights published by then. The learner works on the last round
//!   while the actor collects the next, so the two overlap, yet every update samples the
//!   same buffer and every round acts with the same weights at any speed and load (the same
//!   numbers on one kind of CPU; the matrix kernels, chosen by CPU, round differently on
//!   others).
//! - `free`: the learner updates whenever the replay-ratio ceiling allows and the actor never
//!   waits; updates per agent step follow the machine's speed (throughput benchmarks).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, TryRecvError};
use std::time::{Duration, Instant};

use anyhow::Context;

use rand::SeedableRng;
use rand::rngs::StdRng;
use tch::nn::VarStore;
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};

use crate::algo::buffer::{BufferCounters, SegmentBatch, SegmentBuffer};
use crate::checkpoint;
use crate::config::Pacing;
use crate::learner::{Learner, UpdateMetrics};
use crate::train::weights::{WeightSnapshot, nice_current_thread, thread_cpu_seconds};

/// What the actor sends the learner, in the order it happens.
pub enum ToLearner {
    /// One group's finished segments.
    Segments(SegmentBatch),
    /// Write a checkpoint once every earlier batch is learned from (lockstep) or at once.
    Checkpoint { path: PathBuf, agent_steps: u64 },
}

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

/// The learner's answer: its progress after `batches_done` segment batches, and new weights
/// when it published some since its last report.
pub struct LearnerReport {
    pub batches_done: u64,
    pub progress: LearnerProgress,
    pub weights: Option<WeightSnapshot>,
    /// A checkpoint the learner failed to write.
    pub checkpoint_error: Option<String>,
}

pub struct LearnerThreadArgs {
    pub learner: Learner,
    pub buffer: SegmentBuffer,
    pub inbox: Receiver<ToLearner>,
    pub reports: UnboundedSender<LearnerReport>,
    /// Free pacing only: set when the actor stops, so the learner stops without draining.
    pub stop: Arc<AtomicBool>,
    pub seed: u64,
    pub extra_meta: HashMap<String, String>,
}

/// What the thread hands back when it stops.
pub struct LearnerThreadResult {
    pub learner: Learner,
    pub buffer_counters: BufferCounters,
}

/// The learner's state between messages.
struct LearnerState {
    learner: Learner,
    buffer: SegmentBuffer,
    rng: StdRng,
    target_period: u64,
    published: u64,
    pending_weights: Option<WeightSnapshot>,
    pending_error: Option<String>,
    skipped: u64,
    last: Option<UpdateMetrics>,
    batches_done: u64,
    extra_meta: HashMap<String, String>,
}

impl LearnerState {
    /// One update if the buffer allows it; whether it made one (or refused a non-finite one).
    fn try_update(&mut self) -> bool {
        let Some(batch) = self.buffer.sample(&mut self.rng) else {
            return false;
        };
        match self.learner.update(&batch) {
            Ok(m) => self.last = Some(m),
            Err(e) => {
                self.skipped += 1;
                tracing::warn!(%e, "learner update skipped");
            }
        }
        if self.learner.updates() >= self.published + self.target_period {
            self.published = self.learner.updates();
            self.pending_weights =
                Some(WeightSnapshot::of(self.published, self.learner.var_store()));
        }
        true
    }

    fn checkpoint(&mut self, path: &std::path::Path, agent_steps: u64) {
        if let Err(e) = checkpoint::save(
            path,
            &self.learner,
            agent_steps,
            self.buffer.counters(),
            &self.extra_meta,
        ) {
            self.pending_error = Some(e.to_string());
        }
    }

    fn report(&mut self) -> LearnerReport {
        LearnerReport {
            batches_done: self.batches_done,
            progress: LearnerProgress {
                updates: self.learner.updates(),
                last: self.last.clone(),
                replay_ratio: self.buffer.replay_ratio(),
                buffer_counters: self.buffer.counters(),
                buffer_len: self.buffer.len(),
                cpu_seconds: thread_cpu_seconds(),
                skipped_updates: self.skipped,
            },
            weights: self.pending_weights.take(),
            checkpoint_error: self.pending_error.take(),
        }
    }
}

pub fn run_learner(args: LearnerThreadArgs) -> LearnerThreadResult {
    let LearnerThreadArgs {
        learner,
        buffer,
        inbox,
        reports,
        stop,
        seed,
        extra_meta,
    } = args;
    learner.config().runtime.apply();
    nice_current_thread(learner.config().runtime.learner_nice);
    let pacing = learner.config().buffer.pacing;
    let mut state = LearnerState {
        target_period: learner.config().buffer.target_period as u64,
        published: learner.updates(),
        // The actor starts with the learner's weights; the first snapshot comes T_target on.
        pending_weights: None,
        pending_error: None,
        rng: StdRng::seed_from_u64(seed ^ 0x5eed_1ea7),
        skipped: 0,
        last: None,
        batches_done: 0,
        learner,
        buffer,
        extra_meta,
    };
    // A send fails only once the actor has gone; the learner then just finishes.
    let _ = reports.send(state.report());
    match pacing {
        Pacing::Lockstep => {
            // Every message is handled, the last ones after the actor stopped too, so the
            // final weights are those of all the segments the run produced.
            while let Ok(msg) = inbox.recv() {
                match msg {
                    ToLearner::Segments(batch) => {
                        state.buffer.push_batch(&batch);
                        while state.try_update() {}
                        state.batches_done += 1;
                        let _ = reports.send(state.report());
                    }
                    ToLearner::Checkpoint { path, agent_steps } => {
                        state.checkpoint(&path, agent_steps)
                    }
                }
            }
        }
        Pacing::Free => 'run: loop {
            let handle = |state: &mut LearnerState, msg: ToLearner| match msg {
                ToLearner::Segments(batch) => {
                    state.buffer.push_batch(&batch);
                    state.batches_done += 1;
                }
                ToLearner::Checkpoint { path, agent_steps } => state.checkpoint(&path, agent_steps),
            };
            loop {
                match inbox.try_recv() {
                    Ok(msg) => handle(&mut state, msg),
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => break 'run,
                }
            }
            if stop.load(Ordering::Relaxed) {
                break;
            }
            if !state.try_update() {
                match inbox.recv_timeout(Duration::from_millis(20)) {
                    Ok(msg) => handle(&mut state, msg),
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
            }
            let _ = reports.send(state.report());
        },
    }
    LearnerThreadResult {
        buffer_counters: state.buffer.counters(),
        learner: state.learner,
    }
}

/// The actor's end of the learner thread: what it sent, what the learner reported back, and
/// the weights it acts with.
pub struct LearnerLink {
    pacing: Pacing,
    reports: UnboundedReceiver<LearnerReport>,
    /// Segment batches sent so far, and as of the previous round's start.
    batches_sent: u64,
    batches_sent_last_round: u64,
    batches_done: u64,
    progress: LearnerProgress,
    /// The newest weights reported and not yet acted with.
    held: Option<WeightSnapshot>,
    checkpoint_error: Option<String>,
    /// Time spent waiting for the learner (lockstep).
    pub waited: Duration,
}

impl LearnerLink {
    pub fn new(pacing: Pacing, reports: UnboundedReceiver<LearnerReport>) -> Self {
        Self {
            pacing,
            reports,
            batches_sent: 0,
            batches_sent_last_round: 0,
            batches_done: 0,
            progress: LearnerProgress::default(),
            held: None,
            checkpoint_error: None,
            waited: Duration::ZERO,
        }
    }

    /// Counts one batch handed to the learner.
    pub fn sent_batch(&mut self) {
        self.batches_sent += 1;
    }

    /// At the start of a round of segments: brings the actor's weights up to date. Lockstep
    /// waits until the learner has learned from every batch sent before the previous round
    /// started and takes the newest weights published by then; free pacing takes whatever is
    /// newest without waiting. `learner_running` false ends a wait (the thread died).
    pub async fn start_round(
        &mut self,
        actor: &mut VarStore,
        learner_running: impl Fn() -> bool,
    ) -> anyhow::Result<()> {
        match self.pacing {
            Pacing::Lockstep => {
                let due = self.batches_sent_last_round;
                let start = Instant::now();
                while self.batches_done < due {
                    let report = tokio::select! {
                        r = self.reports.recv() => r,
                        _ = tokio::time::sleep(Duration::from_millis(200)) => {
                            anyhow::ensure!(learner_running(), "the learner thread stopped");
                            continue;
                        }
                    };
                    let report = report.context("the learner thread stopped")?;
                    self.take(report);
                }
                self.waited += start.elapsed();
            }
            Pacing::Free => self.drain(),
        }
        self.batches_sent_last_round = self.batches_sent;
        if let Some(w) = self.held.take() {
            w.apply_to(actor);
        }
        Ok(())
    }

    /// Takes every report already waiting (free pacing; lockstep reads only what a round
    /// needs, so that what it logs is the same at any speed and load).
    fn drain(&mut self) {
        while let Ok(report) = self.reports.try_recv() {
            self.take(report);
        }
    }

    fn take(&mut self, report: LearnerReport) {
        self.batches_done = report.batches_done;
        self.progress = report.progress;
        if let Some(w) = report.weights {
            self.held = Some(w);
        }
        if let Some(e) = report.checkpoint_error {
            self.checkpoint_error.get_or_insert(e);
        }
    }

    /// The learner's progress as of the reports taken so far (free pacing: all waiting ones).
    pub fn progress(&mut self) -> &LearnerProgress {
        if self.pacing == Pacing::Free {
            self.drain();
        }
        &self.progress
    }

    /// Takes every report left (once the thread has ended): the learner's last progress.
    pub fn drain_all(&mut self) -> LearnerProgress {
        self.drain();
        self.progress.clone()
    }

    /// A checkpoint error the learner reported, once.
    pub fn take_checkpoint_error(&mut self) -> Option<String> {
        self.checkpoint_error.take()
    }
}
