"""Keeps the curves of runs in the repository: runs/ is not kept, so a result's evidence goes
where the result's page can point to it.

For each RUN_DIR, writes OUT/<run folder name>/metrics.jsonl with the run's evaluation records
(`eval/...`), its stochastic training success (`train/success`) and, for a run with a goal head
(`model.goal_prediction`), its goal errors (`learner/goal_error`, `learner/task_goal_error/...`,
read by tools/goal_error.py), each record keeping its `step` and `wall_time`, and copies the
run's config.toml (what was run). tools/seed_summary.py,
tools/plot_curves.py and `million report` (which draws the original's logged points for ML10
and ML45 runs from the config's env id) read the copy as they read the run. A few tens of kB
per run, where the whole metrics file is a few MB.

With --checkpoint it also keeps the run's newest checkpoint (checkpoints/step-*.safetensors,
about 7 MB at ML10's sizes), which makes the copy a run folder that `million train --resume`
continues: a run that has to stop before its budget is carried on that way from
OUT/<name>, copied back to runs/<name> and resumed with the same config and seed. The resumed
run's metrics.jsonl then holds only these records before the resume step. Keeping the run
again without --checkpoint, once it has finished, removes the carried checkpoint from OUT.
Such an OUT belongs on storage of its own, not in the repository, which takes no file over
5 MB.

Usage: .venv/bin/python tools/keep_evaluations.py RUN_DIR ... --out docs/experiments/data/DATE-NAME
       [--checkpoint]
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

# The same reader as the statistic's: a line cut short is skipped with a warning.
from seed_summary import records

KEPT_PREFIXES = ("eval/", "learner/task_goal_error/")
KEPT_KEYS = ("step", "wall_time", "train/success", "learner/goal_error")


def kept(record: dict[str, object]) -> dict[str, object] | None:
    """The record's kept part, or None when it holds no evaluation and no training success."""
    out = {k: v for k, v in record.items() if k in KEPT_KEYS or k.startswith(KEPT_PREFIXES)}
    if not any(k not in ("step", "wall_time") for k in out):
        return None
    return out


def newest_checkpoint(run: Path) -> Path:
    """The run's newest checkpoint (names sort by step, as `million train --resume` reads them)."""
    found = sorted((run / "checkpoints").glob("step-*.safetensors"))
    if not found:
        raise SystemExit(f"{run}: no checkpoints/step-*.safetensors to keep")
    return found[-1]


def keep_run(run: Path, out_dir: Path, checkpoint: Path | None = None) -> int:
    """Writes the kept records of `run` and `checkpoint` (one of its checkpoints) in place of
    any carried before; without one, removes any carried before. Returns how many records."""
    target = out_dir / run.name
    if target.resolve() == run.resolve():
        raise SystemExit(f"{run}: the kept copy would be the run itself; name another --out")
    lines = [
        json.dumps(part, separators=(",", ":"))
        for part in map(kept, records(run))
        if part is not None
    ]
    target.mkdir(parents=True, exist_ok=True)
    (target / "metrics.jsonl").write_text("".join(f"{line}\n" for line in lines))
    config = run / "config.toml"
    if config.is_file():
        shutil.copyfile(config, target / "config.toml")
    kept_dir = target / "checkpoints"
    for older in kept_dir.glob("step-*.safetensors"):
        if checkpoint is None or older.name != checkpoint.name:
            older.unlink()
            print(f"removed the carried checkpoint {older}")
    if checkpoint is not None:
        kept_dir.mkdir(exist_ok=True)
        shutil.copyfile(checkpoint, kept_dir / checkpoint.name)
    elif kept_dir.is_dir() and not any(kept_dir.iterdir()):
        kept_dir.rmdir()
    return len(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, required=True, help="folder of the kept curves")
    parser.add_argument(
        "--checkpoint",
        action="store_true",
        help="also keep the newest checkpoint, so the copy can be resumed later",
    )
    args = parser.parse_args()
    # Every run's checkpoint is found before anything is written.
    checkpoints = [newest_checkpoint(run) if args.checkpoint else None for run in args.runs]
    for run, checkpoint in zip(args.runs, checkpoints, strict=True):
        n = keep_run(run, args.out, checkpoint)
        print(f"{run} -> {args.out / run.name / 'metrics.jsonl'}: {n} records")


if __name__ == "__main__":
    main()
