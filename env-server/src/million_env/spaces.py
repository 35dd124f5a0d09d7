"""Gymnasium spaces to and from `Space` messages, and batches of observations and
actions to and from tensors, checked against their space."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from million_env._proto import env_pb2
from million_env.errors import invalid
from million_env.tensors import decode_tensor, dtype_to_proto, encode_tensor

SUPPORTED_SPACES = "Box, Discrete, MultiBinary, MultiDiscrete and Dict of those"


class UnsupportedSpaceError(ValueError):
    """The environment uses a space the env API cannot describe."""


def space_to_proto(space: spaces.Space) -> env_pb2.Space:
    if isinstance(space, spaces.Box):
        try:
            dtype = dtype_to_proto(space.dtype)
        except ValueError as err:
            raise UnsupportedSpaceError(str(err)) from err
        return env_pb2.Space(
            box=env_pb2.BoxSpace(
                shape=space.shape,
                dtype=dtype,
                low=encode_tensor(space.low),
                high=encode_tensor(space.high),
            )
        )
    if isinstance(space, spaces.Discrete):
        return env_pb2.Space(discrete=env_pb2.DiscreteSpace(n=int(space.n), start=int(space.start)))
    if isinstance(space, spaces.MultiBinary):
        shape = (space.n,) if np.isscalar(space.n) else tuple(space.n)
        return env_pb2.Space(multi_binary=env_pb2.MultiBinarySpace(shape=shape))
    if isinstance(space, spaces.MultiDiscrete):
        return env_pb2.Space(
            multi_discrete=env_pb2.MultiDiscreteSpace(
                nvec=space.nvec.reshape(-1).tolist(),
                shape=space.shape,
                start=space.start.reshape(-1).tolist(),
            )
        )
    if isinstance(space, spaces.Dict):
        return env_pb2.Space(
            dict=env_pb2.DictSpace(
                entries=[
                    env_pb2.NamedSpace(name=name, space=space_to_proto(sub))
                    for name, sub in space.spaces.items()
                ]
            )
        )
    raise UnsupportedSpaceError(
        f"{type(space).__name__} spaces are not supported; the env API serves {SUPPORTED_SPACES}"
    )


def space_from_proto(message: env_pb2.Space) -> spaces.Space:
    kind = message.WhichOneof("kind")
    if kind == "box":
        low = decode_tensor(message.box.low)
        high = decode_tensor(message.box.high)
        return spaces.Box(low=low, high=high, shape=tuple(message.box.shape), dtype=low.dtype)
    if kind == "discrete":
        return spaces.Discrete(message.discrete.n, start=message.discrete.start)
    if kind == "multi_binary":
        shape = tuple(message.multi_binary.shape)
        return spaces.MultiBinary(shape[0] if len(shape) == 1 else list(shape))
    if kind == "multi_discrete":
        shape = tuple(message.multi_discrete.shape)
        nvec = np.array(message.multi_discrete.nvec, dtype=np.int64).reshape(shape)
        start = np.array(message.multi_discrete.start, dtype=np.int64).reshape(shape)
        return spaces.MultiDiscrete(nvec, dtype=np.int64, start=start)
    if kind == "dict":
        return spaces.Dict({e.name: space_from_proto(e.space) for e in message.dict.entries})
    raise ValueError(f"Space message without a kind: {message}")


def leaf_dtype(space: spaces.Space) -> np.dtype:
    """The dtype values of a non-Dict space travel in."""
    if isinstance(space, spaces.Box):
        return np.dtype(space.dtype)
    if isinstance(space, spaces.MultiBinary):
        return np.dtype(np.int8)
    return np.dtype(np.int64)


def leaf_shape(space: spaces.Space) -> tuple[int, ...]:
    return () if isinstance(space, spaces.Discrete) else tuple(space.shape)


def encode_observations(space: spaces.Space, rows: Sequence[Any]) -> env_pb2.Observation:
    """One Observation with a leading batch dimension from per-environment values."""
    if isinstance(space, spaces.Dict):
        return env_pb2.Observation(
            dict=env_pb2.ObservationDict(
                entries=[
                    env_pb2.NamedObservation(
                        name=name, value=encode_observations(sub, [row[name] for row in rows])
                    )
                    for name, sub in space.spaces.items()
                ]
            )
        )
    dtype = leaf_dtype(space)
    if rows:
        batch = np.stack([np.asarray(row, dtype=dtype) for row in rows])
    else:
        batch = np.zeros((0, *leaf_shape(space)), dtype=dtype)
    return env_pb2.Observation(tensor=encode_tensor(batch))


def zero_observation(space: spaces.Space) -> Any:
    """A placeholder value of the space (zeros) for rows with nothing to report."""
    if isinstance(space, spaces.Dict):
        return {name: zero_observation(sub) for name, sub in space.spaces.items()}
    return np.zeros(leaf_shape(space), dtype=leaf_dtype(space))


def decode_observations(message: env_pb2.Observation) -> Any:
    """A batched array, or a dict of them for a Dict space (the client side)."""
    kind = message.WhichOneof("kind")
    if kind == "tensor":
        return decode_tensor(message.tensor)
    if kind == "dict":
        return {e.name: decode_observations(e.value) for e in message.dict.entries}
    raise ValueError("Observation message without a kind")


def decode_actions(space: spaces.Space, tensor: env_pb2.Tensor, num_envs: int) -> np.ndarray:
    """The [num_envs, ...] action batch, validated against the action space.

    INVALID_ARGUMENT on a wrong dtype, shape or size, a non-finite value, or an
    integer outside a discrete space.
    """
    if isinstance(space, spaces.Dict):
        raise invalid("Dict action spaces are not served")
    expected_dtype = leaf_dtype(space)
    expected_shape = (num_envs, *leaf_shape(space))
    try:
        got_dtype = env_pb2.DType.Name(tensor.dtype)
    except ValueError:
        got_dtype = str(tensor.dtype)
    if tensor.dtype != dtype_to_proto(expected_dtype):
        raise invalid(
            f"action dtype is {got_dtype}; this env takes "
            f"{env_pb2.DType.Name(dtype_to_proto(expected_dtype))}"
        )
    if tuple(tensor.shape) != expected_shape:
        raise invalid(f"action shape is {list(tensor.shape)}; expected {list(expected_shape)}")
    actions = decode_tensor(tensor)
    if actions.dtype.kind == "f":
        if not np.isfinite(actions).all():
            raise invalid("actions must be finite (got NaN or infinity)")
    elif isinstance(space, spaces.Discrete):
        if actions.size and (actions.min() < space.start or actions.max() >= space.start + space.n):
            raise invalid(f"discrete action outside [{space.start}, {space.start + space.n})")
    elif isinstance(space, spaces.MultiDiscrete):
        if actions.size and ((actions < space.start) | (actions >= space.start + space.nvec)).any():
            raise invalid("multi-discrete action outside [start, start + nvec)")
    elif isinstance(space, spaces.MultiBinary):
        if actions.size and ((actions != 0) & (actions != 1)).any():
            raise invalid("multi-binary actions must be 0 or 1")
    # frombuffer arrays are read-only; environments may write into their action.
    return actions.copy()
