"""Seeded sampling of Meta-World v3 tasks (a task class plus one of its goals).

Meta-World's own ``reset(seed=...)`` does not seed which task or goal comes next,
so this module owns that randomness: one ``numpy.random.Generator`` picks the
class and the goal, and every Meta-World env gets a seed derived from the same
seed and its task id. The same seed therefore always yields the same sequence of
tasks, goals and reset observations.
"""

from __future__ import annotations

import functools
import random
import threading
from dataclasses import dataclass
from typing import Any

import metaworld
import numpy as np
from metaworld.env_dict import MT50_V3

#: The 50 Meta-World v3 task names in MT50 order; a name's index is its task id.
ALL_TASK_NAMES: tuple[str, ...] = tuple(MT50_V3.keys())

BENCHMARKS: tuple[str, ...] = ("ML1", "ML10", "ML45")
SPLITS: tuple[str, ...] = ("train", "test")

#: Seed of the benchmark's goal set (50 goals per class) when none is given, so
#: that every server process serves the same goals.
DEFAULT_BENCHMARK_SEED = 0

_TASK_IDS = {name: index for index, name in enumerate(ALL_TASK_NAMES)}

# Benchmark construction seeds numpy's *global* RNG and restores it afterwards;
# two constructions in parallel threads would interleave and change each other's
# goals, so they are serialised.
_BENCHMARK_LOCK = threading.Lock()


@functools.lru_cache(maxsize=16)
def _benchmark_unlocked(benchmark: str, task: str | None, seed: int) -> metaworld.Benchmark:
    if benchmark == "ML1":
        return metaworld.ML1(task, seed=seed)
    if benchmark == "ML10":
        return metaworld.ML10(seed=seed)
    return metaworld.ML45(seed=seed)


def load_benchmark(benchmark: str, task: str | None, seed: int) -> metaworld.Benchmark:
    """The Meta-World benchmark object, built once per process (ML45 takes ~40 s)."""
    with _BENCHMARK_LOCK:
        return _benchmark_unlocked(benchmark, task, seed)


def _validate(benchmark: str, split: str, task: str | None) -> None:
    if benchmark not in BENCHMARKS:
        raise ValueError(
            f"unknown Meta-World benchmark {benchmark!r}; expected one of {BENCHMARKS}"
        )
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {SPLITS}")
    if benchmark == "ML1":
        if task is None:
            raise ValueError(f"ML1 needs a task name, one of {ALL_TASK_NAMES}")
        if task not in _TASK_IDS:
            raise ValueError(f"unknown Meta-World task {task!r}; expected one of {ALL_TASK_NAMES}")
    elif task is not None:
        raise ValueError(f"{benchmark} takes no task name (got {task!r}); only ML1 does")


@dataclass
class SampledTask:
    """One sampled task: its class name, its MT50 index and the env with the task set."""

    name: str
    task_id: int
    env: Any


TASK_ORDERS = ("random", "cycle")


def parse_task_order(task_order: str) -> bool:
    """True for ``"cycle"``, False for ``"random"``; anything else is a ValueError."""
    if task_order not in TASK_ORDERS:
        raise ValueError(f"task_order must be one of {TASK_ORDERS}, got {task_order!r}")
    return task_order == "cycle"


class MetaWorldTaskSampler:
    """Seeded sampling of a (task class, goal variation) from a Meta-World v3 benchmark split.

    One Meta-World env per task class is built once (on first use) and reused;
    ``max_built_envs`` bounds how many stay built (least recently used are closed).

    ``task_order="cycle"`` takes the classes in turn instead of at random, starting at
    class ``seed mod n`` after ``seed(seed)``: envs seeded ``s + i`` then cover every class
    equally, which evaluation uses to score each task on the same number of episodes.
    """

    def __init__(
        self,
        benchmark: str,
        split: str,
        task: str | None = None,
        seed: int | None = None,
        benchmark_seed: int = DEFAULT_BENCHMARK_SEED,
        max_built_envs: int | None = None,
        task_order: str = "random",
    ) -> None:
        _validate(benchmark, split, task)
        self._cycle = parse_task_order(task_order)
        if max_built_envs is not None and max_built_envs < 1:
            raise ValueError(f"max_built_envs must be at least 1, got {max_built_envs}")
        # Each built Meta-World env holds ~20 MB; ML45 builds up to 45 of them per
        # sampler unless this caps it (least recently used ones are closed).
        self._max_built_envs = max_built_envs
        self.benchmark = benchmark
        self.split = split
        bench = load_benchmark(benchmark, task, benchmark_seed)
        classes = bench.train_classes if split == "train" else bench.test_classes
        tasks = bench.train_tasks if split == "train" else bench.test_tasks
        self._classes: dict[str, type] = dict(classes)
        self.task_names: tuple[str, ...] = tuple(self._classes)
        self._tasks_by_name: dict[str, list[Any]] = {name: [] for name in self.task_names}
        for mw_task in tasks:
            self._tasks_by_name[mw_task.env_name].append(mw_task)
        self._envs: dict[str, Any] = {}
        self._seed: int | None = None
        self._rng = np.random.default_rng()
        self._next_class = 0
        if seed is not None:
            self.seed(seed)

    def seed(self, seed: int) -> None:
        """Reseeds the task/goal sampling and every Meta-World env's own RNG."""
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self._seed = int(seed)
        self._rng = np.random.default_rng(self._seed)
        self._next_class = self._seed % len(self.task_names)
        for name, env in self._envs.items():
            env.seed(self._env_seed(name))

    def sample(self) -> SampledTask:
        """Picks a class (uniformly, or the next in turn), then one of its goals uniformly;
        sets that task on the class's env."""
        if self._cycle:
            name = self.task_names[self._next_class]
            self._next_class = (self._next_class + 1) % len(self.task_names)
        else:
            name = self.task_names[int(self._rng.integers(len(self.task_names)))]
        goals = self._tasks_by_name[name]
        mw_task = goals[int(self._rng.integers(len(goals)))]
        env = self._env(name)
        env.set_task(mw_task)
        return SampledTask(name=name, task_id=_TASK_IDS[name], env=env)

    def envs(self) -> list[Any]:
        """The Meta-World envs built now, least recently used first."""
        return list(self._envs.values())

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()

    def _env(self, name: str) -> Any:
        env = self._envs.pop(name, None)
        if env is None:
            if self._max_built_envs is not None and len(self._envs) >= self._max_built_envs:
                oldest = next(iter(self._envs))
                self._envs.pop(oldest).close()
            env = self._classes[name]()
            env.seed(self._env_seed(name))
        self._envs[name] = env  # (re)inserted last: the dict's order is recency
        return env

    def _env_seed(self, name: str) -> int:
        # Derived from (seed, task id) so that it does not depend on the order in
        # which classes were first sampled.
        if self._seed is None:
            return random.SystemRandom().randrange(2**31)
        seq = np.random.SeedSequence([self._seed, _TASK_IDS[name]])
        return int(seq.generate_state(1)[0] & 0x7FFFFFFF)
