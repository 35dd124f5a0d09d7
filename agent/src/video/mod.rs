//! Videos of the agent following instructions: one deterministic evaluation episode per task
//! of a split, as an animated GIF (`million eval --video DIR`).
//!
//! The episode runs like an evaluation episode (`train::eval`: the policy's mean action,
//! clipped to the action bounds, the acting state reset at the episode start) on one env of
//! its own, with the server's `Render` RPC (feature "render") drawing the scene. To find
//! one episode per task, seeds `seed, seed + 1, ...` are reset in turn and the first seed
//! that yields each task runs (the env reports its task in the info's `task_name`); the
//! search stops once no new task has appeared for a while.
//!
//! Frames, cheap by design:
//! - each instruction word is one frame (the scene does not move while words are given, so
//!   it is rendered once per instruction phase), its caption growing word by word;
//! - a trial renders its first step and then every `every`-th agent step, and its last;
//! - the end of each trial adds one frame that holds the outcome for a moment.

pub mod canvas;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use million_env::{AutoresetMode, EnvClient, Frames, InfoBatch, Tensor as EnvTensor};
use serde::Serialize;
use tch::Tensor;

use crate::model::Model;
use crate::report::slug;
use crate::run_config::EvalSplit;
use crate::train::actor::ActionBounds;
use crate::train::tokens::TokenBuilder;
use canvas::{Canvas, Caption, GifWriter};

/// How videos are made.
#[derive(Debug, Clone)]
pub struct VideoOptions {
    /// Render every k-th agent step of a trial (1 = every step).
    pub every: usize,
    /// Size of the rendered picture in pixels.
    pub width: u32,
    pub height: u32,
    /// Camera name ("" = the server's default view).
    pub camera: String,
    /// Milliseconds a trial frame is shown per agent step it stands for.
    pub step_ms: u32,
    /// Milliseconds each instruction word is shown.
    pub word_ms: u32,
    /// Milliseconds the outcome of a trial is held.
    pub outcome_ms: u32,
    /// Give up looking for new tasks after this many seeds without one (at least; see
    /// `stop_after`).
    pub patience: usize,
    /// Also write the last frame of each video as a PNG next to it.
    pub poster: bool,
}

impl Default for VideoOptions {
    fn default() -> Self {
        Self {
            every: 2,
            width: 224,
            height: 224,
            camera: String::new(),
            step_ms: 60,
            word_ms: 300,
            outcome_ms: 1200,
            patience: 50,
            poster: true,
        }
    }
}

/// What one video holds.
#[derive(Debug, Clone, Serialize)]
pub struct VideoSummary {
    pub task: String,
    pub path: PathBuf,
    /// The reset seed of the episode.
    pub seed: i64,
    /// Frames written: `words + rendered + trials.len()`.
    pub frames: usize,
    /// Instruction words shown (one frame each).
    pub words: usize,
    /// Trial frames (each a fresh render).
    pub rendered: usize,
    /// Render calls made (trial frames plus one per instruction phase).
    pub render_calls: usize,
    /// Outcome of each trial (true = success).
    pub trials: Vec<bool>,
    pub agent_steps: usize,
    /// Wall time of the episode, rendering and encoding included.
    pub seconds: f64,
}

/// Seeds to try without a new task before the search for tasks stops: `patience`, or four
/// times the tasks found when that is more (finding the last of n tasks takes about n
/// draws).
pub fn stop_after(patience: usize, tasks_found: usize) -> usize {
    patience.max(4 * tasks_found)
}

fn text(info: &InfoBatch, name: &str) -> String {
    info.strings(name)
        .ok()
        .and_then(|v| v.first().cloned())
        .unwrap_or_default()
}

fn flag(info: &InfoBatch, name: &str) -> bool {
    info.bools(name)
        .ok()
        .and_then(|v| v.first().copied())
        .unwrap_or(false)
}

fn int(info: &InfoBatch, name: &str) -> usize {
    info.f64s(name)
        .ok()
        .and_then(|v| v.first().copied())
        .map_or(0, |v| v.max(0.0) as usize)
}

/// One video per task of `split`, written to `out/<task>.gif`. Uses one env of its own on
/// `client`'s server.
pub async fn record_split(
    client: &EnvClient,
    split: &EvalSplit,
    model: &Model,
    seed: u64,
    opts: &VideoOptions,
    out: &Path,
) -> anyhow::Result<Vec<VideoSummary>> {
    anyhow::ensure!(opts.every >= 1, "render every k-th step needs k >= 1");
    anyhow::ensure!(
        client.server().has_feature(million_env::FEATURE_RENDER),
        "the env server at {} does not render (its handshake lacks the \"render\" feature)",
        client.addr()
    );
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    // NEXT_STEP: the reply of an episode's last step still shows its final state.
    let (handle, spec) = client
        .make(&split.env_id, &split.kwargs, 1, AutoresetMode::NextStep)
        .await
        .with_context(|| format!("making {} for videos", split.env_id))?;
    let result = async {
        let bounds = ActionBounds::from_space(&spec.action_space, model.config().action_dim)?;
        // The MILLION envs' `trials` kwarg, after defaults (3 otherwise).
        let trials = match spec.kwargs.get("trials") {
            Some(million_env::Value::Int(n)) if *n > 0 => *n as usize,
            _ => 3,
        };
        let mut seen = BTreeSet::new();
        let mut videos = vec![];
        let mut since_new = 0usize;
        let mut s = seed as i64;
        while since_new < stop_after(opts.patience, seen.len()) {
            let reset = client.reset(&handle, &[], &[s]).await?;
            let task = text(&reset.info, "task_name");
            let task = if task.is_empty() {
                split.env_id.clone()
            } else {
                task
            };
            if seen.insert(task.clone()) {
                since_new = 0;
                let path = out.join(format!("{}.gif", slug(&task)));
                let v = record_episode(client, &handle, model, &bounds, reset, trials, opts, &path)
                    .await
                    .with_context(|| format!("video of {task} (seed {s})"))?;
                tracing::info!(
                    task,
                    frames = v.frames,
                    seconds = v.seconds,
                    "video written"
                );
                videos.push(VideoSummary { seed: s, task, ..v });
            } else {
                since_new += 1;
            }
            s += 1;
        }
        anyhow::Ok(videos)
    }
    .await;
    client.close(&handle).await?;
    result
}

/// Records the episode that `reset` started on env 0 of `handle` into `path` (`trials`:
/// trials per episode, for the caption).
#[allow(clippy::too_many_arguments)]
pub async fn record_episode(
    client: &EnvClient,
    handle: &str,
    model: &Model,
    bounds: &ActionBounds,
    reset: million_env::ResetResult,
    trials: usize,
    opts: &VideoOptions,
    path: &Path,
) -> anyhow::Result<VideoSummary> {
    let start = Instant::now();
    let (w, h) = (opts.width, opts.height);
    let render = |what: &'static str| async move {
        let f: Frames = client
            .render(handle, &[0], w, h, &opts.camera)
            .await
            .with_context(|| format!("rendering {what}"))?;
        anyhow::Ok(f.frame(0).to_vec())
    };
    let task = text(&reset.info, "task_name");
    let mut state = model.acting_state(1);
    let mut tokens = TokenBuilder::new(model.config(), 1);
    let mut first_step = true;
    let mut obs = reset.obs.fields();
    let mut info = reset.info;

    let mut caption = Caption {
        task: task.clone(),
        trials,
        ..Caption::default()
    };
    let mut gif: Option<GifWriter> = None;
    let mut push = |canvas: &Canvas, delay: u32| -> anyhow::Result<()> {
        if gif.is_none() {
            gif = Some(GifWriter::create(path, canvas.width, canvas.height)?);
        }
        gif.as_mut().expect("created").push(canvas, delay)
    };
    let mut picture: Vec<u8> = vec![];
    let mut last_phase = String::new();
    let mut summary = VideoSummary {
        task,
        path: path.to_owned(),
        seed: 0,
        frames: 0,
        words: 0,
        rendered: 0,
        render_calls: 0,
        trials: vec![],
        agent_steps: 0,
        seconds: 0.0,
    };
    let mut last_canvas: Option<Canvas> = None;
    let mut steps_in_trial = 0usize;
    loop {
        // The observation in hand: show it.
        let phase = text(&info, "phase");
        caption.trial = int(&info, "trial");
        if phase == "instruction" {
            if last_phase != "instruction" {
                picture = render("an instruction phase").await?;
                summary.render_calls += 1;
                caption.words.clear();
            }
            caption.instructing = true;
            caption.words.push(text(&info, "token"));
            let c = Canvas::compose(&picture, w, h, &caption)?;
            push(&c, opts.word_ms)?;
            summary.words += 1;
            last_canvas = Some(c);
        } else {
            if last_phase != "trial" {
                steps_in_trial = 0;
                let sentence = text(&info, "instruction");
                caption.words = sentence.split_whitespace().map(str::to_owned).collect();
            }
            caption.instructing = false;
            if steps_in_trial.is_multiple_of(opts.every) {
                picture = render("a trial step").await?;
                summary.render_calls += 1;
                let c = Canvas::compose(&picture, w, h, &caption)?;
                push(&c, opts.step_ms * opts.every as u32)?;
                summary.rendered += 1;
                last_canvas = Some(c);
            }
        }
        last_phase = phase;

        // Act deterministically and step.
        let inputs = tokens.step_inputs(model.config(), &obs, Some(&info), &[first_step])?;
        let episode_start = Tensor::from_slice(&[first_step]);
        let out = model.act(&mut state, &inputs.token, &episode_start);
        let action = bounds.clip(&out.mean);
        let tensor = EnvTensor::from_f32(vec![1, action.len()], &action)
            .map_err(|e| anyhow::anyhow!("action tensor: {e}"))?;
        let step = client.step(handle, &tensor).await?;
        summary.agent_steps += 1;
        first_step = false;
        info = step.info;
        obs = step.obs.fields();
        if last_phase == "trial" {
            steps_in_trial += 1;
        }
        let terminated = step.terminated[0] || step.truncated[0];
        if flag(&info, "trial_end") || terminated {
            let success = flag(&info, "success");
            summary.trials.push(success);
            caption.outcomes.push(success);
            caption.trial = summary.trials.len() - 1;
            let shown = if terminated {
                // The last step's reply still holds the episode's final state.
                picture = render("the final state").await?;
                summary.render_calls += 1;
                picture.clone()
            } else {
                // The MDP was already reset for the next trial: hold the last picture.
                picture.clone()
            };
            let c = Canvas::compose(&shown, w, h, &caption)?;
            push(&c, opts.outcome_ms)?;
            last_canvas = Some(c);
            // Trial phases after a success start without words.
            last_phase = String::new();
        }
        if terminated {
            break;
        }
    }
    let gif = gif.context("the episode produced no frame")?;
    summary.frames = gif.frames();
    drop(gif);
    if opts.poster
        && let Some(c) = &last_canvas
    {
        c.save_png(&path.with_extension("png"))?;
    }
    summary.seconds = start.elapsed().as_secs_f64();
    Ok(summary)
}
