"""The random policy's success on a MILLION env: the floor every learned task must beat.

Uniform random actions in [-1, 1] on `million/<id>` stepped in-process, episodes spread
evenly over the split's tasks (`task_order = "cycle"`, as `million train` evaluates), and
the same trial metrics as `million train`'s evaluation: success = successful trials /
trials, first-trial success, per task. Prints one JSON object.

Usage: .venv/bin/python tools/random_baseline.py --env million/ML10-train --episodes-per-task 10
       [--kwargs '{"task": "reach-v3"}'] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict

import gymnasium as gym
import numpy as np

from million_env.million.registry import register_envs


def run(env_id: str, kwargs: dict, episodes_per_task: int, seed: int) -> dict:
    register_envs()
    env = gym.make(env_id, task_order="cycle", **kwargs)
    num_tasks = len(env.unwrapped.task_names)
    rng = np.random.default_rng(seed)
    trials: dict[str, list[bool]] = defaultdict(list)
    first: dict[str, list[bool]] = defaultdict(list)
    for episode in range(episodes_per_task * num_tasks):
        # Seeding the first reset with s starts the cycle at task s mod n; each later
        # reset takes the next task, so every task gets the same number of episodes.
        _, info = env.reset(seed=seed + episode) if episode == 0 else env.reset()
        task = info["task_name"]
        outcomes: list[bool] = []
        while True:
            action = rng.uniform(-1.0, 1.0, size=env.action_space.shape).astype(np.float32)
            _, _, terminated, truncated, info = env.step(action)
            if info["trial_end"]:
                outcomes.append(bool(info["success"]))
            if terminated or truncated:
                break
        trials[task].extend(outcomes)
        first[task].append(outcomes[0])
    env.close()
    per_task = {t: float(np.mean(v)) for t, v in sorted(trials.items())}
    return {
        "env": env_id,
        "kwargs": kwargs,
        "episodes_per_task": episodes_per_task,
        "success": float(np.mean([s for v in trials.values() for s in v])),
        "first_trial_success": float(np.mean([s for v in first.values() for s in v])),
        "task": per_task,
        "trials_per_task": {t: len(v) for t, v in sorted(trials.items())},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="million/ML10-train")
    parser.add_argument("--kwargs", default="{}", help="JSON object of env kwargs")
    parser.add_argument("--episodes-per-task", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    kwargs = json.loads(args.kwargs)
    if not isinstance(kwargs, dict):
        parser.error("--kwargs must be a JSON object")
    print(json.dumps(run(args.env, kwargs, args.episodes_per_task, args.seed)))


if __name__ == "__main__":
    main()
