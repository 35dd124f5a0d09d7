"""Entry points of the MILLION env ids (see `registry.py`).

Both take the protocol options as keyword arguments (`million_env.million.options`
declares them, their defaults per source and their checks); only what picks the task
set (Meta-World's `task` and `tasks`) is a parameter of its own.
"""

from __future__ import annotations

from typing import Any

from million_env.million.instructions import metaworld_instructions, point_goal_instructions
from million_env.million.metaworld_source import MetaWorldSource
from million_env.million.options import METAWORLD, POINT_GOAL, ProtocolOptions
from million_env.million.point_goal import PointGoalSource
from million_env.million.protocol import MillionEnv


def make_metaworld_million(
    benchmark: str,
    split: str,
    *,
    task: str | None = None,
    tasks: list[str] | None = None,
    **options: Any,
) -> MillionEnv:
    """MILLION episodes over a Meta-World v3 benchmark split (ML1 needs `task`; ML10 and ML45
    take `tasks`, a subset of the split's classes); trials run their full length (the
    original code; `million_env.million.options` says why). `object_position="centre"`
    puts reach-v3's puck at one place for every goal, so that its position no longer tells
    which of the split's goals an episode has."""
    # Checked before the benchmark is built, which takes seconds.
    chosen = ProtocolOptions.for_source(METAWORLD, options)
    sentences = metaworld_instructions(chosen.instruction_set)
    source = MetaWorldSource(
        benchmark,
        split,
        task=task,
        task_order=chosen.task_order,
        tasks=tasks,
        object_position=chosen.object_position,
    )
    try:
        return MillionEnv(source, sentences, chosen)
    except Exception:
        source.close()
        raise


def make_point_goal_million(**options: Any) -> MillionEnv:
    """MILLION episodes over PointGoal with `num_goals` (2, 4 or 8) compass goals; a trial
    ends at its success (its potential-based reward is made for that)."""
    chosen = ProtocolOptions.for_source(POINT_GOAL, options)
    sentences = point_goal_instructions(chosen.instruction_set, chosen.num_goals)
    source = PointGoalSource(tuple(sentences), task_order=chosen.task_order)
    return MillionEnv(source, sentences, chosen)
