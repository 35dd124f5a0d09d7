"""TLS and the shared token, end to end against a real server process."""

from __future__ import annotations

import secrets
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import grpc
import numpy as np
import pytest
from grpc_health.v1 import health_pb2, health_pb2_grpc
from tls_certs import CertFiles, make_certs

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.client import RemoteEnv, RemoteVectorEnv, open_channel
from million_env.security import TOKEN_ENV_VAR, bearer_metadata
from million_env.server_process import start_server, stop_server


@dataclass(frozen=True)
class SecureServer:
    address: str
    token: str
    certs: CertFiles
    log: Path


@pytest.fixture(scope="module")
def secure_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SecureServer]:
    directory = tmp_path_factory.mktemp("tls")
    certs = make_certs(directory)
    token = secrets.token_urlsafe(16)
    log = directory / "server.log"
    with log.open("w") as sink:
        process, address = start_server(
            "--tls-cert", str(certs.cert), "--tls-key", str(certs.key), "--log-level", "DEBUG",
            log=sink, tls_root_cert=certs.ca, env={TOKEN_ENV_VAR: token},
        )  # fmt: skip
        try:
            yield SecureServer(address, token, certs, log)
        finally:
            stop_server(process)


def test_tls_and_token_end_to_end(secure_server: SecureServer) -> None:
    env = RemoteEnv(
        secure_server.address,
        "Pendulum-v1",
        token=secure_server.token,
        tls_root_cert=secure_server.certs.ca,
    )
    try:
        env.reset(seed=0)
        assert np.isfinite(env.step(np.zeros(1, np.float32))[1])
    finally:
        env.close()


def test_token_from_the_environment(
    secure_server: SecureServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(TOKEN_ENV_VAR, secure_server.token)
    env = RemoteVectorEnv(
        secure_server.address, "CartPole-v1", 2, tls_root_cert=secure_server.certs.ca.read_bytes()
    )
    env.reset(seed=1)
    env.close()


@pytest.mark.parametrize("token", [None, "wrong", "Bearer"])
def test_missing_or_wrong_token_is_unauthenticated(
    secure_server: SecureServer, token: str | None
) -> None:
    with open_channel(secure_server.address, secure_server.certs.ca) as channel:
        stub = env_pb2_grpc.EnvServiceStub(channel)
        calls = [
            lambda md: stub.ListEnvs(env_pb2.ListEnvsRequest(), metadata=md, timeout=10),
            lambda md: stub.Make(
                env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=1), metadata=md, timeout=10
            ),
            lambda md: list(
                stub.Session(iter([env_pb2.SessionRequest()]), metadata=md, timeout=10)
            ),
            # Undecodable bytes: refused before anything is parsed.
            lambda md: channel.unary_unary("/million.env.v1.EnvService/Step")(
                b"\xff" * 11, metadata=md, timeout=10
            ),
        ]
        for call in calls:
            with pytest.raises(grpc.RpcError) as caught:
                call(bearer_metadata(token))
            assert caught.value.code() == grpc.StatusCode.UNAUTHENTICATED
            assert "token" in caught.value.details()
        stats = stub.GetStats(
            env_pb2.GetStatsRequest(), metadata=bearer_metadata(secure_server.token), timeout=10
        ).counters
        assert stats["errors.UNAUTHENTICATED"] >= len(calls)
        assert stats["envs_alive"] == 0


def test_health_is_open_without_token(secure_server: SecureServer) -> None:
    with open_channel(secure_server.address, secure_server.certs.ca) as channel:
        health = health_pb2_grpc.HealthStub(channel)
        reply = health.Check(health_pb2.HealthCheckRequest(), timeout=10)
    assert reply.status == health_pb2.HealthCheckResponse.SERVING


def test_plaintext_client_cannot_talk_to_a_tls_server(secure_server: SecureServer) -> None:
    with grpc.insecure_channel(secure_server.address) as channel:
        with pytest.raises(grpc.RpcError) as caught:
            env_pb2_grpc.EnvServiceStub(channel).ListEnvs(
                env_pb2.ListEnvsRequest(), metadata=bearer_metadata(secure_server.token), timeout=5
            )
    assert caught.value.code() == grpc.StatusCode.UNAVAILABLE


def test_untrusted_ca_is_refused(secure_server: SecureServer, tmp_path: Path) -> None:
    other = make_certs(tmp_path)
    with pytest.raises(grpc.RpcError) as caught:
        RemoteEnv(
            secure_server.address, "Pendulum-v1", token=secure_server.token,
            tls_root_cert=other.ca, timeout=5,
        )  # fmt: skip
    assert caught.value.code() == grpc.StatusCode.UNAVAILABLE


def test_token_never_logged(secure_server: SecureServer) -> None:
    # Runs last in this module: the DEBUG log has seen every call above.
    text = secure_server.log.read_text()
    assert "listening" in text
    assert secure_server.token not in text
