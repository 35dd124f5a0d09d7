//! `million bench learner --reference`: the Rust learner against a PyTorch reference of the
//! same model and V-MPO update (`bench/learner_reference.py`).
//!
//! 1. Builds the learner of the config, randomises what starts at a constant (relative
//!    biases, Pop-Art statistics), makes a random batch, and writes weights, batch and agent
//!    config to a directory (safetensors + JSON).
//! 2. Check: the loss terms on those weights and that batch (no update), the metrics of one
//!    update, and the terms after it, in Rust and in PyTorch; every value must agree to
//!    1e-5 (absolute or relative; 1e-3 after the Adam step), else the command fails.
//! 3. Timing: per intra-op thread count, rounds of `iters` updates (each after one untimed
//!    update), Rust then PyTorch, then PyTorch then Rust, and so on, so that drift in the
//!    machine's load reaches both sides alike. The PyTorch side is one long-lived process
//!    that answers JSON lines, so neither side pays for start-up inside a round.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, ExitCode, Stdio};
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use serde::Serialize;
use serde_json::{Value, json};
use tch::{Device, Kind, Tensor};

use million_env::find_in_repository;

use crate::algo::buffer::SegmentBatch;
use crate::config::{AgentConfig, GoalPrediction};
use crate::learner::Learner;
use crate::run_config::RunConfig;

/// Largest difference (absolute, or relative to the Rust value) accepted between the two on
/// the same weights and batch: the loss terms before the update and the update's metrics.
pub const TOLERANCE: f64 = 1e-5;
/// The same after one Adam step. Adam's first step moves every weight by ± its step size
/// whatever the gradient's magnitude, so a near-zero gradient whose last bits differ in sign
/// puts that weight two step sizes apart; the terms after the step then differ by up to
/// ~1e-4 (relative) on some random batches at configs/ml10.toml's sizes.
pub const AFTER_STEP_TOLERANCE: f64 = 1e-3;

fn tolerance(stage: &str) -> f64 {
    if stage == "after" {
        AFTER_STEP_TOLERANCE
    } else {
        TOLERANCE
    }
}

const SCRIPT: &str = "bench/learner_reference.py";

#[derive(Debug, Args)]
pub struct ReferenceArgs {
    /// Compare with the PyTorch reference (bench/learner_reference.py): the same loss on the
    /// same weights and batch (fails beyond 1e-5), then updates/s side by side.
    #[arg(long)]
    pub reference: bool,
    /// Intra-op thread counts to time (with --reference).
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 2], requires = "reference")]
    pub threads: Vec<usize>,
    /// Rounds per thread count, each `--iters` updates per side, the order alternating.
    #[arg(long, default_value_t = 2, requires = "reference")]
    pub rounds: usize,
    /// Python with torch (default: .venv/bin/python of the repository, else python3).
    #[arg(long, requires = "reference")]
    pub python: Option<PathBuf>,
    /// Write weights, batch and config here and keep them (default: a temporary directory).
    #[arg(long, requires = "reference")]
    pub dir: Option<PathBuf>,
    /// Machine-readable output (with --reference).
    #[arg(long, requires = "reference")]
    pub json: bool,
}

/// Fails clearly when `python` cannot run or has no torch; its torch version otherwise.
fn torch_version(python: &Path) -> anyhow::Result<String> {
    let out = Command::new(python)
        .args(["-c", "import torch; print(torch.__version__)"])
        .output()
        .with_context(|| format!("cannot run {} (pass --python)", python.display()))?;
    if !out.status.success() {
        bail!(
            "{} cannot import torch, which the PyTorch reference needs (run `make setup`, or \
             pass --python with torch installed):\n{}",
            python.display(),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// Relative biases and Pop-Art statistics start at constants; random values exercise the
/// distance lookup and the (un)normalisation.
fn randomise(learner: &Learner) {
    let popart = learner.config().popart.enabled;
    let vars = learner.var_store().variables();
    tch::no_grad(|| {
        for (name, t) in &vars {
            let mut t = t.shallow_clone();
            if name.ends_with("rel_bias") || (popart && name.ends_with("popart.mu")) {
                t.copy_(&(t.randn_like() * 0.5));
            } else if popart && name.ends_with("popart.sigma") {
                t.copy_(&(t.rand_like() * 1.5 + 0.5));
            }
        }
        for (name, t) in &vars {
            if let Some(prefix) = name.strip_suffix("popart.nu")
                && popart
            {
                let mu = &vars[&format!("{prefix}popart.mu")];
                let sigma = &vars[&format!("{prefix}popart.sigma")];
                t.shallow_clone().copy_(&(sigma.square() + mu.square()));
            }
        }
    });
}

/// Writes config, weights and batch for the reference script.
fn write_inputs(
    dir: &Path,
    agent: &AgentConfig,
    learner: &Learner,
    b: &SegmentBatch,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(
        dir.join("config.json"),
        serde_json::to_string_pretty(agent)?,
    )?;
    let cpu = |t: &Tensor| t.detach().to_device(Device::Cpu);
    let mut weights: Vec<(String, Tensor)> = learner
        .var_store()
        .variables()
        .into_iter()
        .map(|(name, t)| (name, cpu(&t)))
        .collect();
    weights.sort_by(|a, b| a.0.cmp(&b.0));
    Tensor::write_safetensors(&weights, dir.join("weights.safetensors"))?;
    let fields = [
        ("obs", &b.obs),
        ("actions", &b.actions),
        ("rewards", &b.rewards),
        ("terminated", &b.terminated),
        ("truncated", &b.truncated),
        ("episode_start", &b.episode_start),
        ("instruction", &b.instruction),
        ("task", &b.task),
        ("behaviour_mean", &b.behaviour_mean),
        ("behaviour_std", &b.behaviour_std),
        ("bootstrap_obs", &b.bootstrap_obs),
        ("bootstrap_start", &b.bootstrap_start),
        ("memory", &b.memory),
        ("memory_len", &b.memory_len),
    ];
    let batch: Vec<(&str, Tensor)> = fields.iter().map(|(n, t)| (*n, cpu(t))).collect();
    Tensor::write_safetensors(&batch, dir.join("batch.safetensors"))?;
    Ok(())
}

/// The reference script in `serve` mode: one JSON command a line in, one JSON answer out.
struct Reference {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

impl Reference {
    fn start(python: &Path, script: &Path, dir: &Path, device: Device) -> anyhow::Result<Self> {
        let device = if device.is_cuda() { "cuda" } else { "cpu" };
        let mut child = Command::new(python)
            .arg(script)
            .arg("serve")
            .arg(dir)
            .args(["--device", device])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {} {}", python.display(), script.display()))?;
        let stdin = child.stdin.take().expect("piped stdin");
        let stdout = BufReader::new(child.stdout.take().expect("piped stdout"));
        let mut r = Self {
            child,
            stdin,
            stdout,
        };
        r.read().context("the PyTorch reference did not start")?;
        Ok(r)
    }

    fn read(&mut self) -> anyhow::Result<Value> {
        let mut line = String::new();
        if self.stdout.read_line(&mut line)? == 0 {
            let status = self.child.wait()?;
            bail!("the PyTorch reference exited ({status}); its error is above");
        }
        let v: Value = serde_json::from_str(&line)
            .with_context(|| format!("unreadable answer from the reference: {line}"))?;
        if let Some(e) = v.get("error") {
            bail!("the PyTorch reference: {e}");
        }
        Ok(v)
    }

    fn ask(&mut self, cmd: Value) -> anyhow::Result<Value> {
        writeln!(self.stdin, "{cmd}")?;
        self.stdin.flush()?;
        self.read()
    }
}

impl Drop for Reference {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "{}", json!({"op": "quit"}));
        let _ = self.stdin.flush();
        if !matches!(self.child.try_wait(), Ok(Some(_))) {
            std::thread::sleep(std::time::Duration::from_millis(200));
            if !matches!(self.child.try_wait(), Ok(Some(_))) {
                let _ = self.child.kill();
            }
        }
        let _ = self.child.wait();
    }
}

/// One compared value: the Rust and PyTorch numbers and their largest difference.
#[derive(Debug, Clone, Serialize)]
pub struct Compared {
    pub stage: &'static str,
    pub term: String,
    pub rust: f64,
    pub pytorch: f64,
    pub abs_diff: f64,
    pub ok: bool,
}

fn compare(stage: &'static str, rust: &Value, pytorch: &Value) -> anyhow::Result<Vec<Compared>> {
    let rust = rust.as_object().context("Rust metrics are an object")?;
    let mut out = Vec::with_capacity(rust.len());
    for (term, r) in rust {
        let p = pytorch
            .get(term)
            .with_context(|| format!("the reference reports no `{term}` ({stage})"))?;
        // A map of scalars (task_psi_mass: task id → Σ ψ): the same keys on both sides, each
        // compared as its own term.
        if let Some(inner) = r.as_object() {
            let p = p
                .as_object()
                .with_context(|| format!("the reference's `{term}` is not a map ({stage})"))?;
            let (mut rk, mut pk): (Vec<_>, Vec<_>) = (inner.keys().collect(), p.keys().collect());
            rk.sort();
            pk.sort();
            anyhow::ensure!(
                rk == pk,
                "`{term}` ({stage}): Rust keys {rk:?}, reference {pk:?}"
            );
            for (key, r) in inner {
                out.push(compared(stage, format!("{term}/{key}"), r, &p[key])?);
            }
            continue;
        }
        out.push(compared(stage, term.clone(), r, p)?);
    }
    Ok(out)
}

fn compared(stage: &'static str, term: String, r: &Value, p: &Value) -> anyhow::Result<Compared> {
    let r = r.as_f64().context("Rust metric is a number")?;
    let p = p
        .as_f64()
        .with_context(|| format!("the reference's `{term}` is not a number ({stage})"))?;
    let abs_diff = (r - p).abs();
    // Absolute near zero, relative for large terms.
    let tolerance = tolerance(stage) * r.abs().max(1.0);
    Ok(Compared {
        stage,
        term,
        rust: r,
        pytorch: p,
        abs_diff,
        ok: abs_diff <= tolerance,
    })
}

/// Updates/s of both sides at one thread count.
#[derive(Debug, Clone, Serialize)]
pub struct Timing {
    pub threads: usize,
    pub rust_updates_per_s: f64,
    pub pytorch_updates_per_s: f64,
    /// Rust updates/s ÷ PyTorch updates/s.
    pub ratio: f64,
    /// Per round, in the order they ran.
    pub rust_rounds: Vec<f64>,
    pub pytorch_rounds: Vec<f64>,
}

fn rust_round(learner: &mut Learner, batch: &SegmentBatch, iters: usize) -> anyhow::Result<f64> {
    learner.update(batch)?;
    let start = Instant::now();
    for _ in 0..iters {
        learner.update(batch)?;
    }
    Ok(start.elapsed().as_secs_f64())
}

pub fn run(
    config: &Path,
    iters: usize,
    args: &ReferenceArgs,
    random_batch: impl Fn(&AgentConfig, i64) -> SegmentBatch,
) -> anyhow::Result<ExitCode> {
    if iters == 0 || args.rounds == 0 || args.threads.contains(&0) {
        bail!("--iters, --rounds and every --threads must be at least 1");
    }
    let python = super::python(args.python.as_deref());
    let torch = torch_version(&python)?;
    let script = find_in_repository(Path::new(SCRIPT))
        .with_context(|| format!("{SCRIPT} not found (set MILLION_ROOT to the repository)"))?;
    let cfg = RunConfig::from_file(config)?;
    let agent = cfg.agent();
    if agent.model.instruction_words > 0 {
        bail!(
            "{}: the PyTorch reference implements the paper's network, without the \
             instruction slots; set model.instruction_words = 0 to compare",
            config.display()
        );
    }
    if agent.model.goal_prediction != GoalPrediction::Off {
        bail!(
            "{}: the PyTorch reference implements the paper's network, without the goal \
             head; set model.goal_prediction = \"off\" to compare",
            config.display()
        );
    }
    let device = cfg.runtime.device();
    tch::manual_seed(cfg.env.agent_seed as i64);
    let mut learner = Learner::new(agent.clone(), device);
    randomise(&learner);
    let b = agent.buffer.batch_segments as i64;
    let mut batch = random_batch(&agent, b);
    // Every mask path: memories of any length, truncated steps.
    let m = agent.model.memory_len as i64;
    batch.memory_len = Tensor::randint(m + 1, [b], (Kind::Int64, Device::Cpu));
    batch.truncated = Tensor::rand(batch.rewards.size(), (Kind::Float, Device::Cpu)).lt(0.003);

    let dir = args.dir.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("million-bench-reference-{}", std::process::id()))
    });
    write_inputs(&dir, &agent, &learner, &batch)?;
    let remove_inputs = || {
        if args.dir.is_none() {
            let _ = std::fs::remove_dir_all(&dir);
        }
    };
    let mut reference = Reference::start(&python, &script, &dir, device).inspect_err(|_| {
        remove_inputs();
    })?;

    // Check: terms before, the update's metrics, terms after; on both sides.
    cfg.runtime.apply();
    let before = serde_json::to_value(learner.loss_terms(&batch)?)?;
    let update = serde_json::to_value(learner.update(&batch)?)?;
    let after = serde_json::to_value(learner.loss_terms(&batch)?)?;
    let py = reference.ask(json!({"op": "check"}))?;
    let mut compared = compare("before", &before, &py["before"])?;
    compared.extend(compare("update", &update, &py["update"])?);
    compared.extend(compare("after", &after, &py["after"])?);
    let failed: Vec<&Compared> = compared.iter().filter(|c| !c.ok).collect();
    if !failed.is_empty() {
        let lines: Vec<String> = failed
            .iter()
            .map(|c| {
                format!(
                    "  {} {}: rust {:.8e}, pytorch {:.8e}, |diff| {:.3e}",
                    c.stage, c.term, c.rust, c.pytorch, c.abs_diff
                )
            })
            .collect();
        bail!(
            "the PyTorch reference disagrees with the Rust learner beyond {TOLERANCE} \
             ({AFTER_STEP_TOLERANCE} after the step; inputs in {}):\n{}",
            dir.display(),
            lines.join("\n")
        );
    }
    remove_inputs();

    // Timing, alternating the order each round.
    let load_before = super::load_average();
    let mut timings = Vec::with_capacity(args.threads.len());
    for &threads in &args.threads {
        let (mut rust, mut pytorch) = (vec![], vec![]);
        let (mut rust_s, mut pytorch_s) = (0.0, 0.0);
        for round in 0..args.rounds {
            for rust_side in [round % 2 == 0, round % 2 == 1] {
                if rust_side {
                    tch::set_num_threads(threads as i32);
                    let s = rust_round(&mut learner, &batch, iters)?;
                    rust_s += s;
                    rust.push(iters as f64 / s);
                } else {
                    let t =
                        reference.ask(json!({"op": "time", "threads": threads, "iters": iters}))?;
                    let s = t["seconds"].as_f64().context("reference timing")?;
                    pytorch_s += s;
                    pytorch.push(iters as f64 / s);
                }
            }
        }
        let n = (iters * args.rounds) as f64;
        let (r, p) = (n / rust_s, n / pytorch_s);
        timings.push(Timing {
            threads,
            rust_updates_per_s: r,
            pytorch_updates_per_s: p,
            ratio: r / p,
            rust_rounds: rust,
            pytorch_rounds: pytorch,
        });
    }
    let load_after = super::load_average();
    drop(reference);

    let max_diff = |term: &str| {
        compared
            .iter()
            .filter(|c| c.term == term)
            .map(|c| c.abs_diff)
            .fold(0.0, f64::max)
    };
    let terms: Vec<&str> = compared
        .iter()
        .filter(|c| c.stage == "before")
        .map(|c| c.term.as_str())
        .collect();
    let model = &agent.model;
    if args.json {
        let check: serde_json::Map<String, Value> = terms
            .iter()
            .map(|t| (t.to_string(), json!(max_diff(t))))
            .collect();
        let out = json!({
            "config": config.display().to_string(),
            "batch_segments": b,
            "segment_len": model.segment_len,
            "layers": model.layers,
            "device": format!("{device:?}"),
            "torch": torch,
            "iters": iters,
            "rounds": args.rounds,
            "check": {
                "tolerance": TOLERANCE,
                "tolerance_after_step": AFTER_STEP_TOLERANCE,
                "passed": true,
                "max_abs_diff": check,
                "values": compared,
            },
            "timing": timings,
            "load_average_1m": {"before": load_before, "after": load_after},
            "machine": crate::machine::cpu_description(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "check: {} terms agree with the PyTorch reference (torch {torch}) within {TOLERANCE} \
             before and in one update, {AFTER_STEP_TOLERANCE} after it; b={b} T={} layers={}",
            terms.len(),
            model.segment_len,
            model.layers
        );
        println!(
            "  {:<18} {:>14} {:>12}",
            "term", "rust (before)", "max |diff|"
        );
        for c in compared.iter().filter(|c| c.stage == "before") {
            println!(
                "  {:<18} {:>14.6} {:>12.2e}",
                c.term,
                c.rust,
                max_diff(&c.term)
            );
        }
        println!(
            "timing: {} rounds x {iters} updates per side (alternating), load {} -> {}",
            args.rounds,
            load_before.map_or("?".into(), |l| format!("{l:.2}")),
            load_after.map_or("?".into(), |l| format!("{l:.2}"))
        );
        println!(
            "  {:>7} {:>15} {:>18} {:>13}",
            "threads", "rust updates/s", "pytorch updates/s", "rust/pytorch"
        );
        for t in &timings {
            println!(
                "  {:>7} {:>15.3} {:>18.3} {:>13.3}",
                t.threads, t.rust_updates_per_s, t.pytorch_updates_per_s, t.ratio
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
