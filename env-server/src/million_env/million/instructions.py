"""Instruction sentences (from the package's data files) and their GloVe encoding."""

from __future__ import annotations

import functools
import json
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np
import numpy.typing as npt

from million_env.million.glove import EMBED_DIM, GOAL_TOKEN, glove
from million_env.million.stats import COUNTERS

INSTRUCTION_SETS: tuple[str, ...] = ("train", "heldout")
METAWORLD_FILE = "metaworld_instructions.json"
POINT_GOAL_FILE = "point_goal_instructions.json"


def read_data_file(name: str) -> dict[str, Any]:
    """A JSON file shipped in ``million_env/data``."""
    text = resources.files("million_env.data").joinpath(name).read_text(encoding="utf-8")
    data = json.loads(text)
    if not isinstance(data, dict):
        raise ValueError(f"instruction file {name} must hold a JSON object")
    return data


def tokenize(sentence: str) -> tuple[str, ...]:
    """Lower-cased whitespace tokens; ``goal_pos`` is kept as the goal placeholder."""
    tokens = tuple(word.lower() for word in sentence.split())
    if not tokens:
        raise ValueError("an instruction sentence must have at least one word")
    return tokens


def check_instruction_set(instruction_set: Any) -> None:
    """A ValueError unless `instruction_set` names one of `INSTRUCTION_SETS`."""
    if instruction_set not in INSTRUCTION_SETS:
        raise ValueError(
            f"unknown instruction_set {instruction_set!r}; expected one of {INSTRUCTION_SETS}"
        )


def _sentence_list(where: str, value: Any) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(s, str) for s in value):
        raise ValueError(f"{where} must be a non-empty list of sentences")
    for sentence in value:
        tokenize(sentence)
    return tuple(value)


def metaworld_instructions(instruction_set: str) -> dict[str, tuple[str, ...]]:
    """{task name: sentences} of the chosen set for all 50 Meta-World v3 tasks."""
    check_instruction_set(instruction_set)
    tasks = read_data_file(METAWORLD_FILE).get("tasks")
    if not isinstance(tasks, dict):
        raise ValueError(f"{METAWORLD_FILE} has no 'tasks' object")
    return {
        name: _sentence_list(
            f"{METAWORLD_FILE} tasks.{name}.{instruction_set}", sets.get(instruction_set)
        )
        for name, sets in tasks.items()
    }


@functools.cache
def point_goal_counts() -> tuple[int, ...]:
    """The goal counts PointGoal has sentences for (`num_goals`), ascending."""
    goal_names = read_data_file(POINT_GOAL_FILE).get("goal_names", {})
    return tuple(sorted(int(count) for count in goal_names))


def point_goal_instructions(instruction_set: str, num_goals: int) -> dict[str, tuple[str, ...]]:
    """{goal name: sentences} for PointGoal with `num_goals` goals, in goal order."""
    check_instruction_set(instruction_set)
    data = read_data_file(POINT_GOAL_FILE)
    names = data.get("goal_names", {}).get(str(num_goals))
    if names is None:
        counts = list(point_goal_counts())
        raise ValueError(f"num_goals must be one of {counts}, got {num_goals!r}")
    templates = _sentence_list(f"{POINT_GOAL_FILE} {instruction_set}", data.get(instruction_set))
    for template in templates:
        if "{goal}" not in template:
            raise ValueError(f"PointGoal template {template!r} does not name the goal")
    return {name: tuple(t.replace("{goal}", name) for t in templates) for name in names}


@dataclass(frozen=True)
class EncodedInstruction:
    """One sentence as the word vectors fed during an instruction phase."""

    text: str  # the sentence chosen
    tokens: tuple[str, ...]  # the words fed (`word_noise` may have replaced some of the text's)
    vectors: npt.NDArray[np.float32]  # (len(tokens), 50); read-only


class InstructionEncoder:
    """Turns sentences into GloVe rows, caching the goal-free part per sentence.

    The cache matters for speed only: a sentence's words never change, only the
    goal that `goal_pos` stands for.
    """

    def __init__(self) -> None:
        self._glove = glove()
        self._lock = threading.Lock()
        self._cache: dict[str, tuple[tuple[str, ...], npt.NDArray[np.float32], list[str]]] = {}

    def _lookup(self, sentence: str) -> tuple[tuple[str, ...], npt.NDArray[np.float32], list[str]]:
        with self._lock:
            cached = self._cache.get(sentence)
        if cached is not None:
            return cached
        tokens = tokenize(sentence)
        vectors = np.zeros((len(tokens), EMBED_DIM), dtype=np.float32)
        unknown: list[str] = []
        for i, token in enumerate(tokens):
            if token == GOAL_TOKEN:
                continue
            vector = self._glove.vector(token)
            if vector is None:
                unknown.append(token)
            else:
                vectors[i] = vector
        entry = (tokens, vectors, unknown)
        with self._lock:
            self._cache[sentence] = entry
        return entry

    def encode(self, sentence: str, goal: npt.NDArray[np.floating]) -> EncodedInstruction:
        """The sentence's vectors with ``goal_pos`` as [goal_x, goal_y, goal_z, 0 x 47].

        Every call counts its tokens (and unknown words) in the process counters,
        since each call is one instruction fed to an agent.
        """
        tokens, base, unknown = self._lookup(sentence)
        vectors = base.copy()
        goal_rows = [i for i, token in enumerate(tokens) if token == GOAL_TOKEN]
        if goal_rows:
            goal = np.asarray(goal, dtype=np.float64).reshape(-1)
            if goal.shape != (3,):
                raise ValueError(f"goal_pos needs a 3-d goal, got shape {goal.shape}")
            vectors[goal_rows, :3] = goal.astype(np.float32)
        vectors.flags.writeable = False
        COUNTERS.count_tokens(len(tokens), unknown)
        return EncodedInstruction(text=sentence, tokens=tokens, vectors=vectors)


#: Rows of GloVe's most frequent words that `word_noise` draws its replacements from.
NOISE_VOCABULARY = 20_000


@functools.cache
def noise_rows() -> npt.NDArray[np.int64]:
    """Rows among GloVe's `NOISE_VOCABULARY` most frequent words (GloVe lists words by
    frequency) that no shipped sentence uses, training or held-out: a word that replaces
    another under `word_noise` never teaches a held-out paraphrase's words."""
    table = glove()
    used = set()
    for instruction_set in INSTRUCTION_SETS:
        groups = [*metaworld_instructions(instruction_set).values()]
        for count in point_goal_counts():
            groups.extend(point_goal_instructions(instruction_set, count).values())
        for group in groups:
            for sentence in group:
                used.update(tokenize(sentence))
    used_rows = {row for row in (table.row(word) for word in used) if row is not None}
    return np.array(
        [row for row in range(NOISE_VOCABULARY) if row not in used_rows], dtype=np.int64
    )


def with_word_noise(
    instruction: EncodedInstruction, probability: float, rng: np.random.Generator
) -> EncodedInstruction:
    """The instruction with each word but ``goal_pos`` replaced, with `probability`, by a
    random word of `noise_rows()` (its GloVe vector and its token); ``text`` stays the
    sentence. A training-time augmentation: the goal word stays, the wording varies."""
    replace = rng.random(len(instruction.tokens)) < probability
    replace &= np.array([token != GOAL_TOKEN for token in instruction.tokens])
    if not replace.any():
        return instruction
    pool = noise_rows()
    table = glove()
    rows = pool[rng.integers(len(pool), size=int(replace.sum()))]
    vectors = instruction.vectors.copy()
    vectors[replace] = table.matrix[rows]
    vectors.flags.writeable = False
    tokens = list(instruction.tokens)
    for index, row in zip(np.flatnonzero(replace), rows, strict=True):
        tokens[index] = table.word(int(row))
    return EncodedInstruction(text=instruction.text, tokens=tuple(tokens), vectors=vectors)


def unknown_words(sentences: Mapping[str, Sequence[str]]) -> list[str]:
    """Every token of the given sentences that GloVe lacks (``goal_pos`` excepted)."""
    table = glove()
    return [
        token
        for group in sentences.values()
        for sentence in group
        for token in tokenize(sentence)
        if token != GOAL_TOKEN and token not in table
    ]
