"""The MILLION protocol's options, declared once.

Each option is one field of `ProtocolOptions`: its default (per task source where they
differ), the values it takes with their check, a one-line description, and which task
sources take it. The env (`protocol.MillionEnv`), the factories (`envs.py`), the registered
kwargs and ListEnvs descriptions (`registry.py`) and the table in env-server/README.md
(`options_table()`, checked by a test) all read this declaration, so an option is added
with one field here plus its behaviour.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from million_env.metaworld_tasks import TASK_ORDERS
from million_env.million.instructions import (
    INSTRUCTION_SETS,
    check_instruction_set,
    point_goal_counts,
)
from million_env.million.metaworld_source import OBJECT_POSITIONS

#: The task sources, as `Option.sources` names them: Meta-World (million/ML*) and PointGoal.
METAWORLD = "metaworld"
POINT_GOAL = "point_goal"
SOURCES: tuple[str, ...] = (METAWORLD, POINT_GOAL)
#: The ids of each source, as messages and the README table name them.
SOURCE_IDS = {METAWORLD: "million/ML*", POINT_GOAL: "million/PointGoal"}

TIME_OBS_MODES: tuple[str, ...] = ("trial", "episode")
#: What `goal_pos` names: the real goal, or (a diagnostic) the real goal reflected through
#: the centre of the task's goal range, a wrong goal about as far from the centre (on reach
#: ~19 cm RMS from the real one; ~1 % of goals lie so near the centre that it is within 5 cm).
INSTRUCTION_GOALS: tuple[str, ...] = ("real", "reflected")
#: How `goal_pos` writes the goal into the word vector's first three entries: "raw" metres
#: (the original code), or "range": each coordinate mapped affinely from the task's goal range
#: to [-1, 1] and clipped there. Reach's goals span only 0.1 to 0.25 m per axis (std 0.03 to
#: 0.07), against a GloVe entry's std of 0.64; "range" gives them the scale of the words
#: around them (docs/experiments/2026-11-23-ml1-reach-goal-word.md, "The goal word's scale").
GOAL_ENCODINGS: tuple[str, ...] = ("raw", "range")


@dataclass(frozen=True)
class Allowed:
    """The values an option takes: a plain-text summary (no Markdown: it lands in table
    cells and ListEnvs descriptions) and the check, which raises ValueError naming the option."""

    text: str
    check: Callable[[str, Any], None]


def one_of(choices: tuple[Any, ...]) -> Allowed:
    """One of `choices`, compared with ==."""

    def check(name: str, value: Any) -> None:
        if value not in choices:
            raise ValueError(f"{name} must be one of {choices}, got {value!r}")

    return Allowed(", ".join(repr(c) for c in choices), check)


def _check_bool(name: str, value: Any) -> None:
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be a bool, got {value!r}")


def _check_positive_int(name: str, value: Any) -> None:
    # bool is an int subclass; True as a count is a mistake, not 1.
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")


def _check_probability(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < 1.0:
        raise ValueError(f"{name} must be a probability in [0, 1), got {value!r}")


def _check_goal_count(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value not in point_goal_counts():
        raise ValueError(f"{name} must be one of {list(point_goal_counts())}, got {value!r}")


BOOL = Allowed("bool", _check_bool)
POSITIVE_INT = Allowed("int >= 1", _check_positive_int)
PROBABILITY = Allowed("float in [0, 1)", _check_probability)


@dataclass(frozen=True)
class Option:
    """One declared option (a field of `ProtocolOptions`)."""

    name: str
    default: Any
    allowed: Allowed
    about: str
    sources: tuple[str, ...]
    source_defaults: Mapping[str, Any]

    def default_for(self, source: str) -> Any:
        """The default on ids of `source` (the general default unless it has its own)."""
        return self.source_defaults.get(source, self.default)

    def describe(self) -> str:
        """Allowed values and meaning, one line (ListEnvs descriptions)."""
        return f"{self.allowed.text}; {self.about}"


_DECLARED = "million_option"


def _option(
    default: Any,
    allowed: Allowed,
    about: str,
    *,
    sources: tuple[str, ...] = SOURCES,
    **source_defaults: Any,
) -> Any:
    """A `ProtocolOptions` field: `default` everywhere but where a source named in
    `source_defaults` (e.g. ``point_goal=1``) has its own."""
    unknown = set(source_defaults) - set(sources)
    if unknown:
        raise TypeError(f"defaults for sources that do not take the option: {sorted(unknown)}")
    declared = {"default": default, "allowed": allowed, "about": about, "sources": sources}
    return dataclasses.field(
        default=default, metadata={_DECLARED: {**declared, "source_defaults": source_defaults}}
    )


@dataclass(frozen=True)
class ProtocolOptions:
    """Every option of the MILLION env ids, validated on construction.

    Field order is the order of the registered kwargs and of the documentation table.
    `for_source` builds one from the kwargs an id was made with.
    """

    num_goals: int = _option(
        4,
        Allowed(", ".join(map(str, point_goal_counts())), _check_goal_count),
        "compass goals on a circle around the start",
        sources=(POINT_GOAL,),
    )
    instruction_set: str = _option(
        "train",
        Allowed(", ".join(map(repr, INSTRUCTION_SETS)), lambda _n, v: check_instruction_set(v)),
        "'train' sentences, or 'heldout' paraphrases never used in training",
    )
    instructions: bool = _option(
        True,
        BOOL,
        "False: no instruction phases (ablation), and prev_reward holds the previous reward",
    )
    reward_in_obs: bool = _option(
        False,
        BOOL,
        "True: prev_reward holds the previous reward with instructions too (without them it "
        "always does)",
    )
    time_obs: str = _option(
        "trial",
        one_of(TIME_OBS_MODES),
        "what the time observation counts: env steps of the trial, or agent steps of the episode",
    )
    action_repeat: int = _option(2, POSITIVE_INT, "env steps per agent step", point_goal=1)
    trials: int = _option(3, POSITIVE_INT, "trials per episode")
    trial_len: int = _option(
        200,
        POSITIVE_INT,
        "env steps per trial (at most what the task allows after a reset: Meta-World 500)",
        point_goal=25,
    )
    task_order: str = _option(
        "random",
        one_of(TASK_ORDERS),
        "'cycle': task (seed + k) mod n at the k-th episode, for evaluations with equal shares",
    )
    instruction_goal: str = _option(
        "real",
        one_of(INSTRUCTION_GOALS),
        "diagnostic 'reflected': goal_pos names the real goal reflected through the goal "
        "range's centre, a wrong goal",
    )
    goal_encoding: str = _option(
        "raw",
        one_of(GOAL_ENCODINGS),
        "goal_pos in metres ('raw'), or scaled from the task's goal range to [-1, 1] per axis",
    )
    goal_in_state: bool = _option(
        False,
        BOOL,
        "diagnostic: the real goal also in the trial state's last three entries, as MT1 shows it",
    )
    # The original code runs every trial for its full length and records whether it succeeded
    # at any step. Ending at success makes Meta-World's dense rewards pay for *not* succeeding:
    # a scripted reach policy hovering 12 cm from the goal earns 5,129 per episode (discounted
    # at 0.99: 1,489) against 948 (620) for one that succeeds at once, since each success cuts
    # its trial's reward short (docs/experiments/2026-12-01-full-length-trials.md). PointGoal's
    # potential-based reward is built for it.
    end_on_success: bool = _option(
        False,
        BOOL,
        "True: a trial ends at the env step that succeeds; False: it runs its full length",
        point_goal=True,
    )
    word_noise: float = _option(
        0.0,
        PROBABILITY,
        "augmentation: each instruction word but goal_pos replaced with this probability by a "
        "random frequent GloVe word that no sentence uses",
    )
    object_position: str = _option(
        "task",
        one_of(OBJECT_POSITIONS),
        "'centre': reach-v3's puck at one place for every goal, so it does not tell the goal "
        "(reach-v3 only)",
        sources=(METAWORLD,),
    )

    def __post_init__(self) -> None:
        for option in declared_options():
            option.allowed.check(option.name, getattr(self, option.name))

    @classmethod
    def for_source(cls, source: str, given: Mapping[str, Any]) -> ProtocolOptions:
        """The options of an id over `source` made with kwargs `given`: the source's defaults
        for the rest. TypeError for an option the source does not take (what Python raises
        for an unknown keyword), ValueError for a bad value."""
        taken = {option.name: option for option in declared_options() if source in option.sources}
        unknown = [name for name in given if name not in taken]
        if unknown:
            raise TypeError(
                f"got an unexpected keyword argument {unknown[0]!r}; the options of "
                f"{SOURCE_IDS[source]} are {', '.join(taken)}"
            )
        values = {name: option.default_for(source) for name, option in taken.items()}
        return cls(**{**values, **given})

    @staticmethod
    def defaults(source: str) -> dict[str, Any]:
        """{option: default} of the options `source` takes, in declaration order."""
        return {o.name: o.default_for(source) for o in declared_options() if source in o.sources}


@functools.cache
def declared_options() -> tuple[Option, ...]:
    """Every option, in the field order of `ProtocolOptions`."""
    return tuple(
        Option(name=f.name, **f.metadata[_DECLARED]) for f in dataclasses.fields(ProtocolOptions)
    )


def options_table() -> str:
    """The Markdown table of env-server/README.md (a test keeps the two equal)."""
    headings = [f"`{SOURCE_IDS[s]}` default" for s in SOURCES]
    rows = [
        "| option | " + " | ".join(headings) + " | values | what it does |",
        "| --- | " + " | ".join("---" for _ in SOURCES) + " | --- | --- |",
    ]
    for option in declared_options():
        defaults = [
            f"`{option.default_for(s)!r}`" if s in option.sources else "not taken" for s in SOURCES
        ]
        rows.append(
            f"| `{option.name}` | " + " | ".join(defaults) + f" | {option.allowed.text} | "
            f"{option.about} |"
        )
    return "\n".join(rows) + "\n"
