"""How soon a first trial can succeed on MILLION's ML1 reach-v3: the yardsticks of
`eval.first_trial_within`, whose budgets `million bench learning` reports the gaps for.

Two policies play one-trial episodes of `million/ML1-train` and `million/ML1-test` (the
protocol's defaults: 200 env steps per trial, action repeat 2) and report each trial's
`steps_to_success`:

- `scripted`: Meta-World's own `SawyerReachV3Policy`, given the goal from info (what an
  agent that read the goal word perfectly could do at the scripted policy's pace, under the
  protocol's action repeat 2);
- `random`: uniform actions (what a first trial without any information scores).

Run: `.venv/bin/python tools/scripted_reach_steps.py [--episodes 50]`.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt
from metaworld.policies import SawyerReachV3Policy

from million_env.million import register_envs

BUDGETS = (25, 50, 100, 200)
Policy = Callable[[dict[str, Any], dict[str, Any]], npt.NDArray[np.float32]]


def scripted() -> Policy:
    policy = SawyerReachV3Policy()

    def act(obs: dict[str, Any], info: dict[str, Any]) -> npt.NDArray[np.float32]:
        state = obs["state"].copy()
        # ML1 hides the goal (zeros in the state's last three entries); info holds it.
        state[-3:] = info["goal"]
        return np.asarray(policy.get_action(state), dtype=np.float32)

    return act


def uniform(seed: int) -> Policy:
    rng = np.random.default_rng(seed)

    def act(_obs: dict[str, Any], _info: dict[str, Any]) -> npt.NDArray[np.float32]:
        return rng.uniform(-1.0, 1.0, 4).astype(np.float32)

    return act


def steps_to_success(env: gymnasium.Env[Any, Any], policy: Policy, seed: int) -> int:
    """One single-trial episode; the env steps its trial took to succeed, -1 if it failed."""
    obs, info = env.reset(seed=seed)
    while True:
        action = policy(obs, info) if info["phase"] == "trial" else np.zeros(4, np.float32)
        obs, _reward, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return int(info["steps_to_success"])


def summary(hits: list[int]) -> dict[str, Any]:
    arr = np.asarray(hits)
    ok = arr[arr > 0]
    return {
        "success": float((arr > 0).mean()),
        "steps_median": float(np.median(ok)) if ok.size else None,
        "steps_max": int(ok.max()) if ok.size else None,
        "within": {k: float(((arr > 0) & (arr <= k)).mean()) for k in BUDGETS},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    args = parser.parse_args()
    register_envs()
    out: dict[str, Any] = {}
    for split in ("train", "test"):
        env = gymnasium.make(f"million/ML1-{split}", task="reach-v3", trials=1)
        for name, policy in (("scripted", scripted()), ("random", uniform(0))):
            hits = [steps_to_success(env, policy, seed) for seed in range(args.episodes)]
            out[f"{split}/{name}"] = summary(hits)
        env.close()
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
