"""MetaWorldTaskSampler: seeded, reproducible task/goal sampling on real Meta-World."""

from __future__ import annotations

import numpy as np
import pytest

from million_env.metaworld_tasks import ALL_TASK_NAMES, BuiltEnvs, MetaWorldTaskSampler


def _rollout(sampler: MetaWorldTaskSampler, episodes: int) -> list[tuple[str, int, bytes]]:
    out = []
    for _ in range(episodes):
        sampled = sampler.sample()
        obs, _info = sampled.env.reset()
        out.append((sampled.name, sampled.task_id, obs.tobytes()))
    return out


def test_task_names_are_mt50_v3() -> None:
    assert len(ALL_TASK_NAMES) == 50
    assert len(set(ALL_TASK_NAMES)) == 50
    assert all(name.endswith("-v3") for name in ALL_TASK_NAMES)
    assert "reach-v3" in ALL_TASK_NAMES


def test_ml1_same_seed_same_tasks_and_obs() -> None:
    a = _rollout(MetaWorldTaskSampler("ML1", "train", task="reach-v3", seed=3), 6)
    b = _rollout(MetaWorldTaskSampler("ML1", "train", task="reach-v3", seed=3), 6)
    assert a == b
    assert {name for name, _, _ in a} == {"reach-v3"}
    assert a[0][1] == ALL_TASK_NAMES.index("reach-v3")
    # Goals vary between episodes, so the reset observations of ML1 (goal hidden)
    # still differ through the object/hand layout of each goal's rand_vec.
    assert len({obs for _, _, obs in a}) > 1


def test_ml1_different_seeds_differ() -> None:
    a = _rollout(MetaWorldTaskSampler("ML1", "train", task="reach-v3", seed=1), 6)
    b = _rollout(MetaWorldTaskSampler("ML1", "train", task="reach-v3", seed=2), 6)
    assert a != b


def test_reseed_restarts_the_sequence_and_env_rngs() -> None:
    sampler = MetaWorldTaskSampler("ML10", "train", seed=5)
    first = _rollout(sampler, 8)
    first_action = sampler.envs()[0].action_space.sample()
    sampler.seed(5)
    again = _rollout(sampler, 8)
    again_action = sampler.envs()[0].action_space.sample()
    assert first == again
    np.testing.assert_array_equal(first_action, again_action)
    assert len({name for name, _, _ in first}) > 1
    assert all(name in sampler.task_names for name, _, _ in first)


def test_ml10_split_classes() -> None:
    train = MetaWorldTaskSampler("ML10", "train", seed=0)
    test = MetaWorldTaskSampler("ML10", "test", seed=0)
    assert len(train.task_names) == 10
    assert len(test.task_names) == 5
    assert not set(train.task_names) & set(test.task_names)
    sampled = test.sample()
    assert sampled.name in test.task_names
    obs, _ = sampled.env.reset()
    assert obs.dtype == np.float64 and obs.shape == (39,)


@pytest.mark.parametrize(
    ("benchmark", "split", "task", "message"),
    [
        ("ML2", "train", None, "unknown Meta-World benchmark"),
        ("ML10", "validation", None, "unknown split"),
        ("ML1", "train", None, "ML1 needs a task name"),
        ("ML1", "train", "fly-v3", "unknown Meta-World task"),
        ("ML10", "train", "reach-v3", "takes no task name"),
    ],
)
def test_bad_arguments_are_value_errors(
    benchmark: str, split: str, task: str | None, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        MetaWorldTaskSampler(benchmark, split, task=task)


def test_tasks_selects_a_subset_of_the_split_in_its_order() -> None:
    sampler = MetaWorldTaskSampler(
        "ML10", "train", seed=0, tasks=["push-v3", "reach-v3"], task_order="cycle"
    )
    assert sampler.task_names == ("reach-v3", "push-v3")
    assert {sampler.sample().name for _ in range(6)} == {"reach-v3", "push-v3"}


@pytest.mark.parametrize(
    ("benchmark", "tasks", "message"),
    [
        ("ML10", [], "non-empty list"),
        ("ML10", "reach-v3", "non-empty list"),
        ("ML10", [["reach-v3"]], "non-empty list"),
        ("ML10", ["reach-v3", "drawer-open-v3"], r"\['drawer-open-v3'\] not in the split"),
        ("ML10", ["reach-v3", "reach-v3"], "names a task twice"),
        ("ML1", ["reach-v3"], "not `tasks`"),
    ],
)
def test_bad_task_subsets_are_value_errors(benchmark: str, tasks: object, message: str) -> None:
    task = "reach-v3" if benchmark == "ML1" else None
    with pytest.raises(ValueError, match=message):
        MetaWorldTaskSampler(benchmark, "train", task=task, tasks=tasks)  # type: ignore[arg-type]


def test_cycle_order_starts_at_seed_mod_n_and_takes_classes_in_turn() -> None:
    sampler = MetaWorldTaskSampler("ML10", "test", task_order="cycle")
    names = sampler.task_names
    for seed in (0, 3, 7):
        sampler.seed(seed)
        got = [sampler.sample().name for _ in range(len(names) + 1)]
        expected = [names[(seed + k) % len(names)] for k in range(len(names) + 1)]
        assert got == expected
    # Envs seeded s + i, one episode each, cover every class equally.
    firsts = []
    for i in range(3 * len(names)):
        sampler.seed(100 + i)
        firsts.append(sampler.sample().name)
    assert all(firsts.count(n) == 3 for n in names)
    with pytest.raises(ValueError, match="task_order"):
        MetaWorldTaskSampler("ML10", "test", task_order="sorted")


def test_negative_seed_rejected() -> None:
    sampler = MetaWorldTaskSampler("ML1", "train", task="reach-v3")
    with pytest.raises(ValueError, match="non-negative"):
        sampler.seed(-1)


def test_samplers_share_built_envs_and_keep_their_own_sequences() -> None:
    built = BuiltEnvs(max_idle=3)
    alone = _rollout(MetaWorldTaskSampler("ML10", "train", seed=8, built_envs=built), 10)
    built_before = built.builds
    # Two samplers interleaved on the same envs: each sees what it saw alone.
    a = MetaWorldTaskSampler("ML10", "train", seed=8, built_envs=built)
    b = MetaWorldTaskSampler("ML10", "train", seed=9, built_envs=built)
    mixed_a, mixed_b = [], []
    for _ in range(10):
        mixed_a += _rollout(a, 1)
        mixed_b += _rollout(b, 1)
    assert mixed_a == alone
    assert mixed_b == _rollout(MetaWorldTaskSampler("ML10", "train", seed=9), 10)
    assert len({name for name, _, _ in alone}) > 2
    # Each sampler holds one env; at most 3 wait idle; idle ones were reused, not rebuilt.
    assert len(a.envs()) == 1 and len(b.envs()) == 1
    assert built.idle() <= 3
    assert built.builds - built_before < 20
    a.close()
    b.close()
    assert a.envs() == [] and built.idle() <= 3
    with pytest.raises(ValueError, match="idle envs"):
        BuiltEnvs(max_idle=-1)
