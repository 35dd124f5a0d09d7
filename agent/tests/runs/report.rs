//! `million report`: a report from a short real run (a local env server, the quickstart
//! config cut to a few thousand steps) writes every figure, and report.md says what
//! metrics.jsonl says; synthetic runs check the figures for one task and for ML45's 50.

use std::path::{Path, PathBuf};

use crate::common::{metrics_records, shipped_config, train_in};
use million::report::write_report;

/// Width and height of a PNG file, from its IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(
        &bytes[..8],
        b"\x89PNG\r\n\x1a\n",
        "{} is a PNG",
        path.display()
    );
    assert_eq!(&bytes[12..16], b"IHDR");
    let be = |b: &[u8]| u32::from_be_bytes(b.try_into().unwrap());
    (be(&bytes[16..20]), be(&bytes[20..24]))
}

/// The last record holding `key`, and its value.
fn last_value(
    recs: &[serde_json::Map<String, serde_json::Value>],
    key: &str,
) -> Option<(u64, f64)> {
    recs.iter()
        .rev()
        .find_map(|r| Some((r["step"].as_u64()?, r.get(key)?.as_f64()?)))
}

#[test]
fn report_of_a_short_real_run_matches_its_metrics() {
    let mut cfg = shipped_config("quickstart.toml");
    cfg.train.total_agent_steps = 6_000;
    cfg.train.eval_interval = 2_000;
    cfg.train.log_interval = 1_000;
    cfg.train.checkpoint_interval = 0;
    cfg.buffer.min_segments = 16;
    cfg.eval.episodes = 8;
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("short");
    train_in(cfg, &run, true, 300.0);

    let out = dir.path().join("report");
    let report = write_report(std::slice::from_ref(&run), &out).unwrap();
    assert_eq!(
        report.figures,
        vec![out.join("curves.png"), out.join("tasks-short.png")]
    );
    for f in &report.figures {
        let (w, h) = png_size(f);
        assert!(w >= 500 && h >= 200, "{}: {w} x {h}", f.display());
    }
    let md = std::fs::read_to_string(&report.markdown).unwrap();
    eprintln!("{md}");

    // The summary row holds the last step and each split's last evaluation, as written in
    // metrics.jsonl.
    let recs = metrics_records(&run);
    let last_step = recs
        .iter()
        .filter_map(|r| r["step"].as_u64())
        .max()
        .unwrap();
    let (_, train) = last_value(&recs, "eval/train/success").unwrap();
    let (_, test) = last_value(&recs, "eval/test/success").unwrap();
    let (_, train_first) = last_value(&recs, "eval/train/first_trial_success").unwrap();
    let (_, test_first) = last_value(&recs, "eval/test/first_trial_success").unwrap();
    let row = md
        .lines()
        .find(|l| l.starts_with("| short |"))
        .expect("a summary row for the run");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    assert_eq!(cells[2], "million/PointGoal");
    assert_eq!(cells[3], last_step.to_string());
    assert_eq!(cells[6], format!("{train:.3}"));
    assert_eq!(cells[7], format!("{test:.3}"));
    assert_eq!(cells[8], format!("{train_first:.3}"));
    assert_eq!(cells[9], format!("{test_first:.3}"));
    assert_eq!(cells[10], "million/PointGoal, heldout sentences");
    let wall = recs.last().unwrap()["wall_time"].as_f64().unwrap()
        - recs[0]["wall_time"].as_f64().unwrap();
    assert_eq!(cells[4], million::report::format_duration(wall));

    // Every goal's final per-task success appears in the per-task table.
    let mut tasks = 0;
    for split in ["train", "test"] {
        let prefix = format!("eval/{split}/task/");
        let (step, _) = last_value(&recs, &format!("eval/{split}/success")).unwrap();
        let rec = recs
            .iter()
            .rev()
            .find(|r| {
                r["step"].as_u64() == Some(step) && r.contains_key(&format!("eval/{split}/success"))
            })
            .unwrap();
        for (k, v) in rec.iter().filter(|(k, _)| k.starts_with(&prefix)) {
            let task = &k[prefix.len()..];
            let line = format!("| {split} | {task} | {:.3} | {step} |", v.as_f64().unwrap());
            assert!(md.contains(&line), "report.md lacks {line:?}");
            tasks += 1;
        }
    }
    assert!(tasks >= 2, "per-task values were recorded ({tasks})");
    // The evaluations made the curve: one point per eval record and split.
    let evals = recs
        .iter()
        .filter(|r| r.contains_key("eval/train/success"))
        .count();
    assert_eq!(report.runs[0].curves["train"].len(), evals);
    assert!(
        evals >= 3,
        "evaluations at 2k, 4k, 6k steps and the final one"
    );
}

/// A synthetic run directory: evaluations every `every` steps up to `last`, per-task values
/// for `train_tasks` / `test_tasks`.
fn synthetic_run(
    root: &Path,
    name: &str,
    env_id: &str,
    train_tasks: &[String],
    test_tasks: &[String],
    last: u64,
) -> PathBuf {
    let dir = root.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    let mut lines = vec![];
    let n = 5u64;
    for k in 1..=n {
        let step = last * k / n;
        let mut r = serde_json::Map::new();
        r.insert("step".into(), step.into());
        r.insert("wall_time".into(), (1000.0 + k as f64 * 60.0).into());
        let frac = k as f64 / n as f64;
        for (split, tasks) in [("train", train_tasks), ("test", test_tasks)] {
            r.insert(format!("eval/{split}/success"), (0.8 * frac).into());
            r.insert(
                format!("eval/{split}/first_trial_success"),
                (0.5 * frac).into(),
            );
            for (i, t) in tasks.iter().enumerate() {
                let v = (frac * (i + 1) as f64 / tasks.len() as f64).min(1.0);
                r.insert(format!("eval/{split}/task/{t}"), v.into());
            }
            // A key a later version might add: ignored.
            r.insert(format!("eval/{split}/episodes_per_task"), 3.into());
        }
        lines.push(serde_json::Value::Object(r).to_string());
    }
    std::fs::write(dir.join("metrics.jsonl"), lines.join("\n") + "\n").unwrap();
    std::fs::write(
        dir.join("config.toml"),
        format!("[env]\nid = \"{env_id}\"\n[eval]\ntest_id = \"{env_id}\"\n"),
    )
    .unwrap();
    dir
}

#[test]
fn figures_hold_one_task_and_fifty_and_overlay_runs() {
    let dir = tempfile::tempdir().unwrap();
    let names = |n: usize, p: &str| {
        (0..n)
            .map(|i| format!("{p}-task-{i:02}-v3"))
            .collect::<Vec<_>>()
    };
    let ml45 = synthetic_run(
        dir.path(),
        "ml45",
        "million/ML45-train",
        &names(45, "train"),
        &names(5, "test"),
        2_000_000,
    );
    let ablation = synthetic_run(
        dir.path(),
        "ml45-no-instructions",
        "million/ML45-train",
        &names(45, "train"),
        &names(5, "test"),
        1_000_000,
    );
    let single = synthetic_run(
        dir.path(),
        "one",
        "million/ML1-train",
        &names(1, "x"),
        &[],
        1000,
    );
    let out = dir.path().join("out");
    let report = write_report(&[ml45, ablation, single], &out).unwrap();
    let (_, h45) = png_size(&out.join("tasks-ml45.png"));
    let (_, h1) = png_size(&out.join("tasks-one.png"));
    assert!(h45 >= 45 * 20, "45 train tasks get room ({h45} px)");
    assert!(h1 < h45);
    png_size(&out.join("curves.png"));
    let md = std::fs::read_to_string(&report.markdown).unwrap();
    assert!(md.contains("Reference results for ML45"));
    assert!(md.contains("| paper V1 (final) | – | 0.950 | 0.480 |"));
    assert!(!md.contains("Reference results for ML10"));
    for run in ["ml45", "ml45-no-instructions", "one"] {
        assert!(md.contains(&format!("| {run} |")), "summary row of {run}");
    }
    assert_eq!(report.runs[0].final_eval["train"].per_task.len(), 45);
    // Values as written: the last record has frac = 1.
    assert!(md.contains(
        "| ml45 | million/ML45-train | 2000000 | 4 min 00 s | 6667 | 0.800 | 0.800 | 0.500 | 0.500 |"
    ));
    assert!(md.contains("| train | train-task-44-v3 | 1.000 | 2000000 |"));
    assert!(md.contains("| test | test-task-00-v3 | 0.200 | 2000000 |"));
}
