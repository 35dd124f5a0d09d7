"""MILLION env ids served by the real env server (a subprocess on a free port),
compared with the same envs made in-process."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import grpc
import gymnasium
import numpy as np
import pytest

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.client import RemoteEnv
from million_env.million import register_envs
from million_env.million.protocol import INFO_FIELDS
from million_env.server_process import running_server
from million_env.tensors import python_to_values


@pytest.fixture(scope="module")
def address(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    log_path: Path = tmp_path_factory.mktemp("million-server") / "server.log"
    with log_path.open("w") as log, running_server(log=log) as served:
        yield served


@pytest.fixture(scope="module")
def stub(address: str) -> Iterator[env_pb2_grpc.EnvServiceStub]:
    with grpc.insecure_channel(address) as channel:
        yield env_pb2_grpc.EnvServiceStub(channel)


def test_all_million_ids_are_listed(stub: env_pb2_grpc.EnvServiceStub) -> None:
    listed = {e.env_id: e.description for e in stub.ListEnvs(env_pb2.ListEnvsRequest()).envs}
    for env_id, description in register_envs().items():
        assert listed[env_id] == description


def test_spec_declares_the_protocol_layout(stub: env_pb2_grpc.EnvServiceStub) -> None:
    made = stub.Make(
        env_pb2.MakeRequest(
            env_id="million/PointGoal", kwargs=python_to_values({"num_goals": 8}), num_envs=2
        )
    )
    try:
        entries = made.spec.observation_space.dict.entries
        assert [e.name for e in entries] == [
            "state",
            "word",
            "time",
            "phase",
            "trial_success",
            "task_id",
            "prev_reward",
        ]
        assert entries[0].space.box.dtype == env_pb2.DTYPE_FLOAT64
        assert list(entries[0].space.box.shape) == [39]
        assert entries[1].space.box.dtype == env_pb2.DTYPE_FLOAT32
        assert list(entries[1].space.box.shape) == [50]
        assert entries[4].space.box.dtype == env_pb2.DTYPE_FLOAT32
        assert list(entries[4].space.box.shape) == [1]
        assert entries[5].space.discrete.n == 1
        fields = {f.name: f for f in made.spec.info_fields}
        assert list(fields) == [f.name for f in INFO_FIELDS]
        assert fields["instruction"].dtype == env_pb2.DTYPE_STRING
        assert fields["success"].dtype == env_pb2.DTYPE_BOOL
        assert list(fields["goal"].shape) == [3]
        # The spec lists every protocol kwarg, defaults included.
        made_with = made.spec.kwargs
        assert made_with["num_goals"].int_value == 8
        assert made_with["trial_len"].int_value == 25
        assert made_with["instructions"].bool_value is True
        assert made_with["instruction_set"].string_value == "train"
    finally:
        stub.Close(env_pb2.CloseRequest(handle=made.handle))


def _episodes(env: gymnasium.Env, seed: int, episodes: int) -> list[tuple[Any, ...]]:
    rng = np.random.default_rng(seed)
    out: list[tuple[Any, ...]] = []
    for episode in range(episodes):
        obs, info = env.reset(seed=seed if episode == 0 else None)
        out.append(_record(obs, 0.0, False, info))
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(
                rng.uniform(-1, 1, size=4).astype(np.float32)
            )
            done = terminated or truncated
            out.append(_record(obs, reward, terminated, info))
    return out


def _record(obs: dict[str, Any], reward: float, terminated: bool, info: dict[str, Any]) -> tuple:
    values = tuple(np.asarray(obs[k]).tobytes() for k in sorted(obs))
    text = tuple(str(info[k]) for k in ("phase", "task_name", "instruction", "token"))
    numbers = (bool(info["success"]), int(info["trial"]), np.asarray(info["goal"]).tobytes())
    return (*values, reward, terminated, *text, *numbers)


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("million/PointGoal", {}),
        ("million/PointGoal", {"instructions": False, "time_obs": "episode"}),
        ("million/ML1-train", {"instruction_set": "heldout", "trial_len": 40}),
    ],
)
def test_served_episodes_equal_in_process_episodes(
    address: str, env_id: str, kwargs: dict[str, Any]
) -> None:
    register_envs()
    local = gymnasium.make(env_id, **kwargs)
    remote = RemoteEnv(address, env_id, **kwargs)
    try:
        assert _episodes(remote, 5, 2) == _episodes(local, 5, 2)
    finally:
        remote.close()
        local.close()


def test_stats_count_instruction_words_and_no_unknown_ones(
    address: str, stub: env_pb2_grpc.EnvServiceStub
) -> None:
    remote = RemoteEnv(address, "million/PointGoal")
    try:
        before = stub.GetStats(env_pb2.GetStatsRequest()).counters
        _episodes(remote, 1, 2)
        after = stub.GetStats(env_pb2.GetStatsRequest()).counters
    finally:
        remote.close()
    assert after["instruction_tokens"] > before["instruction_tokens"]
    assert after["unknown_words"] == 0


@pytest.mark.parametrize(
    "kwargs",
    [{"trials": 0}, {"time_obs": "wall"}, {"instruction_set": "test"}, {"colour": "red"}],
)
def test_bad_kwargs_are_invalid_argument(
    stub: env_pb2_grpc.EnvServiceStub, kwargs: dict[str, Any]
) -> None:
    with pytest.raises(grpc.RpcError) as caught:
        stub.Make(
            env_pb2.MakeRequest(
                env_id="million/PointGoal", kwargs=python_to_values(kwargs), num_envs=1
            )
        )
    assert caught.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert "million/PointGoal" in caught.value.details()
