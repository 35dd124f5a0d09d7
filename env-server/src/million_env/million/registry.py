"""Registers the MILLION env ids with Gymnasium.

Each id binds its task source (benchmark and split, or PointGoal) into the entry
point, so a user cannot re-point `million/ML10-train` at another benchmark; the
protocol options are registered with their defaults and described as
`million_env.million.options` declares them, so the spec of a made env lists every value.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import gymnasium

from million_env.million.envs import make_metaworld_million, make_point_goal_million
from million_env.million.options import METAWORLD, POINT_GOAL, ProtocolOptions, declared_options

# `task` picks ML1's class; it is a parameter of the id, not a protocol option.
_TASK_MEANING = "Meta-World task class"


def _describe(what: str, kwargs: dict[str, Any]) -> str:
    meanings = {option.name: option.describe() for option in declared_options()}
    meanings["task"] = _TASK_MEANING
    listed = ", ".join(f"{k}={v!r} ({meanings[k]})" for k, v in kwargs.items())
    return f"MILLION protocol over {what}; kwargs: {listed}"


def _entries() -> list[tuple[str, Callable[..., Any], dict[str, Any], str]]:
    entries = []
    # `task` names the ML1 class; the other benchmarks take none, but may take `tasks`, a
    # subset of their split (both default to None, which a Value cannot hold: not listed).
    protocol = ProtocolOptions.defaults(METAWORLD)
    for benchmark in ("ML1", "ML10", "ML45"):
        for split in ("train", "test"):
            kwargs = dict(protocol)
            what = f"Meta-World v3 {benchmark} {split} tasks (GloVe instruction phases, trials)"
            if benchmark == "ML1":
                kwargs = {"task": "reach-v3", **kwargs}
                what = f"Meta-World v3 ML1 {split} goals of one task class"
            else:
                what += " (kwarg tasks: a list naming a subset of them)"
            entry = functools.partial(make_metaworld_million, benchmark, split)
            entries.append((f"million/{benchmark}-{split}", entry, kwargs, _describe(what, kwargs)))
    point = ProtocolOptions.defaults(POINT_GOAL)
    entries.append(
        (
            "million/PointGoal",
            make_point_goal_million,
            point,
            _describe(
                "a 2-D point that must reach the goal named only in the instruction "
                "(the fast learning test; task_id is always 0)",
                point,
            ),
        )
    )
    return entries


def register_envs() -> dict[str, str]:
    """Registers every MILLION env id (idempotent) and returns {env_id: description}."""
    described: dict[str, str] = {}
    for env_id, entry_point, kwargs, description in _entries():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, kwargs=kwargs)
        described[env_id] = description
    return described
