"""Meta-World v3 benchmarks as a task source of the MILLION protocol."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt

from million_env.metaworld_tasks import ALL_TASK_NAMES, MetaWorldTaskSampler
from million_env.rendering import render_metaworld


class MetaWorldTask:
    """A Meta-World env with one task (class + goal) set on it."""

    def __init__(self, name: str, task_id: int, env: Any) -> None:
        self._name = name
        self._task_id = task_id
        self._env = env

    @property
    def name(self) -> str:
        return self._name

    @property
    def task_id(self) -> int:
        return self._task_id

    @property
    def env(self) -> Any:
        return self._env

    def reset(self) -> npt.NDArray[np.float64]:
        # set_task froze the task's random vector, so every reset keeps the goal.
        obs, _ = self._env.reset()
        return obs

    def step(self, action: npt.NDArray[np.float32]) -> tuple[npt.NDArray[np.float64], float, bool]:
        # Meta-World flags truncation at its max_path_length-th step; trial_len is at
        # most that and the trial then ends, so the MDP is reset before any step past
        # it (which Meta-World would refuse).
        obs, reward, _terminated, _truncated, info = self._env.step(action)
        return obs, float(reward), bool(info["success"])

    def goal(self) -> npt.NDArray[np.float64]:
        return np.array(self._env._target_pos, dtype=np.float64)

    def goal_range(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        space = self._env.goal_space
        return np.asarray(space.low, dtype=np.float64), np.asarray(space.high, dtype=np.float64)

    def render(self, width: int, height: int, camera: str, cache: Any) -> npt.NDArray[np.uint8]:
        """The scene in its current state (`million_env.rendering.render_metaworld`)."""
        return render_metaworld(self._env, width, height, camera, cache)


class MetaWorldSource:
    """Tasks of a benchmark split, sampled by the shared `MetaWorldTaskSampler`."""

    def __init__(
        self,
        benchmark: str,
        split: str,
        task: str | None = None,
        task_order: str = "random",
        tasks: Sequence[str] | None = None,
    ) -> None:
        self._sampler = MetaWorldTaskSampler(
            benchmark, split, task=task, task_order=task_order, tasks=tasks
        )
        # Every Meta-World v3 env has the same action space and path limit; read
        # them from one env so that a change upstream is followed.
        probe = self._sampler.sample()
        self._action_space: gymnasium.spaces.Box = probe.env.action_space
        self._max_steps = int(probe.env.max_path_length)

    @property
    def action_space(self) -> gymnasium.spaces.Box:
        return self._action_space

    @property
    def num_task_ids(self) -> int:
        return len(ALL_TASK_NAMES)

    @property
    def task_names(self) -> tuple[str, ...]:
        return self._sampler.task_names

    @property
    def max_steps_per_reset(self) -> int:
        return self._max_steps

    def seed(self, seed: int) -> None:
        self._sampler.seed(seed)

    def sample(self) -> MetaWorldTask:
        sampled = self._sampler.sample()
        return MetaWorldTask(sampled.name, sampled.task_id, sampled.env)

    def close(self) -> None:
        self._sampler.close()
