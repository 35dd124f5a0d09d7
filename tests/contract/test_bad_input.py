"""Bad input gets the right gRPC status, and nothing else breaks."""

from __future__ import annotations

from collections.abc import Iterator

import grpc
import numpy as np
import pytest
from contract_support import Api, EnvCase, check, encode, expect_status, random_actions
from million_env._proto import env_pb2

PENDULUM = EnvCase("Pendulum-v1")
CARTPOLE = EnvCase("CartPole-v1")


@pytest.fixture
def pendulum(api: Api) -> Iterator[env_pb2.MakeResponse]:
    """A reset 2-env Pendulum handle that must keep working after each bad request."""
    made = api.make(PENDULUM, 2)
    api.reset(made.handle, seeds=[0, 1])
    yield made
    good = np.zeros((2, 1), dtype=np.float32)
    reply = api.step(made.handle, good)
    assert len(reply.reward) == 2, "the handle stopped working after a bad request"
    api.close(made.handle)


def assert_server_serves(api: Api) -> None:
    made = api.make(CARTPOLE, 2)
    try:
        api.reset(made.handle, seeds=[5, 6])
        reply = api.step(made.handle, np.array([0, 1], dtype=np.int64))
        assert len(reply.reward) == 2
    finally:
        api.close(made.handle)


@check("error_wrong_action_shape")
def test_wrong_action_shape(api: Api, pendulum: env_pb2.MakeResponse) -> None:
    for shape in [(2,), (3, 1), (2, 2), (1, 2, 1)]:
        bad = np.zeros(shape, dtype=np.float32)
        expect_status(
            grpc.StatusCode.INVALID_ARGUMENT, lambda b=bad: api.step(pendulum.handle, b)
        )


@check("error_wrong_action_dtype")
def test_wrong_action_dtype(api: Api, pendulum: env_pb2.MakeResponse) -> None:
    for dtype in (np.float64, np.int64, np.int32):
        bad = np.zeros((2, 1), dtype=dtype)
        expect_status(
            grpc.StatusCode.INVALID_ARGUMENT, lambda b=bad: api.step(pendulum.handle, b)
        )
    short = env_pb2.Tensor(dtype=env_pb2.DTYPE_FLOAT32, shape=[2, 1], data=b"\x00" * 7)
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT,
        lambda: api.stub.Step(
            env_pb2.StepRequest(handle=pendulum.handle, action=short)
        ),
    )
    unset = env_pb2.Tensor(shape=[2, 1], data=b"\x00" * 8)
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT,
        lambda: api.stub.Step(
            env_pb2.StepRequest(handle=pendulum.handle, action=unset)
        ),
    )


@check("error_nonfinite_action")
def test_nonfinite_action(api: Api, pendulum: env_pb2.MakeResponse) -> None:
    for value in (np.nan, np.inf, -np.inf):
        bad = np.array([[0.0], [value]], dtype=np.float32)
        expect_status(
            grpc.StatusCode.INVALID_ARGUMENT, lambda b=bad: api.step(pendulum.handle, b)
        )


@check("error_unknown_env_id")
def test_unknown_env_id(api: Api) -> None:
    err = expect_status(
        grpc.StatusCode.INVALID_ARGUMENT, lambda: api.make(EnvCase("NoSuchEnv-v0"), 1)
    )
    assert "NoSuchEnv-v0" in err.details()


@check("error_bad_kwargs")
def test_bad_kwargs(api: Api) -> None:
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT,
        lambda: api.make(EnvCase("Pendulum-v1", (("no_such_kwarg", 3),)), 1),
    )
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT,
        lambda: api.make(EnvCase("metaworld/ML1-train", (("task", "fly-v3"),)), 1),
    )


@check("error_unknown_handle")
def test_unknown_handle(api: Api) -> None:
    ghost = "no-such-handle"
    expect_status(grpc.StatusCode.NOT_FOUND, lambda: api.reset(ghost))
    expect_status(
        grpc.StatusCode.NOT_FOUND,
        lambda: api.step(ghost, np.zeros((1, 1), dtype=np.float32)),
    )
    expect_status(grpc.StatusCode.NOT_FOUND, lambda: api.close(ghost))


@check("error_closed_handle")
def test_closed_handle(api: Api) -> None:
    made = api.make(PENDULUM, 1)
    api.reset(made.handle, seeds=[0])
    api.close(made.handle)
    expect_status(
        grpc.StatusCode.NOT_FOUND,
        lambda: api.step(made.handle, np.zeros((1, 1), dtype=np.float32)),
    )


@check("error_step_before_reset")
def test_step_before_reset(api: Api) -> None:
    made = api.make(PENDULUM, 2)
    try:
        action = np.zeros((2, 1), dtype=np.float32)
        expect_status(
            grpc.StatusCode.FAILED_PRECONDITION, lambda: api.step(made.handle, action)
        )
        api.reset(made.handle, seeds=[0], indices=[1])
        expect_status(
            grpc.StatusCode.FAILED_PRECONDITION, lambda: api.step(made.handle, action)
        )
        api.reset(made.handle, seeds=[0], indices=[0])
        assert len(api.step(made.handle, action).reward) == 2
    finally:
        api.close(made.handle)


@check("error_oversized_batch")
def test_oversized_batch(api: Api) -> None:
    caps = api.stub.Handshake(
        env_pb2.HandshakeRequest(client_version=env_pb2.ApiVersion(major=1))
    ).capabilities
    expect_status(
        grpc.StatusCode.RESOURCE_EXHAUSTED,
        lambda: api.make(PENDULUM, caps.max_envs_per_handle + 1),
    )
    expect_status(grpc.StatusCode.INVALID_ARGUMENT, lambda: api.make(PENDULUM, 0))


def test_bad_reset_requests(api: Api, pendulum: env_pb2.MakeResponse) -> None:
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT, lambda: api.reset(pendulum.handle, seeds=[1])
    )
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT,
        lambda: api.reset(pendulum.handle, indices=[0, 2]),
    )
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT,
        lambda: api.reset(pendulum.handle, seeds=[-1, 2]),
    )


def test_out_of_range_discrete_action(api: Api) -> None:
    made = api.make(CARTPOLE, 1)
    try:
        api.reset(made.handle, seeds=[0])
        expect_status(
            grpc.StatusCode.INVALID_ARGUMENT,
            lambda: api.step(made.handle, np.array([2], dtype=np.int64)),
        )
        assert len(api.step(made.handle, np.array([1], dtype=np.int64)).reward) == 1
    finally:
        api.close(made.handle)


@check("error_in_stream_continues")
def test_error_in_stream_continues(api: Api, pendulum: env_pb2.MakeResponse) -> None:
    good = encode(np.zeros((2, 1), dtype=np.float32))
    bad_shape = encode(np.zeros((3, 1), dtype=np.float32))
    requests = [
        env_pb2.SessionRequest(
            request_id=1, step=env_pb2.StepRequest(handle=pendulum.handle, action=good)
        ),
        env_pb2.SessionRequest(
            request_id=2,
            step=env_pb2.StepRequest(handle=pendulum.handle, action=bad_shape),
        ),
        env_pb2.SessionRequest(
            request_id=3, step=env_pb2.StepRequest(handle="ghost", action=good)
        ),
        env_pb2.SessionRequest(
            request_id=4, reset=env_pb2.ResetRequest(handle=pendulum.handle, seeds=[1])
        ),
        env_pb2.SessionRequest(
            request_id=5, step=env_pb2.StepRequest(handle=pendulum.handle, action=good)
        ),
    ]
    replies = list(api.stub.Session(iter(requests), timeout=60))
    assert [r.request_id for r in replies] == [1, 2, 3, 4, 5]
    kinds = [r.WhichOneof("response") for r in replies]
    assert kinds == ["step", "error", "error", "error", "step"]
    assert replies[1].error.code == grpc.StatusCode.INVALID_ARGUMENT.value[0]
    assert replies[2].error.code == grpc.StatusCode.NOT_FOUND.value[0]
    assert replies[3].error.code == grpc.StatusCode.INVALID_ARGUMENT.value[0]
    assert all(r.error.message for r in replies[1:4])


@check("server_survives_bad_input")
def test_server_survives_bad_input(api: Api) -> None:
    # Runs after the bad-input checks above (file order); each of them also checks
    # that its own handle keeps working.
    pendulum = api.make(PENDULUM, 1)
    api.reset(pendulum.handle, seeds=[0])
    for bad in (np.full((1, 1), np.nan, np.float32), np.zeros((1,), np.float64)):
        expect_status(
            grpc.StatusCode.INVALID_ARGUMENT, lambda b=bad: api.step(pendulum.handle, b)
        )
    expect_status(
        grpc.StatusCode.INVALID_ARGUMENT, lambda: api.make(EnvCase("NoSuchEnv-v0"), 1)
    )
    api.close(pendulum.handle)
    assert_server_serves(api)
    rng = np.random.default_rng(0)
    made = api.make(PENDULUM, 2)
    api.reset(made.handle)
    api.step(made.handle, random_actions(made.spec.action_space, 2, rng))
    api.close(made.handle)
