"""Meta-World's fast paths give what Meta-World's own code gives, bit for bit: the object
quaternion on random rotations, on the branches' edge cases, on matrices scipy must repair or
refuse, and in the observations of every class that uses it; the gripper-contact test in
every class whose reward uses it, along scripted grasps; the reset in every class, over new
tasks and repeated resets of one, and under the MILLION protocol."""

from __future__ import annotations

import contextlib
import inspect
import subprocess
import sys
from collections.abc import Iterator
from typing import Any

import gymnasium
import numpy as np
import pytest
from metaworld.env_dict import ALL_V3_ENVIRONMENTS
from metaworld.sawyer_xyz_env import SawyerXYZEnv
from scipy.spatial.transform import Rotation

from million_env import metaworld_fast_paths
from million_env.metaworld_fast_paths import MatrixRotation, quaternion_from_matrix, touching_object
from million_env.metaworld_tasks import load_benchmark


def scipy_quaternion(matrix: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(matrix).as_quat()


@pytest.fixture
def no_fallback(monkeypatch: pytest.MonkeyPatch) -> None:
    """Makes the hand-over to scipy fail: a test with it proves the fast path itself ran."""

    def refuse(matrix: object) -> np.ndarray:
        raise AssertionError(f"the fast path handed {matrix!r} to scipy")

    monkeypatch.setattr(metaworld_fast_paths, "scipy_quaternion", refuse)


def test_random_rotations_match_scipy_bit_for_bit(no_fallback: None) -> None:
    matrices = Rotation.random(20_000, rng=7).as_matrix()
    mismatched = [
        m for m in matrices if not np.array_equal(quaternion_from_matrix(m), scipy_quaternion(m))
    ]
    assert not mismatched, f"{len(mismatched)} of {len(matrices)} differ, e.g. {mismatched[0]}"


@pytest.mark.parametrize(
    "rotation",
    [
        Rotation.identity(),
        # Half turns: the trace is -1 and one diagonal entry is the largest (each branch).
        Rotation.from_euler("x", 180, degrees=True),
        Rotation.from_euler("y", 180, degrees=True),
        Rotation.from_euler("z", 180, degrees=True),
        # Ties between diagonal entries: the first of equal maxima decides, as numpy's argmax.
        Rotation.from_rotvec(np.pi * np.array([1.0, 1.0, 0.0]) / np.sqrt(2)),
        Rotation.from_rotvec(np.pi * np.array([0.0, 1.0, 1.0]) / np.sqrt(2)),
        Rotation.from_rotvec(np.pi * np.ones(3) / np.sqrt(3)),
        Rotation.from_euler("xyz", [90, 90, 0], degrees=True),
    ],
)
def test_edge_cases_match_scipy(rotation: Rotation, no_fallback: None) -> None:
    matrix = rotation.as_matrix()
    assert np.array_equal(quaternion_from_matrix(matrix), scipy_quaternion(matrix))


def test_a_matrix_that_is_not_a_rotation_is_left_to_scipy() -> None:
    # Not 3x3 float64: scipy's own answer (and its errors), not a reshaped guess.
    flat = Rotation.from_euler("z", 30, degrees=True).as_matrix().reshape(9)
    with pytest.raises(ValueError):
        quaternion_from_matrix(flat)
    skewed = Rotation.from_euler("z", 30, degrees=True).as_matrix() * 1.01
    # scipy orthogonalises it first; the stand-in hands it over and gives the same.
    assert np.array_equal(quaternion_from_matrix(skewed), scipy_quaternion(skewed))
    reflection = np.diag([1.0, 1.0, -1.0])
    with pytest.raises(ValueError, match="determinant"):
        quaternion_from_matrix(reflection)


def test_any_other_use_of_rotation_fails_loudly() -> None:
    with pytest.raises(AttributeError):
        MatrixRotation.from_euler("x", 90)  # type: ignore[attr-defined]


@pytest.fixture
def fast_paths() -> Iterator[None]:
    """The fast paths installed, and installed again afterwards whatever the test set."""
    metaworld_fast_paths.install(True)
    yield
    metaworld_fast_paths.install(True)


FRESH_PROCESS = """
from metaworld.sawyer_xyz_env import SawyerXYZEnv
from million_env import metaworld_fast_paths as fast
from million_env.registry import make_env
make_env("Meta-World/MT1", {"env_name": "reach-v3"}).close()
modules = fast.env_modules()
print(len(modules), all(m.Rotation is fast.MatrixRotation for m in modules),
      SawyerXYZEnv.touching_object is fast.touching_object)
"""


def test_a_fresh_process_installs_it_when_it_makes_an_env() -> None:
    out = subprocess.run(
        [sys.executable, "-c", FRESH_PROCESS], capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == ["22", "True", "True"]


def test_the_reset_can_be_chosen_apart(fast_paths: None) -> None:
    metaworld_fast_paths.install(True, fast_reset=False)
    assert SawyerXYZEnv.reset is not metaworld_fast_paths.reset
    assert SawyerXYZEnv.touching_object is touching_object
    metaworld_fast_paths.install(False, fast_reset=True)
    assert SawyerXYZEnv.reset is metaworld_fast_paths.reset
    assert SawyerXYZEnv.touching_object is not touching_object
    metaworld_fast_paths.install(True)
    assert SawyerXYZEnv.reset is metaworld_fast_paths.reset


@contextlib.contextmanager
def task_env(name: str, seed: int) -> Iterator[Any]:
    """A Meta-World env of class `name` with its first ML1 goal set, closed afterwards."""
    bench = load_benchmark("ML1", name, 0)
    env = dict(bench.train_classes)[name]()
    try:
        env.seed(seed)
        env.set_task(bench.train_tasks[0])
        yield env
    finally:
        env.close()


PATCHED_CLASSES = sorted(
    name
    for name, cls in ALL_V3_ENVIRONMENTS.items()
    if cls.__module__ in {m.__name__ for m in metaworld_fast_paths.env_modules()}
)


@pytest.mark.parametrize("name", PATCHED_CLASSES)
def test_observations_match_scipys_in_every_patched_class(
    name: str, fast_paths: None, no_fallback: None
) -> None:
    with task_env(name, seed=3) as env:
        env.reset()
        actions = np.random.default_rng(3).uniform(-1, 1, (25, 4)).astype(np.float32)
        for action in actions:
            env.step(action)
            metaworld_fast_paths.install(False)
            assert sys.modules[type(env).__module__].Rotation is Rotation
            with_scipy = env._get_obs()
            metaworld_fast_paths.install(True)
            assert sys.modules[type(env).__module__].Rotation is MatrixRotation
            with_stand_in = env._get_obs()
            assert np.array_equal(with_stand_in, with_scipy)


CONTACT_CLASSES = sorted(
    name
    for name, cls in ALL_V3_ENVIRONMENTS.items()
    if "touching_main_object" in inspect.getsource(sys.modules[cls.__module__])
)


def grasp_actions(obs: np.ndarray, step: int) -> np.ndarray:
    """Over the object, down onto it, close the gripper, lift: contacts of both pads."""
    hand, obj = obs[0:3], obs[4:7]
    if step < 40:
        target, grip = obj + np.array([0.0, 0.0, 0.08]), -1.0
    elif step < 80:
        target, grip = obj, -1.0
    elif step < 110:
        target, grip = hand, 1.0
    else:
        target, grip = hand + np.array([0.0, 0.0, 0.05]), 1.0
    return np.append(np.clip(10 * (target - hand), -1, 1), grip).astype(np.float32)


@pytest.mark.parametrize("name", CONTACT_CLASSES)
def test_the_contact_test_matches_metaworlds_along_a_grasp(name: str, fast_paths: None) -> None:
    metaworld_fast_paths.install(False)
    metaworld_code = SawyerXYZEnv.touching_object
    assert metaworld_code is not touching_object
    metaworld_fast_paths.install(True)
    assert SawyerXYZEnv.touching_object is touching_object
    with task_env(name, seed=5) as env:
        obs, _ = env.reset()
        touching = 0
        for step in range(150):
            obs = env.step(grasp_actions(obs, step))[0]
            object_id = env._get_id_main_object()
            expected = metaworld_code(env, object_id)
            assert touching_object(env, object_id) == expected, f"step {step}"
            touching += bool(expected)
    # The grasp must reach states where the answer is yes, or the comparison proves little.
    if name in ("pick-place-v3", "pick-place-wall-v3", "push-v3", "shelf-place-v3"):
        assert touching > 0


ALL_CLASSES = sorted(ALL_V3_ENVIRONMENTS)


def class_and_tasks(name: str) -> tuple[Any, list[Any]]:
    """The class `name` and its ML45 tasks (ML45's two splits hold all 50 classes; it is built
    once per process, where ML1 would be built once per class)."""
    bench = load_benchmark("ML45", None, 0)
    for classes, tasks in (
        (bench.train_classes, bench.train_tasks),
        (bench.test_classes, bench.test_tasks),
    ):
        if name in classes:
            return classes[name], [t for t in tasks if t.env_name == name]
    raise KeyError(name)


def count_reset_model_calls(env: Any) -> list[int]:
    """Counts the env's `reset_model` calls in the returned list's one entry."""
    calls = [0]
    own = env.reset_model

    def counted() -> Any:
        calls[0] += 1
        return own()

    env.reset_model = counted
    return calls


def in_turn(fast: bool, env: Any, method: str, *args: Any, **kwargs: Any) -> Any:
    """`env.method(*args, **kwargs)` with the fast paths in place or Meta-World's code, as
    `fast` says (the method is looked up after the choice, so it is the chosen one)."""
    metaworld_fast_paths.install(fast)
    return getattr(env, method)(*args, **kwargs)


@pytest.mark.parametrize("name", ALL_CLASSES)
def test_resets_match_metaworlds_in_every_class(name: str, fast_paths: None) -> None:
    """Two envs of the class, one reset by the fast path and one by Meta-World's code, given
    the same two tasks, two resets each with random steps between: every observation,
    reward and success flag equal; the fast path calls `reset_model` 2 + 1 times a task
    where Meta-World calls it 2 + 2."""
    cls, tasks = class_and_tasks(name)
    envs = {True: cls(), False: cls()}
    calls = {fast: count_reset_model_calls(env) for fast, env in envs.items()}
    actions = np.random.default_rng(7).uniform(-1, 1, (10, 4)).astype(np.float32)
    try:
        for task in tasks[:2]:
            for env in envs.values():
                env.seed(11)
                env.set_task(task)
            for _reset in range(2):
                first = {fast: in_turn(fast, env, "reset")[0] for fast, env in envs.items()}
                assert np.array_equal(first[True], first[False])
                for action in actions:
                    steps = {fast: in_turn(fast, env, "step", action) for fast, env in envs.items()}
                    (obs, reward, _, _, info), (mw_obs, mw_reward, _, _, mw_info) = (
                        steps[True],
                        steps[False],
                    )
                    assert np.array_equal(obs, mw_obs)
                    assert reward == mw_reward
                    assert info["success"] == mw_info["success"]
    finally:
        for env in envs.values():
            env.close()
    assert calls[True][0] == 2 * (2 + 1)
    assert calls[False][0] == 2 * (2 + 2)


def test_million_episodes_match_metaworlds_resets(fast_paths: None) -> None:
    """The MILLION protocol on reach, whose puck `object_position="centre"` moves after each
    reset: the same episodes, number for number, with either reset."""
    from million_env.million import register_envs

    register_envs()
    envs = {
        fast: gymnasium.make(
            "million/ML10-train", tasks=["reach-v3"], object_position="centre"
        ).unwrapped
        for fast in (True, False)
    }
    actions = np.random.default_rng(3).uniform(-1, 1, (2_000, 4)).astype(np.float32)
    try:
        for fast, env in envs.items():
            in_turn(fast, env, "reset", seed=5)
        trial_ends = 0
        for action in actions:
            steps = {fast: in_turn(fast, env, "step", action) for fast, env in envs.items()}
            (obs, reward, done, _, info), (mw_obs, mw_reward, _, _, _) = steps[True], steps[False]
            for key in obs:
                assert np.array_equal(obs[key], mw_obs[key]), key
            assert reward == mw_reward
            trial_ends += info["trial_end"]
            if done:
                for fast, env in envs.items():
                    in_turn(fast, env, "reset")
    finally:
        for env in envs.values():
            env.close()
    assert trial_ends >= 6  # resets within episodes happened, not only the first
