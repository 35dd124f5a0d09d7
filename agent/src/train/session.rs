//! One training run: env servers (local or given), the env pool with G groups, the actor loop
//! on this thread (gRPC streams on tokio workers), the learner on its own thread, periodic
//! logs, evaluation and checkpoints, and a summary at the end.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use million_env::{AutoresetMode, EnvPool, PoolConfig, SupervisedServer};
use serde::Serialize;
use tch::nn::VarStore;

use crate::algo::buffer::{ReplayFloor, SegmentBuffer};
use crate::checkpoint;
use crate::learner::Learner;
use crate::metrics::{MetricsWriter, Scalars};
use crate::model::Model;
use crate::run_config::RunConfig;
use crate::train::actor::{ActionBounds, GroupActor};
use crate::train::eval::{EvalReport, Evaluator};
use crate::train::learner_loop::{LearnerThreadArgs, Shared, run_learner, wait_for_learner};
use crate::train::outcomes::{EpisodeReturns, SuccessTable, TrialTracker};
use crate::train::servers::{EnvAccess, client_config, start_local_servers};
use crate::train::weights::thread_cpu_seconds;

/// The stop reason of a run whose train-split evaluation reached `train.stop_at_success`.
const TARGET_REACHED: &str = "target success reached";

/// Metadata key under which checkpoints keep the full run config (TOML).
pub const RUN_CONFIG_KEY: &str = "run_config";

pub struct TrainOptions {
    pub config: RunConfig,
    /// Env servers to use; empty = start `runtime.env_servers` local ones.
    pub servers: Vec<String>,
    /// Token and TLS for the given servers.
    pub env_access: EnvAccess,
    /// Metrics and checkpoints go here; None = nothing written (benchmarks).
    pub run_dir: Option<PathBuf>,
    pub resume: bool,
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

/// `run_dir/checkpoints/step-<agent steps>.safetensors`
pub fn checkpoint_path(run_dir: &Path, agent_steps: u64) -> PathBuf {
    run_dir
        .join("checkpoints")
        .join(format!("step-{agent_steps:015}.safetensors"))
}

/// The newest checkpoint of a run directory (or `path` itself when it is a file).
pub fn latest_checkpoint(path: &Path) -> anyhow::Result<PathBuf> {
    if path.is_file() {
        return Ok(path.to_owned());
    }
    let dir = path.join("checkpoints");
    let mut found: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("no checkpoints in {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("step-") && n.ends_with(".safetensors"))
        })
        .collect();
    found.sort();
    found
        .pop()
        .with_context(|| format!("no checkpoint files in {}", dir.display()))
}

struct Intervals {
    next_log: u64,
    next_eval: u64,
    next_ckpt: u64,
}

fn next_multiple(now: u64, every: u64) -> u64 {
    now.checked_div(every)
        .map_or(u64::MAX, |k| (k + 1).saturating_mul(every))
}

pub async fn train(opts: TrainOptions) -> anyhow::Result<TrainSummary> {
    let cfg = opts.config.clone();
    let agent_cfg = cfg.agent();
    agent_cfg.runtime.apply();
    tch::manual_seed(cfg.env.agent_seed as i64);
    let device = cfg.runtime.device();

    let (local_servers, servers): (Vec<SupervisedServer>, Vec<String>) = if opts.servers.is_empty()
    {
        let local =
            start_local_servers(cfg.runtime.env_servers, &cfg.runtime.env_server_args).await?;
        let addrs = local.iter().map(|s| s.addr().to_owned()).collect();
        (local, addrs)
    } else {
        (vec![], opts.servers.clone())
    };

    let mut learner = Learner::new(agent_cfg.clone(), device);
    let mut buffer = SegmentBuffer::new(&agent_cfg.buffer);
    let mut agent_steps = 0u64;
    if opts.resume {
        let dir = opts
            .run_dir
            .as_ref()
            .context("--resume needs a run directory")?;
        let path = latest_checkpoint(dir)?;
        let meta = checkpoint::load(&path, &mut learner)
            .with_context(|| format!("resuming from {}", path.display()))?;
        agent_steps = meta.counters.agent_steps;
        buffer.restore_counters(meta.counters.buffer);
        tracing::info!(checkpoint = %path.display(), agent_steps, updates = learner.updates(), "resumed");
    }
    let start_updates = learner.updates();
    let mut actor_vs = VarStore::new(device);
    let model = Model::new(&actor_vs.root(), &cfg.model, &cfg.popart);
    learner
        .copy_weights_to(&mut actor_vs)
        .context("initial actor weights")?;

    let client = client_config(&cfg, &opts.env_access);
    let mut pool_cfg = PoolConfig::new(servers.clone(), cfg.env.id.clone(), cfg.env.num_envs);
    pool_cfg.kwargs = cfg.env_kwargs()?;
    pool_cfg.groups = cfg.env.groups;
    pool_cfg.seed = Some(cfg.env.seed.wrapping_add(agent_steps));
    pool_cfg.autoreset = AutoresetMode::SameStep;
    pool_cfg.client = client.clone();
    let mut pool = EnvPool::connect(pool_cfg)
        .await
        .with_context(|| format!("env pool for {} on {}", cfg.env.id, servers.join(", ")))?;
    let bounds = ActionBounds::from_space(&pool.spec().action_space, cfg.model.action_dim)?;
    let mut evaluators = vec![];
    if opts.evaluate {
        for split in cfg.eval_splits()? {
            evaluators.push(
                Evaluator::connect(
                    &servers,
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
    }
    let mut metrics = match &opts.run_dir {
        Some(dir) => {
            std::fs::create_dir_all(dir.join("checkpoints"))
                .with_context(|| format!("creating {}", dir.display()))?;
            std::fs::write(dir.join("config.toml"), toml::to_string(&cfg)?)?;
            Some(MetricsWriter::open(dir)?)
        }
        None => None,
    };

    let mut extra = HashMap::new();
    extra.insert(RUN_CONFIG_KEY.to_owned(), toml::to_string(&cfg)?);
    let shared = Arc::new(Shared::default());
    shared.agent_steps.store(agent_steps, Ordering::Relaxed);
    let (tx, rx) = mpsc::channel();
    let learner_handle = {
        let shared = shared.clone();
        let args = LearnerThreadArgs {
            learner,
            buffer,
            segments: rx,
            shared,
            seed: cfg.env.agent_seed,
            extra_meta: extra.clone(),
        };
        std::thread::Builder::new()
            .name("learner".into())
            .spawn(move || run_learner(args))
            .context("starting the learner thread")?
    };

    let bar = if opts.progress {
        let bar = ProgressBar::new(cfg.train.total_agent_steps);
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

    let start = Instant::now();
    let start_steps = agent_steps;
    let cpu_start = thread_cpu_seconds();
    let mut curve = vec![];
    let mut iv = Intervals {
        next_log: next_multiple(agent_steps, cfg.train.log_interval),
        next_eval: next_multiple(agent_steps, cfg.train.eval_interval),
        next_ckpt: next_multiple(agent_steps, cfg.train.checkpoint_interval),
    };
    let mut window = SuccessTable::default();
    let mut returns = EpisodeReturns::new(pool.num_envs());
    let mut trials = TrialTracker::new(pool.num_envs(), &pool.spec().env_id);
    let mut last_log = (Instant::now(), agent_steps, 0u64);
    let mut weights_version = 0u64;
    let replay_floor = ReplayFloor::new(&cfg.buffer);
    let mut actor_wait_s = 0.0;
    let mut groups: Vec<GroupActor> = (0..pool.num_groups())
        .map(|g| GroupActor::new(&model, &pool, g))
        .collect();
    let result: anyhow::Result<Option<&'static str>> = async {
        for reset in pool.reset_all().await? {
            groups[reset.group].observe_reset(&model, &reset.obs)?;
        }
        for g in groups.iter_mut() {
            g.act_and_send(&model, &mut pool, &bounds, false)?;
        }
        let mut stop_reason = None;
        while stop_reason.is_none() {
            for gi in 0..groups.len() {
                if gi == 0 && groups[0].segment_step() == 0 {
                    weights_version = shared.weights.refresh(weights_version, &mut actor_vs);
                }
                let step = pool.recv(gi).await?;
                let g = &mut groups[gi];
                if let Some(batch) = g.observe_step(&model, &step, true)? {
                    tx.send(batch)
                        .map_err(|_| anyhow::anyhow!("the learner thread stopped"))?;
                }
                for t in trials.outcomes(g.offset, &step) {
                    window.record(&t.task, t.success);
                }
                returns.record(g.offset, &step);
                agent_steps += step.rows() as u64;
                if let Some(floor) = &replay_floor {
                    actor_wait_s +=
                        wait_for_learner(floor, &shared, || !learner_handle.is_finished())
                            .await
                            .as_secs_f64();
                }
                g.act_and_send(&model, &mut pool, &bounds, false)?;
            }
            shared.agent_steps.store(agent_steps, Ordering::Relaxed);
            bar.set_position(agent_steps);

            let elapsed = start.elapsed().as_secs_f64();
            if agent_steps >= iv.next_log {
                iv.next_log = next_multiple(agent_steps, cfg.train.log_interval);
                let progress = shared.progress.lock().expect("lock").clone();
                let dt = last_log.0.elapsed().as_secs_f64().max(1e-9);
                let sps = (agent_steps - last_log.1) as f64 / dt;
                let ups = (progress.updates - last_log.2) as f64 / dt;
                last_log = (Instant::now(), agent_steps, progress.updates);
                let finished = returns.take_finished();
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
                s.insert("cpu/actor_s".into(), thread_cpu_seconds() - cpu_start);
                // Seconds the actor held its envs for buffer.min_replay_ratio.
                s.insert("train/actor_wait_s".into(), actor_wait_s);
                s.insert("cpu/learner_s".into(), progress.cpu_seconds);
                let restarts: u64 = local_servers.iter().map(SupervisedServer::restarts).sum();
                s.insert("env/local_server_restarts".into(), restarts as f64);
                if window.trials() > 0 {
                    s.insert("train/success".into(), window.mean());
                }
                if window.tasks.len() > 1 {
                    for (task, rate) in window.per_task() {
                        s.insert(format!("train/task/{task}"), rate);
                    }
                }
                if !finished.is_empty() {
                    s.insert(
                        "train/episode_return".into(),
                        finished.iter().sum::<f64>() / finished.len() as f64,
                    );
                }
                if let Some(m) = &progress.last
                    && let Ok(serde_json::Value::Object(map)) = serde_json::to_value(m)
                {
                    for (k, v) in map {
                        match v {
                            // Per-task maps (task_psi_mass, ...): learner/<name>/<task id>
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
                bar.set_message(format!(
                    "{sps:.0} steps/s  {ups:.1} upd/s  train success {:.2}",
                    window.mean()
                ));
                tracing::debug!(agent_steps, ?s, "log");
                window = SuccessTable::default();
                if let Some(w) = metrics.as_mut() {
                    w.write(agent_steps, &s)?;
                }
            }
            if agent_steps >= iv.next_eval && !evaluators.is_empty() {
                iv.next_eval = next_multiple(agent_steps, cfg.train.eval_interval);
                let mut s = Scalars::new();
                for ev in evaluators.iter_mut() {
                    // A failed periodic evaluation (its env servers lost on every attempt)
                    // is skipped, not the end of the run: training has its own pool.
                    let r = match ev.run(&model).await {
                        Ok(r) => r,
                        Err(e) => {
                            tracing::warn!("evaluation at {agent_steps} steps skipped: {e:#}");
                            continue;
                        }
                    };
                    record_eval(&mut s, &r);
                    curve.push(CurvePoint::of(
                        &r,
                        agent_steps,
                        start.elapsed().as_secs_f64(),
                    ));
                    bar.println(format!(
                        "eval {} at {agent_steps} steps: success {:.3} (first trials {:.3})",
                        r.split, r.mean, r.first_trial
                    ));
                    if r.split == "train" && r.mean >= cfg.train.stop_at_success {
                        stop_reason = Some(TARGET_REACHED);
                    }
                }
                if let Some(w) = metrics.as_mut() {
                    w.write(agent_steps, &s)?;
                }
            }
            if agent_steps >= iv.next_ckpt {
                iv.next_ckpt = next_multiple(agent_steps, cfg.train.checkpoint_interval);
                if let Some(dir) = &opts.run_dir {
                    *shared.checkpoint_request.lock().expect("lock") =
                        Some(checkpoint_path(dir, agent_steps));
                }
            }
            if let Some(e) = shared.checkpoint_error.lock().expect("lock").take() {
                anyhow::bail!("writing a checkpoint: {e}");
            }
            if agent_steps >= cfg.train.total_agent_steps {
                stop_reason = Some("step budget reached");
            }
            if opts.max_seconds.is_some_and(|m| elapsed >= m) {
                stop_reason = Some("time limit reached");
            }
            if opts.interrupt.load(Ordering::Relaxed) {
                stop_reason = Some("interrupted");
            }
        }
        tracing::info!(
            reason = stop_reason.unwrap_or(""),
            agent_steps,
            "training stops"
        );
        for gi in 0..groups.len() {
            pool.recv(gi).await?;
        }
        Ok(stop_reason)
    }
    .await;
    let actor_cpu_s = thread_cpu_seconds() - cpu_start;
    let wall_s = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    shared.stop.store(true, Ordering::Relaxed);
    drop(tx);
    let done = learner_handle
        .join()
        .map_err(|_| anyhow::anyhow!("the learner thread panicked"))?;
    let progress = shared.progress.lock().expect("lock").clone();
    let stop_reason = result?;
    let mut learner = done.learner;
    // The run stopped right after an evaluation of the actor's weights reached the target; the
    // learner has gone on updating since. Those evaluated weights are the result (the final
    // checkpoint and evaluation), else the final figures could fall below the target that
    // ended the run (PointGoal: 0.96 at the stop, 0.79 for the learner's newer weights).
    let target_reached = stop_reason == Some(TARGET_REACHED);
    if target_reached {
        learner
            .load_network_from(&actor_vs)
            .context("taking the evaluated weights as the result")?;
    }
    let updates = learner.updates();

    let mut final_checkpoint = None;
    if let Some(dir) = &opts.run_dir {
        let path = checkpoint_path(dir, agent_steps);
        checkpoint::save(&path, &learner, agent_steps, done.buffer_counters, &extra)?;
        final_checkpoint = Some(path);
    }
    let mut final_eval = vec![];
    if opts.evaluate {
        // The final evaluation uses the learner's newest weights (the evaluated ones when
        // they reached the target: then the actor holds them already).
        if !target_reached {
            learner.copy_weights_to(&mut actor_vs)?;
        }
        let mut s = Scalars::new();
        for mut ev in evaluators {
            let r = ev.run(&model).await?;
            record_eval(&mut s, &r);
            curve.push(CurvePoint::of(
                &r,
                agent_steps,
                start.elapsed().as_secs_f64(),
            ));
            final_eval.push(r);
            ev.close().await?;
        }
        if let Some(w) = metrics.as_mut() {
            w.write(agent_steps, &s)?;
        }
    }
    pool.close().await?;
    let steps = agent_steps - start_steps;
    Ok(TrainSummary {
        agent_steps,
        updates,
        wall_s,
        agent_steps_per_s: steps as f64 / wall_s.max(1e-9),
        updates_per_s: (updates - start_updates) as f64 / wall_s.max(1e-9),
        actor_cpu_s,
        learner_cpu_s: progress.cpu_seconds,
        replay_ratio: progress.replay_ratio,
        curve,
        final_eval,
        final_checkpoint,
    })
}

fn record_eval(s: &mut Scalars, r: &EvalReport) {
    s.insert(format!("eval/{}/success", r.split), r.mean);
    s.insert(
        format!("eval/{}/first_trial_success", r.split),
        r.first_trial,
    );
    for (k, v) in &r.first_trial_within {
        s.insert(
            format!("eval/{}/first_trial_success_within/{k}", r.split),
            *v,
        );
    }
    s.insert(
        format!("eval/{}/after_success_trial_success", r.split),
        r.after_success,
    );
    s.insert(
        format!("eval/{}/after_failure_trial_success", r.split),
        r.after_failure,
    );
    s.insert(format!("eval/{}/episode_return", r.split), r.mean_return);
    for (task, v) in &r.per_task {
        s.insert(format!("eval/{}/task/{task}", r.split), *v);
    }
}
