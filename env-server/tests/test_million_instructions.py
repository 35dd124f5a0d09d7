"""Instruction data and GloVe encoding of the MILLION protocol, on the real GloVe table."""

from __future__ import annotations

import logging

import gymnasium
import numpy as np
import pytest

from million_env.metaworld_tasks import ALL_TASK_NAMES
from million_env.million import protocol_stats, register_envs
from million_env.million.glove import EMBED_DIM, glove
from million_env.million.instructions import (
    INSTRUCTION_SETS,
    NOISE_VOCABULARY,
    InstructionEncoder,
    metaworld_instructions,
    point_goal_instructions,
    tokenize,
    unknown_words,
    with_word_noise,
)
from million_env.million.protocol import PHASE_INSTRUCTION

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


def every_instruction_word() -> set[str]:
    words = set()
    for instruction_set in INSTRUCTION_SETS:
        for group in metaworld_instructions(instruction_set).values():
            for sentence in group:
                words.update(tokenize(sentence))
        for count in POINT_GOAL_COUNTS:
            for group in point_goal_instructions(instruction_set, count).values():
                for sentence in group:
                    words.update(tokenize(sentence))
    return words


def test_word_noise_replaces_words_but_goal_pos_by_unused_glove_words() -> None:
    goal = np.array([0.05, 0.85, 0.2])
    clean = InstructionEncoder().encode("move the hand to goal_pos", goal)
    rng = np.random.default_rng(0)
    noisy = [with_word_noise(clean, 0.5, rng) for _ in range(200)]
    table = glove()
    used = every_instruction_word()
    replaced = 0
    for instruction in noisy:
        assert instruction.text == clean.text
        assert instruction.tokens[-1] == "goal_pos"
        np.testing.assert_array_equal(instruction.vectors[-1], clean.vectors[-1])
        for i, (token, original) in enumerate(zip(instruction.tokens, clean.tokens, strict=True)):
            if token == original:
                np.testing.assert_array_equal(instruction.vectors[i], clean.vectors[i])
                continue
            replaced += 1
            assert token not in used
            assert table.row(token) < NOISE_VOCABULARY
            np.testing.assert_array_equal(instruction.vectors[i], table.vector(token))
    # 4 replaceable words at p = 0.5 over 200 draws: ~400 replacements.
    assert 300 < replaced < 500
    assert with_word_noise(clean, 0.0, rng) is clean


def test_word_noise_in_the_protocol_is_seeded_and_keeps_the_goal_word() -> None:
    def fed_words(seed: int, word_noise: float) -> list[np.ndarray]:
        register_envs()
        env = gymnasium.make("million/ML1-train", word_noise=word_noise)
        obs, info = env.reset(seed=seed)
        words = []
        while info["phase"] == PHASE_INSTRUCTION:
            words.append(obs["word"].copy())
            obs, _reward, _terminated, _truncated, info = env.step(np.zeros(4, dtype=np.float32))
        env.close()
        return words

    clean, noisy, again = fed_words(3, 0.0), fed_words(3, 0.9), fed_words(3, 0.9)
    assert len(clean) == len(noisy)
    assert all(np.array_equal(a, b) for a, b in zip(noisy, again, strict=True))
    # The goal word (the last, [x, y, z, 0...]) is kept; most others are replaced.
    np.testing.assert_array_equal(noisy[-1], clean[-1])
    assert sum(not np.array_equal(a, b) for a, b in zip(noisy[:-1], clean[:-1], strict=True)) > 0
    for bad in (-0.1, 1.0, True, "0.2"):
        with pytest.raises(ValueError, match="word_noise"):
            gymnasium.make("million/ML1-train", word_noise=bad)
