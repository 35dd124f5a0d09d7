//! One training run: env servers (local or given), the env pool with G groups, the actor loop
//! on this thread (gRPC streams on tokio workers), the learner on its own thread, periodic
//! logs, evaluation and checkpoints, and a summary at the end.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use million_env::{AutoresetMode, EnvPool, PoolConfig, SupervisedServer};
use serde::Serialize;
use tch::nn::VarStore;

use crate::algo::buffer::{BufferCounters, SegmentBuffer};
use crate::checkpoint;
use crate::learner::{Learner, UpdateMetrics};
use crate::metrics::{MetricsWriter, Scalars};
use crate::model::Model;
use crate::run_config::RunConfig;
use crate::run_dir::{self, CHECKPOINTS_DIR, CONFIG_FILE, checkpoint_path, latest_checkpoint};
use crate::train::actor::{ActionBounds, GroupActor};
use crate::train::eval::{EvalReport, Evaluator};
use crate::train::learner_loop::{
    LearnerLink, LearnerProgress, LearnerThreadArgs, LearnerThreadResult, ToLearner, run_learner,
};
use crate::train::outcomes::{EpisodeReturns, SuccessTable, TrialTracker};
use crate::train::servers::{EnvAccess, client_config, start_local_servers};
use crate::train::weights::thread_cpu_seconds;

/// The stop reason of a run whose train-split evaluation reached `train.stop_at_success`.
const TARGET_REACHED: &str = "target success reached";

/// Metadata key under which checkpoints keep the full run config (TOML).
pub const RUN_CONFIG_KEY: &str = "run_config";
/// Metadata key of the CPU a checkpoint was written on ([`crate::machine::cpu_description`]).
pub const CPU_KEY: &str = "cpu";

pub struct TrainOptions {
    pub config: RunConfig,
    /// Env servers to use; empty = start `runtime.env_servers` local ones.
    pub servers: Vec<String>,
    /// Token and TLS for the given servers.
    pub env_access: EnvAccess,
    /// Metrics and checkpoints go here; None = nothing written (benchmarks).
    pub run_dir: Option<PathBuf>,
    pub resume: bool,
    /// End of this leg in agent steps (the run goes on later with `resume`); None = the budget.
    pub until: Option<u64>,
    pub progress: bool,
    /// Stop after this much wall time (benchmarks), besides the step budget.
    pub max_seconds: Option<f64>,
    /// Periodic and final evaluation.
    pub evaluate: bool,
    /// Set (e.g. by Ctrl-C) to stop cleanly with a final checkpoint.
    pub interrupt: Arc<AtomicBool>,
}

impl TrainOptions {
    /// A fresh run of `config` on its own local env servers, evaluated, writing nothing
    /// (set `run_dir`), without a time limit, progress bar or interrupt flag anyone holds;
    /// callers override fields with `..TrainOptions::local(config)` (e.g. `servers`).
    pub fn local(config: RunConfig) -> Self {
        Self {
            config,
            servers: vec![],
            env_access: EnvAccess::default(),
            run_dir: None,
            resume: false,
            until: None,
            progress: false,
            max_seconds: None,
            evaluate: true,
            interrupt: Arc::new(AtomicBool::new(false)),
        }
    }
}

/// One point of the learning curve.
#[derive(Debug, Clone, Serialize)]
pub struct CurvePoint {
    pub agent_steps: u64,
    pub wall_s: f64,
    pub split: String,
    pub success: f64,
    pub first_trial: f64,
    /// env steps k → first trials that succeeded within k (`EvalReport::first_trial_within`).
    pub first_trial_within: BTreeMap<u64, f64>,
}

impl CurvePoint {
    /// The curve's point of one evaluation made at `agent_steps`, `wall_s` into the run.
    fn of(r: &EvalReport, agent_steps: u64, wall_s: f64) -> Self {
        Self {
            agent_steps,
            wall_s,
            split: r.split.clone(),
            success: r.mean,
            first_trial: r.first_trial,
            first_trial_within: r.first_trial_within.clone(),
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct TrainSummary {
    pub agent_steps: u64,
    pub updates: u64,
    pub wall_s: f64,
    pub agent_steps_per_s: f64,
    pub updates_per_s: f64,
    pub actor_cpu_s: f64,
    pub learner_cpu_s: f64,
    pub replay_ratio: f64,
    pub curve: Vec<CurvePoint>,
    pub final_eval: Vec<EvalReport>,
    pub final_checkpoint: Option<PathBuf>,
}

fn next_multiple(now: u64, every: u64) -> u64 {
    now.checked_div(every)
        .map_or(u64::MAX, |k| (k + 1).saturating_mul(every))
}

/// One run, in order: set-up (servers, learner resumed or new, env pool, evaluators, run
/// folder), the learner thread, the actor loop until a stop rule holds, then the learner's
/// last updates, the final checkpoint and the final evaluation.
pub async fn train(opts: TrainOptions) -> anyhow::Result<TrainSummary> {
    let cfg = opts.config.clone();
    cfg.agent().runtime.apply();
    tch::manual_seed(cfg.env.agent_seed as i64);
    let (local_servers, servers) = env_servers(&opts).await?;
    let cpu = crate::machine::cpu_description();
    let (learner, buffer, agent_steps) = new_or_resumed_learner(&opts, cpu.as_deref())?;
    let start_updates = learner.updates();
    let mut actor_vs = VarStore::new(cfg.runtime.device());
    let model = Model::new(&actor_vs.root(), &cfg.model, &cfg.popart);
    learner
        .copy_weights_to(&mut actor_vs)
        .context("initial actor weights")?;
    let client = client_config(&cfg, &opts.env_access);
    let pool = connect_pool(&cfg, &servers, &client, agent_steps).await?;
    let evaluators = if opts.evaluate {
        connect_evaluators(&cfg, &servers, &client).await?
    } else {
        vec![]
    };
    let metrics = open_run_dir(&opts, agent_steps)?;
    let mut extra = HashMap::new();
    extra.insert(RUN_CONFIG_KEY.to_owned(), toml::to_string(&cfg)?);
    if let Some(cpu) = cpu {
        extra.insert(CPU_KEY.to_owned(), cpu);
    }
    let mut learner_thread = LearnerThread::spawn(learner, buffer, &cfg, extra.clone())?;

    let mut run = ActorLoop::new(
        &opts,
        model,
        actor_vs,
        pool,
        evaluators,
        metrics,
        (agent_steps, start_updates),
    );
    run.local_servers = local_servers;
    let outcome = run.run(&mut learner_thread).await;
    let actor_cpu_s = thread_cpu_seconds() - run.cpu_start;
    let wall_s = run.start.elapsed().as_secs_f64();
    run.bar.finish_and_clear();

    let (mut learner, buffer_counters, learner_cpu_s, replay_ratio) = learner_thread.finish()?;
    let stop_reason = outcome?;
    // The run stopped right after an evaluation of the actor's weights reached the target; the
    // learner has gone on updating since. Those evaluated weights are the result (the final
    // checkpoint and evaluation), else the final figures could fall below the target that
    // ended the run (PointGoal: 0.96 at the stop, 0.79 for the learner's newer weights).
    let target_reached = stop_reason == Some(TARGET_REACHED);
    if target_reached {
        learner
            .load_network_from(&run.actor_vs)
            .context("taking the evaluated weights as the result")?;
    } else {
        learner.copy_weights_to(&mut run.actor_vs)?;
    }
    let final_checkpoint = match &opts.run_dir {
        Some(dir) => {
            let path = checkpoint_path(dir, run.agent_steps);
            checkpoint::save(&path, &learner, run.agent_steps, buffer_counters, &extra)?;
            Some(path)
        }
        None => None,
    };
    let final_eval = run.final_evaluation().await?;
    run.pool.close().await?;
    let steps = run.agent_steps - run.start_steps;
    let updates = learner.updates();
    Ok(TrainSummary {
        agent_steps: run.agent_steps,
        updates,
        wall_s,
        agent_steps_per_s: steps as f64 / wall_s.max(1e-9),
        updates_per_s: (updates - start_updates) as f64 / wall_s.max(1e-9),
        actor_cpu_s,
        learner_cpu_s,
        replay_ratio,
        curve: run.curve,
        final_eval,
        final_checkpoint,
    })
}

/// The env servers of the run: the given ones, or `runtime.env_servers` started here.
async fn env_servers(opts: &TrainOptions) -> anyhow::Result<(Vec<SupervisedServer>, Vec<String>)> {
    if !opts.servers.is_empty() {
        return Ok((vec![], opts.servers.clone()));
    }
    let cfg = &opts.config;
    let local = start_local_servers(cfg.runtime.env_servers, &cfg.runtime.env_server_args).await?;
    let addrs = local.iter().map(|s| s.addr().to_owned()).collect();
    Ok((local, addrs))
}

/// A new learner, or (`--resume`) the newest checkpoint's with its step and buffer counters,
/// with a warning when the checkpoint was written on another kind of CPU than `cpu`.
/// The buffer's segments are not checkpointed: a resumed run refills it.
fn new_or_resumed_learner(
    opts: &TrainOptions,
    cpu: Option<&str>,
) -> anyhow::Result<(Learner, SegmentBuffer, u64)> {
    let agent_cfg = opts.config.agent();
    let mut learner = Learner::new(agent_cfg.clone(), opts.config.runtime.device());
    let mut buffer = SegmentBuffer::new(&agent_cfg.buffer);
    if !opts.resume {
        return Ok((learner, buffer, 0));
    }
    let dir = opts
        .run_dir
        .as_ref()
        .context("--resume needs a run directory")?;
    let path = latest_checkpoint(dir)?;
    let meta = checkpoint::load(&path, &mut learner)
        .with_context(|| format!("resuming from {}", path.display()))?;
    buffer.restore_counters(meta.counters.buffer);
    let agent_steps = meta.counters.agent_steps;
    tracing::info!(checkpoint = %path.display(), agent_steps, updates = learner.updates(), "resumed");
    if let Some(note) = another_cpu(meta.extra.get(CPU_KEY).map(String::as_str), cpu) {
        tracing::warn!("{note}");
    }
    Ok((learner, buffer, agent_steps))
}

/// What to tell a user who resumes a run on another kind of CPU than its checkpoint's: the
/// run goes on, but repeats number for number only on the CPUs each leg ran on.
fn another_cpu(checkpoint: Option<&str>, here: Option<&str>) -> Option<String> {
    match (checkpoint, here) {
        (Some(then), Some(now)) if then != now => Some(format!(
            "resumed on another kind of CPU (checkpoint: {then}; here: {now}): the run goes on, \
             but repeats number for number only on the CPUs its legs ran on"
        )),
        _ => None,
    }
}

/// The training env pool; env i is seeded with `env.seed + i`, moved to a seed of its own
/// when a run resumes ([`crate::run_config::EnvConfig::seed_at`]).
async fn connect_pool(
    cfg: &RunConfig,
    servers: &[String],
    client: &million_env::ClientConfig,
    agent_steps: u64,
) -> anyhow::Result<EnvPool> {
    let mut pool_cfg = PoolConfig::new(servers.to_vec(), cfg.env.id.clone(), cfg.env.num_envs);
    pool_cfg.kwargs = cfg.env_kwargs()?;
    pool_cfg.groups = cfg.env.groups;
    pool_cfg.seed = Some(cfg.env.seed_at(agent_steps));
    pool_cfg.autoreset = AutoresetMode::SameStep;
    pool_cfg.client = client.clone();
    EnvPool::connect(pool_cfg)
        .await
        .with_context(|| format!("env pool for {} on {}", cfg.env.id, servers.join(", ")))
}

async fn connect_evaluators(
    cfg: &RunConfig,
    servers: &[String],
    client: &million_env::ClientConfig,
) -> anyhow::Result<Vec<Evaluator>> {
    let mut evaluators = vec![];
    for split in cfg.eval_splits()? {
        evaluators.push(
            Evaluator::connect(
                servers,
                split,
                cfg.eval.episodes,
                &cfg.eval.first_trial_within,
                cfg.eval.seed,
                client.clone(),
                cfg.model.action_dim,
            )
            .await?,
        );
    }
    Ok(evaluators)
}

/// Creates the run folder (config.toml, checkpoints/) and its metrics files; a run resumed
/// at `agent_steps` keeps the records up to that step.
fn open_run_dir(opts: &TrainOptions, agent_steps: u64) -> anyhow::Result<Option<MetricsWriter>> {
    let Some(dir) = &opts.run_dir else {
        return Ok(None);
    };
    std::fs::create_dir_all(dir.join(CHECKPOINTS_DIR))
        .with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(dir.join(CONFIG_FILE), toml::to_string(&opts.config)?)?;
    let resumed_at = opts.resume.then_some(agent_steps);
    Ok(Some(MetricsWriter::open(dir, resumed_at)?))
}

/// The learner thread and the actor's channels to it.
struct LearnerThread {
    handle: std::thread::JoinHandle<LearnerThreadResult>,
    inbox: mpsc::Sender<ToLearner>,
    link: LearnerLink,
    stop: Arc<AtomicBool>,
}

impl LearnerThread {
    fn spawn(
        learner: Learner,
        buffer: SegmentBuffer,
        cfg: &RunConfig,
        extra_meta: HashMap<String, String>,
    ) -> anyhow::Result<Self> {
        let (inbox, inbox_rx) = mpsc::channel();
        let (reports_tx, reports) = tokio::sync::mpsc::unbounded_channel();
        let stop = Arc::new(AtomicBool::new(false));
        let args = LearnerThreadArgs {
            learner,
            buffer,
            inbox: inbox_rx,
            reports: reports_tx,
            stop: stop.clone(),
            seed: cfg.env.agent_seed,
            extra_meta,
        };
        let handle = std::thread::Builder::new()
            .name("learner".into())
            .spawn(move || run_learner(args))
            .context("starting the learner thread")?;
        Ok(Self {
            handle,
            inbox,
            link: LearnerLink::new(cfg.buffer.pacing, reports),
            stop,
        })
    }

    fn send(&self, msg: ToLearner) -> anyhow::Result<()> {
        self.inbox
            .send(msg)
            .map_err(|_| anyhow::anyhow!("the learner thread stopped"))
    }

    /// Stops the thread (lockstep: after it has learned from every batch sent) and returns
    /// the learner, its buffer counters, its CPU seconds and the replay ratio it reached.
    fn finish(self) -> anyhow::Result<(Learner, BufferCounters, f64, f64)> {
        self.stop.store(true, Ordering::Relaxed);
        drop(self.inbox);
        let done = self
            .handle
            .join()
            .map_err(|_| anyhow::anyhow!("the learner thread panicked"))?;
        let mut link = self.link;
        let p = link.drain_all();
        Ok((
            done.learner,
            done.buffer_counters,
            p.cpu_seconds,
            p.replay_ratio,
        ))
    }
}

/// The actor's side of a run: acting on the pool, logs, evaluations, checkpoint requests.
struct ActorLoop<'a> {
    opts: &'a TrainOptions,
    cfg: &'a RunConfig,
    model: Model,
    actor_vs: VarStore,
    pool: EnvPool,
    evaluators: Vec<Evaluator>,
    metrics: Option<MetricsWriter>,
    local_servers: Vec<SupervisedServer>,
    bar: ProgressBar,
    agent_steps: u64,
    start_steps: u64,
    curve: Vec<CurvePoint>,
    next_log: u64,
    next_eval: u64,
    next_ckpt: u64,
    window: SuccessTable,
    returns: EpisodeReturns,
    trials: TrialTracker,
    last_log: (Instant, u64, u64),
    start: Instant,
    cpu_start: f64,
}

impl<'a> ActorLoop<'a> {
    fn new(
        opts: &'a TrainOptions,
        model: Model,
        actor_vs: VarStore,
        pool: EnvPool,
        evaluators: Vec<Evaluator>,
        metrics: Option<MetricsWriter>,
        (agent_steps, updates): (u64, u64),
    ) -> Self {
        let cfg = &opts.config;
        let bar = if opts.progress {
            let bar = ProgressBar::new(cfg.leg_end(opts.until));
            bar.set_style(
                ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:30}] {human_pos}/{human_len} steps  {msg}  ETA {eta}",
                )
                .expect("progress template")
                .progress_chars("=> "),
            );
            bar.set_position(agent_steps);
            bar
        } else {
            ProgressBar::hidden()
        };
        let returns = EpisodeReturns::new(pool.num_envs());
        let trials = TrialTracker::new(pool.num_envs(), &pool.spec().env_id);
        Self {
            opts,
            cfg,
            model,
            actor_vs,
            pool,
            evaluators,
            metrics,
            local_servers: vec![],
            bar,
            agent_steps,
            start_steps: agent_steps,
            curve: vec![],
            next_log: next_multiple(agent_steps, cfg.train.log_interval),
            next_eval: next_multiple(agent_steps, cfg.train.eval_interval),
            next_ckpt: next_multiple(agent_steps, cfg.train.checkpoint_interval),
            window: SuccessTable::default(),
            returns,
            trials,
            last_log: (Instant::now(), agent_steps, updates),
            start: Instant::now(),
            cpu_start: thread_cpu_seconds(),
        }
    }

    /// Acts until a stop rule holds; returns why it stopped. Every group's last actions are
    /// answered before it returns, so the pool can close cleanly.
    async fn run(&mut self, learner: &mut LearnerThread) -> anyhow::Result<Option<&'static str>> {
        let bounds =
            ActionBounds::from_space(&self.pool.spec().action_space, self.cfg.model.action_dim)?;
        let mut groups: Vec<GroupActor> = (0..self.pool.num_groups())
            .map(|g| GroupActor::new(&self.model, &self.pool, g))
            .collect();
        for reset in self.pool.reset_all().await? {
            groups[reset.group].observe_reset(&self.model, &reset.obs, &reset.info)?;
        }
        for g in groups.iter_mut() {
            g.act_and_send(&self.model, &mut self.pool, &bounds, false)?;
        }
        let mut stop_reason = None;
        while stop_reason.is_none() {
            for gi in 0..groups.len() {
                if gi == 0 && groups[0].segment_step() == 0 {
                    let handle = &learner.handle;
                    learner
                        .link
                        .start_round(&mut self.actor_vs, || !handle.is_finished())
                        .await?;
                }
                let step = self.pool.recv(gi).await?;
                let g = &mut groups[gi];
                if let Some(batch) = g.observe_step(&self.model, &step, true)? {
                    learner.send(ToLearner::Segments(batch))?;
                    learner.link.sent_batch();
                }
                for t in self.trials.outcomes(g.offset, &step) {
                    self.window.record(&t.task, t.success);
                }
                self.returns.record(g.offset, &step);
                self.agent_steps += step.rows() as u64;
                g.act_and_send(&self.model, &mut self.pool, &bounds, false)?;
            }
            self.bar.set_position(self.agent_steps);
            stop_reason = self.between_steps(learner).await?;
        }
        tracing::info!(
            reason = stop_reason.unwrap_or(""),
            agent_steps = self.agent_steps,
            "training stops"
        );
        for gi in 0..groups.len() {
            self.pool.recv(gi).await?;
        }
        Ok(stop_reason)
    }

    /// Logs, evaluations and checkpoints that fall due at the current step; the stop rule
    /// that holds, if any.
    async fn between_steps(
        &mut self,
        learner: &mut LearnerThread,
    ) -> anyhow::Result<Option<&'static str>> {
        let train = &self.cfg.train;
        let mut stop_reason = None;
        if self.agent_steps >= self.next_log {
            self.next_log = next_multiple(self.agent_steps, train.log_interval);
            let waited = learner.link.waited.as_secs_f64();
            let progress = learner.link.progress().clone();
            self.log(&progress, waited)?;
        }
        if self.agent_steps >= self.next_eval && !self.evaluators.is_empty() {
            self.next_eval = next_multiple(self.agent_steps, train.eval_interval);
            if self.evaluate().await? {
                stop_reason = Some(TARGET_REACHED);
            }
        }
        if self.agent_steps >= self.next_ckpt {
            self.next_ckpt = next_multiple(self.agent_steps, train.checkpoint_interval);
            if let Some(dir) = &self.opts.run_dir {
                learner.send(ToLearner::Checkpoint {
                    path: checkpoint_path(dir, self.agent_steps),
                    agent_steps: self.agent_steps,
                })?;
            }
        }
        if let Some(e) = learner.link.take_checkpoint_error() {
            anyhow::bail!("writing a checkpoint: {e}");
        }
        if self.agent_steps >= train.total_agent_steps {
            stop_reason = Some("step budget reached");
        } else if self.opts.until.is_some_and(|u| self.agent_steps >= u) {
            stop_reason = Some("end of the leg (--until) reached");
        }
        let elapsed = self.start.elapsed().as_secs_f64();
        if self.opts.max_seconds.is_some_and(|m| elapsed >= m) {
            stop_reason = Some("time limit reached");
        }
        if self.opts.interrupt.load(Ordering::Relaxed) {
            stop_reason = Some("interrupted");
        }
        Ok(stop_reason)
    }

    /// One log record: throughput, the training window's success and returns, and the
    /// learner's latest update.
    fn log(&mut self, progress: &LearnerProgress, actor_wait_s: f64) -> anyhow::Result<()> {
        let dt = self.last_log.0.elapsed().as_secs_f64().max(1e-9);
        let sps = (self.agent_steps - self.last_log.1) as f64 / dt;
        let ups = (progress.updates.saturating_sub(self.last_log.2)) as f64 / dt;
        self.last_log = (Instant::now(), self.agent_steps, progress.updates);
        let finished = self.returns.take_finished();
        let mut s = Scalars::new();
        s.insert("train/agent_steps_per_s".into(), sps);
        s.insert("train/updates".into(), progress.updates as f64);
        // Updates refused for a non-finite loss or gradient (nothing was changed).
        s.insert(
            "learner/skipped_updates".into(),
            progress.skipped_updates as f64,
        );
        s.insert("train/updates_per_s".into(), ups);
        s.insert("train/replay_ratio".into(), progress.replay_ratio);
        s.insert("train/buffer_segments".into(), progress.buffer_len as f64);
        s.insert("cpu/actor_s".into(), thread_cpu_seconds() - self.cpu_start);
        // Seconds the actor waited for the learner (lockstep pacing).
        s.insert("train/actor_wait_s".into(), actor_wait_s);
        s.insert("cpu/learner_s".into(), progress.cpu_seconds);
        let restarts: u64 = self
            .local_servers
            .iter()
            .map(SupervisedServer::restarts)
            .sum();
        s.insert("env/local_server_restarts".into(), restarts as f64);
        if self.window.trials() > 0 {
            s.insert("train/success".into(), self.window.mean());
        }
        if self.window.tasks.len() > 1 {
            for (task, rate) in self.window.per_task() {
                s.insert(format!("train/task/{task}"), rate);
            }
        }
        if !finished.is_empty() {
            s.insert(
                "train/episode_return".into(),
                finished.iter().sum::<f64>() / finished.len() as f64,
            );
        }
        if let Some(m) = &progress.last {
            record_update(&mut s, m);
        }
        self.bar.set_message(format!(
            "{sps:.0} steps/s  {ups:.1} upd/s  train success {:.2}",
            self.window.mean()
        ));
        tracing::debug!(agent_steps = self.agent_steps, ?s, "log");
        self.window = SuccessTable::default();
        if let Some(w) = self.metrics.as_mut() {
            w.write(self.agent_steps, &s)?;
        }
        Ok(())
    }

    /// Evaluates every split with the actor's weights; whether the train split reached
    /// `train.stop_at_success`. A failed evaluation (its env servers lost on every attempt)
    /// is skipped, not the end of the run: training has its own pool.
    async fn evaluate(&mut self) -> anyhow::Result<bool> {
        let reports = self.evaluate_splits(OnEvalFailure::Skip).await?;
        let stop_at = self.cfg.train.stop_at_success;
        Ok(reports
            .iter()
            .any(|r| r.split == "train" && r.mean >= stop_at))
    }

    /// Evaluates every split with the actor's weights (the result's); unlike a periodic
    /// evaluation, a failure here ends the run with an error.
    async fn final_evaluation(&mut self) -> anyhow::Result<Vec<EvalReport>> {
        self.evaluate_splits(OnEvalFailure::Fail).await
    }

    /// Evaluates every split and records each as a point of the curve and in the metrics.
    async fn evaluate_splits(
        &mut self,
        on_failure: OnEvalFailure,
    ) -> anyhow::Result<Vec<EvalReport>> {
        let mut reports = vec![];
        let mut s = Scalars::new();
        for ev in self.evaluators.iter_mut() {
            let r = match ev.run(&self.model).await {
                Ok(r) => r,
                Err(e) if on_failure == OnEvalFailure::Skip => {
                    tracing::warn!("evaluation at {} steps skipped: {e:#}", self.agent_steps);
                    continue;
                }
                Err(e) => return Err(e),
            };
            record_eval(&mut s, &r);
            self.curve.push(CurvePoint::of(
                &r,
                self.agent_steps,
                self.start.elapsed().as_secs_f64(),
            ));
            self.bar.println(format!(
                "eval {} at {} steps: success {:.3} (first trials {:.3})",
                r.split, self.agent_steps, r.mean, r.first_trial
            ));
            reports.push(r);
        }
        if !reports.is_empty()
            && let Some(w) = self.metrics.as_mut()
        {
            w.write(self.agent_steps, &s)?;
        }
        Ok(reports)
    }
}

/// What a failed evaluation does: a periodic one is skipped (the run goes on past a server
/// that failed once), the final one ends the run with the error.
#[derive(Clone, Copy, PartialEq, Eq)]
enum OnEvalFailure {
    Skip,
    Fail,
}

/// The scalars of one learner update: `learner/<name>`, and `learner/<name>/<task id>` for
/// the per-task maps (task_psi_mass, ...).
fn record_update(s: &mut Scalars, m: &UpdateMetrics) {
    let Ok(serde_json::Value::Object(map)) = serde_json::to_value(m) else {
        return;
    };
    for (k, v) in map {
        match v {
            serde_json::Value::Object(inner) => {
                for (id, x) in inner {
                    if let Some(x) = x.as_f64() {
                        s.insert(format!("learner/{k}/{id}"), x);
                    }
                }
            }
            v => {
                if let Some(x) = v.as_f64() {
                    s.insert(format!("learner/{k}"), x);
                }
            }
        }
    }
}

fn record_eval(s: &mut Scalars, r: &EvalReport) {
    use run_dir::eval;
    let split = r.split.as_str();
    s.insert(eval::success(split), r.mean);
    s.insert(eval::first_trial_success(split), r.first_trial);
    for (k, v) in &r.first_trial_within {
        s.insert(eval::first_trial_success_within(split, *k), *v);
    }
    s.insert(eval::after_success_trial_success(split), r.after_success);
    s.insert(eval::after_failure_trial_success(split), r.after_failure);
    s.insert(eval::episode_return(split), r.mean_return);
    for (task, v) in &r.per_task {
        s.insert(format!("{}{task}", eval::task_prefix(split)), *v);
    }
}

#[cfg(test)]
mod tests {
    use super::another_cpu;

    #[test]
    fn a_resume_on_another_kind_of_cpu_is_told() {
        let zen3 = "AMD EPYC (family 25 model 1 stepping 1), 2 logical cores, AVX2, no AVX-512";
        let zen4 = "AMD EPYC (family 25 model 17 stepping 1), 2 logical cores, AVX-512 with BF16";
        let note = another_cpu(Some(zen4), Some(zen3)).expect("another CPU is told");
        assert!(note.contains(zen4) && note.contains(zen3), "{note}");
        assert_eq!(another_cpu(Some(zen3), Some(zen3)), None);
        // Checkpoints written before the CPU was recorded, or a machine that names none.
        assert_eq!(another_cpu(None, Some(zen3)), None);
        assert_eq!(another_cpu(Some(zen3), None), None);
    }
}
