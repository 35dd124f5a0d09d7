"""What the MILLION protocol's reward pays for: succeeding, or hovering near the goal.

    .venv/bin/python tools/reward_incentive.py [--episodes 5] [--task reach-v3]

Runs Meta-World's scripted policy of the task (it is given the real goal) on
`million/ML1-train` aimed at the goal itself and at points 10-12 cm off it, once with
trials that end at their success (`end_on_success=True`, the protocol before) and once
with full-length trials (the original code and now the default). Prints each policy's
mean episode return, discounted return (gamma 0.99 per agent step, from the episode's
start), successful trials out of 3 and agent steps. If hovering earns more than
succeeding, a return-maximising agent learns not to succeed
(docs/experiments/2026-12-01-full-length-trials.md).
"""

from __future__ import annotations

import argparse
import warnings
from typing import Any

import gymnasium
import numpy as np
from metaworld import policies

from million_env.million import register_envs

TARGETS = {
    "at the goal": (0.0, 0.0, 0.0),
    "hover 10 cm off in x": (0.10, 0.0, 0.0),
    "hover 12 cm above": (0.0, 0.0, 0.12),
}


def scripted_policy(task: str) -> Any:
    # reach-v3 -> SawyerReachV3Policy, pick-place-v3 -> SawyerPickPlaceV3Policy
    name = "Sawyer" + "".join(p.capitalize() for p in task.split("-")[:-1]) + "V3Policy"
    return getattr(policies, name)()


def episode(task: str, offset: np.ndarray, seed: int, gamma: float, **kwargs: Any) -> np.ndarray:
    """(return, discounted return, successful trials, agent steps) of one episode."""
    env = gymnasium.make("million/ML1-train", task=task, **kwargs).unwrapped
    policy = scripted_policy(task)
    try:
        obs, info = env.reset(seed=seed)
        target = np.asarray(info["goal"]) + offset
        total = discounted = 0.0
        successes = steps = 0
        done = False
        while not done:
            if info["phase"] == "trial":
                state = obs["state"].copy()
                state[36:39] = target  # the scripted policy reads the goal there
                action = policy.get_action(state)
            else:
                action = np.zeros(4, dtype=np.float32)
            obs, reward, done, _truncated, info = env.step(action)
            total += reward
            discounted += gamma**steps * reward
            steps += 1
            successes += int(info["trial_end"] and info["success"])
        return np.array([total, discounted, successes, steps], dtype=np.float64)
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="reach-v3")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--gamma", type=float, default=0.99)
    args = parser.parse_args()
    warnings.filterwarnings("ignore", message="Constant.s. may be too high")
    register_envs()
    print("| trials | policy | return | discounted | successes of 3 | agent steps |")
    print("|---|---|---|---|---|---|")
    for mode, kwargs in (
        ("end at success", {"end_on_success": True}),
        ("full length", {}),
    ):
        for name, offset in TARGETS.items():
            runs = np.stack(
                [
                    episode(args.task, np.asarray(offset), seed, args.gamma, **kwargs)
                    for seed in range(args.episodes)
                ]
            )
            total, discounted, successes, steps = runs.mean(axis=0)
            print(
                f"| {mode} | {name} | {total:,.0f} | {discounted:,.0f} | {successes:.1f} "
                f"| {steps:.0f} |"
            )


if __name__ == "__main__":
    main()
