//! `million train` killed with SIGKILL after a checkpoint, then resumed with
//! `--resume` and stopped with Ctrl-C (SIGINT): the resumed run starts from the
//! last checkpoint's counters, keeps metrics.jsonl up to that checkpoint (the killed
//! run's later records move to metrics.superseded.jsonl), and Ctrl-C ends it
//! cleanly with a final checkpoint. Uses the built binary on the quickstart
//! config with short intervals, against an env server this test owns (so a
//! killed agent leaves no orphan server behind).
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use million::checkpoint;
use million::run_dir::latest_checkpoint;
use million_env::{LocalServer, LocalServerOptions, default_server_binary};

const WAIT: Duration = Duration::from_secs(60);

fn write_config(dir: &Path) -> PathBuf {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let text = std::fs::read_to_string(repo.join("configs/quickstart.toml")).unwrap();
    let mut cfg: toml::Table = text.parse().unwrap();
    let train = cfg["train"].as_table_mut().unwrap();
    train.insert("total_agent_steps".into(), 100_000_000.into());
    train.insert("checkpoint_interval".into(), 2_048.into());
    train.insert("log_interval".into(), 1_024.into());
    train.insert("eval_interval".into(), 100_000_000.into());
    cfg["eval"]
        .as_table_mut()
        .unwrap()
        .insert("episodes".into(), 4.into());
    let path = dir.join("resume.toml");
    std::fs::write(&path, toml::to_string(&cfg).unwrap()).unwrap();
    path
}

fn train(config: &Path, run_dir: &Path, server: &str, resume: bool, log: &Path) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_million"));
    cmd.arg("train")
        .arg("--config")
        .arg(config)
        .arg("--run-dir")
        .arg(run_dir)
        .args(["--env-server", server])
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(log.with_extension("out")).unwrap())
        .stderr(std::fs::File::create(log).unwrap());
    if resume {
        cmd.arg("--resume");
    }
    cmd.spawn().expect("million runs")
}

/// Agent steps of the newest checkpoint, once there is one past `after`.
fn wait_for_checkpoint(run_dir: &Path, after: u64, child: &mut Child, log: &Path) -> u64 {
    let start = Instant::now();
    loop {
        if let Ok(path) = latest_checkpoint(run_dir)
            && let Ok(meta) = checkpoint::read_meta(&path)
            && meta.counters.agent_steps > after
        {
            return meta.counters.agent_steps;
        }
        if let Some(status) = child.try_wait().unwrap() {
            panic!(
                "million exited ({status}) early: {}",
                std::fs::read_to_string(log).unwrap_or_default()
            );
        }
        assert!(
            start.elapsed() < WAIT,
            "no checkpoint past {after} in {WAIT:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn metric_lines(run_dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(run_dir.join("metrics.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).expect("every metrics line is whole JSON"))
        .collect()
}

#[test]
fn kill_resume_and_ctrl_c() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path());
    let run_dir = dir.path().join("run");
    let rt = tokio::runtime::Runtime::new().unwrap();
    let binary = default_server_binary().expect("million-env-server installed (make setup)");
    let server = rt
        .block_on(LocalServer::start(&binary, LocalServerOptions::default()))
        .unwrap();

    // 1. Train until a checkpoint exists (and a bit past it), then SIGKILL.
    let log1 = dir.path().join("run1.log");
    let mut first = train(&config, &run_dir, server.addr(), false, &log1);
    let step = wait_for_checkpoint(&run_dir, 0, &mut first, &log1);
    wait_for_checkpoint(&run_dir, step, &mut first, &log1);
    first.kill().unwrap(); // SIGKILL
    first.wait().unwrap();
    let killed_at = checkpoint::read_meta(&latest_checkpoint(&run_dir).unwrap())
        .expect("the last checkpoint survives a kill -9")
        .counters;
    let before = metric_lines(&run_dir);
    assert!(!before.is_empty(), "the first run logged metrics");

    // 2. Resume, wait for a newer checkpoint, then Ctrl-C.
    let log2 = dir.path().join("run2.log");
    let mut second = train(&config, &run_dir, server.addr(), true, &log2);
    wait_for_checkpoint(&run_dir, killed_at.agent_steps, &mut second, &log2);
    // SAFETY: kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(second.id() as i32, libc::SIGINT) }, 0);
    let start = Instant::now();
    let status = loop {
        if let Some(status) = second.try_wait().unwrap() {
            break status;
        }
        assert!(start.elapsed() < WAIT, "Ctrl-C did not end the run");
        std::thread::sleep(Duration::from_millis(100));
    };
    let err = std::fs::read_to_string(&log2).unwrap();
    assert!(status.success(), "Ctrl-C exits cleanly: {status}\n{err}");
    assert!(err.contains("interrupted"), "{err}");
    let out = std::fs::read_to_string(log2.with_extension("out")).unwrap();
    assert!(out.contains("checkpoint:"), "a final checkpoint: {out}");

    // The counters continued from the checkpoint, not from zero.
    let last = checkpoint::read_meta(&latest_checkpoint(&run_dir).unwrap())
        .unwrap()
        .counters;
    assert!(last.agent_steps > killed_at.agent_steps);
    assert!(last.updates >= killed_at.updates);
    assert!(last.adam_steps >= killed_at.adam_steps);

    // metrics.jsonl keeps the first run's lines up to the checkpoint verbatim, then the
    // resumed run's, whose steps start past it: no step is logged twice.
    let kept = before
        .iter()
        .take_while(|r| r["step"].as_u64().unwrap() <= killed_at.agent_steps)
        .count();
    let after = metric_lines(&run_dir);
    assert!(after.len() > kept);
    assert_eq!(after[..kept], before[..kept]);
    let steps: Vec<u64> = after.iter().map(|r| r["step"].as_u64().unwrap()).collect();
    assert!(
        steps[kept..].iter().all(|&s| s > killed_at.agent_steps),
        "resumed steps {steps:?} start after {}",
        killed_at.agent_steps
    );
    assert!(steps.windows(2).all(|w| w[0] <= w[1]), "{steps:?}");
    let superseded =
        std::fs::read_to_string(run_dir.join("metrics.superseded.jsonl")).unwrap_or_default();
    assert_eq!(superseded.lines().count(), before.len() - kept);
    drop(server);
}

/// `million train` checks the run directory before it starts anything: a new run refuses a
/// folder holding another run's checkpoints, `--resume` needs one and the settings the run
/// started with, and a resumed leg already at its end trains nothing and succeeds (a rerun
/// script, a restarted container).
#[test]
fn the_run_directory_is_checked_before_training() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path());
    let run_dir = dir.path().join("run");
    let million = |extra: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_million"))
            .arg("train")
            .arg("--config")
            .arg(&config)
            .arg("--run-dir")
            .arg(&run_dir)
            .args(extra)
            .env("RUST_LOG", "warn")
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        (out.status.success(), text)
    };

    let (ok, text) = million(&["--resume"]);
    assert!(!ok && text.contains("no checkpoint in"), "{text}");

    // A checkpoint at 5,000 agent steps, as a run would leave it.
    let cfg = million::run_config::RunConfig::from_file(&config).unwrap();
    let learner = million::learner::Learner::new(cfg.agent(), tch::Device::Cpu);
    let path = million::run_dir::checkpoint_path(&run_dir, 5_000);
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let run_config = [(
        million::train::session::RUN_CONFIG_KEY.to_owned(),
        toml::to_string(&cfg).unwrap(),
    )]
    .into();
    checkpoint::save(&path, &learner, 5_000, Default::default(), &run_config).unwrap();

    let (ok, text) = million(&[]);
    assert!(!ok, "a new run into another run's folder: {text}");
    assert!(
        text.contains("already holds a run") && text.contains("5000"),
        "{text}"
    );
    let (ok, text) = million(&["--resume", "--until", "5000"]);
    assert!(ok && text.contains("nothing to train"), "{text}");
    let (ok, text) = million(&["--resume", "--until", "4096"]);
    assert!(ok && text.contains("nothing to train"), "{text}");
    // Another replicate's seeds are other settings of what is learned, not another leg.
    let (ok, text) = million(&["--resume", "--seed", "7"]);
    assert!(
        !ok && text.contains("other settings") && text.contains("env.seed"),
        "{text}"
    );
    assert_eq!(
        latest_checkpoint(&run_dir).unwrap(),
        path,
        "no step trained, no checkpoint written"
    );
}
