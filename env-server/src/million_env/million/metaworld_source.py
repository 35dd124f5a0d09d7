"""Meta-World v3 benchmarks as a task source of the MILLION protocol."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt

from million_env.metaworld_tasks import ALL_TASK_NAMES, MetaWorldTaskSampler
from million_env.rendering import render_metaworld

#: `object_position` values: each task's own object position, or every task's object at the
#: centre of its class's initial-position range.
OBJECT_POSITIONS = ("task", "centre")

#: Classes whose object takes no part in the task, so it can be moved without changing it.
#: reach-v3 draws its puck's position with the goal in one random vector: on a split's fixed
#: goals the puck tells a policy which goal it is, without any word
#: (docs/experiments/2026-12-04-bench-learning-and-first-trial-budgets.md).
DISTRACTOR_OBJECT_TASKS = ("reach-v3",)


class MetaWorldTask:
    """A Meta-World env with one task (class + goal) set on it."""

    def __init__(self, name: str, task_id: int, env: Any, object_at_centre: bool = False) -> None:
        self._name = name
        self._task_id = task_id
        self._env = env
        self._object_at_centre = object_at_centre

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
        if self._object_at_centre:
            obs = self._move_object_to_centre()
        return obs

    def _move_object_to_centre(self) -> npt.NDArray[np.float64]:
        """Puts the object at the centre of its class's range and observes again, with the
        previous frame (entries 18-36) equal to the current one, as after Meta-World's reset."""
        env = self._env.unwrapped
        space = env._random_reset_space
        centre = (np.asarray(space.low[:3]) + np.asarray(space.high[:3])) / 2.0
        env.obj_init_pos = centre
        env._set_obj_xyz(centre)
        obs = np.asarray(env._get_obs(), dtype=np.float64)
        env._prev_obs = obs[:18].copy()
        obs[18:36] = env._prev_obs
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
        object_position: str = "task",
    ) -> None:
        if object_position not in OBJECT_POSITIONS:
            raise ValueError(
                f"object_position must be one of {OBJECT_POSITIONS}, got {object_position!r}"
            )
        self._sampler = MetaWorldTaskSampler(
            benchmark, split, task=task, task_order=task_order, tasks=tasks
        )
        self._object_at_centre = object_position == "centre"
        if self._object_at_centre:
            moved = [n for n in self._sampler.task_names if n not in DISTRACTOR_OBJECT_TASKS]
            if moved:
                self._sampler.close()
                raise ValueError(
                    f'object_position="centre" would change tasks {moved}: only the object '
                    f"of {list(DISTRACTOR_OBJECT_TASKS)} takes no part in its task"
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
        return MetaWorldTask(sampled.name, sampled.task_id, sampled.env, self._object_at_centre)

    def close(self) -> None:
        self._sampler.close()
