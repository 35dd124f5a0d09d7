"""Gymnasium semantics of reset and step, checked on every env under test."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import grpc
import numpy as np
import pytest
from contract_support import (
    Api,
    EnvCase,
    check,
    decode,
    encode,
    expect_status,
    leaf_dtype_and_shape,
    observation_arrays,
    observation_leaves,
    random_actions,
    space_leaves,
)
from million_env._proto import env_pb2

# Upper bound on steps to wait for an episode to end in envs without a time limit.
MAX_WAIT_STEPS = 3000


@pytest.fixture
def handle_of(api: Api) -> Iterator:
    """Makes handles that are closed after the test."""
    made: list[str] = []

    def make(
        case: EnvCase, num_envs: int = 2, mode: int = env_pb2.AUTORESET_MODE_UNSPECIFIED
    ):
        reply = api.make(case, num_envs, mode)
        made.append(reply.handle)
        return reply

    yield make
    for handle in made:
        api.close(handle)


def assert_observation_matches(
    spec: env_pb2.EnvSpec, obs: env_pb2.Observation, rows: int
) -> None:
    leaves = dict(observation_leaves(obs))
    spaces = dict(space_leaves(spec.observation_space))
    assert list(leaves) == list(spaces), (
        "observation parts differ from the spec's Dict entries"
    )
    for path, space in spaces.items():
        tensor = leaves[path]
        dtype, shape = leaf_dtype_and_shape(space)
        assert tensor.dtype == dtype, (
            f"{path or 'obs'}: dtype {tensor.dtype} != spec {dtype}"
        )
        assert tuple(tensor.shape) == (rows, *shape), (
            f"{path or 'obs'}: shape {list(tensor.shape)}"
        )
        values = decode(tensor)
        kind = space.WhichOneof("kind")
        if kind == "box":
            low, high = decode(space.box.low), decode(space.box.high)
            finite_low, finite_high = np.isfinite(low), np.isfinite(high)
            assert np.all((values <= high) | ~finite_high), (
                f"{path}: above the Box high bound"
            )
            assert np.all((values >= low) | ~finite_low), (
                f"{path}: below the Box low bound"
            )
        elif kind == "discrete":
            start, n = space.discrete.start, space.discrete.n
            assert np.all((values >= start) & (values < start + n)), (
                f"{path}: outside Discrete"
            )
        elif kind == "multi_binary":
            assert np.isin(values, (0, 1)).all(), path


def assert_info_matches(spec: env_pb2.EnvSpec, info: env_pb2.Info, rows: int) -> None:
    declared = [(f.name, f.dtype, tuple(f.shape)) for f in spec.info_fields]
    sent = [(e.name, e.value.dtype, tuple(e.value.shape[1:])) for e in info.entries]
    assert sent == declared, "info fields sent differ from the declared ones"
    for entry in info.entries:
        assert entry.value.shape[0] == rows, (
            f"info {entry.name}: {entry.value.shape[0]} rows"
        )
        assert len(entry.present) == rows
        decode(entry.value)  # data length agrees with dtype and shape


def run_until_an_episode_ends(
    api: Api, handle: str, spec: env_pb2.EnvSpec, rng: np.random.Generator
) -> tuple[list[env_pb2.StepResponse], list[np.ndarray]]:
    replies, actions = [], []
    limit = spec.max_episode_steps or MAX_WAIT_STEPS
    for _ in range(limit + 1):
        action = random_actions(spec.action_space, spec.num_envs, rng)
        reply = api.step(handle, action)
        replies.append(reply)
        actions.append(action)
        if any(reply.terminated) or any(reply.truncated):
            return replies, actions
    raise AssertionError(f"no episode ended within {limit + 1} steps")


@check("spec_matches_data")
def test_spec_matches_data(api: Api, env_case: EnvCase, handle_of) -> None:
    made = handle_of(env_case, 3)
    spec = made.spec
    assert spec.env_id == env_case.env_id and spec.num_envs == 3
    assert spec.autoreset_mode == env_pb2.AUTORESET_MODE_NEXT_STEP
    reset = api.reset(made.handle, seeds=[0, 1, 2])
    assert_observation_matches(spec, reset.observation, 3)
    assert_info_matches(spec, reset.info, 3)
    rng = np.random.default_rng(0)
    for _ in range(5):
        step = api.step(made.handle, random_actions(spec.action_space, 3, rng))
        assert_observation_matches(spec, step.observation, 3)
        assert_info_matches(spec, step.info, 3)


@check("reset_rows")
def test_reset_rows(api: Api, env_case: EnvCase, handle_of) -> None:
    made = handle_of(env_case, 3)
    full = api.reset(made.handle, seeds=[10, 11, 12])
    assert list(full.env_indices) == [0, 1, 2]
    full_obs = observation_arrays(full.observation)
    subset = api.reset(made.handle, seeds=[12, 10], indices=[2, 0])
    assert list(subset.env_indices) == [2, 0]
    for path, values in observation_arrays(subset.observation).items():
        assert values.shape[0] == 2
        # The same seeds give the same first observations, now in request order.
        assert values.tobytes() == full_obs[path][[2, 0]].tobytes(), path
    assert_info_matches(made.spec, subset.info, 2)


@check("step_rows")
def test_step_rows(api: Api, env_case: EnvCase, handle_of) -> None:
    made = handle_of(env_case, 4)
    api.reset(made.handle, seeds=[0, 1, 2, 3])
    step = api.step(
        made.handle, random_actions(made.spec.action_space, 4, np.random.default_rng(1))
    )
    for path, values in observation_arrays(step.observation).items():
        assert values.shape[0] == 4, path
    assert len(step.reward) == len(step.terminated) == len(step.truncated) == 4
    assert np.isfinite(step.reward).all()


@check("terminated_truncated_distinct")
def test_terminated_truncated_distinct(api: Api, env_case: EnvCase, handle_of) -> None:
    made = handle_of(env_case, 1, env_pb2.AUTORESET_MODE_DISABLED)
    api.reset(made.handle, seeds=[5])
    replies, _ = run_until_an_episode_ends(
        api, made.handle, made.spec, np.random.default_rng(5)
    )
    last = replies[-1]
    assert not (last.terminated[0] and last.truncated[0]), (
        "terminated and truncated merged"
    )
    for earlier in replies[:-1]:
        assert not earlier.terminated[0] and not earlier.truncated[0]
    limit = made.spec.max_episode_steps
    if limit and not last.terminated[0]:
        assert last.truncated[0] and len(replies) == limit, (
            f"truncated after {len(replies)} steps; max_episode_steps is {limit}"
        )
    if limit:
        assert len(replies) <= limit


@check("autoreset_next_step")
def test_autoreset_next_step(api: Api, env_case: EnvCase, handle_of) -> None:
    made = handle_of(env_case, 2, env_pb2.AUTORESET_MODE_NEXT_STEP)
    api.reset(made.handle, seeds=[7, 8])
    rng = np.random.default_rng(7)
    replies, _ = run_until_an_episode_ends(api, made.handle, made.spec, rng)
    ending = replies[-1]
    ended = np.logical_or(ending.terminated, ending.truncated)
    assert not ending.HasField("final_observation"), (
        "NEXT_STEP sends no final_observation"
    )
    ending_obs = observation_arrays(ending.observation)
    after = api.step(made.handle, random_actions(made.spec.action_space, 2, rng))
    after_obs = observation_arrays(after.observation)
    for i in np.flatnonzero(ended):
        assert after.reward[i] == 0.0
        assert not after.terminated[i] and not after.truncated[i]
        # The autoreset row is a first observation: the one a fresh reset gives.
        assert any(
            ending_obs[p][i].tobytes() != after_obs[p][i].tobytes() for p in after_obs
        )
    assert_observation_matches(made.spec, after.observation, 2)


@check("autoreset_same_step")
def test_autoreset_same_step(api: Api, env_case: EnvCase, handle_of) -> None:
    made = handle_of(env_case, 2, env_pb2.AUTORESET_MODE_SAME_STEP)
    twin = handle_of(env_case, 2, env_pb2.AUTORESET_MODE_DISABLED)
    api.reset(made.handle, seeds=[3, 4])
    api.reset(twin.handle, seeds=[3, 4])
    rng = np.random.default_rng(3)
    replies, actions = run_until_an_episode_ends(api, made.handle, made.spec, rng)
    twin_last = None
    for action in actions:
        twin_last = api.step(twin.handle, action)
    ending = replies[-1]
    ended = np.logical_or(ending.terminated, ending.truncated)
    assert list(twin_last.terminated) == list(ending.terminated)
    assert list(twin_last.truncated) == list(ending.truncated)
    assert ending.HasField("final_observation") and ending.HasField("final_info")
    final = observation_arrays(ending.final_observation)
    twin_obs = observation_arrays(twin_last.observation)
    new_obs = observation_arrays(ending.observation)
    for path in final:
        for i in np.flatnonzero(ended):
            assert final[path][i].tobytes() == twin_obs[path][i].tobytes(), (
                "final obs lost"
            )
    assert_observation_matches(made.spec, ending.final_observation, 2)
    assert_info_matches(made.spec, ending.final_info, 2)
    for entry in ending.final_info.entries:
        assert not any(p for p, e in zip(entry.present, ended, strict=True) if not e)
    # The rows that ended already hold the next episode's first observation.
    for i in np.flatnonzero(ended):
        assert any(new_obs[p][i].tobytes() != final[p][i].tobytes() for p in final)
    follow = api.step(made.handle, random_actions(made.spec.action_space, 2, rng))
    assert not any(
        follow.terminated[i] or follow.truncated[i] for i in np.flatnonzero(ended)
    )


@check("autoreset_disabled")
def test_autoreset_disabled(api: Api, env_case: EnvCase, handle_of) -> None:
    made = handle_of(env_case, 2, env_pb2.AUTORESET_MODE_DISABLED)
    api.reset(made.handle, seeds=[1, 2])
    rng = np.random.default_rng(1)
    replies, _ = run_until_an_episode_ends(api, made.handle, made.spec, rng)
    ended = np.flatnonzero(np.logical_or(replies[-1].terminated, replies[-1].truncated))
    action = random_actions(made.spec.action_space, 2, rng)
    expect_status(
        grpc.StatusCode.FAILED_PRECONDITION, lambda: api.step(made.handle, action)
    )
    api.reset(
        made.handle, seeds=[int(9 + i) for i in ended], indices=[int(i) for i in ended]
    )
    api.step(made.handle, action)


def trajectory(api: Api, case: EnvCase, seeds: list[int], steps: int) -> list[bytes]:
    made = api.make(case, len(seeds), env_pb2.AUTORESET_MODE_NEXT_STEP)
    try:
        rng = np.random.default_rng(99)
        reset = api.reset(made.handle, seeds=seeds)
        out = [reset.observation.SerializeToString(deterministic=True)]
        for _ in range(steps):
            step = api.step(
                made.handle, random_actions(made.spec.action_space, len(seeds), rng)
            )
            out.append(step.SerializeToString(deterministic=True))
        return out
    finally:
        api.close(made.handle)


# Env ids whose first observation does not depend on the seed (none by default).
DETERMINISTIC_RESET: set[str] = set()


@check("seed_determinism")
def test_seed_determinism(api: Api, env_case: EnvCase) -> None:
    first = trajectory(api, env_case, [21, 22], 30)
    second = trajectory(api, env_case, [21, 22], 30)
    assert first == second, "same seeds and actions gave different trajectories"
    if env_case.env_id not in DETERMINISTIC_RESET:
        other = trajectory(api, env_case, [31, 32], 0)
        assert other[0] != first[0], "different seeds gave the same first observations"


@check("session_stream")
def test_session_stream(api: Api, env_case: EnvCase, handle_of) -> None:
    unary = handle_of(env_case, 2)
    streamed = handle_of(env_case, 2)
    rng = np.random.default_rng(4)
    actions = [random_actions(unary.spec.action_space, 2, rng) for _ in range(6)]
    expected = [api.reset(unary.handle, seeds=[40, 41])]
    expected += [api.step(unary.handle, a) for a in actions]

    requests = [
        env_pb2.SessionRequest(
            request_id=100,
            reset=env_pb2.ResetRequest(handle=streamed.handle, seeds=[40, 41]),
        )
    ] + [
        env_pb2.SessionRequest(
            request_id=101 + i,
            step=env_pb2.StepRequest(handle=streamed.handle, action=encode(a)),
        )
        for i, a in enumerate(actions)
    ]
    replies = list(api.stub.Session(iter(requests), timeout=120))
    assert [r.request_id for r in replies] == [r.request_id for r in requests]
    assert replies[0].WhichOneof("response") == "reset"
    assert replies[0].reset == expected[0]
    for reply, want in zip(replies[1:], expected[1:], strict=True):
        assert reply.WhichOneof("response") == "step"
        assert reply.step == want


@check("concurrent_isolation")
def test_concurrent_isolation(api: Api, env_case: EnvCase, server_address: str) -> None:
    alone_a = trajectory(api, env_case, [1, 2], 20)
    alone_b = trajectory(api, env_case, [3, 4], 20)
    results: dict[str, list[bytes]] = {}

    def run(name: str, seeds: list[int]) -> None:
        client = Api(server_address)  # its own channel: a second client
        try:
            results[name] = trajectory(client, env_case, seeds, 20)
        finally:
            client.channel.close()

    threads = [
        threading.Thread(target=run, args=("a", [1, 2])),
        threading.Thread(target=run, args=("b", [3, 4])),
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert results["a"] == alone_a
    assert results["b"] == alone_b
