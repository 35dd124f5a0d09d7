"""Registers the MILLION env ids with Gymnasium.

Each id fixes the task source (benchmark and split, or PointGoal); the protocol
kwargs (instruction set, ablations, trial shape) are passed through `gymnasium.make`.
"""

from __future__ import annotations

from typing import Any

import gymnasium

_PROTOCOL_KWARGS = (
    "instruction_set='train'|'heldout', instructions=True (False: no instruction phases, "
    "previous reward in obs), time_obs='trial'|'episode', action_repeat={ar}, trials=3, "
    "trial_len={tl} (env steps)"
)
_METAWORLD_ENTRY = "million_env.million.envs:make_metaworld_million"
_POINT_GOAL_ENTRY = "million_env.million.envs:make_point_goal_million"


def _metaworld_ids() -> list[tuple[str, dict[str, Any], str]]:
    protocol = _PROTOCOL_KWARGS.format(ar=2, tl=200)
    ids: list[tuple[str, dict[str, Any], str]] = []
    for benchmark in ("ML1", "ML10", "ML45"):
        for split in ("train", "test"):
            kwargs: dict[str, Any] = {"benchmark": benchmark, "split": split}
            what = f"Meta-World v3 {benchmark} {split} tasks"
            if benchmark == "ML1":
                kwargs["task"] = "reach-v3"
                what = f"Meta-World v3 ML1 {split} goals of one task class (task='reach-v3')"
            description = (
                f"MILLION protocol over {what}: GloVe instruction phases then 3 trials; "
                f"kwargs: {protocol}"
            )
            ids.append((f"million/{benchmark}-{split}", kwargs, description))
    return ids


def register_envs() -> dict[str, str]:
    """Registers every MILLION env id (idempotent) and returns {env_id: description}."""
    entries = [(env_id, _METAWORLD_ENTRY, kw, d) for env_id, kw, d in _metaworld_ids()]
    entries.append(
        (
            "million/PointGoal",
            _POINT_GOAL_ENTRY,
            {},
            "MILLION protocol over a 2-D point that must reach the one of num_goals=4 goals "
            "named only in the instruction (the learning test's env); kwargs: "
            + _PROTOCOL_KWARGS.format(ar=1, tl=25)
            + ", num_goals=4",
        )
    )
    described: dict[str, str] = {}
    for env_id, entry_point, kwargs, description in entries:
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, kwargs=kwargs)
        described[env_id] = description
    return described
