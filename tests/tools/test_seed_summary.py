"""tools/seed_summary.py: the evidence standard's statistic (the mean of each run's last three
evaluations, then the runs' mean and range) and, with --tasks, the same per task."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _write_run(run: Path, evaluations: list[dict[str, float]]) -> None:
    run.mkdir()
    rows = [
        {"step": 1000 * (i + 1), "train/success": 0.5, **values}
        for i, values in enumerate(evaluations)
    ]
    (run / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")


def _summary(*args: object) -> str:
    return subprocess.run(
        [sys.executable, str(ROOT / "tools" / "seed_summary.py"), *map(str, args)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def test_the_statistic_and_the_per_task_tables(tmp_path: Path) -> None:
    # Seed 1 learns task a from its second evaluation; seed 2 learns b, and its task-a
    # evaluations stop after two (a run cut short), so a's mean is seed 1's alone.
    seed1, seed2 = tmp_path / "seed1", tmp_path / "seed2"
    _write_run(
        seed1,
        [
            {"eval/train/success": s, "eval/train/task/a": a, "eval/train/task/b": 0.0}
            for s, a in ((0.0, 0.0), (0.5, 1.0), (0.5, 1.0), (0.5, 1.0))
        ],
    )
    _write_run(
        seed2,
        [
            {
                "eval/train/success": 0.25,
                "eval/train/task/a": 0.0,
                "eval/train/task/b": 0.5,
            },
            {
                "eval/train/success": 0.25,
                "eval/train/task/a": 0.0,
                "eval/train/task/b": 0.5,
            },
            {"eval/train/success": 0.25, "eval/train/task/b": 0.5},
        ],
    )
    plain = _summary(seed1, seed2)
    assert "train success: mean 0.375, range 0.250-0.500 over 2 runs" in plain
    assert "| train task" not in plain

    tables = _summary("--tasks", seed1, seed2)
    assert "| train task | seed1 | seed2 | mean |" in tables
    assert "| a | 1.00 | - | 1.00 |" in tables
    assert "| b | 0.00 | 0.50 | 0.25 |" in tables
    # --at cuts every run at one budget: seed 1's last three are then its first three.
    assert "| a | 0.67 | - | 0.67 |" in _summary("--tasks", "--at", 3000, seed1, seed2)
