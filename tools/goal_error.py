"""How far a goal head's guess lies from the task's goal (`model.goal_prediction`), per task,
over a window of agent steps: for each run, the root of the mean of the squared
`learner/task_goal_error/<task id>` over the window's log records (each record is one update's
batch, so one task's error in one record rests on one or two segments; pooling the window
evens that out), and the same for `learner/goal_error` over all tasks.

With --spread N it also prints the yardstick: how far each task's goals lie from their mean
over the first N seeds of the env ids given by --spread-env (what a head that knows the task
but not the episode's goal can do at best).

Usage: .venv/bin/python tools/goal_error.py RUN_DIR ... [--from STEPS] [--to STEPS]
       [--spread 300 --spread-env million/ML10-train --spread-env million/ML10-test]
"""

from __future__ import annotations

import argparse
import collections
import math
import statistics
from pathlib import Path

# The same reader as the statistic's: a line cut short is skipped with a warning.
from seed_summary import records

TASK_PREFIX = "learner/task_goal_error/"
OVERALL = "learner/goal_error"


def pooled(rows: list[dict[str, float]], lo: int, hi: int) -> dict[str, tuple[float, int]]:
    """Key -> (root of the mean of its squared values, how many records) over lo <= step <= hi."""
    squares: dict[str, list[float]] = collections.defaultdict(list)
    for r in rows:
        if not lo <= int(r["step"]) <= hi:
            continue
        for key, value in r.items():
            if (key == OVERALL or key.startswith(TASK_PREFIX)) and value is not None:
                squares[key].append(float(value) ** 2)
    return {k: (math.sqrt(statistics.fmean(v)), len(v)) for k, v in squares.items()}


def task_names() -> dict[str, str]:
    """Task id -> Meta-World name, where the env server's package is installed."""
    try:
        from million_env.metaworld_tasks import ALL_TASK_NAMES
    except ImportError:
        return {}
    return {str(i): name.removesuffix("-v3") for i, name in enumerate(ALL_TASK_NAMES)}


def goal_spread(env_ids: list[str], seeds: int) -> dict[str, float]:
    """Task name -> root mean squared distance of its goals from their mean over `seeds` resets."""
    import gymnasium as gym
    import numpy as np

    from million_env.million import register_envs

    register_envs()
    goals: dict[str, list[np.ndarray]] = collections.defaultdict(list)
    for env_id in env_ids:
        env = gym.make(env_id)
        for seed in range(seeds):
            _, info = env.reset(seed=seed)
            goals[str(info["task_name"]).removesuffix("-v3")].append(np.asarray(info["goal"]))
        env.close()
    spread = {}
    for name, g in goals.items():
        stacked = np.stack(g)
        spread[name] = float(np.sqrt(((stacked - stacked.mean(0)) ** 2).sum(1).mean()))
    return spread


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--from", dest="lo", type=int, default=0, help="first step of the window")
    parser.add_argument("--to", dest="hi", type=int, default=None, help="last step of the window")
    parser.add_argument("--spread", type=int, default=0, help="seeds for the yardstick (0: none)")
    parser.add_argument("--spread-env", action="append", default=[], help="env id (repeatable)")
    args = parser.parse_args()
    hi = args.hi if args.hi is not None else 1 << 62
    by_run = {run: pooled(records(run), args.lo, hi) for run in args.runs}
    if not any(by_run.values()):
        raise SystemExit(
            "no goal errors in the window: was the run made with model.goal_prediction?"
        )
    names = task_names()
    spread = goal_spread(args.spread_env, args.spread) if args.spread else {}
    ids = sorted(
        {k[len(TASK_PREFIX) :] for p in by_run.values() for k in p if k.startswith(TASK_PREFIX)},
        key=int,
    )
    header = "| task | " + " | ".join(run.name for run in args.runs) + " | mean |"
    if spread:
        header += " goals' spread |"
    print(header)
    print("|---|" + "---|" * (len(args.runs) + 1 + bool(spread)))
    for key, label in [(OVERALL, "all tasks")] + [(TASK_PREFIX + i, names.get(i, i)) for i in ids]:
        got = [by_run[run].get(key) for run in args.runs]
        cells = ["-" if g is None else f"{g[0]:.3f} ({g[1]})" for g in got]
        values = [g[0] for g in got if g is not None]
        row = f"| {label} | " + " | ".join(cells)
        row += f" | {statistics.fmean(values):.3f} |" if values else " | - |"
        if spread:
            row += f" {spread[label]:.3f} |" if label in spread else " - |"
        print(row)
    print(
        f"\nmetres; root of the mean squared error over the records of steps {args.lo:,}-"
        f"{'end' if args.hi is None else f'{args.hi:,}'} (records in brackets)"
    )


if __name__ == "__main__":
    main()
