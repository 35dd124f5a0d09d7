"""A served Meta-World trajectory equals the in-process one, bit for bit."""

from __future__ import annotations

import numpy as np
from contract_support import Api, EnvCase, check, decode, observation_arrays
from million_env._proto import env_pb2
from million_env.metaworld_tasks import MetaWorldTaskSampler

TASK = "reach-v3"
SEED = 17
STEPS = 120


@check("metaworld_in_process_equal")
def test_served_metaworld_equals_in_process(api: Api) -> None:
    case = EnvCase("metaworld/ML1-train", (("task", TASK),))
    made = api.make(case, num_envs=1, mode=env_pb2.AUTORESET_MODE_DISABLED)
    try:
        reset = api.reset(made.handle, seeds=[SEED])
        served_obs = [observation_arrays(reset.observation)[""][0]]
        served_rewards, served_flags = [], []
        rng = np.random.default_rng(SEED)
        actions = rng.uniform(-1, 1, size=(STEPS, 1, 4)).astype(np.float32)
        for action in actions:
            step = api.step(made.handle, action)
            served_obs.append(decode(step.observation.tensor)[0])
            served_rewards.append(step.reward[0])
            served_flags.append((step.terminated[0], step.truncated[0]))
        task_name = next(e for e in reset.info.entries if e.name == "task_name")
    finally:
        api.close(made.handle)

    sampler = MetaWorldTaskSampler("ML1", "train", task=TASK, seed=SEED)
    sampled = sampler.sample()
    assert decode(task_name.value)[0] == sampled.name
    obs, _ = sampled.env.reset()
    local_obs, local_rewards, local_flags = [obs], [], []
    for action in actions:
        obs, reward, terminated, truncated, _ = sampled.env.step(action[0])
        local_obs.append(obs)
        local_rewards.append(float(reward))
        local_flags.append((bool(terminated), bool(truncated)))
    sampler.close()

    assert served_obs[0].dtype == np.float64
    assert [o.tobytes() for o in served_obs] == [o.tobytes() for o in local_obs]
    assert np.array(served_rewards).tobytes() == np.array(local_rewards).tobytes()
    assert served_flags == local_flags
