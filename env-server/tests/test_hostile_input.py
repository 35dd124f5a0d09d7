"""Hostile input against the real server: bytes that are no message, random
bytes, impossible shapes and sizes, wrong types. Every answer is a deliberate
status code (never UNKNOWN), and the server and other clients keep working."""

from __future__ import annotations

from collections.abc import Iterator

import grpc
import numpy as np
import pytest

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.client import MAX_MESSAGE_BYTES, RemoteVectorEnv
from million_env.handlers import SERVICE_DESCRIPTOR, SERVICE_NAME

Code = grpc.StatusCode
UNARY = [m.name for m in SERVICE_DESCRIPTOR.methods if not m.client_streaming]
# Bytes no request type can parse: truncated lengths, an overlong varint.
UNDECODABLE = [b"\x0a\xff", b"\xff" * 11, b"\x12\x05abc"]
# What a random (but parseable) request may fairly get, per method.
ALLOWED = {
    "Handshake": {Code.OK, Code.FAILED_PRECONDITION, Code.INVALID_ARGUMENT},
    "ListEnvs": {Code.OK, Code.INVALID_ARGUMENT},
    "Make": {Code.INVALID_ARGUMENT, Code.RESOURCE_EXHAUSTED},
    "Reset": {Code.INVALID_ARGUMENT, Code.NOT_FOUND},
    "Step": {Code.INVALID_ARGUMENT, Code.NOT_FOUND},
    "Close": {Code.INVALID_ARGUMENT, Code.NOT_FOUND},
    "GetStats": {Code.OK, Code.INVALID_ARGUMENT},
    # A random handle is unknown; a random size may be out of range.
    "Render": {Code.INVALID_ARGUMENT, Code.NOT_FOUND},
}


@pytest.fixture(scope="module")
def channel(server_address: str) -> Iterator[grpc.Channel]:
    # A client limit above the server's, so that the server's own limit is tested.
    big = 2 * MAX_MESSAGE_BYTES
    options = [("grpc.max_send_message_length", big), ("grpc.max_receive_message_length", big)]
    with grpc.insecure_channel(server_address, options=options) as ch:
        yield ch


def raw_unary(channel: grpc.Channel, method: str, payload: bytes) -> Code:
    """Sends ``payload`` as the request body (no serializer: identity)."""
    call = channel.unary_unary(f"/{SERVICE_NAME}/{method}")
    try:
        call(payload, timeout=30)
    except grpc.RpcError as err:
        return err.code()
    return Code.OK


def raw_session(channel: grpc.Channel, payloads: list[bytes]) -> list[env_pb2.SessionResponse]:
    call = channel.stream_stream(f"/{SERVICE_NAME}/Session")
    return [env_pb2.SessionResponse.FromString(r) for r in call(iter(payloads), timeout=30)]


def stats(channel: grpc.Channel) -> dict[str, float]:
    stub = env_pb2_grpc.EnvServiceStub(channel)
    return dict(stub.GetStats(env_pb2.GetStatsRequest(), timeout=10).counters)


def test_undecodable_requests_get_invalid_argument(channel: grpc.Channel) -> None:
    for method in UNARY:
        for payload in UNDECODABLE:
            call = channel.unary_unary(f"/{SERVICE_NAME}/{method}")
            with pytest.raises(grpc.RpcError) as caught:
                call(payload, timeout=30)
            assert caught.value.code() == Code.INVALID_ARGUMENT, (method, payload)
            assert "is not a valid million.env.v1." in caught.value.details()


def test_undecodable_stream_message_gets_an_error_reply(channel: grpc.Channel) -> None:
    good = env_pb2.SessionRequest(
        request_id=7, reset=env_pb2.ResetRequest(handle="ghost")
    ).SerializeToString()
    replies = raw_session(channel, [UNDECODABLE[0], good, UNDECODABLE[1]])
    assert [r.WhichOneof("response") for r in replies] == ["error"] * 3
    assert [r.error.code for r in replies] == [3, 5, 3]  # the stream went on
    assert replies[1].request_id == 7
    assert "SessionRequest" in replies[0].error.message


def test_random_bytes_to_every_method(channel: grpc.Channel) -> None:
    before = stats(channel)
    rng = np.random.default_rng(10)
    seen: dict[str, set[Code]] = {m: set() for m in UNARY}
    for _ in range(40):
        for method in UNARY:
            payload = rng.bytes(int(rng.integers(1, 64)))
            code = raw_unary(channel, method, payload)
            assert code in ALLOWED[method], (method, payload, code)
            seen[method].add(code)
        replies = raw_session(channel, [rng.bytes(int(rng.integers(1, 64))) for _ in range(3)])
        assert len(replies) == 3
        for reply in replies:
            kind = reply.WhichOneof("response")
            assert kind == "error", kind  # no handle can be guessed
            assert reply.error.code in (3, 5, 8)  # INVALID_ARGUMENT, NOT_FOUND, EXHAUSTED
    assert all(Code.INVALID_ARGUMENT in codes for codes in seen.values()), seen
    after = stats(channel)
    assert after["envs_alive"] == before["envs_alive"], "a hostile request leaked envs"
    assert "errors.UNKNOWN" not in after
    assert after["errors.INVALID_ARGUMENT"] > before.get("errors.INVALID_ARGUMENT", 0)


def make_pendulum(stub: env_pb2_grpc.EnvServiceStub, n: int) -> str:
    made = stub.Make(env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=n), timeout=60)
    stub.Reset(env_pb2.ResetRequest(handle=made.handle), timeout=30)
    return made.handle


@pytest.mark.parametrize(
    "shape",
    [[-1, 1], [2, -3], [2**40, 2**40], [2**62, 4], [2, 1, 2**31], [], [0, 2**62]],
)
def test_impossible_action_shapes(channel: grpc.Channel, shape: list[int]) -> None:
    stub = env_pb2_grpc.EnvServiceStub(channel)
    handle = make_pendulum(stub, 2)
    try:
        action = env_pb2.Tensor(dtype=env_pb2.DTYPE_FLOAT32, shape=shape, data=b"\x00" * 8)
        with pytest.raises(grpc.RpcError) as caught:
            stub.Step(env_pb2.StepRequest(handle=handle, action=action), timeout=30)
        assert caught.value.code() == Code.INVALID_ARGUMENT
        good = env_pb2.Tensor(dtype=env_pb2.DTYPE_FLOAT32, shape=[2, 1], data=b"\x00" * 8)
        assert len(stub.Step(env_pb2.StepRequest(handle=handle, action=good)).reward) == 2
    finally:
        stub.Close(env_pb2.CloseRequest(handle=handle), timeout=30)


def test_wrong_types(channel: grpc.Channel) -> None:
    stub = env_pb2_grpc.EnvServiceStub(channel)
    handle = make_pendulum(stub, 1)
    try:
        cases = [
            env_pb2.Tensor(dtype=77, shape=[1, 1], data=b"\x00" * 4),  # no such dtype
            env_pb2.Tensor(dtype=env_pb2.DTYPE_STRING, shape=[1, 1], strings=["x"]),
            env_pb2.Tensor(dtype=env_pb2.DTYPE_BOOL, shape=[1, 1], data=b"\x01"),
        ]
        for action in cases:
            with pytest.raises(grpc.RpcError) as caught:
                stub.Step(env_pb2.StepRequest(handle=handle, action=action), timeout=30)
            assert caught.value.code() == Code.INVALID_ARGUMENT, action
        with pytest.raises(grpc.RpcError) as caught:
            unset = {"g": env_pb2.Value()}  # a Value with no kind
            stub.Make(env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=1, kwargs=unset))
        assert caught.value.code() == Code.INVALID_ARGUMENT
        with pytest.raises(grpc.RpcError) as caught:
            stub.Make(env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=1, autoreset_mode=9))
        assert caught.value.code() == Code.INVALID_ARGUMENT
    finally:
        stub.Close(env_pb2.CloseRequest(handle=handle), timeout=30)


def test_oversized_batches(channel: grpc.Channel) -> None:
    stub = env_pb2_grpc.EnvServiceStub(channel)
    for n in (2**32 - 1, 10_000):
        with pytest.raises(grpc.RpcError) as caught:
            stub.Make(env_pb2.MakeRequest(env_id="Pendulum-v1", num_envs=n), timeout=30)
        assert caught.value.code() == Code.RESOURCE_EXHAUSTED
    with pytest.raises(grpc.RpcError) as caught:
        stub.Reset(env_pb2.ResetRequest(handle="ghost", env_indices=range(100_000)), timeout=30)
    assert caught.value.code() == Code.NOT_FOUND


def test_message_over_the_maximum_size(channel: grpc.Channel, server_address: str) -> None:
    payload = env_pb2.StepRequest(
        handle="x", action=env_pb2.Tensor(data=b"\x00" * (MAX_MESSAGE_BYTES + 1024))
    ).SerializeToString()
    assert raw_unary(channel, "Step", payload) == Code.RESOURCE_EXHAUSTED
    # The server and other clients go on.
    env = RemoteVectorEnv(server_address, "CartPole-v1", num_envs=2)
    try:
        env.reset(seed=0)
        assert env.step(np.array([0, 1]))[1].shape == (2,)
    finally:
        env.close()
