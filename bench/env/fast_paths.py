"""Meta-World's step with and without million_env's fast paths, per task class.

Each class of the chosen benchmark split is stepped with the same random actions, once with
Meta-World's own code and once with the fast paths (`million_env.metaworld_fast_paths`),
alternating, and the fastest of the repeats is kept. Times are this process's CPU time per
env step, so other processes on a shared machine count little.

    .venv/bin/python bench/env/fast_paths.py --benchmark ML10 --steps 400 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from million_env import metaworld_fast_paths
from million_env.metaworld_tasks import load_benchmark
from million_env.registry import env_descriptions


def time_class(name: str, steps: int, repeats: int) -> dict[str, float]:
    bench = load_benchmark("ML1", name, 0)
    env = dict(bench.train_classes)[name]()
    env.seed(0)
    env.set_task(bench.train_tasks[0])
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 4)).astype(np.float32)
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(repeats):
        for fast in (True, False):
            metaworld_fast_paths.install(fast)
            env.reset()
            start = time.process_time()
            for action in actions:
                env.step(action)
            times[fast].append((time.process_time() - start) / steps * 1e6)
    metaworld_fast_paths.install(True)
    env.close()
    fast_us, metaworld_us = min(times[True]), min(times[False])
    return {
        "metaworld_us_per_step": round(metaworld_us, 1),
        "fast_paths_us_per_step": round(fast_us, 1),
        "speedup": round(metaworld_us / fast_us, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--benchmark", choices=["ML10", "ML45"], default="ML10")
    parser.add_argument("--split", choices=["train", "test"], default="train")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    env_descriptions()  # registers the envs, which installs the fast paths
    bench = load_benchmark(args.benchmark, None, 0)
    classes = bench.train_classes if args.split == "train" else bench.test_classes
    per_class = {name: time_class(name, args.steps, args.repeats) for name in classes}
    metaworld = sum(c["metaworld_us_per_step"] for c in per_class.values())
    fast = sum(c["fast_paths_us_per_step"] for c in per_class.values())
    print(
        json.dumps(
            {
                "split": f"{args.benchmark}-{args.split}",
                "per_class": per_class,
                # Every class equally often, as ML10's uniform task sampling gives.
                "mean_metaworld_us_per_step": round(metaworld / len(per_class), 1),
                "mean_fast_paths_us_per_step": round(fast / len(per_class), 1),
                "speedup": round(metaworld / fast, 3),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
