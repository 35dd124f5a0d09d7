"""Handshake, health, discovery, close, and the check list itself."""

from __future__ import annotations

import importlib
from pathlib import Path

import grpc
from contract_support import (
    Api,
    EnvCase,
    check,
    expect_status,
    implemented_checks,
    listed_checks,
)
from grpc_health.v1 import health_pb2, health_pb2_grpc
from million_env._proto import env_pb2

CONTRACT_DIR = Path(__file__).parent


@check("handshake")
def test_handshake(api: Api) -> None:
    reply = api.stub.Handshake(
        env_pb2.HandshakeRequest(
            client_version=env_pb2.ApiVersion(major=1, minor=0),
            client_name="contract-tests",
        ),
        timeout=30,
    )
    assert reply.server_version.major == 1
    assert reply.server_name
    caps = reply.capabilities
    assert caps.max_envs_per_handle >= 1
    assert caps.max_envs_total >= caps.max_envs_per_handle
    assert env_pb2.AUTORESET_MODE_NEXT_STEP in caps.autoreset_modes
    assert caps.streaming
    expect_status(
        grpc.StatusCode.FAILED_PRECONDITION,
        lambda: api.stub.Handshake(
            env_pb2.HandshakeRequest(client_version=env_pb2.ApiVersion(major=2)),
            timeout=30,
        ),
    )


@check("health")
def test_health_serving(api: Api) -> None:
    health = health_pb2_grpc.HealthStub(api.channel)
    reply = health.Check(health_pb2.HealthCheckRequest(service=""), timeout=30)
    assert reply.status == health_pb2.HealthCheckResponse.SERVING


@check("list_envs")
def test_list_envs(api: Api, env_case: EnvCase) -> None:
    envs = api.stub.ListEnvs(env_pb2.ListEnvsRequest(), timeout=60).envs
    ids = [e.env_id for e in envs]
    assert ids, "ListEnvs must not be empty"
    assert len(ids) == len(set(ids)), "env ids must be unique"
    assert all(e.description for e in envs), "every env id needs a description"
    assert env_case.env_id in ids


@check("close_frees")
def test_close_frees(api: Api, env_case: EnvCase) -> None:
    before = api.stats()["envs_alive"]
    made = api.make(env_case, num_envs=3)
    assert api.stats()["envs_alive"] == before + 3
    api.close(made.handle)
    assert api.stats()["envs_alive"] == before
    expect_status(grpc.StatusCode.NOT_FOUND, lambda: api.reset(made.handle))
    expect_status(grpc.StatusCode.NOT_FOUND, lambda: api.close(made.handle))


def test_stats_counters(api: Api) -> None:
    counters = api.stats()
    for name in ("envs_alive", "handles_alive", "steps_served"):
        assert name in counters and counters[name] >= 0


def test_implemented_checks_match_checks_toml() -> None:
    for path in sorted(CONTRACT_DIR.glob("test_*.py")):
        importlib.import_module(path.stem)
    listed = set(listed_checks())
    implemented = implemented_checks()
    assert implemented == listed, (
        f"missing: {sorted(listed - implemented)}; not in checks.toml: {sorted(implemented - listed)}"
    )
