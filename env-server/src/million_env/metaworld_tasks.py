"""Seeded sampling of Meta-World v3 tasks (a task class plus one of its goals).

Meta-World's own ``reset(seed=...)`` does not seed which task or goal comes next,
so this module owns that randomness: one ``numpy.random.Generator`` picks the
class and the goal, and the env of each sampled task is reseeded from the same
generator. The same seed therefore always yields the same sequence of tasks, goals
and reset observations, even though built envs are shared by every sampler of a
process (`BuiltEnvs`).
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import metaworld
import numpy as np
from metaworld.env_dict import MT50_V3

from million_env.errors import require_count

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


def select_classes(
    classes: dict[str, type], benchmark: str, split: str, tasks: Sequence[str] | None
) -> dict[str, type]:
    """The split's classes, or those named in `tasks` (in the split's order): a smaller
    multi-task set of ML10 or ML45, e.g. its goal-dependent tasks."""
    if tasks is None:
        return classes
    where = f"tasks for {benchmark} {split}"
    if benchmark == "ML1":
        raise ValueError(f"{where}: ML1 takes one task class (`task`), not `tasks`")
    if (
        isinstance(tasks, str)
        or not isinstance(tasks, Sequence)
        or not tasks
        or not all(isinstance(name, str) for name in tasks)
    ):
        raise ValueError(f"{where} must be a non-empty list of task names, got {tasks!r}")
    unknown = [name for name in tasks if name not in classes]
    if unknown:
        raise ValueError(f"{where}: {unknown} not in the split; it has {list(classes)}")
    if len(set(tasks)) != len(tasks):
        raise ValueError(f"{where} names a task twice: {list(tasks)}")
    return {name: cls for name, cls in classes.items() if name in tasks}


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


#: Idle built envs a server process keeps by default (see `BuiltEnvs`). A build copies a kept
#: compiled model (`million_env.compiled_models`: ~20 ms of a core instead of ~190 ms), so
#: the memory goes to those instead: with 32 slots serving million/ML10-train, 2 idle envs
#: and 10 kept models peak at 38.7 MB per slot and compile 0.1 times per episode begun,
#: against 39.6 MB and 0.57 compiles with 12 idle envs and no kept models (BENCHMARKS.md,
#: server memory).
DEFAULT_IDLE_ENVS = 2


class BuiltEnvs:
    """The Meta-World envs built in this process, shared by every sampler.

    A built env costs ~20 MB and ~20 ms to build from a kept compiled model (~0.2 s to
    compile one). A sampler holds only the env of its current
    task and gives it back when it samples the next one, so a process holds one env per slot
    in use plus at most `max_idle` idle ones, instead of one per slot per class (ML45, 32
    slots: 48 envs instead of 1,440). When too many are idle, one of the class with the most
    idle copies is closed, which keeps every class at hand for longer than plain LRU.
    Thread-safe: batches step their envs on worker threads.
    """

    def __init__(self, max_idle: int = DEFAULT_IDLE_ENVS) -> None:
        self._lock = threading.Lock()
        self._idle: dict[tuple[Any, ...], list[Any]] = {}
        self.max_idle = max_idle
        self.builds = 0

    @property
    def max_idle(self) -> int:
        return self._max_idle

    @max_idle.setter
    def max_idle(self, value: int) -> None:
        self._max_idle = require_count(value, "idle envs")

    def idle(self) -> int:
        with self._lock:
            return sum(len(envs) for envs in self._idle.values())

    def counters(self) -> dict[str, float]:
        """GetStats counters: envs built since the start, and envs idle now."""
        return {
            "metaworld_envs_built": float(self.builds),
            "metaworld_envs_idle": float(self.idle()),
        }

    def take(self, key: tuple[Any, ...], build: Callable[[], Any]) -> Any:
        """An idle env of `key`, else a new one from `build()` (built outside the lock)."""
        with self._lock:
            envs = self._idle.get(key)
            if envs:
                return envs.pop()
            self.builds += 1
        return build()

    def give_back(self, key: tuple[Any, ...], env: Any) -> None:
        closing = None
        with self._lock:
            self._idle.setdefault(key, []).append(env)
            if sum(len(envs) for envs in self._idle.values()) > self._max_idle:
                fullest = max(self._idle.values(), key=len)
                closing = fullest.pop(0)  # its least recently returned
        if closing is not None:
            closing.close()


#: The process's shared envs; `million-env-server --idle-envs` sets its cap.
BUILT_ENVS = BuiltEnvs()


class MetaWorldTaskSampler:
    """Seeded sampling of a (task class, goal variation) from a Meta-World v3 benchmark split.

    The env of a sampled task comes from the process's `BUILT_ENVS` and goes back there at
    the next `sample()` or `close()`. Because an env may have served another sampler, it is
    reseeded from this sampler's generator at every sample: the same seed gives the same
    tasks, goals and observations whatever else the process runs.

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
        task_order: str = "random",
        built_envs: BuiltEnvs | None = None,
        tasks: Sequence[str] | None = None,
    ) -> None:
        _validate(benchmark, split, task)
        self._cycle = parse_task_order(task_order)
        self._built = BUILT_ENVS if built_envs is None else built_envs
        self._key_prefix = (benchmark, task, benchmark_seed)
        self.benchmark = benchmark
        self.split = split
        bench = load_benchmark(benchmark, task, benchmark_seed)
        classes = bench.train_classes if split == "train" else bench.test_classes
        goals = bench.train_tasks if split == "train" else bench.test_tasks
        self._classes: dict[str, type] = select_classes(dict(classes), benchmark, split, tasks)
        self.task_names: tuple[str, ...] = tuple(self._classes)
        self._tasks_by_name: dict[str, list[Any]] = {name: [] for name in self.task_names}
        for mw_task in goals:
            if mw_task.env_name in self._tasks_by_name:
                self._tasks_by_name[mw_task.env_name].append(mw_task)
        self._held: tuple[str, Any] | None = None
        self._rng = np.random.default_rng()
        self._next_class = 0
        if seed is not None:
            self.seed(seed)

    def seed(self, seed: int) -> None:
        """Restarts the task/goal sequence and the env seeds drawn with it."""
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self._rng = np.random.default_rng(int(seed))
        self._next_class = int(seed) % len(self.task_names)

    def sample(self) -> SampledTask:
        """Picks a class (uniformly, or the next in turn) and one of its goals uniformly;
        returns an env of that class, reseeded, with that task set."""
        if self._cycle:
            name = self.task_names[self._next_class]
            self._next_class = (self._next_class + 1) % len(self.task_names)
        else:
            name = self.task_names[int(self._rng.integers(len(self.task_names)))]
        goals = self._tasks_by_name[name]
        mw_task = goals[int(self._rng.integers(len(goals)))]
        env_seed = int(self._rng.integers(2**31))
        self._give_back()
        env = self._built.take((*self._key_prefix, name), self._classes[name])
        self._held = (name, env)
        env.seed(env_seed)
        env.set_task(mw_task)
        return SampledTask(name=name, task_id=_TASK_IDS[name], env=env)

    def envs(self) -> list[Any]:
        """The env this sampler holds now (empty before the first sample)."""
        return [] if self._held is None else [self._held[1]]

    def close(self) -> None:
        self._give_back()

    def _give_back(self) -> None:
        if self._held is not None:
            name, env = self._held
            self._held = None
            self._built.give_back((*self._key_prefix, name), env)
