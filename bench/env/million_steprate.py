"""Step rate of million/ML10-train next to raw Meta-World on the same tasks.

The MILLION run records, per trial, which task ran and for how many Meta-World
env steps; the raw run replays exactly that schedule on a `MetaWorldTaskSampler`
with the same seed (same task classes and goals, a reset per trial, random
actions). Both therefore simulate the same number of env steps of the same
tasks, and the ratio of their times is the protocol's cost (instruction steps,
observation and info building included). Times are this process's CPU time, so
other processes on a shared machine do not count; runs alternate and the fastest
of each side is kept. `--no-fast-paths` also times Meta-World's own code throughout,
`--metaworld-reset` Meta-World's own reset with the other fast paths.

    .venv/bin/python bench/env/million_steprate.py --episodes 20 --repeats 3
"""

from __future__ import annotations

import argparse
import contextlib
import json
import time
from collections.abc import Iterator

import gymnasium
import numpy as np

from million_env import metaworld_fast_paths
from million_env.metaworld_tasks import MetaWorldTaskSampler
from million_env.million import protocol_stats
from million_env.registry import env_descriptions

ML10_TRAIN = MetaWorldTaskSampler("ML10", "train").task_names
Schedule = list[list[tuple[str, int]]]  # per episode: (task, env steps) per trial


def run_million(seed: int, episodes: int, actions: np.ndarray) -> tuple[float, int, int, Schedule]:
    env = gymnasium.make("million/ML10-train", disable_env_checker=True)
    # Meta-World envs are built on a class's first sample; build all before timing.
    seen: set[str] = set()
    while len(seen) < len(ML10_TRAIN):
        seen.add(env.reset()[1]["task_name"])
    schedule: Schedule = []
    agent_steps = env_steps = 0
    start = time.process_time()
    for episode in range(episodes):
        _obs, info = env.reset(seed=seed if episode == 0 else None)
        trials: list[tuple[str, int]] = []
        steps_before = 0
        done = False
        while not done:
            action = actions[agent_steps % len(actions)]
            _obs, _r, done, _trunc, info = env.step(action)
            agent_steps += 1
            if info["trial_end"]:
                # steps_in_trial is already the next trial's after a non-final end.
                ended = info["steps_in_trial"] if done else steps_before
                trials.append((info["task_name"], ended))
                env_steps += ended
            steps_before = info["steps_in_trial"]
        schedule.append(trials)
    elapsed = time.process_time() - start
    env.close()
    return elapsed, agent_steps, env_steps, schedule


def run_raw(seed: int, schedule: Schedule, actions: np.ndarray) -> float:
    sampler = MetaWorldTaskSampler("ML10", "train", seed=seed)
    seen: set[str] = set()
    while len(seen) < len(ML10_TRAIN):  # build every env outside the timing
        seen.add(sampler.sample().name)
    sampler.seed(seed)
    step = 0
    start = time.process_time()
    for trials in schedule:
        sampled = sampler.sample()
        for name, env_steps in trials:
            assert name == sampled.name, "raw replay diverged from the MILLION task sequence"
            sampled.env.reset()
            for _ in range(env_steps):
                sampled.env.step(actions[step % len(actions)])
                step += 1
    elapsed = time.process_time() - start
    sampler.close()
    return elapsed


def protocol_cost_per_step(steps: int = 20_000) -> float:
    """Microseconds the protocol adds to one trial step, measured on PointGoal
    (whose own step is a few numpy operations, so the difference is visible)."""
    env = gymnasium.make(
        "million/PointGoal",
        disable_env_checker=True,
        instructions=False,
        trials=1,
        trial_len=10 * steps,
    ).unwrapped
    env.reset(seed=0)
    action = np.zeros(4, dtype=np.float32)
    start = time.process_time()
    for _ in range(steps):
        env.step(action)
    served = time.process_time() - start
    task = env.current_task
    start = time.process_time()
    for _ in range(steps):
        task.step(action)
    bare = time.process_time() - start
    return (served - bare) / steps * 1e6


@contextlib.contextmanager
def metaworld_reset() -> Iterator[None]:
    """Meta-World's own `SawyerXYZEnv.reset` in place of the fast path's, the other fast
    paths kept."""
    metaworld_fast_paths.install(True, fast_reset=False)
    try:
        yield
    finally:
        metaworld_fast_paths.install(True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--no-fast-paths",
        action="store_true",
        help="also time every repeat with Meta-World's own code (million_env."
        "metaworld_fast_paths off), alternating with the fast paths, and report the ratio",
    )
    parser.add_argument(
        "--metaworld-reset",
        action="store_true",
        help="also time every repeat with Meta-World's own reset and the other fast paths, "
        "alternating with all fast paths, and report the ratio: what the reset fast path buys",
    )
    args = parser.parse_args()
    env_descriptions()  # registers the envs as the server does: compiled models, fast paths
    actions = np.random.default_rng(args.seed).uniform(-1, 1, size=(4096, 4)).astype(np.float32)
    million_times, raw_times, reference_million_times, reference_raw_times = [], [], [], []
    own_reset_times: list[float] = []
    for _ in range(args.repeats):
        if args.metaworld_reset:
            with metaworld_reset():
                own_reset_times.append(run_million(args.seed, args.episodes, actions)[0])
        if args.no_fast_paths:
            metaworld_fast_paths.install(False)
            elapsed, _agent_steps, _env_steps, schedule = run_million(
                args.seed, args.episodes, actions
            )
            reference_million_times.append(elapsed)
            reference_raw_times.append(run_raw(args.seed, schedule, actions))
            metaworld_fast_paths.install(True)
        elapsed, agent_steps, env_steps, schedule = run_million(args.seed, args.episodes, actions)
        million_times.append(elapsed)
        raw_times.append(run_raw(args.seed, schedule, actions))
    million, raw = min(million_times), min(raw_times)
    reference_figures = {}
    if args.no_fast_paths:
        reference_million, reference_raw = min(reference_million_times), min(reference_raw_times)
        reference_figures = {
            "metaworld_code_million_agent_steps_per_s": round(agent_steps / reference_million, 1),
            "metaworld_code_raw_metaworld_env_steps_per_s": round(env_steps / reference_raw, 1),
            "fast_paths_speedup_million": round(reference_million / million, 3),
            "fast_paths_speedup_raw": round(reference_raw / raw, 3),
        }
    if args.metaworld_reset:
        own_reset = min(own_reset_times)
        reference_figures["metaworld_reset_million_agent_steps_per_s"] = round(
            agent_steps / own_reset, 1
        )
        reference_figures["fast_reset_speedup_million"] = round(own_reset / million, 3)
    print(
        json.dumps(
            {
                **reference_figures,
                "episodes": args.episodes,
                "tasks": sorted({name for trials in schedule for name, _ in trials}),
                "env_steps": env_steps,
                "agent_steps": agent_steps,
                "million_env_steps_per_s": round(env_steps / million, 1),
                "million_agent_steps_per_s": round(agent_steps / million, 1),
                "raw_metaworld_env_steps_per_s": round(env_steps / raw, 1),
                "protocol_overhead": round(million / raw - 1.0, 4),
                "million_times_s": [round(t, 3) for t in million_times],
                "raw_times_s": [round(t, 3) for t in raw_times],
                "protocol_us_per_agent_step": round(protocol_cost_per_step(), 1),
                "unknown_words": protocol_stats()["unknown_words"],
                "instruction_tokens": protocol_stats()["instruction_tokens"],
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
