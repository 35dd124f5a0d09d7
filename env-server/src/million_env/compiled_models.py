"""Compiled MuJoCo models of Meta-World, kept per process: a new env copies one instead of
compiling its XML again.

Building a Meta-World env is almost all MuJoCo's XML compile (``MjModel.from_xml_path``:
160-480 ms for the ML10 classes here, 99 % of a build), while copying a compiled model
(``mj_copyModel`` through ``copy.deepcopy``) takes 9-37 ms. So the process keeps one pristine
*template* per XML file, never handed to an env, and every env gets its own deep copy of it:
an exact, independent model, as a fresh compile would give (Meta-World writes into its
model, e.g. body positions when a task is set, which is why envs never share one). A template
costs what one built env's model does (~21 MB), so the count is bounded (least recently used
templates are dropped) and the server's idle-env budget is set with it (BENCHMARKS.md,
server memory). ``install()`` makes Meta-World's envs load their models here.
"""

from __future__ import annotations

import copy
import os
import threading
from collections import OrderedDict

import mujoco

from million_env.errors import require_count

#: Templates a process keeps by default: as many as ML10 has train classes (loading the
#: benchmark compiles its 5 test classes too, so a few train classes compile again once),
#: a fifth of ML45's (BENCHMARKS.md, server memory).
DEFAULT_COMPILED_MODELS = 10


class CompiledModels:
    """Up to `max_models` compiled models, one per XML file (least recently used dropped).
    Thread-safe: envs are built on worker threads."""

    def __init__(self, max_models: int = DEFAULT_COMPILED_MODELS) -> None:
        self._lock = threading.Lock()
        # (path, mtime_ns, size) -> template: a top-level XML file changed on disk compiles
        # again (files it includes are not checked; Meta-World's are package data).
        self._templates: OrderedDict[tuple[str, int, int], mujoco.MjModel] = OrderedDict()
        self.max_models = max_models
        self.compiles = 0
        self.copies = 0

    @property
    def max_models(self) -> int:
        return self._max_models

    @max_models.setter
    def max_models(self, value: int) -> None:
        value = require_count(value, "compiled models")
        with self._lock:
            self._max_models = value
            self._evict()

    def __len__(self) -> int:
        with self._lock:
            return len(self._templates)

    def counters(self) -> dict[str, float]:
        """GetStats counters: XML compiles and template copies since the start."""
        return {
            "metaworld_models_compiled": float(self.compiles),
            "metaworld_models_copied": float(self.copies),
        }

    def load(self, path: str) -> mujoco.MjModel:
        """A model of the XML file at `path` that the caller owns: a copy of the template,
        compiled first if there is none (with `max_models` 0: compiled, nothing kept)."""
        stat = os.stat(path)
        key = (os.path.realpath(path), stat.st_mtime_ns, stat.st_size)
        with self._lock:
            template = self._templates.get(key)
            if template is not None:
                self._templates.move_to_end(key)
                self.copies += 1
            else:
                self.compiles += 1
        if template is not None:
            return copy.deepcopy(template)
        # Compiled outside the lock: another thread may build another class meanwhile.
        model = mujoco.MjModel.from_xml_path(path)
        with self._lock:
            if self._max_models == 0:
                return model
            self._templates[key] = model
            self._templates.move_to_end(key)
            self._evict()
        return copy.deepcopy(model)

    def _evict(self) -> None:
        while len(self._templates) > self._max_models:
            self._templates.popitem(last=False)


#: The process's templates; `million-env-server --compiled-models` sets their count.
COMPILED_MODELS = CompiledModels()


def _initialize_simulation(env: object) -> tuple[mujoco.MjModel, mujoco.MjData]:
    # Gymnasium's MujocoEnv._initialize_simulation with its compile replaced by a copy.
    model = COMPILED_MODELS.load(env.fullpath)  # type: ignore[attr-defined]
    # MjrContext copies model.vis.global_.off*; only grow the offscreen buffer, as Gymnasium.
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, env.width)  # type: ignore[attr-defined]
    model.vis.global_.offheight = max(model.vis.global_.offheight, env.height)  # type: ignore[attr-defined]
    return model, mujoco.MjData(model)


def install() -> None:
    """Makes every Meta-World env built in this process take its model from
    `COMPILED_MODELS` (idempotent; other MuJoCo envs are left as they are)."""
    from metaworld.sawyer_xyz_env import SawyerXYZEnv

    SawyerXYZEnv._initialize_simulation = _initialize_simulation  # type: ignore[method-assign,assignment]
