"""The compiled-model cache: a Meta-World env built from a copied model is the env a fresh
compile gives, its model is its own, and the cache keeps at most its count."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from million_env import compiled_models
from million_env.compiled_models import COMPILED_MODELS, CompiledModels
from million_env.metaworld_tasks import load_benchmark

TINY_XML = """<mujoco><worldbody><body name="b" pos="0 0 {z}"><joint type="free"/>
<geom size="0.1"/></body></worldbody></mujoco>"""


@pytest.fixture
def tiny_xml(tmp_path: Path) -> Iterator[Path]:
    paths = []
    for i in range(3):
        path = tmp_path / f"tiny{i}.xml"
        path.write_text(TINY_XML.format(z=i + 1))
        paths.append(path)
    yield tmp_path


@pytest.fixture
def process_cache() -> Iterator[CompiledModels]:
    """The process's cache, installed, with its count restored afterwards."""
    compiled_models.install()
    before = COMPILED_MODELS.max_models
    yield COMPILED_MODELS
    COMPILED_MODELS.max_models = before


def rollout(env_class: type, task: object, seed: int, steps: int = 40) -> np.ndarray:
    env = env_class()
    try:
        env.seed(seed)
        env.set_task(task)
        observations = [env.reset()[0]]
        actions = np.random.default_rng(seed).uniform(-1, 1, (steps, 4)).astype(np.float32)
        for action in actions:
            observations.append(env.step(action)[0])
        return np.stack(observations)
    finally:
        env.close()


@pytest.mark.parametrize("name", ["reach-v3", "push-v3", "door-open-v3"])
def test_a_copied_model_steps_exactly_as_a_compiled_one(
    name: str, process_cache: CompiledModels
) -> None:
    bench = load_benchmark("ML10", None, 42)
    env_class = dict(bench.train_classes)[name]
    task = next(t for t in bench.train_tasks if t.env_name == name)
    process_cache.max_models = 0
    compiled_before = process_cache.compiles
    fresh = rollout(env_class, task, seed=7)
    assert process_cache.compiles == compiled_before + 1
    process_cache.max_models = 4
    rollout(env_class, task, seed=3)  # compiles the template
    copies_before = process_cache.copies
    copied = rollout(env_class, task, seed=7)
    assert process_cache.copies == copies_before + 1
    np.testing.assert_array_equal(copied, fresh)


def test_every_env_owns_its_model(process_cache: CompiledModels) -> None:
    """Meta-World writes into its model (body positions when a task is set), so a change to
    one env's model must reach neither the template nor an env built after it."""
    process_cache.max_models = 4
    bench = load_benchmark("ML10", None, 42)
    env_class = dict(bench.train_classes)["reach-v3"]
    first, second = env_class(), env_class()
    try:
        assert first.model is not second.model
        original = second.model.body_pos.copy()
        first.model.body_pos[:] += 1.0
        np.testing.assert_array_equal(second.model.body_pos, original)
        third = env_class()
        try:
            np.testing.assert_array_equal(third.model.body_pos, original)
        finally:
            third.close()
    finally:
        first.close()
        second.close()


def test_the_cache_keeps_the_most_recently_used_models(tiny_xml: Path) -> None:
    cache = CompiledModels(max_models=2)
    a, b, c = (str(tiny_xml / f"tiny{i}.xml") for i in range(3))
    for path in (a, b, a, c, a, b):
        cache.load(path)
    # a, b compiled; a copied; c compiled (b dropped); a copied; b compiled again.
    assert (cache.compiles, cache.copies) == (4, 2)
    assert len(cache) == 2
    first, second = cache.load(a), cache.load(a)
    assert first is not second
    first.body_pos[1, 2] = 9.0
    assert second.body_pos[1, 2] == 1.0 and cache.load(a).body_pos[1, 2] == 1.0
    cache.max_models = 1
    assert len(cache) == 1


def test_a_changed_file_compiles_again(tiny_xml: Path) -> None:
    cache = CompiledModels(max_models=4)
    path = tiny_xml / "tiny0.xml"
    assert cache.load(str(path)).body_pos[1, 2] == 1.0
    path.write_text(TINY_XML.format(z=5))
    stat = path.stat()
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    assert cache.load(str(path)).body_pos[1, 2] == 5.0
    assert cache.compiles == 2


def test_no_models_kept_with_count_zero(tiny_xml: Path) -> None:
    cache = CompiledModels(max_models=0)
    path = str(tiny_xml / "tiny1.xml")
    cache.load(path)
    cache.load(path)
    assert (cache.compiles, cache.copies, len(cache)) == (2, 0, 0)
    with pytest.raises(ValueError, match="non-negative"):
        cache.max_models = -1
