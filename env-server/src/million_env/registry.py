"""The env ids this server can make, and making one from typed kwargs.

Every id in Gymnasium's registry is served (Meta-World registers its own
``Meta-World/*`` ids on import), plus the Meta-World split ids of
`million_env.metaworld_envs` and the MILLION protocol ids of `million_env.million`.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

import gymnasium as gym

from million_env.errors import internal, invalid
from million_env.metaworld_envs import register_metaworld_envs

_LOG = logging.getLogger(__name__)
_LOCK = threading.Lock()
# Meta-World builds its benchmarks (Meta-World/MT1 included) by seeding numpy's
# global RNG and restoring it afterwards, so two constructions in parallel threads
# would change each other's goals: environments are made one at a time.
_MAKE_LOCK = threading.Lock()
_DESCRIPTIONS: dict[str, str] | None = None


def _register_all() -> dict[str, str]:
    import metaworld  # noqa: F401 - importing it registers Meta-World/* with Gymnasium

    from million_env import compiled_models, metaworld_fast_paths
    from million_env.million import register_envs as register_million_envs

    # Every Meta-World env made here (served or stepped in-process) copies its model and
    # takes the fast paths of its hot spots (the same numbers).
    compiled_models.install()
    metaworld_fast_paths.install()

    own = register_metaworld_envs()
    own.update(register_million_envs())
    return own


def env_descriptions() -> dict[str, str]:
    """{env_id: one-line description} for every id the server can make."""
    global _DESCRIPTIONS
    with _LOCK:
        if _DESCRIPTIONS is None:
            own = _register_all()
            described: dict[str, str] = {}
            for env_id, spec in sorted(gym.registry.items()):
                if env_id in own:
                    continue
                if spec.entry_point is None:
                    continue
                entry = spec.entry_point if isinstance(spec.entry_point, str) else "callable"
                limit = f"; {spec.max_episode_steps} steps" if spec.max_episode_steps else ""
                described[env_id] = f"Gymnasium env ({entry}){limit}; kwargs as in gymnasium.make"
            described.update(own)
            _DESCRIPTIONS = described
        return dict(_DESCRIPTIONS)


def make_env(env_id: str, kwargs: dict[str, Any]) -> gym.Env:
    """One environment; INVALID_ARGUMENT for an unknown id or kwargs it does not take."""
    known = env_descriptions()
    if env_id not in known:
        raise invalid(f"unknown env id {env_id!r}; ListEnvs names the {len(known)} ids served")
    try:
        with _MAKE_LOCK:
            return gym.make(env_id, disable_env_checker=True, **kwargs)
    except TypeError as err:
        raise invalid(f"{env_id} does not take kwargs {sorted(kwargs)}: {err}") from err
    except (ValueError, KeyError, AssertionError, gym.error.Error) as err:
        raise invalid(f"cannot make {env_id} with kwargs {kwargs}: {err}") from err
    except ImportError as err:
        raise invalid(f"{env_id} needs a package this server lacks: {err}") from err
    except Exception as err:
        raise internal(f"making {env_id} raised {type(err).__name__}: {err}") from err
