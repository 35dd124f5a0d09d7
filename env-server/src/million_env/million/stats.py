"""Process-wide protocol counters, read by the server's GetStats."""

from __future__ import annotations

import logging
import threading

_LOG = logging.getLogger(__name__)


class ProtocolCounters:
    """Counts instruction tokens and those without a GloVe vector.

    One instance per process: the server serves envs from several threads, so
    updates take a lock. Each unknown word is logged once, the first time it is seen.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.instruction_tokens = 0
        self.unknown_words = 0
        self._unknown_seen: set[str] = set()

    def count_tokens(self, tokens: int, unknown: list[str]) -> None:
        with self._lock:
            self.instruction_tokens += tokens
            self.unknown_words += len(unknown)
            fresh = [word for word in unknown if word not in self._unknown_seen]
            self._unknown_seen.update(fresh)
        for word in fresh:
            _LOG.warning("instruction word %r has no GloVe vector; it is fed as zeros", word)

    def snapshot(self) -> dict[str, float]:
        with self._lock:
            return {
                "instruction_tokens": float(self.instruction_tokens),
                "unknown_words": float(self.unknown_words),
                "unknown_distinct_words": float(len(self._unknown_seen)),
            }


COUNTERS = ProtocolCounters()


def protocol_stats() -> dict[str, float]:
    """Counters since process start: `instruction_tokens`, `unknown_words` (tokens fed
    as zero vectors because GloVe has no row for them), `unknown_distinct_words`."""
    return COUNTERS.snapshot()
