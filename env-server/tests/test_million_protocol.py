"""The MILLION episode protocol (phases, trials, time, ablations, seeding) on PointGoal.

PointGoal is the cheap source with full control over success and failure: a
policy that walks to the named goal succeeds, one that stands still fails.
Meta-World specifics are in test_million_metaworld.py.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium
import numpy as np
import pytest

from million_env.million import register_envs
from million_env.million.glove import glove
from million_env.million.point_goal import GOAL_RADIUS, SUCCESS_DISTANCE
from million_env.million.protocol import INFO_FIELDS, MillionEnv

Policy = Callable[[dict[str, Any], dict[str, Any]], np.ndarray]
ZERO = np.zeros(4, dtype=np.float32)


def make(**kwargs: Any) -> MillionEnv:
    register_envs()
    env = gymnasium.make("million/PointGoal", **kwargs)
    return env.unwrapped  # type: ignore[return-value]


def stand_still(_obs: dict[str, Any], _info: dict[str, Any]) -> np.ndarray:
    return ZERO


def walk_to_goal(obs: dict[str, Any], info: dict[str, Any]) -> np.ndarray:
    """An oracle reading the goal from info (the env's evaluation field)."""
    delta = info["goal"][:2] - obs["state"][:2]
    action = np.zeros(4, dtype=np.float32)
    action[:2] = np.clip(delta / 0.15, -1.0, 1.0)
    return action


def run_episode(env: MillionEnv, policy: Policy, seed: int | None = None) -> list[dict[str, Any]]:
    """Every transition of one episode: obs/info after reset, then after each step."""
    obs, info = env.reset(seed=seed)
    records = [{"obs": obs, "info": info, "reward": 0.0, "terminated": False, "truncated": False}]
    while not (records[-1]["terminated"] or records[-1]["truncated"]):
        obs, reward, terminated, truncated, info = env.step(policy(obs, info))
        records.append(
            {
                "obs": obs,
                "info": info,
                "reward": reward,
                "terminated": terminated,
                "truncated": truncated,
            }
        )
        assert len(records) < 10_000, "episode does not end"
    return records


def phases(records: list[dict[str, Any]]) -> list[str]:
    """The phase sequence, e.g. ['instruction', 'trial', 'instruction', ...].

    A trial-ending step (not the last) already returns the first observation of
    what follows, so it starts a new entry even when a trial follows a trial.
    """
    out: list[str] = []
    for record in records:
        phase = record["info"]["phase"]
        starts_next = record["info"]["trial_end"] and not record["terminated"]
        if not out or out[-1] != phase or starts_next:
            out.append(phase)
    return out


def test_failed_trials_are_each_followed_by_a_new_instruction() -> None:
    env = make(trials=3, trial_len=25)
    records = run_episode(env, stand_still, seed=0)
    assert phases(records) == [
        "instruction",
        "trial",
        "instruction",
        "trial",
        "instruction",
        "trial",
    ]
    ends = [i for i, r in enumerate(records) if r["info"]["trial_end"]]
    assert len(ends) == 3
    assert not any(r["info"]["success"] for r in records)
    # Only the last step is terminal; trial boundaries are not; never truncated.
    assert [r["terminated"] for r in records].count(True) == 1 and records[-1]["terminated"]
    assert not any(r["truncated"] for r in records)
    # Each failed trial lasted exactly trial_len env steps (action repeat 1).
    assert all(records[i - 1]["info"]["steps_in_trial"] == 24 for i in ends)
    assert records[-1]["info"]["steps_in_trial"] == 25
    with pytest.raises(RuntimeError, match="reset"):
        env.step(ZERO)


def test_successful_trial_is_followed_directly_by_the_next_trial() -> None:
    env = make(trials=3)
    records = run_episode(env, walk_to_goal, seed=1)
    assert phases(records) == ["instruction", "trial", "trial", "trial"]
    ends = [r for r in records if r["info"]["trial_end"]]
    assert [r["info"]["success"] for r in ends] == [True, True, True]
    assert records[-1]["info"]["trial_successes"] == 3
    # A success ends the trial early and the next trial starts from a reset state.
    for i, record in enumerate(records[:-1]):
        if record["info"]["trial_end"]:
            assert record["info"]["steps_in_trial"] == 0
            assert np.linalg.norm(record["obs"]["state"][:2]) < 0.1
            assert records[i + 1]["info"]["phase"] == "trial"
    # The success reward includes the bonus and the final point is at the goal.
    final = records[-1]
    assert np.linalg.norm(final["obs"]["state"][:2] - final["info"]["goal"][:2]) < SUCCESS_DISTANCE


def test_full_length_trials_keep_a_success_that_was_left_behind() -> None:
    """`end_on_success=False`: a trial runs its trial_len env steps; one that met the goal
    and then walked away still counts as a success, and the next trial follows directly."""
    env = make(trials=2, trial_len=25, end_on_success=False)

    def reach_then_leave(obs: dict[str, Any], info: dict[str, Any]) -> np.ndarray:
        if info["steps_in_trial"] < 12:
            return walk_to_goal(obs, info)
        # Back towards the start for the rest of the trial, away from the goal.
        action = np.zeros(4, dtype=np.float32)
        action[:2] = np.clip(-obs["state"][:2] / 0.15, -1.0, 1.0)
        return action

    records = run_episode(env, reach_then_leave, seed=1)
    assert phases(records) == ["instruction", "trial", "trial"]
    ends = [i for i, r in enumerate(records) if r["info"]["trial_end"]]
    assert [records[i]["info"]["success"] for i in ends] == [True, True]
    # Each trial lasted its 25 env steps (action repeat 1), and left the goal before the end.
    assert all(records[i - 1]["info"]["steps_in_trial"] == 24 for i in ends)
    last = records[ends[0] - 1]
    assert np.linalg.norm(last["obs"]["state"][:2] - last["info"]["goal"][:2]) > SUCCESS_DISTANCE
    # `success` is set only at the step that ends a successful trial.
    assert sum(r["info"]["success"] for r in records) == 2
    assert records[-1]["info"]["trial_successes"] == 2


def trial_success_expected(record: dict[str, Any]) -> float:
    """What the `trial_success` observation must be, from info alone: 1 in a trial whose
    success test has held (`steps_to_success` runs from -1 to the step it first held); the
    step that ends a trial (not the last) shows the next trial's first observation, 0."""
    info = record["info"]
    if info["phase"] != "trial":
        return 0.0
    if info["trial_end"]:
        return float(record["terminated"] and info["success"])
    return float(info["steps_to_success"] >= 0)


def test_trial_success_observation_flags_a_trial_that_has_succeeded() -> None:
    """`end_on_success=False`: the flag is 0 until the trial's success test holds, 1 from
    the observation of that step on (also after walking away from the goal), 0 again at the
    next trial's first observation, and 0 throughout instruction phases."""
    env = make(trials=3, trial_len=25, end_on_success=False)
    first_flags: list[float] = []

    def policy(obs: dict[str, Any], info: dict[str, Any]) -> np.ndarray:
        if info["phase"] != "trial" or info["trial"] == 0:
            return ZERO  # the first trial fails, so an instruction phase follows it
        if info["steps_in_trial"] == 0:
            first_flags.append(float(obs["trial_success"][0]))
        if info["steps_in_trial"] < 12:
            return walk_to_goal(obs, info)
        # Away from the goal for the rest of the trial: the flag stays set.
        action = np.zeros(4, dtype=np.float32)
        action[:2] = np.clip(-obs["state"][:2] / 0.15, -1.0, 1.0)
        return action

    records = run_episode(env, policy, seed=1)
    assert phases(records) == ["instruction", "trial", "instruction", "trial", "trial"]
    ends = [r["info"]["success"] for r in records if r["info"]["trial_end"]]
    assert ends == [False, True, True]
    flags = [float(r["obs"]["trial_success"][0]) for r in records]
    assert flags == [trial_success_expected(r) for r in records]
    assert all(r["obs"]["trial_success"].dtype == np.float32 for r in records)
    # Instruction phases, the failed trial and each trial's first observation show 0.
    assert all(f == 0.0 for f, r in zip(flags, records, strict=True) if r["info"]["trial"] == 0)
    assert all(
        f == 0.0 for f, r in zip(flags, records, strict=True) if r["info"]["phase"] != "trial"
    )
    assert first_flags == [0.0, 0.0]
    # Within the second trial: 0s, then 1s to its end, set at the step that reached the goal.
    second = [
        r
        for r in records
        if r["info"]["trial"] == 1 and r["info"]["phase"] == "trial" and not r["info"]["trial_end"]
    ]
    running = [float(r["obs"]["trial_success"][0]) for r in second]
    first = running.index(1.0)
    assert 0 < first and running[first:] == [1.0] * (len(running) - first)
    assert second[first]["info"]["steps_to_success"] == second[first]["info"]["steps_in_trial"]
    assert np.linalg.norm(second[-1]["obs"]["state"][:2] - second[-1]["info"]["goal"][:2]) > (
        SUCCESS_DISTANCE
    )
    # The episode's final observation stays in its last, successful trial.
    assert flags[-1] == 1.0 and records[-1]["terminated"]


def test_trial_success_observation_when_trials_end_at_their_success() -> None:
    """`end_on_success=True` (PointGoal's default): the succeeding step ends the trial and
    already shows the next trial's first observation (0); only the episode's final
    observation, still in its successful last trial, shows 1."""
    env = make(trials=3)
    records = run_episode(env, walk_to_goal, seed=1)
    flags = [float(r["obs"]["trial_success"][0]) for r in records]
    assert flags == [trial_success_expected(r) for r in records]
    assert flags[:-1] == [0.0] * (len(flags) - 1) and flags[-1] == 1.0


@pytest.mark.parametrize("action_repeat", [1, 2])
def test_steps_to_success_says_how_soon_a_trial_first_succeeded(action_repeat: int) -> None:
    """A full-length trial reports at its end the env step at which its success test first
    held (how soon, where `success` says only whether); a failed trial reports -1."""
    env = make(trials=3, trial_len=30, end_on_success=False, action_repeat=action_repeat)
    first_hits: list[int] = []

    def policy(obs: dict[str, Any], info: dict[str, Any]) -> np.ndarray:
        # Trial 0 stands still (fails); the later trials walk to the goal.
        if info["phase"] != "trial" or info["trial"] == 0:
            return ZERO
        distance = np.linalg.norm(obs["state"][:2] - info["goal"][:2])
        if distance < SUCCESS_DISTANCE and len(first_hits) < info["trial"]:
            first_hits.append(info["steps_in_trial"])
        return walk_to_goal(obs, info)

    records = run_episode(env, policy, seed=1)
    ends = [r["info"] for r in records if r["info"]["trial_end"]]
    assert [e["success"] for e in ends] == [False, True, True]
    assert ends[0]["steps_to_success"] == -1
    hits = [e["steps_to_success"] for e in ends[1:]]
    assert all(1 <= h < 30 for h in hits)
    # The agent saw itself within the radius at the observation after the step that got it
    # there; with action repeat that step may have been the first or a later repeat.
    for hit, seen in zip(hits, first_hits, strict=True):
        assert seen - action_repeat < hit <= seen
    # Within a trial the field runs: -1 until the success, then the step it happened at.
    running = [
        r["info"]["steps_to_success"]
        for r in records
        if r["info"]["trial"] == 1 and r["info"]["phase"] == "trial" and not r["info"]["trial_end"]
    ]
    first = running.index(hits[0])
    assert first > 0
    assert running[:first] == [-1] * first
    assert running[first:] == [hits[0]] * (len(running) - first)


def test_steps_to_success_of_a_trial_that_ends_at_its_success() -> None:
    """`end_on_success=True` (PointGoal's default): the trial ends at the env step that
    succeeds, which is the step `steps_to_success` names."""
    env = make(trials=2, trial_len=30, end_on_success=True)
    records = run_episode(env, walk_to_goal, seed=1)
    ends = [i for i, r in enumerate(records) if r["info"]["trial_end"]]
    assert [records[i]["info"]["success"] for i in ends] == [True, True]
    for i in ends:
        # Action repeat 1: one env step after the previous observation's count.
        assert (
            records[i]["info"]["steps_to_success"] == records[i - 1]["info"]["steps_in_trial"] + 1
        )


def test_mixed_outcomes_follow_the_protocol() -> None:
    # Fail the first trial, then succeed: instruction, trial, instruction, trial, trial.
    env = make(trials=3)
    first_trial_done = {"flag": False}

    def policy(obs: dict[str, Any], info: dict[str, Any]) -> np.ndarray:
        if info["trial"] == 0:
            return ZERO
        first_trial_done["flag"] = True
        return walk_to_goal(obs, info)

    records = run_episode(env, policy, seed=2)
    assert first_trial_done["flag"]
    assert phases(records) == ["instruction", "trial", "instruction", "trial", "trial"]
    sentences = [r["info"]["instruction"] for r in records if r["info"]["phase"] == "instruction"]
    first, second = sentences[0], sentences[-1]
    assert first != second, "a re-instruction uses another sentence of the task"
    assert records[-1]["info"]["trial_successes"] == 2


def test_observation_layout_and_values_per_phase() -> None:
    env = make()
    records = run_episode(env, stand_still, seed=3)
    space = env.observation_space
    assert list(space.spaces) == [
        "state",
        "word",
        "time",
        "phase",
        "trial_success",
        "task_id",
        "prev_reward",
    ]
    table = glove()
    for record in records:
        obs, info = record["obs"], record["info"]
        assert space.contains(obs)
        assert obs["state"].dtype == np.float64 and obs["word"].dtype == np.float32
        assert obs["task_id"] == 0 == info["task_id"]
        assert obs["prev_reward"][0] == 0.0
        # Standing still never succeeds.
        assert obs["trial_success"][0] == 0.0
        if info["phase"] == "instruction":
            assert obs["phase"][0] == 1.0 and obs["time"][0] == 0.0
            assert not obs["state"].any()
            np.testing.assert_array_equal(obs["word"], table.matrix[table.row(info["token"])])
            assert info["token"] in info["instruction"].split()
        else:
            assert obs["phase"][0] == 0.0 and info["token"] == ""
            assert not obs["word"].any()
            assert obs["time"][0] == np.float32(info["steps_in_trial"] / 25)
            # The goal is hidden: only the point's position is in the state.
            assert not obs["state"][2:].any()


def test_words_are_fed_in_sentence_order() -> None:
    env = make()
    records = run_episode(env, stand_still, seed=4)
    current: list[str] = []
    for record in records:
        info = record["info"]
        if info["phase"] == "instruction":
            current.append(info["token"])
        elif current:
            assert current == info["instruction"].split()
            current = []


def test_instruction_phase_ignores_the_action_and_pays_nothing() -> None:
    a, b = make(), make()
    obs_a, info_a = a.reset(seed=5)
    obs_b, _ = b.reset(seed=5)
    rng = np.random.default_rng(0)
    steps = 0
    while info_a["phase"] == "instruction":
        wild = rng.uniform(-1, 1, size=4).astype(np.float32)
        obs_a, reward_a, *_rest, info_a = a.step(wild)
        obs_b, reward_b, *_ = b.step(ZERO)
        assert reward_a == 0.0 == reward_b
        steps += 1
    assert steps == len(info_a["instruction"].split())
    for key in obs_a:
        np.testing.assert_array_equal(obs_a[key], obs_b[key])


def test_same_seed_gives_the_same_episode_stream() -> None:
    def stream(env: MillionEnv, seed: int) -> list[Any]:
        rng = np.random.default_rng(123)
        out = []
        for episode in range(3):
            # Only the first reset is seeded; the rest continue the seeded streams.
            records = run_episode(
                env,
                lambda _o, _i: rng.uniform(-1, 1, size=4).astype(np.float32),
                seed=seed if episode == 0 else None,
            )
            for r in records:
                out.append(
                    (
                        r["info"]["task_name"],
                        r["info"]["instruction"],
                        r["obs"]["state"].tobytes(),
                        r["obs"]["word"].tobytes(),
                        r["reward"],
                    )
                )
        return out

    a = stream(make(), 11)
    assert a == stream(make(), 11)
    assert a != stream(make(), 12)


def test_goals_are_all_sampled_and_named_by_the_instruction() -> None:
    env = make(num_goals=4)
    seen = {}
    for seed in range(40):
        _obs, info = env.reset(seed=seed)
        seen[info["task_name"]] = info["goal"]
        assert info["task_name"] in info["instruction"].split()
        assert np.isclose(np.linalg.norm(info["goal"][:2]), GOAL_RADIUS)
    assert set(seen) == {"east", "north", "west", "south"}
    np.testing.assert_allclose(seen["north"][:2], [0.0, GOAL_RADIUS], atol=1e-12)


def test_heldout_instruction_set_feeds_only_heldout_sentences() -> None:
    from million_env.million.instructions import point_goal_instructions

    heldout = {s for g in point_goal_instructions("heldout", 4).values() for s in g}
    train = {s for g in point_goal_instructions("train", 4).values() for s in g}
    env = make(instruction_set="heldout")
    used = set()
    for seed in range(20):
        records = run_episode(env, stand_still, seed=seed)
        used |= {r["info"]["instruction"] for r in records}
    assert used <= heldout and not used & train and len(used) > 1


def test_no_instructions_ablation_gives_the_previous_reward() -> None:
    env = make(instructions=False)
    records = run_episode(env, walk_to_goal, seed=6)
    assert all(r["info"]["phase"] == "trial" for r in records)
    assert all(r["info"]["instruction"] == "" for r in records)
    assert all(not r["obs"]["word"].any() for r in records)
    assert records[0]["obs"]["prev_reward"][0] == 0.0
    for record in records[1:]:
        assert record["obs"]["prev_reward"][0] == np.float32(record["reward"])
    assert any(r["reward"] != 0.0 for r in records[1:])
    # Without instructions a failed trial goes straight on to the next trial.
    failed = run_episode(env, stand_still, seed=6)
    assert phases(failed) == ["trial", "trial", "trial"]


def test_reward_in_obs_gives_the_previous_reward_beside_the_words() -> None:
    env = make(reward_in_obs=True)
    records = run_episode(env, walk_to_goal, seed=6)
    # The words are still fed, and their steps pay nothing.
    fed = [r for r in records if r["info"]["phase"] == "instruction"]
    assert fed and all(r["reward"] == 0.0 for r in fed)
    assert any(r["obs"]["word"].any() for r in records)
    for record in records:
        assert record["obs"]["prev_reward"][0] == np.float32(record["reward"])
    assert any(r["reward"] != 0.0 for r in records)
    # Without the option the same episode shows no reward.
    plain = run_episode(make(), walk_to_goal, seed=6)
    assert [r["reward"] for r in plain] == [r["reward"] for r in records]
    assert not any(r["obs"]["prev_reward"][0] for r in plain)


def test_episode_time_ablation_counts_agent_steps_of_the_episode() -> None:
    env = make(time_obs="episode")
    records = run_episode(env, stand_still, seed=7)
    longest = max(len(s.split()) for g in env._sentences.values() for s in g)
    assert env.max_episode_steps == 3 * (longest + 25)
    for step, record in enumerate(records):
        assert record["info"]["episode_step"] == step
        assert record["obs"]["time"][0] == np.float32(step / env.max_episode_steps)
    assert records[-1]["obs"]["time"][0] <= 1.0


@pytest.mark.parametrize("action_repeat", [1, 3])
def test_action_repeat_steps_the_point_that_many_times(action_repeat: int) -> None:
    env = make(action_repeat=action_repeat, trial_len=10, instructions=False)
    obs, info = env.reset(seed=8)
    push = np.array([0.2, 0.0, 0.0, 0.0], dtype=np.float32)
    start = obs["state"][:2].copy()
    obs, reward, *_rest, info = env.step(push)
    assert info["steps_in_trial"] == action_repeat
    assert obs["state"][0] == pytest.approx(start[0] + action_repeat * 0.2 * 0.15)
    assert obs["state"][1] == start[1]
    # Rewards of the repeats are summed: the potential-based progress adds up.
    goal = info["goal"][:2]
    progress = np.linalg.norm(start - goal) - np.linalg.norm(obs["state"][:2] - goal)
    assert reward == pytest.approx(progress / GOAL_RADIUS)


def test_trial_len_that_is_not_a_multiple_of_the_repeat_is_not_exceeded() -> None:
    env = make(action_repeat=3, trial_len=10, instructions=False, trials=1)
    records = run_episode(env, stand_still, seed=9)
    assert [r["info"]["steps_in_trial"] for r in records] == [0, 3, 6, 9, 10]
    assert records[-1]["terminated"]


def test_trials_kwarg_sets_the_number_of_trials() -> None:
    for trials in (1, 5):
        env = make(trials=trials)
        records = run_episode(env, stand_still, seed=10)
        assert sum(r["info"]["trial_end"] for r in records) == trials
        assert records[-1]["info"]["trial"] == trials - 1


def test_info_fields_are_declared_and_always_set() -> None:
    env = make()
    declared = {f.name: f for f in env.metadata["info_fields"]}
    assert declared == {f.name: f for f in INFO_FIELDS}
    assert {"success", "trial", "task_name", "instruction", "token", "phase"} <= set(declared)
    for record in run_episode(env, walk_to_goal, seed=11):
        assert set(record["info"]) == set(declared)
        for name, field in declared.items():
            value = np.asarray(record["info"][name])
            if field.dtype == "str":
                assert isinstance(record["info"][name], str)
            else:
                assert value.shape == field.shape
                assert np.can_cast(value.dtype, np.dtype(field.dtype), casting="same_kind")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"trials": 0}, "trials"),
        ({"action_repeat": 1.5}, "action_repeat"),
        ({"trial_len": True}, "trial_len"),
        ({"time_obs": "wall"}, "time_obs"),
        ({"instructions": "yes"}, "instructions"),
        ({"instruction_set": "test"}, "instruction_set"),
        ({"num_goals": 3}, "num_goals"),
        ({"task_order": "sorted"}, "task_order"),
    ],
)
def test_bad_kwargs_are_clear_errors(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make(**kwargs)


def test_bad_action_in_a_trial_is_rejected() -> None:
    env = make(instructions=False)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, dtype=np.float32))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0, 0, 0], dtype=np.float32))


def test_word_following_agent_succeeds_and_word_ignoring_agent_does_not() -> None:
    """What makes PointGoal a learning test: the words carry the goal.

    The follower only sees observations: it matches each word vector against the
    goal names' GloVe rows, remembers the match, and walks in that direction.
    """
    table = glove()
    names = ["east", "north", "west", "south"]
    name_vectors = {n: table.matrix[table.row(n)] for n in names}
    directions = {"east": (1, 0), "north": (0, 1), "west": (-1, 0), "south": (0, -1)}

    def follower() -> Policy:
        memory = {"goal": None}

        def act(obs: dict[str, Any], _info: dict[str, Any]) -> np.ndarray:
            if obs["phase"][0] == 1.0:
                for n, v in name_vectors.items():
                    if np.array_equal(obs["word"], v):
                        memory["goal"] = n
                return ZERO
            target = GOAL_RADIUS * np.array(directions[memory["goal"]], dtype=np.float64)
            action = np.zeros(4, dtype=np.float32)
            action[:2] = np.clip((target - obs["state"][:2]) / 0.15, -1, 1)
            return action

        return act

    def always_east(obs: dict[str, Any], _info: dict[str, Any]) -> np.ndarray:
        target = np.array([GOAL_RADIUS, 0.0])
        action = np.zeros(4, dtype=np.float32)
        action[:2] = np.clip((target - obs["state"][:2]) / 0.15, -1, 1)
        return action

    env = make()
    episodes = 200
    follow = ignore = 0
    for seed in range(episodes):
        follow += first_trial_success(run_episode(env, follower(), seed=seed))
        ignore += first_trial_success(run_episode(env, always_east, seed=seed))
    assert follow == episodes
    assert 0.15 < ignore / episodes < 0.35


def first_trial_success(records: list[dict[str, Any]]) -> bool:
    return next(r["info"]["success"] for r in records if r["info"]["trial_end"])


def test_cycle_task_order_gives_envs_seeded_in_a_row_every_goal_equally() -> None:
    names = []
    for i in range(8):
        env = make(task_order="cycle")
        _, info = env.reset(seed=40 + i)
        names.append(info["task_name"])
    # 4 goals, 8 envs seeded in a row: each goal exactly twice.
    assert len(set(names)) == 4
    assert all(names.count(n) == 2 for n in set(names))


def test_sentence_choice_is_independent_of_the_goal_choice() -> None:
    # Goal and sentence come from different streams of the same seed; drawn from
    # one stream, each goal would be paired with only one or two templates.
    env = make()
    templates: dict[str, set[str]] = {}
    for seed in range(200):
        _obs, info = env.reset(seed=seed)
        template = info["instruction"].replace(info["task_name"], "{goal}")
        templates.setdefault(info["task_name"], set()).add(template)
    assert len(templates) == 4
    assert all(len(used) == 5 for used in templates.values()), templates
