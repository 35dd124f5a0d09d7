"""The MILLION episode protocol served as Gymnasium environments.

`register_envs()` puts every MILLION env id into Gymnasium's registry and
`protocol_stats()` reports process-wide counters (unknown instruction words).
The server calls both; everything else lives in the submodules.
"""

from __future__ import annotations

from million_env.million.registry import register_envs
from million_env.million.stats import protocol_stats

__all__ = ["protocol_stats", "register_envs"]
