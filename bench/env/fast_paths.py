"""Meta-World's step and reset with and without million_env's fast paths, per task class.

Each class of the chosen benchmark split is stepped with the same random actions, once with
Meta-World's own code and once with the fast paths (`million_env.metaworld_fast_paths`),
alternating, and the fastest of the repeats is kept; then reset `--resets` times in a row on
its task each way (a task's later resets: the ones the fast path shortens), alternating too.
Times are this process's CPU time per env step and per reset, so other processes on a shared
machine count little.

    .venv/bin/python bench/env/fast_paths.py --benchmark ML10 --steps 400 --resets 10 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from million_env import metaworld_fast_paths
from million_env.metaworld_tasks import load_benchmark
from million_env.registry import env_descriptions


def time_class(name: str, steps: int, resets: int, repeats: int) -> dict[str, float]:
    bench = load_benchmark("ML1", name, 0)
    env = dict(bench.train_classes)[name]()
    env.seed(0)
    env.set_task(bench.train_tasks[0])
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 4)).astype(np.float32)
    times: dict[bool, list[float]] = {True: [], False: []}
    reset_times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(repeats):
        for fast in (True, False):
            metaworld_fast_paths.install(fast)
            env.reset()
            start = time.process_time()
            for action in actions:
                env.step(action)
            times[fast].append((time.process_time() - start) / steps * 1e6)
            start = time.process_time()
            for _ in range(resets):
                env.reset()
            reset_times[fast].append((time.process_time() - start) / resets * 1e6)
    metaworld_fast_paths.install(True)
    env.close()
    fast_us, metaworld_us = min(times[True]), min(times[False])
    fast_reset_us, metaworld_reset_us = min(reset_times[True]), min(reset_times[False])
    return {
        "metaworld_us_per_step": round(metaworld_us, 1),
        "fast_paths_us_per_step": round(fast_us, 1),
        "speedup": round(metaworld_us / fast_us, 3),
        "metaworld_us_per_reset": round(metaworld_reset_us),
        "fast_paths_us_per_reset": round(fast_reset_us),
        "reset_speedup": round(metaworld_reset_us / fast_reset_us, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--benchmark", choices=["ML10", "ML45"], default="ML10")
    parser.add_argument("--split", choices=["train", "test"], default="train")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--resets", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    env_descriptions()  # registers the envs, which installs the fast paths
    bench = load_benchmark(args.benchmark, None, 0)
    classes = bench.train_classes if args.split == "train" else bench.test_classes
    per_class = {name: time_class(name, args.steps, args.resets, args.repeats) for name in classes}
    metaworld = sum(c["metaworld_us_per_step"] for c in per_class.values())
    fast = sum(c["fast_paths_us_per_step"] for c in per_class.values())
    metaworld_reset = sum(c["metaworld_us_per_reset"] for c in per_class.values())
    fast_reset = sum(c["fast_paths_us_per_reset"] for c in per_class.values())
    print(
        json.dumps(
            {
                "split": f"{args.benchmark}-{args.split}",
                "per_class": per_class,
                # Every class equally often, as ML10's uniform task sampling gives.
                "mean_metaworld_us_per_step": round(metaworld / len(per_class), 1),
                "mean_fast_paths_us_per_step": round(fast / len(per_class), 1),
                "speedup": round(metaworld / fast, 3),
                "mean_metaworld_us_per_reset": round(metaworld_reset / len(per_class)),
                "mean_fast_paths_us_per_reset": round(fast_reset / len(per_class)),
                "reset_speedup": round(metaworld_reset / fast_reset, 3),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
