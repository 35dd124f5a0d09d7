"""tools/keep_evaluations.py: the kept copy of a run holds its evaluations, training success
and config, and the evidence statistic (tools/seed_summary.py) reads the same from it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _write_run(run: Path) -> None:
    run.mkdir()
    rows = []
    for step in range(1, 6):
        rows.append(
            {
                "step": step * 1000,
                "wall_time": 1.0 * step,
                "learner/loss": 0.5,
                "train/success": 0.1 * step,
            }
        )
        rows.append(
            {
                "step": step * 1000,
                "wall_time": 1.5 * step,
                "eval/train/success": 0.2 * step,
                "eval/test/success": 0.1 * step,
            }
        )
    lines = [json.dumps(r) for r in rows]
    # A run killed mid-write leaves its last line cut short.
    (run / "metrics.jsonl").write_text("\n".join(lines) + '\n{"step": 60')
    (run / "config.toml").write_text('[env]\nid = "million/ML10-train"\n')


def _tool(name: str, *args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(ROOT / "tools" / name), *map(str, args)],
        capture_output=True,
        text=True,
        check=True,
    )


def test_the_kept_copy_holds_evaluations_success_and_config(tmp_path: Path) -> None:
    run = tmp_path / "ml10-seed1"
    _write_run(run)
    out = tmp_path / "kept"
    _tool("keep_evaluations.py", run, "--out", out)
    kept = out / "ml10-seed1"
    records = [
        json.loads(line) for line in (kept / "metrics.jsonl").read_text().splitlines()
    ]
    assert len(records) == 10
    assert all("learner/loss" not in r for r in records)
    assert [r["eval/train/success"] for r in records if "eval/train/success" in r] == [
        0.2,
        0.4,
        0.6000000000000001,
        0.8,
        1.0,
    ]
    assert (kept / "config.toml").read_text() == (run / "config.toml").read_text()
    # The statistic (mean of the last three evaluations) is the same on the run and its copy.
    on_run = _tool("seed_summary.py", run).stdout.replace(str(run), "RUN")
    on_copy = _tool("seed_summary.py", kept).stdout.replace(str(kept), "RUN")
    assert on_run == on_copy
    assert "0.8" in on_copy


def test_a_kept_checkpoint_is_the_newest_and_replaces_the_last_hand_over(
    tmp_path: Path,
) -> None:
    run = tmp_path / "ml10-seed2"
    _write_run(run)
    checkpoints = run / "checkpoints"
    checkpoints.mkdir()
    for step, body in ((500_000, b"older"), (1_000_000, b"newest")):
        (checkpoints / f"step-{step:015}.safetensors").write_bytes(body)
    out = tmp_path / "kept"
    _tool("keep_evaluations.py", run, "--out", out, "--checkpoint")
    kept = out / "ml10-seed2" / "checkpoints"
    assert [p.name for p in kept.iterdir()] == ["step-000000001000000.safetensors"]
    assert (kept / "step-000000001000000.safetensors").read_bytes() == b"newest"

    # The next hand-over keeps the run's newer checkpoint in place of this one.
    (checkpoints / "step-000000001500000.safetensors").write_bytes(b"later")
    _tool("keep_evaluations.py", run, "--out", out, "--checkpoint")
    assert [p.name for p in kept.iterdir()] == ["step-000000001500000.safetensors"]

    # Kept again once the run has finished, without --checkpoint: the carried one goes.
    _tool("keep_evaluations.py", run, "--out", out)
    assert not kept.exists()

    # Without a checkpoint to keep, the tool says so before it writes anything.
    (out / "ml10-seed2" / "metrics.jsonl").write_text("")
    for path in checkpoints.iterdir():
        path.unlink()
    failed = subprocess.run(
        [
            sys.executable,
            str(ROOT / "tools" / "keep_evaluations.py"),
            run,
            "--out",
            out,
            "--checkpoint",
        ],
        check=False,
        capture_output=True,
        text=True,
    )
    assert failed.returncode != 0
    assert "no checkpoints/step-*.safetensors" in failed.stderr
    assert (out / "ml10-seed2" / "metrics.jsonl").read_text() == ""
