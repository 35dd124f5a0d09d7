"""Declared info fields: which info keys an environment sends, typed, and how a
batch of info dicts becomes an `Info` message.

An environment declares its fields in ``env.metadata["info_fields"]`` (a sequence
of `InfoField`). Meta-World envs get theirs from this module; for any other env
the server probes one throwaway instance (reset and one step) and declares the
scalar, array and text values it saw.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from million_env._proto import env_pb2
from million_env.errors import internal
from million_env.tensors import dtype_to_proto, encode_tensor

METADATA_KEY = "info_fields"


@dataclass(frozen=True)
class InfoField:
    """One info key: its numpy dtype (``"str"`` for text), per-env shape and meaning."""

    name: str
    dtype: str
    shape: tuple[int, ...] = ()
    description: str = ""

    @property
    def numpy_dtype(self) -> np.dtype:
        return np.dtype(object) if self.dtype == "str" else np.dtype(self.dtype)

    def to_proto(self) -> env_pb2.InfoFieldSpec:
        return env_pb2.InfoFieldSpec(
            name=self.name,
            dtype=dtype_to_proto(self.numpy_dtype),
            shape=self.shape,
            description=self.description,
        )


METAWORLD_INFO_FIELDS: tuple[InfoField, ...] = (
    InfoField("success", "float64", (), "1.0 when the task's success criterion holds this step"),
    InfoField("near_object", "float64", (), "Meta-World near-object indicator or distance term"),
    InfoField("grasp_success", "float64", (), "1.0 when the object is grasped"),
    InfoField("grasp_reward", "float64", (), "grasp shaping term of the reward"),
    InfoField("in_place_reward", "float64", (), "placing shaping term of the reward"),
    InfoField("obj_to_target", "float64", (), "distance object to target, metres"),
    InfoField("unscaled_reward", "float64", (), "reward before Meta-World's scaling"),
)


def _is_metaworld(env: gym.Env) -> bool:
    from metaworld.sawyer_xyz_env import SawyerXYZEnv

    return isinstance(env.unwrapped, SawyerXYZEnv)


def _field_from_value(name: str, value: Any) -> InfoField | None:
    if isinstance(value, str):
        return InfoField(name, "str", (), "text")
    if isinstance(value, (bool, np.bool_)):
        return InfoField(name, "bool", ())
    if isinstance(value, (int, np.integer)):
        return InfoField(name, "int64", ())
    if isinstance(value, (float, np.floating)):
        return InfoField(name, "float64", ())
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
        try:
            dtype_to_proto(value.dtype)
        except ValueError:
            return InfoField(name, "float64", tuple(value.shape))
        return InfoField(name, value.dtype.name, tuple(value.shape))
    return None


def _probe(make_env: Callable[[], gym.Env]) -> tuple[InfoField, ...]:
    env = make_env()
    try:
        _, reset_info = env.reset(seed=0)
        env.action_space.seed(0)
        *_, step_info = env.step(env.action_space.sample())
    finally:
        env.close()
    fields: dict[str, InfoField] = {}
    for info in (reset_info, step_info):
        for name, value in info.items():
            field = _field_from_value(name, value)
            if field is not None and name not in fields:
                fields[name] = field
    return tuple(fields.values())


def declared_info_fields(env: gym.Env, make_env: Callable[[], gym.Env]) -> tuple[InfoField, ...]:
    """The info fields of ``env``; ``make_env`` builds a throwaway twin to probe."""
    declared = env.metadata.get(METADATA_KEY)
    if declared is not None:
        return tuple(declared)
    if _is_metaworld(env):
        return METAWORLD_INFO_FIELDS
    return _probe(make_env)


def encode_info(
    fields: Sequence[InfoField], infos: Sequence[Mapping[str, Any] | None]
) -> env_pb2.Info:
    """One Info message: a [rows, *shape] tensor per declared field; keys the env sent
    that are not declared are dropped, rows without the key are zero and not present."""
    entries = []
    rows = len(infos)
    for field in fields:
        name = field.name
        present = [info is not None and name in info for info in infos]
        if field.dtype == "str" and not field.shape:
            strings = [
                str(info[name]) if info is not None and set_ else ""
                for info, set_ in zip(infos, present, strict=True)
            ]
            value = env_pb2.Tensor(dtype=env_pb2.DTYPE_STRING, shape=(rows,), strings=strings)
        else:
            if field.dtype == "str":
                values = np.full((rows, *field.shape), "", dtype=object)
            else:
                values = np.zeros((rows, *field.shape), dtype=field.numpy_dtype)
            for row, info in enumerate(infos):
                if info is not None and name in info:
                    values[row] = _info_value(info[name], field)
            value = encode_tensor(values)
        entries.append(env_pb2.InfoEntry(name=name, value=value, present=present))
    return env_pb2.Info(entries=entries)


def _info_value(value: Any, field: InfoField) -> Any:
    try:
        if field.dtype == "str":
            return np.asarray(value, dtype=object).reshape(field.shape)
        if not field.shape:
            scalar = field.numpy_dtype.type(value)
            if np.ndim(scalar) != 0:
                raise ValueError("expected a scalar")
            return scalar
        return np.asarray(value, dtype=field.numpy_dtype).reshape(field.shape)
    except (TypeError, ValueError) as err:
        raise internal(
            f"info field {field.name!r} = {value!r} does not fit its declared "
            f"{field.dtype}{list(field.shape)}: {err}"
        ) from err


def decode_info(message: env_pb2.Info) -> dict[str, Any]:
    """Gymnasium's vector-env info layout: ``info[name]`` is the batched array and
    ``info["_" + name]`` the boolean mask of rows that set it (the client side)."""
    from million_env.tensors import decode_tensor

    out: dict[str, Any] = {}
    for entry in message.entries:
        out[entry.name] = decode_tensor(entry.value)
        out["_" + entry.name] = np.array(entry.present, dtype=bool)
    return out
