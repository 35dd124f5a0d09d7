"""Learning curves of several runs on one small PNG, from their `metrics.jsonl`.

Each run is `NAME=RUN_DIR` (or just RUN_DIR, named by its folder). Every key given with
`--key` gets its own panel; x is agent steps, or minutes of wall time with `--wall`.

Usage:
  .venv/bin/python tools/plot_curves.py runs/a NAME=runs/b --key eval/train/success \
      --key eval/train/first_trial_success --out docs/figures/mt1-reach.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt


def read_series(run_dir: Path, key: str, wall: bool) -> tuple[list[float], list[float]]:
    xs: list[float] = []
    ys: list[float] = []
    start: float | None = None
    for line in (run_dir / "metrics.jsonl").read_text().splitlines():
        rec = json.loads(line)
        if start is None:
            start = rec.get("wall_time", 0.0) - rec.get("elapsed_s", 0.0)
        if rec.get(key) is None:
            continue
        x = (rec["wall_time"] - start) / 60.0 if wall else rec["step"] / 1e6
        xs.append(x)
        ys.append(float(rec[key]))
    return xs, ys


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("runs", nargs="+", help="RUN_DIR or NAME=RUN_DIR")
    p.add_argument("--key", action="append", required=True, help="metric key (repeatable)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--wall", action="store_true", help="x = wall-clock minutes")
    p.add_argument("--title", default="")
    p.add_argument("--log-key", action="append", default=[], help="panel with a log y axis")
    args = p.parse_args()
    runs = []
    for spec in args.runs:
        name, _, path = spec.rpartition("=")
        runs.append((name or Path(path).name, Path(path)))
    fig, axes = plt.subplots(
        1, len(args.key), figsize=(4.2 * len(args.key), 3.2), squeeze=False, dpi=90
    )
    for ax, key in zip(axes[0], args.key, strict=True):
        for name, path in runs:
            xs, ys = read_series(path, key, args.wall)
            if xs:
                dense = len(xs) > 40  # per-log-interval series: a line, no markers
                ax.plot(xs, ys, marker="" if dense else "o", markersize=3, label=name)
        ax.set_title(key, fontsize=9)
        ax.set_xlabel("wall-clock minutes" if args.wall else "agent steps (millions)")
        ax.set_ylabel("success rate" if "success" in key else key)
        if "success" in key:
            ax.set_ylim(-0.02, 1.02)
        if key in args.log_key:
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    if args.title:
        fig.suptitle(args.title, fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
