"""The MILLION protocol over real Meta-World v3: goal_pos, action repeat against an
in-process Meta-World env, scripted successes, seeding and the registered ids."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
import pytest
from metaworld.policies import SawyerReachV3Policy

from million_env.metaworld_tasks import ALL_TASK_NAMES, MetaWorldTaskSampler
from million_env.million import register_envs
from million_env.million.glove import glove
from million_env.million.metaworld_source import MetaWorldTask
from million_env.million.protocol import MillionEnv

ZERO = np.zeros(4, dtype=np.float32)


def make(env_id: str = "million/ML1-train", **kwargs: Any) -> MillionEnv:
    register_envs()
    return gymnasium.make(env_id, **kwargs).unwrapped  # type: ignore[return-value]


def real_goal(env: MillionEnv) -> np.ndarray:
    task = env.current_task
    assert isinstance(task, MetaWorldTask)
    return np.array(task.env._target_pos)


def skip_instruction(env: MillionEnv, obs: dict[str, Any], info: dict[str, Any]) -> tuple:
    words = []
    while info["phase"] == "instruction":
        words.append((info["token"], obs["word"].copy()))
        obs, reward, _t, _tr, info = env.step(ZERO)
        assert reward == 0.0
    return obs, info, words


def goal_word_of_episode(env: MillionEnv, seed: int) -> tuple[dict[str, Any], np.ndarray]:
    """Resets with `seed` and reads the first instruction: the reset's info and the
    `goal_pos` word's vector."""
    obs, info = env.reset(seed=seed)
    _obs, _info, words = skip_instruction(env, obs, info)
    return info, next(v for t, v in words if t == "goal_pos")


@pytest.fixture(scope="module")
def reach_env() -> MillionEnv:
    return make("million/ML1-train")


def test_registered_ids() -> None:
    described = register_envs()
    expected = {f"million/{b}-{s}" for b in ("ML1", "ML10", "ML45") for s in ("train", "test")}
    assert set(described) == expected | {"million/PointGoal"}
    for env_id, description in described.items():
        assert env_id in gymnasium.registry
        assert "kwargs" in description
    assert gymnasium.registry["million/ML1-train"].kwargs["task"] == "reach-v3"
    assert gymnasium.registry["million/ML10-train"].kwargs == {
        "instruction_set": "train",
        "instructions": True,
        "reward_in_obs": False,
        "time_obs": "trial",
        "action_repeat": 2,
        "trials": 3,
        "trial_len": 200,
        "task_order": "random",
        "instruction_goal": "real",
        "goal_encoding": "raw",
        "goal_in_state": False,
        "end_on_success": False,
        "word_noise": 0.0,
        "object_position": "task",
    }
    # The id fixes its benchmark and split; they are not kwargs.
    with pytest.raises(TypeError, match="benchmark"):
        gymnasium.make("million/ML10-train", benchmark="ML45")
    with pytest.raises(ValueError, match="no task name"):
        gymnasium.make("million/ML10-train", task="reach-v3")


def test_goal_pos_is_the_real_goal_and_words_are_glove_rows(reach_env: MillionEnv) -> None:
    table = glove()
    goals = set()
    for seed in range(4):
        obs, info = reach_env.reset(seed=seed)
        goal = real_goal(reach_env)
        goals.add(goal.tobytes())
        np.testing.assert_array_equal(info["goal"], goal)
        _obs, _info, words = skip_instruction(reach_env, obs, info)
        assert [t for t, _ in words] == info["instruction"].split()
        assert "goal_pos" in info["instruction"].split()
        for token, vector in words:
            if token == "goal_pos":
                np.testing.assert_array_equal(vector[:3], goal.astype(np.float32))
                assert not vector[3:].any()
            else:
                np.testing.assert_array_equal(vector, table.matrix[table.row(token)])
    assert len(goals) > 1, "different seeds sample different goals"


def test_reflected_instruction_goal_names_a_wrong_goal_in_the_goal_range() -> None:
    """The diagnostic `instruction_goal="reflected"`: goal_pos names the real goal
    reflected through the centre of reach's goal box (a goal the agent must not reach),
    while the MDP, its success test and info's `goal` keep the real one."""
    env = make("million/ML1-train", instruction_goal="reflected")
    try:
        for seed in range(3):
            info, vector = goal_word_of_episode(env, seed)
            goal = real_goal(env)
            np.testing.assert_array_equal(info["goal"], goal)
            low, high = env.current_task.goal_range()
            named = vector[:3]
            np.testing.assert_allclose(named, (low + high - goal).astype(np.float32), atol=1e-6)
            assert np.all(named >= low - 1e-6) and np.all(named <= high + 1e-6)
            # Farther from the real goal than reach's 5 cm success radius.
            assert np.linalg.norm(named - goal) > 0.05
    finally:
        env.close()
    with pytest.raises(ValueError, match="instruction_goal"):
        make("million/ML1-train", instruction_goal="swapped")


@pytest.mark.parametrize("instruction_goal", ["real", "reflected"])
def test_range_goal_encoding_scales_the_named_goal_to_the_unit_box(instruction_goal: str) -> None:
    """`goal_encoding="range"` writes the goal that goal_pos names mapped affinely from the
    task's goal range to [-1, 1] per axis: the ends of the range land on -1 and 1, the
    encoding is invertible, and info's `goal` stays the real goal in metres."""
    env = make("million/ML1-train", goal_encoding="range", instruction_goal=instruction_goal)
    try:
        encoded = []
        for seed in range(6):
            info, vector = goal_word_of_episode(env, seed)
            goal = real_goal(env)
            np.testing.assert_array_equal(info["goal"], goal)
            low, high = env.current_task.goal_range()
            assert not vector[3:].any()
            named = goal if instruction_goal == "real" else low + high - goal
            # Decoding the entries gives back the named goal in metres.
            decoded = low + (vector[:3].astype(np.float64) + 1.0) * (high - low) / 2.0
            np.testing.assert_allclose(decoded, named, atol=1e-6)
            assert np.all(np.abs(vector[:3]) <= 1.0 + 1e-6)
            encoded.append(vector[:3])
        # Reach's goals fill the box, so the scaled entries spread over most of [-1, 1]
        # (in metres the x and y entries would span at most 0.2 and 0.1).
        spread = np.ptp(np.stack(encoded), axis=0)
        assert np.all(spread > 0.5), spread
    finally:
        env.close()
    with pytest.raises(ValueError, match="goal_encoding"):
        make("million/ML1-train", goal_encoding="metres")


def test_range_goal_encoding_maps_a_point_axis_to_zero_and_clips() -> None:
    """hand-insert's goal range is a point in z (±1e-4 m): that axis is written as 0, not as
    jitter blown up to [-1, 1], and no entry leaves [-1, 1]."""
    env = make("million/ML1-train", task="hand-insert-v3", goal_encoding="range")
    try:
        for seed in range(3):
            _info, vector = goal_word_of_episode(env, seed)
            low, high = env.current_task.goal_range()
            assert high[2] - low[2] < 0.01, "the z range is a point"
            assert vector[2] == 0.0
            assert np.all(np.abs(vector[:3]) <= 1.0)
    finally:
        env.close()


def test_goal_is_kept_across_trials(reach_env: MillionEnv) -> None:
    reach_env.reset(seed=5)
    goal = real_goal(reach_env)
    trial_goals = []
    done = False
    while not done:
        _obs, _r, done, _tr, info = reach_env.step(ZERO)
        if info["trial_end"]:
            trial_goals.append(real_goal(reach_env))
    for g in trial_goals:
        np.testing.assert_array_equal(g, goal)
    assert len(trial_goals) == 3


def test_trial_equals_in_process_metaworld_with_action_repeat(reach_env: MillionEnv) -> None:
    """Two Meta-World env steps per agent step, rewards summed, bit for bit."""
    seed = 7
    obs, info = reach_env.reset(seed=seed)
    obs, info, _ = skip_instruction(reach_env, obs, info)

    sampled = MetaWorldTaskSampler("ML1", "train", task="reach-v3", seed=seed).sample()
    raw_obs, _ = sampled.env.reset()
    assert sampled.name == info["task_name"]
    np.testing.assert_array_equal(obs["state"], raw_obs)

    rng = np.random.default_rng(0)
    for step in range(1, 101):
        action = rng.uniform(-1, 1, size=4).astype(np.float32)
        obs, reward, terminated, truncated, info = reach_env.step(action)
        raw_reward = 0.0
        for _ in range(2):
            raw_obs, r, _t, raw_truncated, _raw_info = sampled.env.step(action)
            raw_reward += r
            assert not raw_truncated
        assert reward == raw_reward
        assert not (terminated or truncated)
        if step < 100:
            assert not info["trial_end"]
            assert info["steps_in_trial"] == 2 * step
            assert obs["time"][0] == np.float32(2 * step / 200)
            np.testing.assert_array_equal(obs["state"], raw_obs)
    # The 100th agent step is the trial's 200th env step: the trial ends there, whatever
    # happened in it, and the observation already belongs to what follows.
    assert info["trial_end"] and info["steps_in_trial"] == 0


# Meta-World's scripted policies warn about their own gain constants.
@pytest.mark.filterwarnings("ignore:Constant.s. may be too high")
def test_scripted_reach_succeeds_and_starts_the_next_trial_directly(reach_env: MillionEnv) -> None:
    """Meta-World's own reach policy, given the goal read from the goal_pos word."""
    policy = SawyerReachV3Policy()
    obs, info = reach_env.reset(seed=8)
    _o, _i, words = skip_instruction(reach_env, obs, info)
    goal = next(v[:3] for t, v in words if t == "goal_pos").astype(np.float64)
    obs, info = _o, _i
    ends = []
    done = False
    while not done:
        state = obs["state"].copy()
        state[36:39] = goal
        obs, _r, done, truncated, info = reach_env.step(policy.get_action(state))
        assert not truncated
        if info["trial_end"]:
            ends.append((info["success"], info["phase"], info["steps_in_trial"]))
    assert [e[0] for e in ends] == [True, True, True]
    # After a success the next trial starts at once, from a reset MDP.
    assert ends[0][1:] == ("trial", 0) and ends[1][1:] == ("trial", 0)
    assert info["trial_successes"] == 3


@pytest.mark.filterwarnings("ignore:Constant.s. may be too high")
def test_trial_success_observation_follows_the_success_test(reach_env: MillionEnv) -> None:
    """Full-length reach trials (the default): `trial_success` is 0 until Meta-World's success
    test first holds in the trial, then 1 to the trial's end while the hand stays at the goal,
    0 again at the next trial's first observation; 0 in the instruction phase."""
    policy = SawyerReachV3Policy()
    obs, info = reach_env.reset(seed=8)
    goal = np.asarray(info["goal"])
    per_trial: list[list[float]] = [[]]
    done = False
    while not done:
        flag = float(obs["trial_success"][0])
        if info["phase"] == "trial":
            # A trial's observations, first included; `steps_to_success` runs from -1.
            assert flag == float(info["steps_to_success"] >= 0 and not info["trial_end"])
            per_trial[-1].append(flag)
            state = obs["state"].copy()
            state[36:39] = goal
            action = policy.get_action(state)
        else:
            assert flag == 0.0
            action = ZERO
        obs, _r, done, _tr, info = reach_env.step(action)
        if info["trial_end"] and not done:
            per_trial.append([])
    assert float(obs["trial_success"][0]) == 1.0 and info["success"]
    assert len(per_trial) == 3
    for flags in per_trial:
        first = flags.index(1.0)
        assert flags[0] == 0.0 and flags[first:] == [1.0] * (len(flags) - first)


def scripted_reach_episode(env: MillionEnv, seed: int) -> list[tuple[int, bool, float]]:
    """Meta-World's reach policy for one episode: (agent steps, success, return) per trial."""
    policy = SawyerReachV3Policy()
    obs, info = env.reset(seed=seed)
    goal = np.asarray(info["goal"])
    trials, steps, ret, done = [], 0, 0.0, False
    while not done:
        if info["phase"] == "trial":
            state = obs["state"].copy()
            state[36:39] = goal
            action = policy.get_action(state)
            steps += 1
        else:
            action = ZERO
        obs, reward, done, _tr, info = env.step(action)
        ret += reward
        if info["trial_end"]:
            trials.append((steps, bool(info["success"]), ret))
            steps, ret = 0, 0.0
    return trials


@pytest.mark.filterwarnings("ignore:Constant.s. may be too high")
def test_trials_run_their_full_length_and_keep_paying_after_a_success() -> None:
    """As the original code: a trial runs its 200 env steps (100 agent steps) whatever
    happens and succeeds if the success test held at any step, so staying at the goal
    keeps earning reward; `end_on_success=True` ends it at the succeeding step instead."""
    full, ending = make("million/ML1-train"), make("million/ML1-train", end_on_success=True)
    try:
        full_trials = scripted_reach_episode(full, seed=8)
        ending_trials = scripted_reach_episode(ending, seed=8)
    finally:
        full.close()
        ending.close()
    assert [t[:2] for t in full_trials] == [(100, True)] * 3
    assert [t[1] for t in ending_trials] == [True] * 3
    assert all(steps < 50 for steps, _s, _r in ending_trials)
    # The same first steps, then the full trial's reward for holding the goal on top.
    for (_n, _s, whole), (_m, _t, cut) in zip(full_trials, ending_trials, strict=True):
        assert whole > cut + 500
    with pytest.raises(ValueError, match="end_on_success"):
        make("million/ML1-train", end_on_success=1)


def test_seed_determines_task_goal_and_sentences() -> None:
    env_a, env_b = make("million/ML10-train"), make("million/ML10-train")

    def stream(env: MillionEnv) -> list[tuple]:
        out = []
        for episode in range(4):
            obs, info = env.reset(seed=21 if episode == 0 else None)
            out.append((info["task_name"], info["instruction"], info["goal"].tobytes()))
            out.append(obs["word"].tobytes())
        return out

    a = stream(env_a)
    assert a == stream(env_b)
    assert len({entry[0] for entry in a[::2]}) > 1, "ML10 samples several task classes"


def test_ml10_task_ids_index_all_task_names() -> None:
    env = make("million/ML10-test")
    assert env.observation_space["task_id"].n == 50
    names = set()
    for seed in range(12):
        obs, info = env.reset(seed=seed)
        assert ALL_TASK_NAMES[int(obs["task_id"])] == info["task_name"]
        names.add(info["task_name"])
    assert names <= {
        "drawer-open-v3",
        "door-close-v3",
        "shelf-place-v3",
        "sweep-into-v3",
        "lever-pull-v3",
    }


def test_ml10_tasks_kwarg_serves_only_the_named_classes() -> None:
    chosen = {"reach-v3", "push-v3", "pick-place-v3"}
    env = make("million/ML10-train", tasks=sorted(chosen))
    names = {env.reset(seed=seed)[1]["task_name"] for seed in range(12)}
    assert names == chosen
    with pytest.raises(ValueError, match="not in the split"):
        make("million/ML10-train", tasks=["drawer-open-v3"])


def test_trial_longer_than_metaworld_allows_is_rejected() -> None:
    with pytest.raises(ValueError, match="trial_len"):
        make("million/ML1-train", trial_len=501)


def test_full_trial_never_reaches_metaworld_truncation() -> None:
    env = make("million/ML1-test", trial_len=500, trials=2, instructions=False)
    env.reset(seed=0)
    done = False
    steps = 0
    while not done:
        _obs, _r, done, truncated, _info = env.step(ZERO)
        assert not truncated
        steps += 1
    assert steps == 500


def test_ml45_ids_serve_their_splits() -> None:
    # Slow (~1 min): building the ML45 benchmark dominates; both ids share it.
    test_env = make("million/ML45-test")
    train_env = make("million/ML45-train")
    assert set(test_env.task_names) == {
        "bin-picking-v3",
        "box-close-v3",
        "hand-insert-v3",
        "door-lock-v3",
        "door-unlock-v3",
    }
    assert len(train_env.task_names) == 45
    assert not set(train_env.task_names) & set(test_env.task_names)
    for env in (test_env, train_env):
        obs, info = env.reset(seed=0)
        assert info["task_name"] in env.task_names
        assert ALL_TASK_NAMES[int(obs["task_id"])] == info["task_name"]
        obs, info, _ = skip_instruction(env, obs, info)
        assert obs["state"].shape == (39,) and obs["state"].any()


def test_goal_in_state_shows_the_real_goal_in_trials_only() -> None:
    """The diagnostic `goal_in_state=True` writes the real goal into the trial state's last
    three entries (ML1 hides it there); instruction phases keep an all-zero state, and
    the default keeps the goal hidden."""
    shown = make("million/ML1-train", goal_in_state=True)
    hidden = make("million/ML1-train")
    try:
        for env in (shown, hidden):
            obs, info = env.reset(seed=4)
            trial_states = []
            done = False
            while not done:
                if info["phase"] == "trial":
                    trial_states.append(obs["state"])
                else:
                    assert not obs["state"].any()
                obs, _r, done, _tr, info = env.step(ZERO)
            goal_slots = np.stack(trial_states)[:, -3:]
            if env is shown:
                np.testing.assert_array_equal(
                    goal_slots, np.tile(info["goal"], (len(goal_slots), 1))
                )
            else:
                assert not goal_slots.any()
    finally:
        shown.close()
        hidden.close()
    with pytest.raises(ValueError, match="goal_in_state"):
        make("million/ML1-train", goal_in_state="yes")


def test_object_position_centre_puts_reachs_puck_at_one_place_for_every_goal() -> None:
    """reach-v3 draws its puck with the goal, so on a split's fixed goals the puck's place
    names the goal. `object_position="centre"` puts it at the centre of its range for every
    goal, in the simulator and in both frames of the state, and leaves the goal as it was."""
    own = make("million/ML1-train")
    centred = make("million/ML1-train", object_position="centre")
    try:
        pucks: dict[str, set[tuple[float, ...]]] = {"own": set(), "centred": set()}
        for seed in range(4):
            goals = {}
            for name, env in (("own", own), ("centred", centred)):
                obs, info = env.reset(seed=seed)
                goals[name] = real_goal(env)
                obs, info, _ = skip_instruction(env, obs, info)
                state = obs["state"]
                np.testing.assert_array_equal(state[4:7], state[22:25])
                task = env.current_task
                assert isinstance(task, MetaWorldTask)
                np.testing.assert_allclose(task.env.unwrapped._get_pos_objects(), state[4:7])
                pucks[name].add(tuple(np.round(state[4:7], 4)))
            np.testing.assert_array_equal(goals["centred"], goals["own"])
        # Own pucks differ from goal to goal; centred ones sit at the range's centre.
        assert len(pucks["own"]) == 4
        assert pucks["centred"] == {(0.0, 0.65, 0.02)}
    finally:
        own.close()
        centred.close()
    with pytest.raises(ValueError, match="object_position"):
        make("million/ML1-train", object_position="middle")
    with pytest.raises(ValueError, match="push-v3"):
        make("million/ML10-train", tasks=["reach-v3", "push-v3"], object_position="centre")
