"""EnvBatch against Gymnasium's own SyncVectorEnv, in process, all autoreset modes."""

from __future__ import annotations

import grpc
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from million_env._proto import env_pb2
from million_env.batch import EnvBatch
from million_env.errors import ApiError
from million_env.spaces import decode_observations
from million_env.tensors import encode_tensor

MODES = {
    env_pb2.AUTORESET_MODE_NEXT_STEP: AutoresetMode.NEXT_STEP,
    env_pb2.AUTORESET_MODE_SAME_STEP: AutoresetMode.SAME_STEP,
}


@pytest.mark.parametrize("mode", list(MODES))
def test_batch_equals_sync_vector_env(mode: int) -> None:
    n = 3
    batch = EnvBatch("CartPole-v1", {}, n, mode)
    reference = SyncVectorEnv([lambda: gym.make("CartPole-v1")] * n, autoreset_mode=MODES[mode])
    try:
        reset = batch.reset([], [0, 1, 2], {})
        ref_obs, _ = reference.reset(seed=[0, 1, 2])
        assert decode_observations(reset.observation).tobytes() == ref_obs.tobytes()
        rng = np.random.default_rng(0)
        endings = 0
        for _ in range(100):
            actions = rng.integers(0, 2, size=n)
            reply = batch.step(encode_tensor(actions))
            obs, rew, term, trunc, info = reference.step(actions)
            assert decode_observations(reply.observation).tobytes() == obs.tobytes()
            assert list(reply.reward) == rew.tolist()
            assert list(reply.terminated) == term.tolist()
            assert list(reply.truncated) == trunc.tolist()
            if mode == env_pb2.AUTORESET_MODE_SAME_STEP and (term | trunc).any():
                final = decode_observations(reply.final_observation)
                for i in np.flatnonzero(term | trunc):
                    assert final[i].tobytes() == info["final_obs"][i].tobytes()
            endings += int((term | trunc).sum())
        assert endings > 0
    finally:
        batch.close()
        reference.close()


def test_disabled_mode_refuses_ended_envs_until_reset() -> None:
    batch = EnvBatch("CartPole-v1", {}, 1, env_pb2.AUTORESET_MODE_DISABLED)
    try:
        batch.reset([], [0], {})
        push = encode_tensor(np.array([1]))
        for _ in range(500):
            reply = batch.step(push)
            if reply.terminated[0] or reply.truncated[0]:
                break
        assert reply.terminated[0]
        with pytest.raises(ApiError) as caught:
            batch.step(push)
        assert caught.value.code == grpc.StatusCode.FAILED_PRECONDITION
        batch.reset([0], [1], {})
        assert len(batch.step(push).reward) == 1
    finally:
        batch.close()


def test_metaworld_split_never_steps_past_truncation() -> None:
    batch = EnvBatch(
        "metaworld/ML1-train", {"task": "reach-v3"}, 1, env_pb2.AUTORESET_MODE_NEXT_STEP
    )
    try:
        assert batch.spec.max_episode_steps == 500
        first = batch.reset([], [3], {})
        action = encode_tensor(np.zeros((1, 4), np.float32))
        for step in range(1, 501):
            reply = batch.step(action)
            assert reply.truncated[0] == (step == 500)
            assert not reply.terminated[0]
        # Step 501 is the autoreset, not a Meta-World step past truncation (which raises).
        reply = batch.step(action)
        assert not reply.truncated[0] and reply.reward[0] == 0.0
        names = {e.name: e for e in first.info.entries}
        assert names["task_name"].value.strings == ["reach-v3"]
    finally:
        batch.close()


def test_env_error_makes_handle_unusable() -> None:
    batch = EnvBatch("CartPole-v1", {}, 1, env_pb2.AUTORESET_MODE_NEXT_STEP)
    try:
        batch.reset([], [0], {})

        def explode(action: object) -> None:
            raise RuntimeError("simulator diverged")

        batch.envs[0].step = explode  # type: ignore[method-assign]
        with pytest.raises(ApiError) as caught:
            batch.step(encode_tensor(np.array([0])))
        assert caught.value.code == grpc.StatusCode.INTERNAL
        assert "simulator diverged" in caught.value.message
        with pytest.raises(ApiError) as again:
            batch.reset([], [], {})
        assert again.value.code == grpc.StatusCode.FAILED_PRECONDITION
    finally:
        batch.close()


def test_spec_kwargs_and_unknown_kwargs() -> None:
    batch = EnvBatch("Pendulum-v1", {"g": 9.0}, 1, env_pb2.AUTORESET_MODE_UNSPECIFIED)
    try:
        assert batch.spec.autoreset_mode == env_pb2.AUTORESET_MODE_NEXT_STEP
        assert batch.spec.kwargs["g"].float_value == 9.0
        assert batch.spec.max_episode_steps == 200
    finally:
        batch.close()
    with pytest.raises(ApiError) as caught:
        EnvBatch("Pendulum-v1", {"gravity_typo": 1}, 1, env_pb2.AUTORESET_MODE_NEXT_STEP)
    assert caught.value.code == grpc.StatusCode.INVALID_ARGUMENT


def test_reset_options_reach_the_env() -> None:
    batch = EnvBatch("CartPole-v1", {}, 2, env_pb2.AUTORESET_MODE_NEXT_STEP)
    try:
        wide = decode_observations(batch.reset([], [0, 1], {}).observation)
        narrow = decode_observations(
            batch.reset([], [0, 1], {"low": -0.001, "high": 0.001}).observation
        )
        assert np.abs(narrow).max() <= 0.001 < np.abs(wide).max()
    finally:
        batch.close()
