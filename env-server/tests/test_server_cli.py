"""The console script: defaults, limits, and a served Make/Step through it."""

from __future__ import annotations

import queue
import time

import grpc
import numpy as np
import pytest

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.cli import parse_args
from million_env.server_process import start_server, stop_server
from million_env.tensors import encode_tensor


def test_defaults_listen_on_loopback() -> None:
    args = parse_args([])
    assert args.address == "127.0.0.1:50051"
    assert args.max_envs_per_handle >= 1 and args.max_envs_total >= args.max_envs_per_handle


def test_bad_limits_rejected() -> None:
    with pytest.raises(SystemExit):
        parse_args(["--max-envs-total", "0"])


@pytest.mark.parametrize("abbreviated", ["--addr", "--tok", "--tls-c"])
def test_abbreviated_options_are_refused(abbreviated: str) -> None:
    # The agent vets its local servers' extra arguments by exact option names.
    with pytest.raises(SystemExit):
        parse_args([abbreviated, "x"])


@pytest.mark.parametrize("bad", ["ML1", "ML2", "ML10:reach-v3", "ML1:fly-v3"])
def test_bad_preload_rejected(bad: str) -> None:
    with pytest.raises(SystemExit):
        parse_args(["--preload", bad])


def test_preloaded_server_serves_the_benchmark() -> None:
    assert parse_args(["--preload", "ML1:reach-v3", "--preload", "ML10"]).preload == [
        "ML1:reach-v3",
        "ML10",
    ]
    process, address = start_server("--preload", "ML1:reach-v3")
    try:
        with grpc.insecure_channel(address) as channel:
            stub = env_pb2_grpc.EnvServiceStub(channel)
            made = stub.Make(
                env_pb2.MakeRequest(
                    env_id="metaworld/ML1-test",
                    num_envs=1,
                    kwargs={"task": env_pb2.Value(string_value="reach-v3")},
                ),
                timeout=30,
            )
            assert made.spec.observation_space.box.shape == [39]
            stub.Reset(env_pb2.ResetRequest(handle=made.handle, seeds=[0]), timeout=60)
            counters = stub.GetStats(env_pb2.GetStatsRequest(), timeout=10).counters
            # The reset built the slot's reach-v3 env; nothing has been given back yet.
            assert counters["metaworld_envs_built"] == 1.0
            assert counters["metaworld_envs_idle"] == 0.0
            # reach-v3's XML was compiled once (the benchmark's own envs, at preload); the
            # slot's env copied that model instead of compiling it again.
            assert counters["metaworld_models_compiled"] == 1.0
            assert counters["metaworld_models_copied"] >= 1.0
    finally:
        stop_server(process)


def test_limits_are_enforced_by_the_running_server() -> None:
    process, address = start_server("--max-envs-per-handle", "2", "--max-envs-total", "3")
    try:
        with grpc.insecure_channel(address) as channel:
            stub = env_pb2_grpc.EnvServiceStub(channel)
            caps = stub.Handshake(
                env_pb2.HandshakeRequest(client_version=env_pb2.ApiVersion(major=1))
            ).capabilities
            assert (caps.max_envs_per_handle, caps.max_envs_total) == (2, 3)
            first = stub.Make(env_pb2.MakeRequest(env_id="CartPole-v1", num_envs=2))
            with pytest.raises(grpc.RpcError) as caught:
                stub.Make(env_pb2.MakeRequest(env_id="CartPole-v1", num_envs=2))
            assert caught.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
            stub.Close(env_pb2.CloseRequest(handle=first.handle))
            again = stub.Make(env_pb2.MakeRequest(env_id="CartPole-v1", num_envs=2))
            stub.Reset(env_pb2.ResetRequest(handle=again.handle, seeds=[0, 1]))
            reply = stub.Step(
                env_pb2.StepRequest(handle=again.handle, action=encode_tensor(np.array([0, 1])))
            )
            assert len(reply.reward) == 2
            stats = stub.GetStats(env_pb2.GetStatsRequest()).counters
            assert stats["envs_alive"] == 2 and stats["steps_served"] == 2
            assert "unknown_words" in stats  # the MILLION protocol's counters are merged in
    finally:
        stop_server(process)


MAKE_PENDULUM = env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=1)


def test_idle_handles_are_closed_and_busy_ones_kept() -> None:
    """A client that dies without Close must not hold its envs for ever; handles a Session
    stream made end with the stream, however long they wait (an agent's evaluation envs)."""
    assert parse_args([]).handle_idle_timeout > 0
    with pytest.raises(SystemExit):
        parse_args(["--handle-idle-timeout", "-1"])
    process, address = start_server("--handle-idle-timeout", "1")
    try:
        with grpc.insecure_channel(address) as channel:
            stub = env_pb2_grpc.EnvServiceStub(channel)

            def make() -> str:
                handle = stub.Make(MAKE_PENDULUM, timeout=30).handle
                stub.Reset(env_pb2.ResetRequest(handle=handle), timeout=30)
                return handle

            abandoned, busy = make(), make()
            requests: queue.Queue = queue.Queue()
            stream = stub.Session(iter(requests.get, None), timeout=60)
            requests.put(env_pb2.SessionRequest(request_id=1, make=MAKE_PENDULUM))
            waiting = next(stream).make.handle
            requests.put(
                env_pb2.SessionRequest(request_id=2, reset=env_pb2.ResetRequest(handle=waiting))
            )
            assert not next(stream).HasField("error")
            action = encode_tensor(np.zeros((1, 1), dtype=np.float32))
            for _ in range(8):  # 2.4 s of calls on `busy` only
                stub.Step(env_pb2.StepRequest(handle=busy, action=action), timeout=30)
                time.sleep(0.3)

            stub.Step(env_pb2.StepRequest(handle=busy, action=action), timeout=30)
            step = env_pb2.StepRequest(handle=waiting, action=action)
            requests.put(env_pb2.SessionRequest(request_id=3, step=step))
            assert not next(stream).HasField("error")  # the stream's handle outlived the wait
            requests.put(None)
            assert list(stream) == []
            with pytest.raises(grpc.RpcError) as err:
                stub.Step(env_pb2.StepRequest(handle=abandoned, action=action), timeout=30)
            assert err.value.code() == grpc.StatusCode.NOT_FOUND
            assert "without calls" in err.value.details()
            counters = stub.GetStats(env_pb2.GetStatsRequest(), timeout=30).counters
            assert counters["handles_closed_idle"] == 1
            assert counters["envs_alive"] == 1
    finally:
        stop_server(process)
