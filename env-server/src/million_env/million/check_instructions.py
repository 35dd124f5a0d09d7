"""Counts the instruction words GloVe lacks, over every shipped sentence.

    python -m million_env.million.check_instructions

Prints one JSON object and exits non-zero when any word is unknown, so that an
edit of the data files can be checked before it is served.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence

from million_env.million.instructions import (
    INSTRUCTION_SETS,
    metaworld_instructions,
    point_goal_instructions,
    tokenize,
    unknown_words,
)

POINT_GOAL_COUNTS = (2, 4, 8)


def _summary(sentences: Mapping[str, Sequence[str]]) -> dict[str, object]:
    unknown = unknown_words(sentences)
    return {
        "sentences": sum(len(group) for group in sentences.values()),
        "tokens": sum(len(tokenize(s)) for group in sentences.values() for s in group),
        "longest": max(len(tokenize(s)) for group in sentences.values() for s in group),
        "unknown_words": len(unknown),
        "unknown": sorted(set(unknown)),
    }


def main() -> int:
    groups: dict[str, Mapping[str, Sequence[str]]] = {}
    for instruction_set in INSTRUCTION_SETS:
        groups[f"metaworld/{instruction_set}"] = metaworld_instructions(instruction_set)
        for count in POINT_GOAL_COUNTS:
            groups[f"point_goal_{count}/{instruction_set}"] = point_goal_instructions(
                instruction_set, count
            )
    total = sum(len(unknown_words(sentences)) for sentences in groups.values())
    report = {name: _summary(sentences) for name, sentences in groups.items()}
    print(json.dumps({"unknown_words_total": total, "sets": report}, indent=2))
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
