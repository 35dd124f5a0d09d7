"""Prints chosen columns of a run's metrics.jsonl as a table (a quick look during a run).

Usage: .venv/bin/python tools/show_metrics.py runs/NAME [KEY_SUBSTRING ...]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

DEFAULT = [
    "train/success",
    "train/episode_return",
    "eval/train/success",
    "eval/train/first_trial_success",
    "eval/test/success",
    "learner/eta",
    "learner/alpha_mu",
    "learner/alpha_sigma",
    "learner/kl_mu",
    "learner/kl_sigma",
    "learner/mean_std",
    "learner/popart_mean_sigma",
    "train/agent_steps_per_s",
    "train/updates",
]


def main() -> None:
    run = Path(sys.argv[1])
    wanted = sys.argv[2:]
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    keys = [k for k in DEFAULT if not wanted or any(w in k for w in wanted)]
    keys = [k for k in keys if any(k in r for r in rows)]
    print("step".rjust(9), *(k.split("/", 1)[-1][:11].rjust(11) for k in keys))
    for r in rows:
        cells = []
        for k in keys:
            v = r.get(k)
            cells.append(("" if v is None else f"{v:.4g}").rjust(11))
        print(str(r["step"]).rjust(9), *cells)


if __name__ == "__main__":
    main()
