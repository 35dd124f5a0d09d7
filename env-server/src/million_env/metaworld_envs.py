"""Meta-World v3 benchmark splits as Gymnasium environments.

``metaworld/<ML1|ML10|ML45>-<train|test>`` samples a new task (class and goal) at
every reset with `MetaWorldTaskSampler`. ``reset(seed=s)`` reseeds that sampling
and the Meta-World envs, so a seed fixes the whole sequence of tasks and episodes.
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from million_env.errors import precondition
from million_env.info_fields import METADATA_KEY, METAWORLD_INFO_FIELDS, InfoField
from million_env.metaworld_tasks import (
    ALL_TASK_NAMES,
    BENCHMARKS,
    DEFAULT_BENCHMARK_SEED,
    SPLITS,
    MetaWorldTaskSampler,
    load_benchmark,
)
from million_env.rendering import render_metaworld

MAX_PATH_LENGTH = 500
ID_PREFIX = "metaworld/"

TASK_INFO_FIELDS: tuple[InfoField, ...] = (
    InfoField("task_name", "str", (), "Meta-World task class of this episode, e.g. reach-v3"),
    InfoField("task_id", "int64", (), "index of the task class in the MT50 list (0..49)"),
)


@functools.lru_cache(maxsize=16)
def split_observation_space(
    benchmark: str, split: str, task: str | None, benchmark_seed: int
) -> spaces.Box:
    """The union of the split's per-class observation bounds (they differ by class)."""
    bench = load_benchmark(benchmark, task, benchmark_seed)
    classes = bench.train_classes if split == "train" else bench.test_classes
    tasks = bench.train_tasks if split == "train" else bench.test_tasks
    low = high = None
    for name, cls in classes.items():
        env = cls()
        env.set_task(next(t for t in tasks if t.env_name == name))
        box = env.observation_space
        low = box.low if low is None else np.minimum(low, box.low)
        high = box.high if high is None else np.maximum(high, box.high)
        env.close()
    return spaces.Box(low=low, high=high, dtype=np.float64)


class MetaWorldSplitEnv(gym.Env):
    """A Meta-World benchmark split: every reset runs a freshly sampled task."""

    metadata: dict[str, Any] = {  # noqa: RUF012 - Gymnasium's convention is a class attribute
        "render_modes": [],
        METADATA_KEY: METAWORLD_INFO_FIELDS + TASK_INFO_FIELDS,
    }

    def __init__(
        self,
        benchmark: str,
        split: str,
        task: str | None = None,
        benchmark_seed: int = DEFAULT_BENCHMARK_SEED,
    ) -> None:
        self._sampler = MetaWorldTaskSampler(
            benchmark, split, task=task, benchmark_seed=benchmark_seed
        )
        self.observation_space = split_observation_space(benchmark, split, task, benchmark_seed)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._current: Any = None
        self._task_info: dict[str, Any] = {}

    @property
    def task_names(self) -> tuple[str, ...]:
        return self._sampler.task_names

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self._sampler.seed(seed)
            self.action_space.seed(seed)
        sampled = self._sampler.sample()
        self._current = sampled.env
        self._task_info = {"task_name": sampled.name, "task_id": sampled.task_id}
        obs, info = self._current.reset()
        return obs, {**info, **self._task_info}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._current is None:
            raise gym.error.ResetNeeded("call reset before step")
        obs, reward, terminated, truncated, info = self._current.step(action)
        return obs, float(reward), bool(terminated), bool(truncated), {**info, **self._task_info}

    def render_rgb(self, width: int, height: int, camera: str, cache: Any) -> np.ndarray:
        """The current task's scene (`million_env.rendering.render_metaworld`)."""
        if self._current is None:
            raise precondition("render needs a reset first")
        return render_metaworld(self._current, width, height, camera, cache)

    def close(self) -> None:
        self._sampler.close()


def register_metaworld_envs() -> dict[str, str]:
    """Registers the split ids with Gymnasium; returns {env_id: description}."""
    described = {}
    for benchmark in BENCHMARKS:
        for split in SPLITS:
            env_id = f"{ID_PREFIX}{benchmark}-{split}"
            if benchmark == "ML1":
                what = (
                    f"Meta-World v3 ML1 {split} goals of one task class (kwarg task, e.g. "
                    f"'reach-v3'; one of the {len(ALL_TASK_NAMES)} MT50 names)"
                )
            else:
                what = f"Meta-World v3 {benchmark} {split} classes"
            described[env_id] = (
                f"{what}; a new task (class + goal) is sampled at every reset, seeded by "
                f"reset(seed); {MAX_PATH_LENGTH} steps; kwarg benchmark_seed (fixes the "
                f"goal set)"
            )
            if env_id not in gym.registry:
                gym.register(
                    id=env_id,
                    entry_point=MetaWorldSplitEnv,
                    kwargs={"benchmark": benchmark, "split": split},
                    max_episode_steps=MAX_PATH_LENGTH,
                    disable_env_checker=True,
                )
    return described
