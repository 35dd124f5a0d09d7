"""The server's counters behind GetStats: sessions, steps per second, errors by code.

Names of the counters (documented field by field in env.proto, GetStatsResponse):
``sessions_active``, ``sessions_opened``, ``steps_per_s`` and one
``errors.<STATUS_CODE>`` per gRPC status code answered at least once.
"""

from __future__ import annotations

import time
from collections import Counter, deque

import grpc

STEP_RATE_WINDOW_S = 10.0


class ServerStats:
    """Counters of one server process; updated on the event loop thread only."""

    def __init__(self, window_s: float = STEP_RATE_WINDOW_S) -> None:
        self._window_s = window_s
        self._errors: Counter[str] = Counter()
        self._recent_steps: deque[tuple[float, int]] = deque()
        self.sessions_active = 0
        self.sessions_opened = 0
        self.session_handles_freed = 0

    def error(self, code: grpc.StatusCode) -> None:
        self._errors[code.name] += 1

    def steps(self, count: int) -> None:
        now = time.monotonic()
        self._recent_steps.append((now, count))
        self._forget_before(now - self._window_s)

    def session_opened(self) -> None:
        self.sessions_active += 1
        self.sessions_opened += 1

    def session_ended(self, handles_freed: int) -> None:
        self.sessions_active -= 1
        self.session_handles_freed += handles_freed

    def _forget_before(self, horizon: float) -> None:
        while self._recent_steps and self._recent_steps[0][0] < horizon:
            self._recent_steps.popleft()

    def steps_per_s(self) -> float:
        """Env steps served per second over the last window (0 when idle)."""
        self._forget_before(time.monotonic() - self._window_s)
        return sum(n for _, n in self._recent_steps) / self._window_s

    def counters(self) -> dict[str, float]:
        out = {
            "sessions_active": float(self.sessions_active),
            "sessions_opened": float(self.sessions_opened),
            "session_handles_freed": float(self.session_handles_freed),
            "steps_per_s": self.steps_per_s(),
        }
        out.update({f"errors.{code}": float(n) for code, n in self._errors.items()})
        return out
