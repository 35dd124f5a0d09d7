"""Contract-test options and the server under test.

``pytest tests/contract --env-server HOST:PORT`` tests a running server; without
the flag the bundled ``million-env-server`` is started on a free loopback port for
the session. ``--env ID[:key=value,...]`` (repeatable) chooses the env ids.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import grpc
import pytest
from contract_support import Api, EnvCase
from grpc_health.v1 import health_pb2, health_pb2_grpc

# Extend this list as the server gains env families; every entry runs every
# generic check. Meta-World and MILLION ids carry the kwargs they need.
DEFAULT_ENVS = (
    "Pendulum-v1",
    "CartPole-v1",
    "metaworld/ML1-train:task=reach-v3",
    # Meta-World's own id; its goal set is random unless the seed kwarg fixes it.
    "Meta-World/MT1:env_name=reach-v3,seed=1",
    "million/PointGoal",
    "million/ML10-train",
)
REPO_ROOT = Path(__file__).resolve().parents[2]
STARTUP_TIMEOUT_S = 120.0


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("contract", "MILLION env API contract tests")
    group.addoption(
        "--env-server",
        default=None,
        metavar="HOST:PORT",
        help="test this running server instead of starting the bundled one",
    )
    group.addoption(
        "--env",
        action="append",
        default=None,
        metavar="ID[:key=value,...]",
        help=f"env id (with kwargs) to test; repeatable (default: {', '.join(DEFAULT_ENVS)})",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "contract_check(id): the checks.toml check a test implements"
    )


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "env_case" in metafunc.fixturenames:
        texts = metafunc.config.getoption("--env") or list(DEFAULT_ENVS)
        cases = [EnvCase.parse(t) for t in texts]
        metafunc.parametrize(
            "env_case", cases, ids=[str(c) for c in cases], scope="module"
        )


def _server_command() -> list[str]:
    script = REPO_ROOT / ".venv" / "bin" / "million-env-server"
    if script.exists():
        return [str(script)]
    found = shutil.which("million-env-server")
    if found:
        return [found]
    return [sys.executable, "-m", "million_env.cli"]


def wait_until_serving(
    address: str, timeout_s: float, process: subprocess.Popen | None = None
) -> None:
    deadline = time.monotonic() + timeout_s
    with grpc.insecure_channel(address) as channel:
        health = health_pb2_grpc.HealthStub(channel)
        while True:
            if process is not None and process.poll() is not None:
                raise RuntimeError(
                    f"env server exited with {process.returncode} before serving"
                )
            try:
                reply = health.Check(
                    health_pb2.HealthCheckRequest(service=""), timeout=2
                )
                if reply.status == health_pb2.HealthCheckResponse.SERVING:
                    return
            except grpc.RpcError:
                pass
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"env server at {address} not SERVING after {timeout_s} s"
                )
            time.sleep(0.2)


@pytest.fixture(scope="session")
def server_address(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[str]:
    given = request.config.getoption("--env-server")
    if given:
        wait_until_serving(given, 30.0)
        yield given
        return
    log_path = tmp_path_factory.mktemp("env-server") / "server.log"
    with log_path.open("w") as log:
        process = subprocess.Popen(
            [
                *_server_command(),
                "--address",
                "127.0.0.1:0",
                "--max-envs-per-handle",
                "64",
                "--max-envs-total",
                "512",
                "--log-level",
                "WARNING",
            ],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        match = re.search(r"listening on (\S+:\d+)", line)
        if match is None:
            process.wait(timeout=5)
            raise RuntimeError(
                f"env server did not start: {line!r}; log:\n{log_path.read_text()}"
            )
        address = match.group(1)
        wait_until_serving(address, STARTUP_TIMEOUT_S, process)
        yield address
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.fixture(scope="session")
def api(server_address: str) -> Iterator[Api]:
    client = Api(server_address)
    yield client
    client.channel.close()
