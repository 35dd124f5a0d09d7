//! Tiny runs of `million bench env|train|learner|acting|learning|script`, so the benchmarks
//! keep working.
//! They check what each reports is there and sane; a timing is never asserted.

use std::ffi::OsStr;
use std::process::{Command, Output};

use crate::common::repo;
use serde_json::Value;

/// `million ARGS` run to its end in the repository, whatever its exit status.
fn run_million<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<OsStr>,
{
    Command::new(env!("CARGO_BIN_EXE_million"))
        .args(args)
        .current_dir(repo())
        .env("MILLION_ROOT", repo())
        .env("RUST_LOG", "warn")
        .output()
        .expect("million runs")
}

fn million(args: &[&str]) -> String {
    let out = run_million(args);
    assert!(
        out.status.success(),
        "million {args:?}: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// `million bench env ARGS` run to its end: (success, stderr).
fn bench_env_status(extra: &[&str]) -> (bool, String) {
    let base = [
        "bench",
        "env",
        "--env",
        "CartPole-v1",
        "--batch",
        "1",
        "--servers",
        "1",
    ];
    let timing = ["--seconds", "0.2", "--latency-steps", "0"];
    let out = run_million(base.iter().chain(&timing).chain(extra));
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `--server-arg` reaches the servers' command lines (a value the server refuses stops the
/// bench), and the options the agent owns for its local servers are refused up front.
#[test]
fn bench_env_passes_server_args_and_refuses_the_agents_own() {
    let (ok, stderr) = bench_env_status(&["--server-arg=--idle-envs", "--server-arg=-1"]);
    assert!(
        !ok && stderr.contains("exited before it listened"),
        "{stderr}"
    );
    let (ok, stderr) = bench_env_status(&["--server-arg=--token=s3cret"]);
    assert!(!ok && stderr.contains("--env-server"), "{stderr}");
    let (ok, stderr) = bench_env_status(&["--server-arg=--idle-envs", "--server-arg=1"]);
    assert!(ok, "{stderr}");
}

#[test]
fn bench_env_compares_served_with_in_process_steps() {
    let out = million(&[
        "bench",
        "env",
        "--env",
        "CartPole-v1",
        "--batch",
        "2",
        "--servers",
        "1",
        "--seconds",
        "0.5",
        "--latency-steps",
        "50",
        "--json",
    ]);
    let report: Value = serde_json::from_str(&out).unwrap();
    let case = &report["cases"][0];
    assert_eq!(case["env"], "CartPole-v1");
    assert_eq!(case["batch"], 2);
    let served = case["served_steps_per_s"].as_f64().unwrap();
    let in_process = case["in_process_steps_per_s"].as_f64().unwrap();
    assert!(served > 0.0 && in_process > 0.0, "{case}");
    assert!((case["ratio"].as_f64().unwrap() - served / in_process).abs() < 1e-9);
    let latency = &report["latency"];
    assert_eq!(latency["round_trips"], 50);
    assert!(latency["p50_us"].as_f64().unwrap() <= latency["p99_us"].as_f64().unwrap());
}

/// `bench script` runs a Python benchmark of bench/env/ with the arguments after its name
/// (hyphens and all) and exits with the script's status.
#[test]
fn bench_script_runs_a_python_benchmark_with_its_arguments() {
    let out = million(&[
        "bench",
        "script",
        "inprocess-rate",
        "--env",
        "CartPole-v1",
        "--batch",
        "1",
        "--workers",
        "1",
        "--seconds",
        "0.2",
    ]);
    let report: Value = serde_json::from_str(out.trim()).unwrap();
    assert!(
        report["env_steps_per_s"].as_f64().unwrap() > 0.0,
        "{report}"
    );
    // argparse refuses an unknown option with status 2.
    let refused = run_million(["bench", "script", "inprocess-rate", "--no-such-option"]);
    assert_eq!(
        refused.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
}

#[test]
fn bench_train_reports_every_process() {
    let out = million(&[
        "bench",
        "train",
        "--config",
        "configs/quickstart.toml",
        "--seconds",
        "4",
        "--json",
    ]);
    let report: Value = serde_json::from_str(&out).unwrap();
    assert!(
        report["agent_steps_per_s"].as_f64().unwrap() > 0.0,
        "{report}"
    );
    assert!(report["agent"]["peak_rss_mb"].as_f64().unwrap() > 10.0);
    assert!(report["agent"]["cpu_s"].as_f64().unwrap() > 0.0);
    // quickstart.toml runs one local env server; its CPU time and memory are counted.
    let servers = report["env_servers"].as_array().unwrap();
    assert_eq!(servers.len(), 1, "{report}");
    assert!(servers[0]["cpu_s"].as_f64().unwrap() > 0.0);
    assert!(servers[0]["peak_rss_mb"].as_f64().unwrap() > 10.0);
}

#[test]
fn bench_learner_and_acting_run_on_the_quickstart_model() {
    let learner_args = [
        "bench",
        "learner",
        "--config",
        "configs/quickstart.toml",
        "--iters",
        "1",
    ];
    let learner = million(&learner_args);
    assert!(learner.contains("s/update"), "{learner}");
    // The learner's multiply-adds per update at the quickstart's sizes, counted from the
    // config (a change to the count or to the model's sizes shows here).
    assert!(learner.contains("M multiply-adds per update"), "{learner}");
    // Against another build (here the same one): both sides timed, the ratio printed last.
    let exe = env!("CARGO_BIN_EXE_million");
    let against = million(
        &[
            &learner_args[..],
            &["--against", exe, "--against-rounds", "2"],
        ]
        .concat(),
    );
    let report: Value = serde_json::from_str(against.lines().last().unwrap()).unwrap();
    for side in ["this_updates_per_s", "other_updates_per_s"] {
        let rounds = report[side].as_array().unwrap();
        assert_eq!(rounds.len(), 2, "{against}");
        assert!(
            rounds.iter().all(|r| r.as_f64().unwrap() > 0.0),
            "{against}"
        );
    }
    assert!(report["ratio"].as_f64().unwrap() > 0.0, "{against}");
    // Against another config of the same sizes (bfloat16 products, 2 threads): this build on
    // both, each side under its own runtime; a config of other sizes is refused.
    let dir = tempfile::tempdir().unwrap();
    let quickstart = repo().join("configs/quickstart.toml");
    let write = |name: &str, body: &str| {
        let path = dir.path().join(name);
        let text = format!("base = {:?}\n{body}", quickstart.display().to_string());
        std::fs::write(&path, text).unwrap();
        path.display().to_string()
    };
    let bf16 = write(
        "bf16.toml",
        "[model]\nmatmul_dtype = \"bfloat16\"\n[runtime]\nintra_op_threads = 2\n",
    );
    let against = million(
        &[
            &learner_args[..],
            &["--against-config", &bf16, "--against-rounds", "1"],
        ]
        .concat(),
    );
    assert!(against.contains("bf16.toml"), "{against}");
    let report: Value = serde_json::from_str(against.lines().last().unwrap()).unwrap();
    assert!(report["ratio"].as_f64().unwrap() > 0.0, "{against}");
    let wider = write("wider.toml", "[model]\nff_dim = 512\n");
    let refused = run_million([&learner_args[..], &["--against-config", &wider]].concat());
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("different sizes"),
        "{refused:?}"
    );
    let acting = million(&[
        "bench",
        "acting",
        "--config",
        "configs/quickstart.toml",
        "--iters",
        "1",
    ]);
    assert!(acting.contains("agent steps/s"), "{acting}");
}

/// `bench learning` on the quickstart for 20 seconds (then its ablation for the same steps,
/// and both runs' final evaluations: about a minute): a target of 0 is met at the first
/// evaluation, one above 1 never is, both runs are compared at the final steps; an existing
/// run directory is refused.
#[test]
fn bench_learning_reports_targets_and_the_ablation_gap() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("bench");
    let runs_arg = runs.to_str().unwrap();
    let args = [
        "bench",
        "learning",
        "--config",
        "configs/quickstart.toml",
        "--ablation",
        "configs/experiments/quickstart-no-instructions.toml",
        "--steps",
        "20000",
        "--train-target",
        "0",
        "--test-target",
        "1.01",
        "--run-dir",
        runs_arg,
        "--json",
    ];
    let report: Value = serde_json::from_str(&million(&args)).unwrap();
    let steps = report["agent_steps"].as_u64().unwrap();
    assert!(steps > 0, "{report}");
    let splits = report["splits"].as_array().unwrap();
    assert_eq!(splits.len(), 2, "{report}");
    let (train, test) = (&splits[0], &splits[1]);
    assert_eq!(train["split"], "train");
    let first = &train["first_met"];
    assert!(first["agent_steps"].as_u64().unwrap() <= steps, "{train}");
    assert_eq!(test["split"], "test");
    assert!(test["first_met"].is_null(), "{test}");
    assert_eq!(test["last"]["agent_steps"].as_u64().unwrap(), steps);
    let ablation = &report["ablation"];
    assert!(
        ablation["agent_steps"].as_u64().unwrap() >= steps,
        "{ablation}"
    );
    // Both runs are evaluated at the end, at the same steps: each split has a gap there,
    // whose `with` figure is the run's last first-trial success of that split.
    let gaps = ablation["gaps"].as_array().unwrap();
    for split in splits {
        let name = &split["split"];
        let last = gaps
            .iter()
            .rfind(|g| &g["split"] == name)
            .unwrap_or_else(|| panic!("no {name} gap: {ablation}"));
        assert_eq!(last["agent_steps"].as_u64().unwrap(), steps, "{last}");
        assert_eq!(last["with"], split["last"]["first_trial"], "{last}");
        // The same pair for first trials successful within each of the config's budgets
        // (50 and 100 env steps), which PointGoal's 8-step trials always are: the measures
        // agree there.
        let within = ablation["within"].as_array().unwrap();
        let budgets: Vec<u64> = within
            .iter()
            .map(|w| w["env_steps"].as_u64().unwrap())
            .collect();
        assert_eq!(budgets, [50, 100], "{ablation}");
        for w in within {
            let soon = w["gaps"]
                .as_array()
                .unwrap()
                .iter()
                .rfind(|g| &g["split"] == name)
                .unwrap_or_else(|| panic!("no {name} gap within a budget: {ablation}"));
            assert_eq!(soon["agent_steps"], last["agent_steps"], "{soon}");
            assert_eq!(soon["with"], last["with"], "{soon}");
            assert_eq!(soon["without"], last["without"], "{soon}");
        }
    }
    assert!(runs.join("run/metrics.jsonl").is_file());
    assert!(runs.join("ablation/metrics.jsonl").is_file());

    let again = run_million(args);
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(
        !again.status.success() && stderr.contains("exists"),
        "{stderr}"
    );
}
