"""Three of Meta-World's hot spots done without their Python overhead, bit for bit the same.

A profile of Meta-World v3 stepping ML10's train tasks in-process (py-spy, BENCHMARKS.md)
found 22 % of the step in the gripper-contact test and, on a served ML1-reach run, 14 % of
the env server's samples in the object quaternion, against ~24 % for the MuJoCo step itself:

- **The gripper-contact test** (``SawyerXYZEnv.touching_object``, which the reward of 14
  classes calls every step, push, pick-place and sweep among ML10's) walks
  ``data.contact`` in Python twice, building an object per contact: ~180 µs a call. The
  stand-in selects the same contacts with array masks and sums their forces in the same
  order: ~5 µs.
- **The object quaternion**: 22 classes build it with scipy's
  ``Rotation.from_matrix(geom_xmat).as_quat()``, which validates and converts one 3x3
  matrix through scipy's batched machinery (30-135 µs), while the arithmetic is a dozen
  float operations. The stand-in for ``Rotation`` in those modules does scipy's arithmetic
  (the branch on the largest of the diagonal and the trace, then a division by the norm) on
  Python floats in scipy's order. A matrix that is not a right-handed orthonormal one to
  1e-13, which MuJoCo never gives, goes to scipy itself, so its checks and its
  orthogonalisation still apply.
- **The reset** (``SawyerXYZEnv.reset``) runs the class's ``reset_model``, and with it
  ``_reset_hand``'s 250 physics steps, twice: once itself, then again inside Gymnasium's
  ``MujocoEnv.reset`` after ``mj_resetData`` has thrown the first one's simulation state away.
  The first call does leave something behind: skipping it changes the trajectories of 15 of
  the 50 classes after a new task (window-open, for one, moves its window body in the model
  to the task's position there), so the first reset after ``set_task`` keeps
  Meta-World's two calls; later resets of the same task, whose model already holds the task,
  make the second call only. A MILLION episode resets its task four times (before the
  instructions and before each of three trials), so it makes 5 ``reset_model`` calls
  instead of 8.

All three give the same results to the last bit (the tests compare them with Meta-World's own
code on random rotations, edge cases and every patched class's trajectories, grasps
included). ``install()`` puts them in place for every Meta-World env of the process;
``million-env-server --no-fast-paths`` keeps Meta-World's own code, for timing the two.
"""

from __future__ import annotations

import math
import sys
import threading
from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium.envs.mujoco.mujoco_env import MujocoEnv
from scipy.spatial.transform import Rotation

#: Largest deviation of M Mᵀ from the identity handled here; beyond it scipy decides.
ORTHONORMAL_TOLERANCE = 1e-13

_LOCK = threading.Lock()


def quaternion_from_matrix(matrix: Any) -> npt.NDArray[np.float64]:
    """``Rotation.from_matrix(matrix).as_quat()`` for one 3x3 rotation: (x, y, z, w)."""
    array = np.asarray(matrix)
    if array.shape != (3, 3) or array.dtype != np.float64:
        return scipy_quaternion(array)
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = array.tolist()
    if not _proper_rotation(m00, m01, m02, m10, m11, m12, m20, m21, m22):
        return scipy_quaternion(array)
    trace = m00 + m11 + m22
    # numpy's argmax over (m00, m11, m22, trace): the first of equal maxima wins.
    choice, largest = 0, m00
    if m11 > largest:
        choice, largest = 1, m11
    if m22 > largest:
        choice, largest = 2, m22
    if trace > largest:
        choice = 3
    if choice == 0:
        x, y, z, w = 1 - trace + 2 * m00, m10 + m01, m20 + m02, m21 - m12
    elif choice == 1:
        x, y, z, w = m01 + m10, 1 - trace + 2 * m11, m21 + m12, m02 - m20
    elif choice == 2:
        x, y, z, w = m02 + m20, m12 + m21, 1 - trace + 2 * m22, m10 - m01
    else:
        x, y, z, w = m21 - m12, m02 - m20, m10 - m01, 1 + trace
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    return np.array((x / norm, y / norm, z / norm, w / norm))


def scipy_quaternion(matrix: Any) -> npt.NDArray[np.float64]:
    """scipy's own answer, for what the fast path does not handle."""
    return np.asarray(Rotation.from_matrix(matrix).as_quat(), dtype=np.float64)


def _proper_rotation(*m: float) -> bool:
    """Orthonormal to `ORTHONORMAL_TOLERANCE` and right-handed (scipy refuses det <= 0)."""
    determinant = (
        m[0] * (m[4] * m[8] - m[5] * m[7])
        - m[1] * (m[3] * m[8] - m[5] * m[6])
        + m[2] * (m[3] * m[7] - m[4] * m[6])
    )
    if not determinant > 0:
        return False
    rows = (m[0:3], m[3:6], m[6:9])
    for i in range(3):
        for j in range(i, 3):
            dot = rows[i][0] * rows[j][0] + rows[i][1] * rows[j][1] + rows[i][2] * rows[j][2]
            if abs(dot - (1.0 if i == j else 0.0)) > ORTHONORMAL_TOLERANCE:
                return False
    return True


class _Quaternion:
    __slots__ = ("_matrix",)

    def __init__(self, matrix: Any) -> None:
        self._matrix = matrix

    def as_quat(self) -> npt.NDArray[np.float64]:
        return quaternion_from_matrix(self._matrix)


class MatrixRotation:
    """What Meta-World's env modules use of scipy's ``Rotation``: ``from_matrix(m).as_quat()``.
    Any other use fails loudly (AttributeError) instead of giving a different result."""

    @staticmethod
    def from_matrix(matrix: Any) -> _Quaternion:
        return _Quaternion(matrix)


def env_modules() -> list[Any]:
    """The Meta-World v3 env modules that name scipy's ``Rotation`` (or the stand-in)."""
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    modules = {sys.modules[cls.__module__] for cls in ALL_V3_ENVIRONMENTS.values()}
    return sorted(
        (m for m in modules if getattr(m, "Rotation", None) in (Rotation, MatrixRotation)),
        key=lambda m: m.__name__,
    )


def touching_object(env: Any, object_geom_id: int) -> bool:
    """``SawyerXYZEnv.touching_object``: both gripper pads press on the object (the sum of
    the normal forces of their contacts with it is positive), with the contacts chosen by
    masks over ``data.contact``'s arrays instead of a Python loop over its entries."""
    leftpad = env.data.geom("leftpad_geom").id
    rightpad = env.data.geom("rightpad_geom").id
    contact = env.data.contact
    geom1, geom2 = contact.geom1, contact.geom2
    on_object = (geom1 == object_geom_id) | (geom2 == object_geom_id)
    addresses = contact.efc_address
    force = env.data.efc_force
    # Python's sum over the contacts in their order, as Meta-World adds them.
    left = sum(force[a] for a in addresses[on_object & ((geom1 == leftpad) | (geom2 == leftpad))])
    right = sum(
        force[a] for a in addresses[on_object & ((geom1 == rightpad) | (geom2 == rightpad))]
    )
    return 0 < left and 0 < right


#: The env attribute naming the task vector the env's model was last fully reset for.
_RESET_FOR = "_million_model_reset_for"


def reset(
    env: Any, seed: int | None = None, options: dict[str, Any] | None = None
) -> tuple[npt.NDArray[np.float64], dict[str, Any]]:
    """``SawyerXYZEnv.reset``, with one ``reset_model`` call where Meta-World makes two, once
    the env's model holds its task: after a reset with Meta-World's code since the task's
    random vector was set and frozen (``set_task`` sets a new array, so a new task or a
    changed vector takes Meta-World's path again)."""
    task_vector = env._last_rand_vec
    if not (
        env._freeze_rand_vec
        and task_vector is not None
        and env.__dict__.get(_RESET_FOR) is task_vector
    ):
        obs, info = _METAWORLD_RESET(env, seed=seed, options=options)
        env.__dict__[_RESET_FOR] = task_vector if env._freeze_rand_vec else None
        return obs, info
    env.curr_path_length = 0
    obs, info = MujocoEnv.reset(env)
    env._prev_obs = obs[:18].copy()
    obs[18:36] = env._prev_obs
    return obs.astype(np.float64), info


_METAWORLD_TOUCHING_OBJECT: Any = None
_METAWORLD_RESET: Any = None

#: The process's choice, read by `install()`; ``million-env-server --no-fast-paths`` clears
#: it (for timing the two against each other: the numbers are the same).
ENABLED = True


def install(enabled: bool | None = None, *, fast_reset: bool | None = None) -> int:
    """Puts the fast paths in place, or Meta-World's own code back when `enabled` (default:
    `ENABLED`) is false; idempotent. `fast_reset` (default: as `enabled`) chooses the reset
    apart, so the reset's share can be timed with the other fast paths kept. Returns how many
    env modules' ``Rotation`` it set."""
    global _METAWORLD_TOUCHING_OBJECT, _METAWORLD_RESET
    from metaworld.sawyer_xyz_env import SawyerXYZEnv

    use_fast = ENABLED if enabled is None else enabled
    use_fast_reset = use_fast if fast_reset is None else fast_reset
    with _LOCK:
        if _METAWORLD_TOUCHING_OBJECT is None:
            _METAWORLD_TOUCHING_OBJECT = SawyerXYZEnv.touching_object
            _METAWORLD_RESET = SawyerXYZEnv.reset
        SawyerXYZEnv.touching_object = (  # type: ignore[method-assign]
            touching_object if use_fast else _METAWORLD_TOUCHING_OBJECT
        )
        SawyerXYZEnv.reset = reset if use_fast_reset else _METAWORLD_RESET  # type: ignore[method-assign]
        modules = env_modules()
        for module in modules:
            module.Rotation = MatrixRotation if use_fast else Rotation
        return len(modules)
