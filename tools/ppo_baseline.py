"""PPO yardstick for MT1 reach: Stable-Baselines3 PPO on Meta-World's own MT1 task.

The same env as `configs/mt1-reach.toml` (goal visible, 500-step episodes),
stepped in-process. Writes `RUN_DIR/metrics.jsonl` with the keys `million train` uses, so
`tools/plot_curves.py` draws both on one figure:

- `train/success`: share of the training episodes that finished since the last record
  with `success` at any step (Meta-World's criterion; stochastic policy);
- `eval/train/success`: deterministic episodes (mean action), same criterion.

Usage:
  .venv/bin/python tools/ppo_baseline.py --task reach-v3 --steps 1000000 --run-dir runs/ppo-reach
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import metaworld  # noqa: F401  (registers the Meta-World/* ids)
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv


def make_env(task: str, goal_seed: int, env_seed: int) -> gym.Env:
    env = gym.make("Meta-World/MT1", env_name=task, seed=goal_seed)
    env.reset(seed=env_seed)
    return env


def evaluate(model: PPO, task: str, goal_seed: int, episodes: int, seed: int) -> float:
    """Deterministic success rate over `episodes` episodes (success at any step)."""
    env = make_env(task, goal_seed, seed)
    wins = 0
    for k in range(episodes):
        obs, _ = env.reset(seed=seed + k)
        success = False
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            success |= bool(info.get("success", 0.0))
            done = terminated or truncated
        wins += success
    env.close()
    return wins / episodes


class Recorder(BaseCallback):
    """Tracks per-episode success and writes records every `interval` steps."""

    def __init__(self, args: argparse.Namespace, out: Any) -> None:
        super().__init__()
        self.args = args
        self.out = out
        self.seen = np.zeros(args.num_envs, dtype=bool)
        self.finished: list[bool] = []
        self.next_record = args.eval_interval
        self.start = time.monotonic()

    def _on_step(self) -> bool:
        for i, (info, done) in enumerate(
            zip(self.locals["infos"], self.locals["dones"], strict=True)
        ):
            self.seen[i] |= bool(info.get("success", 0.0))
            if done:
                self.finished.append(bool(self.seen[i]))
                self.seen[i] = False
        if self.num_timesteps >= self.next_record:
            self.next_record += self.args.eval_interval
            self.record()
        return True

    def record(self) -> None:
        a = self.args
        rec: dict[str, Any] = {
            "step": self.num_timesteps,
            "wall_time": time.time(),
            "elapsed_s": time.monotonic() - self.start,
            "eval/train/success": evaluate(
                self.model, a.task, a.goal_seed, a.eval_episodes, a.seed + 1_000_000
            ),
        }
        if self.finished:
            rec["train/success"] = float(np.mean(self.finished))
            self.finished = []
        self.out.write(json.dumps(rec) + "\n")
        self.out.flush()
        print(json.dumps(rec), flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--task", default="reach-v3")
    p.add_argument("--steps", type=int, default=1_000_000)
    p.add_argument("--run-dir", type=Path, required=True)
    p.add_argument("--num-envs", type=int, default=8)
    p.add_argument("--goal-seed", type=int, default=1, help="MT1's seed kwarg (goal set)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-interval", type=int, default=100_000)
    p.add_argument("--eval-episodes", type=int, default=32)
    args = p.parse_args()
    torch.set_num_threads(1)
    args.run_dir.mkdir(parents=True, exist_ok=True)
    venv = DummyVecEnv(
        [
            (lambda i=i: make_env(args.task, args.goal_seed, args.seed + i))
            for i in range(args.num_envs)
        ]
    )
    # The settings of the measurement: n_steps 512, batch 256, otherwise SB3 defaults.
    model = PPO("MlpPolicy", venv, n_steps=512, batch_size=256, seed=args.seed, verbose=0)
    (args.run_dir / "config.json").write_text(json.dumps(vars(args), default=str, indent=1))
    with open(args.run_dir / "metrics.jsonl", "a") as out:
        model.learn(total_timesteps=args.steps, callback=Recorder(args, out))


if __name__ == "__main__":
    main()
