"""tools/goal_error.py: a goal head's error per task, pooled over a window of steps as the root
of the mean of the records' squares, read the same from a run and from its kept copy."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
REACH, PUSH = 43, 40  # task ids: indices in Meta-World's MT50 order


def _write_run(run: Path, reach_errors: list[float]) -> None:
    """One log record per 10,000 steps with reach's error; push's only in the first record."""
    run.mkdir()
    rows = []
    for i, error in enumerate(reach_errors):
        row = {
            "step": 10_000 * (i + 1),
            "wall_time": 1.0 * i,
            "train/success": 0.0,
            "learner/loss": 1.0,
            "learner/goal_error": error,
            f"learner/task_goal_error/{REACH}": error,
        }
        if i == 0:
            row[f"learner/task_goal_error/{PUSH}"] = 0.5
        rows.append(row)
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def _tool(name: str, *args: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(ROOT / "tools" / name), *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
    )


def _rows(table: str) -> dict[str, list[str]]:
    return {
        cells[0]: cells[1:]
        for line in table.splitlines()
        if line.startswith("| ") and not line.startswith("| task")
        for cells in [[c.strip() for c in line.strip("|").split("|")]]
    }


def test_the_window_pools_squares_and_names_the_tasks(tmp_path: Path) -> None:
    seed1, seed2 = tmp_path / "seed1", tmp_path / "seed2"
    _write_run(seed1, [0.5, 0.3, 0.4])
    _write_run(seed2, [0.5, 0.1, 0.1])

    # Steps 20,000-30,000: seed 1 pools 0.3 and 0.4 (root of 0.125), seed 2 0.1 and 0.1;
    # push has no record in the window.
    got = _tool("goal_error.py", seed1, seed2, "--from", 20_000, "--to", 30_000)
    assert got.returncode == 0, got.stderr
    rows = _rows(got.stdout)
    assert rows["reach"] == ["0.354 (2)", "0.100 (2)", "0.227"]
    assert rows["all tasks"] == rows["reach"]
    assert "push" not in rows

    # The whole run: push appears with its one record.
    rows = _rows(_tool("goal_error.py", seed1).stdout)
    assert rows["push"] == ["0.500 (1)", "0.500"]

    # The kept copy of a run holds its goal errors, so the tool reads the same from it.
    kept = tmp_path / "kept"
    assert _tool("keep_evaluations.py", seed1, "--out", kept).returncode == 0
    copy = [json.loads(line) for line in (kept / "seed1" / "metrics.jsonl").open()]
    assert all("learner/loss" not in r for r in copy)
    assert (
        _tool("goal_error.py", kept / "seed1").stdout
        == _tool("goal_error.py", seed1).stdout
    )


def test_a_run_without_a_goal_head_is_told_so(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text('{"step": 10000, "train/success": 0.1}\n')
    got = _tool("goal_error.py", run)
    assert got.returncode != 0
    assert "model.goal_prediction" in got.stderr
