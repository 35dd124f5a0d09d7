"""Instruction data and GloVe encoding of the MILLION protocol, on the real GloVe table."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from million_env.metaworld_tasks import ALL_TASK_NAMES
from million_env.million import protocol_stats
from million_env.million.glove import EMBED_DIM, glove
from million_env.million.instructions import (
    INSTRUCTION_SETS,
    InstructionEncoder,
    metaworld_instructions,
    point_goal_instructions,
    tokenize,
    unknown_words,
)

POINT_GOAL_COUNTS = (2, 4, 8)


def test_glove_is_the_real_6b_50d_table() -> None:
    table = glove()
    assert table.matrix.shape == (400_000, EMBED_DIM)
    assert table.matrix.dtype == np.float32
    # Memory-mapped, not read into RAM.
    assert isinstance(table.matrix, np.memmap)
    assert table.row("the") == 0
    # Lookups are case-insensitive (GloVe 6B is lower-cased).
    assert table.row("Door") == table.row("door")
    np.testing.assert_array_equal(table.vector("door"), table.matrix[table.row("door")])
    assert glove() is table


@pytest.mark.parametrize("instruction_set", INSTRUCTION_SETS)
def test_every_metaworld_task_has_at_least_four_sentences(instruction_set: str) -> None:
    sentences = metaworld_instructions(instruction_set)
    assert set(sentences) == set(ALL_TASK_NAMES)
    for name, group in sentences.items():
        assert len(group) >= 4, name
        assert len(set(group)) == len(group), f"{name} repeats a sentence"


def test_heldout_sentences_are_disjoint_from_training() -> None:
    train = metaworld_instructions("train")
    heldout = metaworld_instructions("heldout")
    for name in ALL_TASK_NAMES:
        assert not set(train[name]) & set(heldout[name]), name
    all_train = {s for group in train.values() for s in group}
    all_heldout = {s for group in heldout.values() for s in group}
    assert not all_train & all_heldout
    for num_goals in POINT_GOAL_COUNTS:
        pg_train = point_goal_instructions("train", num_goals)
        pg_heldout = point_goal_instructions("heldout", num_goals)
        for goal in pg_train:
            assert not set(pg_train[goal]) & set(pg_heldout[goal])


def test_no_instruction_word_is_missing_from_glove() -> None:
    for instruction_set in INSTRUCTION_SETS:
        assert unknown_words(metaworld_instructions(instruction_set)) == []
        for num_goals in POINT_GOAL_COUNTS:
            assert unknown_words(point_goal_instructions(instruction_set, num_goals)) == []


def test_metaworld_sentences_name_a_goal_or_an_object_of_their_task() -> None:
    # Reach-like tasks must tell where to go; the rest name what to act on.
    train = metaworld_instructions("train")
    for group in (train["reach-v3"], train["push-v3"], train["pick-place-v3"]):
        assert all("goal_pos" in tokenize(s) for s in group)
    assert all("door" in tokenize(s) for s in train["door-open-v3"])
    assert all("drawer" in tokenize(s) for s in train["drawer-close-v3"])
    assert all(tokenize(s) for s in train["peg-insert-side-v3"])


def test_point_goal_sentences_name_exactly_their_goal() -> None:
    sentences = point_goal_instructions("train", 4)
    assert list(sentences) == ["east", "north", "west", "south"]
    for goal, group in sentences.items():
        for sentence in group:
            named = [g for g in sentences if g in tokenize(sentence)]
            assert named == [goal], sentence
    # The goal words must be told apart by their vectors.
    vectors = np.stack([glove().vector(goal) for goal in sentences])
    assert len({v.tobytes() for v in vectors}) == 4
    with pytest.raises(ValueError, match="num_goals"):
        point_goal_instructions("train", 5)


def test_unknown_instruction_set_is_rejected() -> None:
    with pytest.raises(ValueError, match="instruction_set"):
        metaworld_instructions("validation")


def test_encoding_uses_glove_rows_and_the_real_goal() -> None:
    encoder = InstructionEncoder()
    goal = np.array([0.1, 0.8, 0.05])
    encoded = encoder.encode("Reach To goal_pos", goal)
    assert encoded.tokens == ("reach", "to", "goal_pos")
    table = glove()
    np.testing.assert_array_equal(encoded.vectors[0], table.matrix[table.row("reach")])
    np.testing.assert_array_equal(encoded.vectors[1], table.matrix[table.row("to")])
    expected_goal = np.zeros(EMBED_DIM, dtype=np.float32)
    expected_goal[:3] = goal
    np.testing.assert_array_equal(encoded.vectors[2], expected_goal)
    # The cached goal-free part is not changed by the goal of an earlier call.
    other = encoder.encode("Reach To goal_pos", np.array([-0.2, 0.6, 0.2]))
    np.testing.assert_array_equal(other.vectors[2, :3], np.float32([-0.2, 0.6, 0.2]))
    np.testing.assert_array_equal(encoded.vectors[2], expected_goal)


def test_unknown_word_is_zero_counted_and_logged_once(caplog: pytest.LogCaptureFixture) -> None:
    encoder = InstructionEncoder()
    before = protocol_stats()
    with caplog.at_level(logging.WARNING, logger="million_env.million.stats"):
        encoded = encoder.encode("press the qzxvbnt button", np.zeros(3))
        encoder.encode("press the qzxvbnt button", np.zeros(3))
    after = protocol_stats()
    np.testing.assert_array_equal(encoded.vectors[2], np.zeros(EMBED_DIM, dtype=np.float32))
    assert after["unknown_words"] - before["unknown_words"] == 2
    assert after["instruction_tokens"] - before["instruction_tokens"] == 8
    assert sum("qzxvbnt" in record.getMessage() for record in caplog.records) == 1


def test_check_instructions_command_reports_zero_unknown_words() -> None:
    import json
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "million_env.million.check_instructions"],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["unknown_words_total"] == 0
    assert report["sets"]["metaworld/train"]["sentences"] >= 200
    assert report["sets"]["metaworld/heldout"]["sentences"] >= 200
