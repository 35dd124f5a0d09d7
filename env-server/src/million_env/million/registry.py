"""Registers the MILLION env ids with Gymnasium.

Each id binds its task source (benchmark and split, or PointGoal) into the entry
point, so a user cannot re-point `million/ML10-train` at another benchmark; the
protocol kwargs are registered with their defaults, read from the entry points'
signatures (one source of truth), so the spec of a made env lists every value.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from typing import Any

import gymnasium

from million_env.million.envs import make_metaworld_million, make_point_goal_million

_MEANINGS = {
    "instruction_set": "'train'|'heldout' sentences",
    "instructions": "False = no instruction phases, previous reward in obs",
    "time_obs": "'trial'|'episode'",
    "action_repeat": "env steps per agent step",
    "trials": "trials per episode",
    "trial_len": "env steps per trial",
    "num_goals": "2|4|8",
    "task": "Meta-World task class",
    "task_order": "'random'|'cycle' (cycle: task (seed + k) mod n at the k-th episode)",
    "instruction_goal": "'real'|'reflected' (diagnostic: goal_pos names a wrong goal)",
    "goal_encoding": "'raw'|'range' (goal_pos in metres, or scaled from the goal range to [-1, 1])",
    "goal_in_state": "True = diagnostic: the real goal in the trial state's last 3 entries",
    "end_on_success": "True = a trial ends at its success (Meta-World default: full length)",
    "word_noise": "p: each instruction word but goal_pos replaced by a random unused word",
    "object_position": "'task'|'centre' (reach-v3 only: its puck at one place for every goal)",
}


def keyword_defaults(entry: Callable[..., Any]) -> dict[str, Any]:
    """The keyword-only parameters of an entry point with their defaults."""
    return {
        name: parameter.default
        for name, parameter in inspect.signature(entry).parameters.items()
        if parameter.kind is inspect.Parameter.KEYWORD_ONLY
    }


def _describe(what: str, kwargs: dict[str, Any]) -> str:
    listed = ", ".join(f"{k}={v!r} ({_MEANINGS.get(k, '')})" for k, v in kwargs.items())
    return f"MILLION protocol over {what}; kwargs: {listed}"


def _entries() -> list[tuple[str, Callable[..., Any], dict[str, Any], str]]:
    entries = []
    # `task` names the ML1 class; the other benchmarks take none, but may take `tasks`, a
    # subset of their split (both default to None, which a Value cannot hold: not listed).
    protocol = {
        k: v
        for k, v in keyword_defaults(make_metaworld_million).items()
        if k not in ("task", "tasks")
    }
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
    point = keyword_defaults(make_point_goal_million)
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
