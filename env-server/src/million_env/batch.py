"""A batch of environments of one id, reset and stepped together with Gymnasium
1.x vector semantics (the three autoreset modes)."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from million_env._proto import env_pb2
from million_env.errors import ApiError, internal, invalid, precondition
from million_env.info_fields import InfoField, declared_info_fields, encode_info
from million_env.registry import make_env
from million_env.rendering import RendererCache, frame_size, on_render_thread, render_env
from million_env.spaces import (
    UnsupportedSpaceError,
    decode_actions,
    encode_observations,
    space_to_proto,
    zero_observation,
)
from million_env.tensors import encode_tensor, representable_values

_LOG = logging.getLogger(__name__)

NEXT_STEP = env_pb2.AUTORESET_MODE_NEXT_STEP
SAME_STEP = env_pb2.AUTORESET_MODE_SAME_STEP
DISABLED = env_pb2.AUTORESET_MODE_DISABLED
AUTORESET_MODES = (NEXT_STEP, SAME_STEP, DISABLED)


def _seed_metaworld(env: gym.Env, seed: int) -> None:
    # Meta-World's own envs ignore reset(seed) for their RNG and pick the next task
    # from it before reseeding; seeding the base env first makes a seed decide it.
    from metaworld.sawyer_xyz_env import SawyerXYZEnv

    if isinstance(env.unwrapped, SawyerXYZEnv):
        env.unwrapped.seed(seed)


def _fix_metaworld_observation_space(env: gym.Env) -> None:
    # A raw Meta-World env declares its observation space at construction, before
    # any task says whether the goal is observable; the goal-observable tasks of
    # Meta-World/MT1 then send goals outside those (zero) bounds. Setting a task of
    # the env's own task list first and re-reading the space makes them agree.
    from metaworld.sawyer_xyz_env import SawyerXYZEnv

    base = env.unwrapped
    if not isinstance(base, SawyerXYZEnv) or env.observation_space is not base.observation_space:
        return
    layer: Any = env
    while layer is not base and not hasattr(layer, "tasks"):
        layer = layer.env
    tasks = getattr(layer, "tasks", None)
    if tasks:
        base.set_task(tasks[0])
        base.observation_space = base.sawyer_observation_space


class EnvBatch:
    """N environments of one env id with one spec; not thread-safe on its own
    (the service serialises the calls of one handle)."""

    def __init__(
        self, env_id: str, kwargs: dict[str, Any], num_envs: int, autoreset_mode: int
    ) -> None:
        if autoreset_mode == env_pb2.AUTORESET_MODE_UNSPECIFIED:
            autoreset_mode = NEXT_STEP
        if autoreset_mode not in AUTORESET_MODES:
            raise invalid(f"unknown autoreset mode {autoreset_mode}")
        self.env_id = env_id
        self.num_envs = num_envs
        self.autoreset_mode = autoreset_mode
        self.envs: list[gym.Env] = []
        self._renderers = RendererCache()
        try:
            for _ in range(num_envs):
                self.envs.append(make_env(env_id, kwargs))
                _fix_metaworld_observation_space(self.envs[-1])
            first = self.envs[0]
            self.observation_space = first.observation_space
            self.action_space = first.action_space
            if isinstance(self.action_space, gym.spaces.Dict):
                raise invalid(f"{env_id} has a Dict action space, which the env API does not serve")
            try:
                self._spec = env_pb2.EnvSpec(
                    env_id=env_id,
                    num_envs=num_envs,
                    observation_space=space_to_proto(self.observation_space),
                    action_space=space_to_proto(self.action_space),
                    autoreset_mode=autoreset_mode,
                )
            except UnsupportedSpaceError as err:
                raise invalid(f"{env_id} cannot be served: {err}") from err
            self.info_fields: tuple[InfoField, ...] = declared_info_fields(
                first, lambda: make_env(env_id, kwargs)
            )
        except BaseException:
            self.close()
            raise
        self._spec.info_fields.extend(f.to_proto() for f in self.info_fields)
        self._spec.max_episode_steps = (first.spec.max_episode_steps if first.spec else 0) or 0
        made_with = dict(first.spec.kwargs) if first.spec else dict(kwargs)
        for key, value in representable_values(made_with).items():
            self._spec.kwargs[key].CopyFrom(value)
        self._was_reset = np.zeros(num_envs, dtype=bool)
        self._ended = np.zeros(num_envs, dtype=bool)
        self._broken: str | None = None

    @property
    def spec(self) -> env_pb2.EnvSpec:
        return self._spec

    def close(self) -> None:
        # GL contexts are freed on the thread that made them, before their scenes go.
        on_render_thread(self._renderers.close)
        for env in self.envs:
            try:
                env.close()
            except Exception:
                _LOG.exception("closing an environment of %s failed", self.env_id)
        self.envs = []

    def reset(
        self, indices: Sequence[int], seeds: Sequence[int], options: Mapping[str, Any]
    ) -> env_pb2.ResetResponse:
        self._check_usable()
        rows = self._rows(indices)
        if seeds and len(seeds) != len(rows):
            raise invalid(f"{len(seeds)} seeds for {len(rows)} environments; give one each or none")
        if any(s < 0 for s in seeds):
            raise invalid(f"seeds must be non-negative, got {list(seeds)}")
        observations, infos = [], []
        for position, index in enumerate(rows):
            seed = int(seeds[position]) if seeds else None
            env = self.envs[index]
            obs, info = self._guarded(
                lambda env=env, seed=seed: self._reset_env(env, seed, dict(options)), "reset"
            )
            observations.append(obs)
            infos.append(info)
            self._was_reset[index] = True
            self._ended[index] = False
        return env_pb2.ResetResponse(
            observation=encode_observations(self.observation_space, observations),
            info=encode_info(self.info_fields, infos),
            env_indices=rows,
        )

    def step(self, action: env_pb2.Tensor) -> env_pb2.StepResponse:
        self._check_usable()
        actions = decode_actions(self.action_space, action, self.num_envs)
        if not self._was_reset.all():
            missing = np.flatnonzero(~self._was_reset).tolist()
            raise precondition(f"environments {missing} were never reset; call Reset first")
        if self.autoreset_mode == DISABLED and self._ended.any():
            ended = np.flatnonzero(self._ended).tolist()
            raise precondition(
                f"environments {ended} ended their episode and autoreset is DISABLED; reset them"
            )
        n = self.num_envs
        observations: list[Any] = [None] * n
        infos: list[Any] = [None] * n
        rewards = np.zeros(n, dtype=np.float64)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        final_obs: list[Any] | None = None
        final_infos: list[Any] | None = None
        for i, env in enumerate(self.envs):
            if self.autoreset_mode == NEXT_STEP and self._ended[i]:
                observations[i], infos[i] = self._guarded(env.reset, "autoreset")
                self._ended[i] = False
                continue
            obs, reward, term, trunc, info = self._guarded(
                lambda env=env, a=actions[i]: env.step(a), "step"
            )
            rewards[i], terminated[i], truncated[i] = reward, term, trunc
            if self.autoreset_mode == SAME_STEP and (term or trunc):
                if final_obs is None:
                    final_obs = [zero_observation(self.observation_space)] * n
                    final_infos = [None] * n
                final_obs[i], final_infos[i] = obs, info
                obs, info = self._guarded(env.reset, "autoreset")
            else:
                self._ended[i] = bool(term or trunc)
            observations[i], infos[i] = obs, info
        response = env_pb2.StepResponse(
            observation=encode_observations(self.observation_space, observations),
            reward=rewards.tolist(),
            terminated=terminated.tolist(),
            truncated=truncated.tolist(),
            info=encode_info(self.info_fields, infos),
        )
        if final_obs is not None and final_infos is not None:
            response.final_observation.CopyFrom(
                encode_observations(self.observation_space, final_obs)
            )
            response.final_info.CopyFrom(encode_info(self.info_fields, final_infos))
        return response

    def render(
        self, indices: Sequence[int], width: int, height: int, camera: str
    ) -> env_pb2.RenderResponse:
        """uint8 RGB frames [rows, height, width, 3] of the named envs (all when empty),
        drawn on the render thread; rendering changes no environment, so a failure
        leaves the handle usable."""
        self._check_usable()
        rows = self._rows(indices)
        width, height = frame_size(width, height)
        never = [i for i in rows if not self._was_reset[i]]
        if never:
            raise precondition(f"environments {never} were never reset; call Reset first")

        def draw() -> np.ndarray:
            frames = np.empty((len(rows), height, width, 3), dtype=np.uint8)
            for position, index in enumerate(rows):
                frames[position] = render_env(
                    self.envs[index], width, height, camera, self._renderers
                )
            return frames

        try:
            frames = on_render_thread(draw)
        except ApiError:
            raise
        except Exception as err:
            _LOG.exception("rendering %s failed", self.env_id)
            raise internal(f"rendering raised {type(err).__name__}: {err}") from err
        return env_pb2.RenderResponse(frames=encode_tensor(frames), env_indices=rows)

    def _rows(self, indices: Sequence[int]) -> list[int]:
        rows = list(indices) if indices else list(range(self.num_envs))
        bad = [i for i in rows if i >= self.num_envs]
        if bad:
            raise invalid(f"env indices {bad} out of range for a batch of {self.num_envs}")
        if len(set(rows)) != len(rows):
            raise invalid(f"env indices {rows} name an environment twice")
        return rows

    def _reset_env(
        self, env: gym.Env, seed: int | None, options: dict[str, Any]
    ) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            _seed_metaworld(env, seed)
        return env.reset(seed=seed, options=options or None)

    def _guarded(self, call: Any, what: str) -> Any:
        try:
            return call()
        except ApiError:
            raise
        except Exception as err:
            self._broken = f"{what} raised {type(err).__name__}: {err}"
            _LOG.exception("%s of %s raised; the handle is now unusable", what, self.env_id)
            raise internal(f"the environment's {self._broken}; close this handle") from err

    def _check_usable(self) -> None:
        if self._broken is not None:
            raise precondition(f"this handle is unusable since its {self._broken}; close it")
