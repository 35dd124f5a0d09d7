"""Helpers for the contract tests: the check registry, env cases, and a minimal
wire codec written from the proto alone (independent of the server's code)."""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import grpc
import numpy as np
import pytest
from million_env._proto import env_pb2, env_pb2_grpc

CHECKS_FILE = Path(__file__).with_name("checks.toml")
RUNNER = "pytest"
F = TypeVar("F", bound=Callable[..., Any])

_IMPLEMENTED: set[str] = set()


def check(check_id: str) -> Callable[[F], F]:
    """Marks a test as implementing one check of checks.toml."""

    def mark(test: F) -> F:
        _IMPLEMENTED.add(check_id)
        return pytest.mark.contract_check(check_id)(test)

    return mark


def implemented_checks() -> set[str]:
    return set(_IMPLEMENTED)


def listed_checks(runner: str = RUNNER) -> dict[str, dict[str, Any]]:
    """The checks of checks.toml this runner must implement, by id."""
    with CHECKS_FILE.open("rb") as f:
        checks = tomllib.load(f)["check"]
    return {c["id"]: c for c in checks if runner in c.get("runners", [runner])}


# -- env cases ----------------------------------------------------------------


@dataclass(frozen=True)
class EnvCase:
    """An env id plus its kwargs; written ``ID`` or ``ID:key=value,key=value``."""

    env_id: str
    kwargs: tuple[tuple[str, Any], ...] = field(default=())

    @staticmethod
    def parse(text: str) -> EnvCase:
        env_id, _, rest = text.partition(":")
        pairs = []
        for item in filter(None, rest.split(",")):
            key, sep, raw = item.partition("=")
            if not sep:
                raise ValueError(f"--env {text!r}: expected key=value, got {item!r}")
            pairs.append((key.strip(), _parse_scalar(raw.strip())))
        return EnvCase(env_id.strip(), tuple(pairs))

    def __str__(self) -> str:
        extra = ",".join(f"{k}={v}" for k, v in self.kwargs)
        return f"{self.env_id}:{extra}" if extra else self.env_id

    def proto_kwargs(self) -> dict[str, env_pb2.Value]:
        return {key: to_value(value) for key, value in self.kwargs}


def _parse_scalar(raw: str) -> Any:
    if raw in ("true", "false"):
        return raw == "true"
    for cast in (int, float):
        try:
            return cast(raw)
        except ValueError:
            pass
    return raw


def to_value(value: Any) -> env_pb2.Value:
    if isinstance(value, bool):
        return env_pb2.Value(bool_value=value)
    if isinstance(value, int):
        return env_pb2.Value(int_value=value)
    if isinstance(value, float):
        return env_pb2.Value(float_value=value)
    return env_pb2.Value(string_value=str(value))


# -- wire codec ---------------------------------------------------------------

NUMPY_DTYPES = {
    env_pb2.DTYPE_FLOAT32: np.dtype("<f4"),
    env_pb2.DTYPE_FLOAT64: np.dtype("<f8"),
    env_pb2.DTYPE_INT8: np.dtype("i1"),
    env_pb2.DTYPE_INT16: np.dtype("<i2"),
    env_pb2.DTYPE_INT32: np.dtype("<i4"),
    env_pb2.DTYPE_INT64: np.dtype("<i8"),
    env_pb2.DTYPE_UINT8: np.dtype("u1"),
    env_pb2.DTYPE_BOOL: np.dtype("?"),
}
PROTO_DTYPES = {dt: code for code, dt in NUMPY_DTYPES.items()}


def decode(tensor: env_pb2.Tensor) -> np.ndarray:
    shape = tuple(tensor.shape)
    if tensor.dtype == env_pb2.DTYPE_STRING:
        assert not tensor.data
        return np.array(list(tensor.strings), dtype=object).reshape(shape)
    return np.frombuffer(tensor.data, dtype=NUMPY_DTYPES[tensor.dtype]).reshape(shape)


def encode(array: np.ndarray) -> env_pb2.Tensor:
    array = np.ascontiguousarray(array)
    return env_pb2.Tensor(
        dtype=PROTO_DTYPES[array.dtype],
        shape=array.shape,
        data=array.tobytes(),
    )


def space_leaves(
    space: env_pb2.Space, path: str = ""
) -> Iterator[tuple[str, env_pb2.Space]]:
    """(path, leaf space) for every non-Dict space, Dict entries in declared order."""
    if space.WhichOneof("kind") == "dict":
        for entry in space.dict.entries:
            yield from space_leaves(entry.space, f"{path}/{entry.name}")
    else:
        yield path, space


def observation_leaves(
    obs: env_pb2.Observation, path: str = ""
) -> Iterator[tuple[str, env_pb2.Tensor]]:
    if obs.WhichOneof("kind") == "dict":
        for entry in obs.dict.entries:
            yield from observation_leaves(entry.value, f"{path}/{entry.name}")
    else:
        yield path, obs.tensor


def observation_arrays(obs: env_pb2.Observation) -> dict[str, np.ndarray]:
    return {path: decode(t) for path, t in observation_leaves(obs)}


def leaf_dtype_and_shape(space: env_pb2.Space) -> tuple[int, tuple[int, ...]]:
    kind = space.WhichOneof("kind")
    if kind == "box":
        return space.box.dtype, tuple(space.box.shape)
    if kind == "discrete":
        return env_pb2.DTYPE_INT64, ()
    if kind == "multi_binary":
        return env_pb2.DTYPE_INT8, tuple(space.multi_binary.shape)
    if kind == "multi_discrete":
        return env_pb2.DTYPE_INT64, tuple(space.multi_discrete.shape)
    raise AssertionError(f"unexpected leaf space kind {kind}")


def random_actions(
    space: env_pb2.Space, num_envs: int, rng: np.random.Generator
) -> np.ndarray:
    """A valid random action batch for the action space."""
    kind = space.WhichOneof("kind")
    if kind == "box":
        low, high = decode(space.box.low), decode(space.box.high)
        dtype = NUMPY_DTYPES[space.box.dtype]
        shape = (num_envs, *space.box.shape)
        if dtype.kind == "f":
            lo = np.where(np.isfinite(low), low, -1.0)
            hi = np.where(np.isfinite(high), high, 1.0)
            return rng.uniform(lo, hi, size=shape).astype(dtype)
        return rng.integers(low, high, size=shape, endpoint=True).astype(dtype)
    if kind == "discrete":
        start, n = space.discrete.start, space.discrete.n
        return rng.integers(start, start + n, size=num_envs).astype(np.int64)
    if kind == "multi_binary":
        return rng.integers(0, 2, size=(num_envs, *space.multi_binary.shape)).astype(
            np.int8
        )
    if kind == "multi_discrete":
        shape = tuple(space.multi_discrete.shape)
        nvec = np.array(space.multi_discrete.nvec).reshape(shape)
        start = np.array(space.multi_discrete.start).reshape(shape)
        return (start + rng.integers(0, nvec, size=(num_envs, *shape))).astype(np.int64)
    raise AssertionError(f"unexpected action space kind {kind}")


# -- calls ----------------------------------------------------------------------


class Api:
    """Thin typed calls on one channel, each checking nothing but transport."""

    def __init__(self, address: str) -> None:
        self.channel = grpc.insecure_channel(address)
        self.stub = env_pb2_grpc.EnvServiceStub(self.channel)

    def make(
        self,
        case: EnvCase,
        num_envs: int = 2,
        mode: int = env_pb2.AUTORESET_MODE_UNSPECIFIED,
    ) -> env_pb2.MakeResponse:
        return self.stub.Make(
            env_pb2.MakeRequest(
                env_id=case.env_id,
                kwargs=case.proto_kwargs(),
                num_envs=num_envs,
                autoreset_mode=mode,
            ),
            timeout=300,
        )

    def reset(
        self,
        handle: str,
        seeds: list[int] | None = None,
        indices: list[int] | None = None,
    ) -> env_pb2.ResetResponse:
        return self.stub.Reset(
            env_pb2.ResetRequest(
                handle=handle, seeds=seeds or [], env_indices=indices or []
            ),
            timeout=120,
        )

    def step(self, handle: str, actions: np.ndarray) -> env_pb2.StepResponse:
        return self.stub.Step(
            env_pb2.StepRequest(handle=handle, action=encode(actions)), timeout=120
        )

    def close(self, handle: str) -> None:
        self.stub.Close(env_pb2.CloseRequest(handle=handle), timeout=60)

    def stats(self) -> dict[str, float]:
        return dict(self.stub.GetStats(env_pb2.GetStatsRequest(), timeout=30).counters)


def expect_status(code: grpc.StatusCode, call: Callable[[], Any]) -> grpc.RpcError:
    """Runs a call that must fail with ``code``; returns the error."""
    with pytest.raises(grpc.RpcError) as caught:
        call()
    err = caught.value
    assert err.code() == code, (
        f"expected {code.name}, got {err.code().name}: {err.details()}"
    )
    assert err.details(), "an error must carry a message"
    return err
