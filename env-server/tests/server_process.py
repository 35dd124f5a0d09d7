"""Starting and stopping a real env server (the installed console script) for tests."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc

VENV_SCRIPT = Path(sys.executable).with_name("million-env-server")


def _wait_serving(address: str, process: subprocess.Popen, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    with grpc.insecure_channel(address) as channel:
        stub = health_pb2_grpc.HealthStub(channel)
        while time.monotonic() < deadline:
            if process.poll() is not None:
                raise RuntimeError(f"server exited with {process.returncode}")
            try:
                if stub.Check(health_pb2.HealthCheckRequest(), timeout=2).status == 1:
                    return
            except grpc.RpcError:
                pass
            time.sleep(0.2)
    raise TimeoutError(f"server at {address} not serving after {timeout_s} s")


def start_server(*extra: str) -> tuple[subprocess.Popen, str]:
    command = (
        [str(VENV_SCRIPT)] if VENV_SCRIPT.exists() else [sys.executable, "-m", "million_env.cli"]
    )
    process = subprocess.Popen(
        [*command, "--address", "127.0.0.1:0", "--log-level", "WARNING", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert process.stdout is not None
    match = re.search(r"listening on (\S+:\d+)", process.stdout.readline())
    if match is None:
        stop_server(process)
        raise RuntimeError("env server did not print its address")
    _wait_serving(match.group(1), process)
    return process, match.group(1)


def stop_server(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
