"""Server hygiene: stream-owned envs are freed when their stream ends, however it
ends; SIGTERM drains gracefully; stats count sessions, steps and errors; logs
can be JSON lines."""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import grpc
import numpy as np
import pytest
from grpc_health.v1 import health_pb2, health_pb2_grpc

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.server_process import start_server, stop_server
from million_env.tensors import encode_tensor

END = object()


class Stream:
    """A Session stream fed from a queue, so a test can pause and cancel it."""

    def __init__(self, stub: env_pb2_grpc.EnvServiceStub) -> None:
        self._requests: queue.Queue = queue.Queue()
        self._next_id = 0
        self.call = stub.Session(iter(self._requests.get, END), timeout=120)

    def ask(self, **request: object) -> env_pb2.SessionResponse:
        self._next_id += 1
        self._requests.put(env_pb2.SessionRequest(request_id=self._next_id, **request))
        reply = next(self.call)
        assert reply.request_id == self._next_id
        return reply

    def end(self) -> None:
        self._requests.put(END)


def counters(stub: env_pb2_grpc.EnvServiceStub) -> dict[str, float]:
    return dict(stub.GetStats(env_pb2.GetStatsRequest(), timeout=10).counters)


def wait_for(condition: Callable[[], bool], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def stub(server_address: str) -> Iterator[env_pb2_grpc.EnvServiceStub]:
    with grpc.insecure_channel(server_address) as channel:
        yield env_pb2_grpc.EnvServiceStub(channel)


MAKE = env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=3)


def step_all(stream: Stream, handle: str) -> env_pb2.SessionResponse:
    action = encode_tensor(np.zeros((3, 1), np.float32))
    return stream.ask(step=env_pb2.StepRequest(handle=handle, action=action))


@pytest.mark.parametrize("how", ["end", "cancel"])
def test_stream_owned_envs_freed_when_the_stream_ends(
    stub: env_pb2_grpc.EnvServiceStub, how: str
) -> None:
    before = counters(stub)
    stream = Stream(stub)
    handle = stream.ask(make=MAKE).make.handle
    stream.ask(reset=env_pb2.ResetRequest(handle=handle, seeds=[0, 1, 2]))
    assert len(step_all(stream, handle).step.reward) == 3
    during = counters(stub)
    assert during["envs_alive"] == before["envs_alive"] + 3
    assert during["sessions_active"] == before["sessions_active"] + 1
    if how == "end":
        stream.end()
        assert list(stream.call) == []
    else:
        stream.call.cancel()
    wait_for(lambda: counters(stub)["sessions_active"] == before["sessions_active"])
    after = counters(stub)
    assert after["envs_alive"] == before["envs_alive"]
    assert after["session_handles_freed"] == before.get("session_handles_freed", 0) + 1
    with pytest.raises(grpc.RpcError) as caught:
        stub.Reset(env_pb2.ResetRequest(handle=handle), timeout=10)
    assert caught.value.code() == grpc.StatusCode.NOT_FOUND


def test_stream_owned_envs_freed_when_the_client_process_dies(
    stub: env_pb2_grpc.EnvServiceStub, server_address: str
) -> None:
    before = counters(stub)
    client = subprocess.Popen(
        [sys.executable, "-c", _DYING_CLIENT, server_address],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert client.stdout is not None
        assert client.stdout.readline().strip() == "made"
        assert counters(stub)["envs_alive"] == before["envs_alive"] + 3
        client.kill()  # kill -9: no goodbye on the connection
    finally:
        client.wait()
    wait_for(lambda: counters(stub)["envs_alive"] == before["envs_alive"])


_DYING_CLIENT = """
import sys, threading, grpc
from million_env._proto import env_pb2, env_pb2_grpc
stub = env_pb2_grpc.EnvServiceStub(grpc.insecure_channel(sys.argv[1]))
hold = threading.Event()
def requests():
    make = env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=3)
    yield env_pb2.SessionRequest(request_id=1, make=make)
    hold.wait()
replies = stub.Session(requests())
next(replies)
print("made", flush=True)
hold.wait()
"""


def test_unary_handles_outlive_streams(stub: env_pb2_grpc.EnvServiceStub) -> None:
    made = stub.Make(MAKE, timeout=60)
    try:
        stream = Stream(stub)
        stream.ask(reset=env_pb2.ResetRequest(handle=made.handle))
        stream.end()
        list(stream.call)
        stub.Reset(env_pb2.ResetRequest(handle=made.handle), timeout=10)  # still there
    finally:
        stub.Close(env_pb2.CloseRequest(handle=made.handle), timeout=10)


def test_stats_show_steps_per_second_and_errors(stub: env_pb2_grpc.EnvServiceStub) -> None:
    stream = Stream(stub)
    handle = stream.ask(make=MAKE).make.handle
    stream.ask(reset=env_pb2.ResetRequest(handle=handle))
    for _ in range(5):
        step_all(stream, handle)
    assert stream.ask(step=env_pb2.StepRequest(handle="ghost")).error.code == 5
    before_close = counters(stub)
    assert stream.ask(close=env_pb2.CloseRequest(handle=handle)).WhichOneof("response") == "close"
    stream.end()
    list(stream.call)
    assert before_close["steps_per_s"] > 0
    assert before_close["errors.NOT_FOUND"] >= 1
    # Closed by the client: nothing left for the stream's end to free.
    assert counters(stub)["session_handles_freed"] == before_close.get("session_handles_freed", 0)


def test_sigterm_drains_then_exits(tmp_path: Path) -> None:
    log = tmp_path / "server.log"
    with log.open("w") as sink:
        process, address = start_server(
            "--shutdown-grace", "3", "--log-format", "json", "--log-level", "INFO", log=sink
        )
        try:
            with grpc.insecure_channel(address) as channel:
                watch = health_pb2_grpc.HealthStub(channel).Watch(
                    health_pb2.HealthCheckRequest(), timeout=60
                )
                assert next(watch).status == health_pb2.HealthCheckResponse.SERVING
                stream = Stream(env_pb2_grpc.EnvServiceStub(channel))
                handle = stream.ask(make=MAKE).make.handle
                stream.ask(reset=env_pb2.ResetRequest(handle=handle))
                start = time.monotonic()
                process.send_signal(signal.SIGTERM)
                assert next(watch).status == health_pb2.HealthCheckResponse.NOT_SERVING
                # The call in flight keeps working during the grace period.
                assert len(step_all(stream, handle).step.reward) == 3
                stream.end()
                assert process.wait(timeout=30) == 0
                assert time.monotonic() - start < 15
        finally:
            if process.poll() is None:
                stop_server(process)
    entries = [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]
    shutdown = [e for e in entries if e["message"].startswith("shutting down")]
    assert shutdown and shutdown[0]["signal"] == "SIGTERM" and shutdown[0]["grace_s"] == 3
    assert any(e["message"] == "stopped" for e in entries)
