"""Running ``million-env-server`` as a child process, for tests and scripts.

The server binds port 0 and reports the port it got on its first stdout line
(``listening on HOST:PORT``), so parallel starts never race for a port; it is
ready once grpc.health answers SERVING, and is stopped with SIGTERM (SIGKILL if
it does not exit). The Rust twin of this is ``million_env::LocalServer``.
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
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc

STARTUP_TIMEOUT_S = 120.0


class ServerStartError(RuntimeError):
    """The server process exited or never became healthy."""


def server_command() -> list[str]:
    """The console script next to this interpreter, else on PATH, else ``python -m``."""
    beside = Path(sys.executable).with_name("million-env-server")
    if beside.exists():
        return [str(beside)]
    found = shutil.which("million-env-server")
    return [found] if found else [sys.executable, "-m", "million_env.cli"]


def wait_until_serving(
    address: str,
    timeout_s: float = STARTUP_TIMEOUT_S,
    process: subprocess.Popen | None = None,
    tls_root_cert: Path | None = None,
) -> None:
    """Polls grpc.health until SERVING; raises if ``process`` exits or time runs out.
    Health needs no token; a TLS server needs its CA (``tls_root_cert``)."""
    from million_env.client import open_channel

    deadline = time.monotonic() + timeout_s
    with open_channel(address, tls_root_cert) as channel:
        health = health_pb2_grpc.HealthStub(channel)
        while True:
            if process is not None and process.poll() is not None:
                raise ServerStartError(
                    f"env server exited with {process.returncode} before serving"
                )
            try:
                reply = health.Check(health_pb2.HealthCheckRequest(service=""), timeout=2)
                if reply.status == health_pb2.HealthCheckResponse.SERVING:
                    return
            except grpc.RpcError:
                pass
            if time.monotonic() > deadline:
                raise ServerStartError(f"env server at {address} not SERVING after {timeout_s} s")
            time.sleep(0.2)


def start_server(
    *extra_args: str,
    log: IO[str] | int = subprocess.DEVNULL,
    tls_root_cert: Path | None = None,
    env: dict[str, str] | None = None,
) -> tuple[subprocess.Popen, str]:
    """Starts a server on a free loopback port and waits until it serves.

    Returns the process and its ``HOST:PORT``. ``extra_args`` go to the command
    line (``--max-envs-total 8``, ``--tls-cert``, ...); the server's stderr goes to
    ``log``; ``tls_root_cert`` is the CA to check its health over TLS; ``env``
    adds environment variables (``MILLION_ENV_TOKEN``)."""
    process = subprocess.Popen(
        [*server_command(), "--address", "127.0.0.1:0", "--log-level", "WARNING", *extra_args],
        stdout=subprocess.PIPE,
        stderr=log,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
    )
    assert process.stdout is not None
    line = process.stdout.readline()
    match = re.search(r"listening on (\S+:\d+)", line)
    try:
        if match is None:
            raise ServerStartError(f"env server did not report its address: {line!r}")
        wait_until_serving(match.group(1), STARTUP_TIMEOUT_S, process, tls_root_cert)
    except BaseException:
        stop_server(process)
        raise
    return process, match.group(1)


def stop_server(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


@contextmanager
def running_server(
    *extra_args: str,
    log: IO[str] | int = subprocess.DEVNULL,
    tls_root_cert: Path | None = None,
    env: dict[str, str] | None = None,
) -> Iterator[str]:
    """``with running_server() as address:`` — a server for the block's duration."""
    process, address = start_server(*extra_args, log=log, tls_root_cert=tls_root_cert, env=env)
    try:
        yield address
    finally:
        stop_server(process)
