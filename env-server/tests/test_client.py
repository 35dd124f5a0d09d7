"""RemoteEnv and RemoteVectorEnv against a real server, compared with in-process
Gymnasium."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import million_env.metaworld_envs  # noqa: F401 - registers metaworld/* for the in-process twin
from million_env.client import RemoteEnv, RemoteVectorEnv
from million_env.metaworld_envs import register_metaworld_envs

register_metaworld_envs()


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("Pendulum-v1", {}),
        ("metaworld/ML1-train", {"task": "reach-v3"}),
        ("Meta-World/MT1", {"env_name": "reach-v3", "seed": 3}),
    ],
)
def test_remote_env_passes_check_env(server_address: str, env_id: str, kwargs: dict) -> None:
    env = RemoteEnv(server_address, env_id, **kwargs)
    try:
        with warnings.catch_warnings():
            # Meta-World's own spaces have constant and infinite bounds; check_env
            # warns about those, which is not what this test is about.
            warnings.simplefilter("ignore", UserWarning)
            check_env(env, skip_render_check=True)
    finally:
        env.close()


def test_remote_env_matches_gymnasium(server_address: str) -> None:
    remote = RemoteEnv(server_address, "Pendulum-v1")
    local = gym.make("Pendulum-v1")
    try:
        assert remote.observation_space == local.observation_space
        assert remote.action_space == local.action_space
        assert remote.max_episode_steps == 200
        obs_r, _ = remote.reset(seed=11)
        obs_l, _ = local.reset(seed=11)
        assert obs_r.tobytes() == obs_l.tobytes()
        rng = np.random.default_rng(0)
        steps = 0
        for _ in range(200):
            action = rng.uniform(-2, 2, size=(1,)).astype(np.float32)
            r = remote.step(action)
            lo = local.step(action)
            assert r[0].tobytes() == lo[0].tobytes()
            assert r[1:4] == lo[1:4]
            steps += 1
        assert r[3] is True and steps == 200  # truncated by the time limit, not terminated
        with pytest.raises(Exception, match="ended their episode"):
            remote.step(action)
    finally:
        remote.close()
        local.close()


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_remote_vector_env_matches_sync_vector_env(
    server_address: str, mode: AutoresetMode
) -> None:
    n = 4
    remote = RemoteVectorEnv(server_address, "CartPole-v1", n, autoreset_mode=mode)
    local = SyncVectorEnv([lambda: gym.make("CartPole-v1")] * n, autoreset_mode=mode)
    try:
        assert remote.metadata["autoreset_mode"] == mode
        assert remote.single_observation_space == local.single_observation_space
        assert remote.action_space == local.action_space
        obs_r, _ = remote.reset(seed=5)
        obs_l, _ = local.reset(seed=5)
        np.testing.assert_array_equal(obs_r, obs_l)
        rng = np.random.default_rng(5)
        ended_any = False
        for _ in range(80):
            actions = rng.integers(0, 2, size=n)
            o_r, rew_r, term_r, trunc_r, info_r = remote.step(actions)
            o_l, rew_l, term_l, trunc_l, info_l = local.step(actions)
            assert o_r.tobytes() == o_l.tobytes()
            np.testing.assert_array_equal(rew_r, rew_l)
            np.testing.assert_array_equal(term_r, term_l)
            np.testing.assert_array_equal(trunc_r, trunc_l)
            if mode == AutoresetMode.SAME_STEP and "final_obs" in info_l:
                ended_any = True
                np.testing.assert_array_equal(info_r["_final_obs"], info_l["_final_obs"])
                for i in np.flatnonzero(info_l["_final_obs"]):
                    assert info_r["final_obs"][i].tobytes() == info_l["final_obs"][i].tobytes()
            ended_any = ended_any or bool(term_l.any())
        assert ended_any
    finally:
        remote.close()
        local.close()


def test_remote_vector_env_partial_reset(server_address: str) -> None:
    env = RemoteVectorEnv(server_address, "Pendulum-v1", 3, autoreset_mode=AutoresetMode.DISABLED)
    try:
        env.reset(seed=[1, 2, 3])
        stepped, *_ = env.step(np.zeros((3, 1), dtype=np.float32))
        again, _ = env.reset(seed=[7, 8, 9], options={"reset_mask": np.array([False, True, False])})
        fresh = RemoteEnv(server_address, "Pendulum-v1")
        try:
            expected, _ = fresh.reset(seed=8)
        finally:
            fresh.close()
        assert again[1].tobytes() == expected.tobytes()
        # Rows not reset keep the observation of the last step.
        assert again[[0, 2]].tobytes() == stepped[[0, 2]].tobytes()
    finally:
        env.close()


def test_remote_vector_env_dict_observations(server_address: str) -> None:
    env = RemoteVectorEnv(server_address, "million/PointGoal", 2)
    try:
        assert isinstance(env.single_observation_space, gym.spaces.Dict)
        obs, _ = env.reset(seed=0)
        assert set(obs) == set(env.single_observation_space.spaces)
        for name, space in env.single_observation_space.spaces.items():
            assert obs[name].shape[0] == 2
            assert obs[name][0] in space
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert reward.shape == (2,) and terminated.dtype == truncated.dtype == bool
        assert all(obs[name].shape[0] == 2 for name in obs)
    finally:
        env.close()


def test_bad_env_id_raises_grpc_error(server_address: str) -> None:
    import grpc

    with pytest.raises(grpc.RpcError) as caught:
        RemoteEnv(server_address, "NoSuchEnv-v0")
    assert caught.value.code() == grpc.StatusCode.INVALID_ARGUMENT
