"""A bounded soak: many make/step/close cycles and streams dropped mid-run
against one server process; envs, sessions and memory come back to where they
were."""

from __future__ import annotations

import queue
import time
from collections.abc import Iterator
from pathlib import Path

import grpc
import numpy as np
import pytest

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.server_process import start_server, stop_server
from million_env.tensors import encode_tensor

CYCLES = 60
END = object()


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


@pytest.fixture(scope="module")
def server() -> Iterator[tuple[int, env_pb2_grpc.EnvServiceStub]]:
    process, address = start_server()
    try:
        with grpc.insecure_channel(address) as channel:
            yield process.pid, env_pb2_grpc.EnvServiceStub(channel)
    finally:
        stop_server(process)


def unary_cycle(stub: env_pb2_grpc.EnvServiceStub) -> None:
    made = stub.Make(env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=4), timeout=60)
    stub.Reset(env_pb2.ResetRequest(handle=made.handle), timeout=30)
    action = encode_tensor(np.zeros((4, 1), np.float32))
    for _ in range(5):
        stub.Step(env_pb2.StepRequest(handle=made.handle, action=action), timeout=30)
    stub.Close(env_pb2.CloseRequest(handle=made.handle), timeout=30)


def dropped_stream_cycle(stub: env_pb2_grpc.EnvServiceStub) -> None:
    """Makes and steps envs on a stream, then cancels it without closing them."""
    requests: queue.Queue = queue.Queue()
    call = stub.Session(iter(requests.get, END), timeout=60)
    make = env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=4)
    requests.put(env_pb2.SessionRequest(request_id=1, make=make))
    handle = next(call).make.handle
    requests.put(env_pb2.SessionRequest(request_id=2, reset=env_pb2.ResetRequest(handle=handle)))
    next(call)
    action = encode_tensor(np.zeros((4, 1), np.float32))
    requests.put(
        env_pb2.SessionRequest(request_id=3, step=env_pb2.StepRequest(handle=handle, action=action))
    )
    next(call)
    call.cancel()


def test_cycles_and_dropped_streams_leak_nothing(
    server: tuple[int, env_pb2_grpc.EnvServiceStub],
) -> None:
    pid, stub = server
    for _ in range(5):  # warm-up: first makes load Gymnasium modules and caches
        unary_cycle(stub)
        dropped_stream_cycle(stub)
    start = rss_mib(pid)
    for _ in range(CYCLES):
        unary_cycle(stub)
        dropped_stream_cycle(stub)
    end = rss_mib(pid)
    stats = dict(stub.GetStats(env_pb2.GetStatsRequest(), timeout=10).counters)
    # The last cancelled stream may still be freeing its envs.
    for _ in range(100):
        if stats["envs_alive"] == 0 and stats["sessions_active"] == 0:
            break
        time.sleep(0.05)
        stats = dict(stub.GetStats(env_pb2.GetStatsRequest(), timeout=10).counters)
    assert stats["envs_alive"] == 0
    assert stats["handles_alive"] == 0
    assert stats["sessions_active"] == 0
    assert stats["session_handles_freed"] == CYCLES + 5
    print(f"server RSS {start:.1f} MiB -> {end:.1f} MiB over {CYCLES} x 2 cycles")
    assert end - start < 40, f"RSS grew from {start:.1f} to {end:.1f} MiB"
