"""The simulator's own speed: the same envs as a server would serve, stepped in-process.

    .venv/bin/python bench/env/inprocess_rate.py \
        --env million/ML10-train --batch 16 --workers 2 --seconds 10 [--kwargs '{}']

`--workers` processes each make their share of `--batch` envs (`million_env.registry`
makes them exactly as the server does), reset them with seeds `seed + i`, then step them
in a tight loop with random actions (the action space's own sampler), resetting an env
when its episode ends (as the server's autoreset does), for `--seconds`. Prints one JSON
object: env steps/s summed over the workers. This is the yardstick of `million bench env`:
served ÷ in-process shows what serving costs over simulating.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import threading
import time
from typing import Any

import numpy as np


def _worker(
    env_id: str,
    kwargs: dict[str, Any],
    first_env: int,
    count: int,
    seed: int,
    seconds: float,
    ready: Any,
    results: Any,
) -> None:
    try:
        from million_env.registry import make_env

        envs = [make_env(env_id, kwargs) for _ in range(count)]
        for i, env in enumerate(envs):
            env.reset(seed=seed + first_env + i)
        space = envs[0].action_space
        space.seed(seed + first_env)
    except BaseException as err:
        results.put(f"{type(err).__name__}: {err}")
        ready.abort()  # the parent and the other workers stop waiting
        raise
    ready.wait()
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for env in envs:
            _, _, terminated, truncated, _ = env.step(space.sample())
            if terminated or truncated:
                env.reset()
        steps += count
    results.put((steps, time.perf_counter() - start))
    for env in envs:
        env.close()


def measure(
    env_id: str, kwargs: dict[str, Any], batch: int, workers: int, seconds: float, seed: int
) -> dict[str, Any]:
    if workers < 1 or batch < workers:
        raise ValueError(f"need 1 <= workers <= batch, got workers={workers} batch={batch}")
    ctx = mp.get_context("spawn")
    ready = ctx.Barrier(workers + 1)
    results = ctx.Queue()
    shares = [batch // workers + (1 if w < batch % workers else 0) for w in range(workers)]
    firsts = np.cumsum([0, *shares[:-1]])
    procs = [
        ctx.Process(
            target=_worker,
            args=(env_id, kwargs, int(first), share, seed, seconds, ready, results),
        )
        for first, share in zip(firsts, shares, strict=True)
    ]
    for p in procs:
        p.start()
    try:
        ready.wait(timeout=900)
    except threading.BrokenBarrierError:
        for p in procs:
            p.kill()
        raise RuntimeError(f"a worker could not make {env_id}: {results.get(timeout=5)}") from None
    counts = [results.get(timeout=seconds + 900) for _ in procs]
    for p in procs:
        p.join()
    steps = sum(c for c, _ in counts)
    elapsed = max(t for _, t in counts)
    return {
        "env": env_id,
        "batch": batch,
        "workers": workers,
        "env_steps": steps,
        "seconds": round(elapsed, 3),
        "env_steps_per_s": steps / elapsed,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="million/ML10-train")
    parser.add_argument("--kwargs", default="{}", help="JSON object of env kwargs")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    kwargs = json.loads(args.kwargs)
    if not isinstance(kwargs, dict):
        parser.error("--kwargs must be a JSON object")
    print(json.dumps(measure(args.env, kwargs, args.batch, args.workers, args.seconds, args.seed)))


if __name__ == "__main__":
    main()
