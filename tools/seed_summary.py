"""The evidence standard's statistic over the seeds of one arm (RESULTS.md, "How results are
measured"): per run, the mean of its last three evaluations of each split; over the runs,
their mean and range. Stochastic training success (the last three logs' `train/success`)
is printed beside it.

At a run's last step there are two evaluations, the periodic one (the actors' weights) and
the final one (the learner's weights after every update); the final one counts, so the last
three are those of the last three distinct evaluation steps.

With --tasks it also prints each split's per-task success (the same last three evaluations)
as a Markdown table, one column per run and their mean: which tasks a multi-task arm learns.

Usage: .venv/bin/python tools/seed_summary.py [--metric first_trial_success] [--tasks] RUN_DIR ...
       (runs of one arm: one config, several seeds; --at STEPS cuts every run there)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

LAST = 3


def records(run: Path) -> list[dict[str, float]]:
    """The run's records; a line cut short (a run killed mid-write, a file being written)
    is skipped with a warning."""
    rows = []
    path = run / "metrics.jsonl"
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            print(f"warning: {path}:{number} is not a whole record; skipped", file=sys.stderr)
    return rows


def evaluations(rows: list[dict[str, float]], key: str, at: int | None) -> list[tuple[int, float]]:
    """(step, value) of `key`, one per step (the later record wins), up to `at`."""
    by_step: dict[int, float] = {}
    for r in rows:
        step = int(r["step"])
        if key in r and r[key] is not None and (at is None or step <= at):
            by_step[step] = float(r[key])
    return sorted(by_step.items())


def last_mean(points: list[tuple[int, float]]) -> tuple[float, list[int]] | None:
    if len(points) < LAST:
        return None
    tail = points[-LAST:]
    return statistics.fmean(v for _, v in tail), [s for s, _ in tail]


def task_table(
    runs: list[Path], rows_of: dict[Path, list[dict[str, float]]], split: str, at: int | None
) -> list[str]:
    """Markdown rows: each task's success over its last three evaluations, per run and the
    runs' mean; a run without the task's three evaluations shows "-" and is left out of the
    mean."""
    prefix = f"eval/{split}/task/"
    tasks = sorted(
        {
            k[len(prefix) :]
            for rows in rows_of.values()
            for r in rows
            for k in r
            if k.startswith(prefix)
        }
    )
    if not tasks:
        return []
    lines = [
        f"| {split} task | " + " | ".join(run.name for run in runs) + " | mean |",
        "|---|" + "---|" * (len(runs) + 1),
    ]
    for task in tasks:
        cells, values = [], []
        for run in runs:
            got = last_mean(evaluations(rows_of[run], prefix + task, at))
            cells.append("-" if got is None else f"{got[0]:.2f}")
            if got is not None:
                values.append(got[0])
        mean = f"{statistics.fmean(values):.2f}" if values else "-"
        lines.append(f"| {task} | " + " | ".join(cells) + f" | {mean} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--metric", default="success", help="eval/<split>/<metric>")
    parser.add_argument("--at", type=int, default=None, help="ignore records after this step")
    parser.add_argument("--tasks", action="store_true", help="per-task success tables too")
    args = parser.parse_args()
    rows_of: dict[Path, list[dict[str, float]]] = {}
    splits = ("train", "test")
    per_split: dict[str, list[float]] = {s: [] for s in splits}
    stochastic: list[float] = []
    ends: dict[Path, int] = {}
    for run in args.runs:
        rows = rows_of[run] = records(run)
        ends[run] = max((int(r["step"]) for r in rows), default=0)
        cells = []
        for split in splits:
            got = last_mean(evaluations(rows, f"eval/{split}/{args.metric}", args.at))
            if got is None:
                continue
            mean, steps = got
            per_split[split].append(mean)
            cells.append(f"{split} {mean:.3f} (steps {', '.join(f'{s:,}' for s in steps)})")
        train = evaluations(rows, "train/success", args.at)[-LAST:]
        if train:
            stochastic.append(statistics.fmean(v for _, v in train))
            cells.append(f"stochastic train {stochastic[-1]:.3f}")
        print(f"{run}: " + "; ".join(cells))
    if args.at is None and len(set(ends.values())) > 1:
        print(
            "warning: the runs end at different steps "
            f"({', '.join(f'{e:,}' for e in sorted(set(ends.values())))}); --at STEPS compares "
            "them at one budget",
            file=sys.stderr,
        )
    for split, values in per_split.items():
        if values:
            print(
                f"{split} {args.metric}: mean {statistics.fmean(values):.3f}, "
                f"range {min(values):.3f}-{max(values):.3f} over {len(values)} runs"
            )
    if stochastic:
        print(
            f"stochastic train success: mean {statistics.fmean(stochastic):.3f}, "
            f"range {min(stochastic):.3f}-{max(stochastic):.3f}"
        )
    if args.tasks:
        for split in splits:
            table = task_table(args.runs, rows_of, split, args.at)
            if table:
                print()
                print("\n".join(table))


if __name__ == "__main__":
    main()
