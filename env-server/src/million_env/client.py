"""Gymnasium front-ends for a remote env server, so existing Python agents work
unchanged: `RemoteEnv` is a `gymnasium.Env`, `RemoteVectorEnv` a
`gymnasium.vector.VectorEnv`."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import grpc
import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.info_fields import decode_info
from million_env.security import TOKEN_ENV_VAR, bearer_metadata
from million_env.spaces import decode_observations, leaf_dtype, space_from_proto
from million_env.tensors import decode_tensor, encode_tensor, python_to_values

API_VERSION = env_pb2.ApiVersion(major=1, minor=1)
CLIENT_NAME = "million_env.client"
# The API's maximum message size (env.proto), both ways.
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
# The first Make of a Meta-World benchmark builds its goal set (ML45: about a minute).
MAKE_TIMEOUT_S = 600.0
_MODE_TO_PROTO = {
    AutoresetMode.NEXT_STEP: env_pb2.AUTORESET_MODE_NEXT_STEP,
    AutoresetMode.SAME_STEP: env_pb2.AUTORESET_MODE_SAME_STEP,
    AutoresetMode.DISABLED: env_pb2.AUTORESET_MODE_DISABLED,
}


def open_channel(address: str, tls_root_cert: str | Path | bytes | None = None) -> grpc.Channel:
    """A channel to ``address`` with the API's message size limit; TLS when a CA
    certificate (PEM: a path, or the bytes) is given."""
    options = [
        ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
        ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
    ]
    if tls_root_cert is None:
        return grpc.insecure_channel(address, options=options)
    pem = tls_root_cert if isinstance(tls_root_cert, bytes) else Path(tls_root_cert).read_bytes()
    credentials = grpc.ssl_channel_credentials(root_certificates=pem)
    return grpc.secure_channel(address, credentials, options=options)


def resolve_token(token: str | None) -> str | None:
    """The given token, else ``$MILLION_ENV_TOKEN``, else none."""
    return token if token is not None else (os.environ.get(TOKEN_ENV_VAR) or None)


class _RemoteBatch:
    """One handle on a server: the channel, the spec, and typed reset/step calls."""

    def __init__(
        self,
        address: str,
        env_id: str,
        num_envs: int,
        autoreset_mode: int,
        kwargs: dict[str, Any],
        timeout: float | None,
        token: str | None,
        tls_root_cert: str | Path | bytes | None,
    ) -> None:
        self._timeout = timeout
        self._metadata = bearer_metadata(resolve_token(token))
        self._channel = open_channel(address, tls_root_cert)
        self._stub = env_pb2_grpc.EnvServiceStub(self._channel)
        self.handle: str | None = None
        try:
            shook = self._stub.Handshake(
                env_pb2.HandshakeRequest(client_version=API_VERSION, client_name=CLIENT_NAME),
                timeout=timeout,
                metadata=self._metadata,
            )
            made = self._stub.Make(
                env_pb2.MakeRequest(
                    env_id=env_id,
                    kwargs=python_to_values(kwargs),
                    num_envs=num_envs,
                    autoreset_mode=autoreset_mode,
                ),
                timeout=None if timeout is None else max(timeout, MAKE_TIMEOUT_S),
                metadata=self._metadata,
            )
        except BaseException:
            self._channel.close()
            raise
        self.handle = made.handle
        self.spec = made.spec
        #: Optional server features from the handshake, e.g. {"render"}.
        self.features = frozenset(shook.capabilities.features)
        self.observation_space = space_from_proto(made.spec.observation_space)
        self.action_space = space_from_proto(made.spec.action_space)
        self._action_dtype = leaf_dtype(self.action_space)

    def reset(
        self, indices: Sequence[int], seeds: Sequence[int], options: dict[str, Any] | None
    ) -> tuple[Any, dict[str, Any]]:
        reply = self._stub.Reset(
            env_pb2.ResetRequest(
                handle=self.handle,
                env_indices=indices,
                seeds=seeds,
                options=python_to_values(options or {}),
            ),
            timeout=self._timeout,
            metadata=self._metadata,
        )
        return decode_observations(reply.observation), decode_info(reply.info)

    def step(self, actions: Any) -> env_pb2.StepResponse:
        batch = np.asarray(actions, dtype=self._action_dtype).reshape(
            (self.spec.num_envs, *self.action_space.shape)
        )
        return self._stub.Step(
            env_pb2.StepRequest(handle=self.handle, action=encode_tensor(batch)),
            timeout=self._timeout,
            metadata=self._metadata,
        )

    def render(self, indices: Sequence[int], width: int, height: int, camera: str) -> np.ndarray:
        """uint8 RGB frames [rows, height, width, 3] (row 0 at the top)."""
        if "render" not in self.features:
            raise RuntimeError("this env server does not render (no 'render' feature)")
        reply = self._stub.Render(
            env_pb2.RenderRequest(
                handle=self.handle,
                env_indices=list(indices),
                width=width,
                height=height,
                camera=camera,
            ),
            timeout=self._timeout,
        )
        return decode_tensor(reply.frames)

    def close(self) -> None:
        if self.handle is not None:
            try:
                self._stub.Close(
                    env_pb2.CloseRequest(handle=self.handle),
                    timeout=self._timeout,
                    metadata=self._metadata,
                )
            except grpc.RpcError as err:
                if err.code() not in (grpc.StatusCode.NOT_FOUND, grpc.StatusCode.UNAVAILABLE):
                    raise
            self.handle = None
        self._channel.close()


def _row(batch: Any, index: int) -> Any:
    if isinstance(batch, dict):
        return {name: _row(value, index) for name, value in batch.items()}
    return batch[index]


def _rows(batch: Any, indices: Sequence[int]) -> Any:
    """Batched values (array or dict of arrays) restricted to some rows."""
    if isinstance(batch, dict):
        return {name: _rows(value, indices) for name, value in batch.items()}
    return batch[np.asarray(indices, dtype=np.int64)]


def _single_info(info: dict[str, Any], index: int = 0) -> dict[str, Any]:
    """One row of a batched info, keeping only the fields that row set."""
    out = {}
    for name, values in info.items():
        if name.startswith("_") or not info.get("_" + name, np.zeros(0))[index : index + 1].any():
            continue
        value = values[index]
        out[name] = value.item() if isinstance(value, np.generic) else value
    return out


class RemoteEnv(gym.Env):
    """One environment served remotely, with single-env Gymnasium semantics (no
    autoreset: after an episode ends, call reset). `render_frame` returns an RGB picture
    of the env when the server renders (feature "render").

    ``token``: the server's shared token (default ``$MILLION_ENV_TOKEN``);
    ``tls_root_cert``: the CA certificate (PEM path or bytes) to connect with TLS."""

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        address: str,
        env_id: str,
        *,
        timeout: float | None = 60.0,
        token: str | None = None,
        tls_root_cert: str | Path | bytes | None = None,
        **kwargs: Any,
    ) -> None:
        self._remote = _RemoteBatch(
            address,
            env_id,
            1,
            env_pb2.AUTORESET_MODE_DISABLED,
            kwargs,
            timeout,
            token,
            tls_root_cert,
        )
        self.observation_space = self._remote.observation_space
        self.action_space = self._remote.action_space
        self.env_id = env_id
        self.max_episode_steps = int(self._remote.spec.max_episode_steps) or None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        obs, info = self._remote.reset([], [] if seed is None else [seed], options)
        return _row(obs, 0), _single_info(info)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        reply = self._remote.step(np.asarray(action)[None])
        return (
            _row(decode_observations(reply.observation), 0),
            float(reply.reward[0]),
            bool(reply.terminated[0]),
            bool(reply.truncated[0]),
            _single_info(decode_info(reply.info)),
        )

    def render_frame(self, width: int = 0, height: int = 0, camera: str = "") -> np.ndarray:
        """uint8 RGB [height, width, 3], row 0 at the top; 0 / "" = the server's defaults."""
        return self._remote.render([], width, height, camera)[0]

    def close(self) -> None:
        self._remote.close()
        super().close()


class RemoteVectorEnv(gym.vector.VectorEnv):
    """A batch of environments served remotely; the server does the autoreset, in
    the mode declared in ``metadata["autoreset_mode"]``. ``token`` and
    ``tls_root_cert`` as for ``RemoteEnv``."""

    def __init__(
        self,
        address: str,
        env_id: str,
        num_envs: int,
        *,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        timeout: float | None = 60.0,
        token: str | None = None,
        tls_root_cert: str | Path | bytes | None = None,
        **kwargs: Any,
    ) -> None:
        mode = AutoresetMode(autoreset_mode)
        self._remote = _RemoteBatch(
            address,
            env_id,
            num_envs,
            _MODE_TO_PROTO[mode],
            kwargs,
            timeout,
            token,
            tls_root_cert,
        )
        self.num_envs = num_envs
        self.single_observation_space = self._remote.observation_space
        self.single_action_space = self._remote.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.metadata = {"autoreset_mode": mode, "render_modes": []}
        self.render_mode = None
        self.env_id = env_id
        self._last_obs: Any = None

    def reset(
        self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        indices = list(range(self.num_envs)) if mask is None else np.flatnonzero(mask).tolist()
        if seed is None:
            seeds: list[int] = []
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in indices]
        else:
            seeds = [int(s) for s in seed]
            if mask is not None:
                seeds = [seeds[i] for i in indices]
        if seed is not None and not isinstance(seed, (int, np.integer)):
            super().reset(seed=None)
        else:
            super().reset(seed=seed)
        obs, info = self._remote.reset(indices if mask is not None else [], seeds, options)
        if mask is None or self._last_obs is None:
            self._last_obs = obs
        else:
            self._last_obs = _scatter(self._last_obs, obs, indices)
        return self._last_obs, _widen_info(
            info, indices, self.num_envs
        ) if mask is not None else info

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        reply = self._remote.step(actions)
        obs = decode_observations(reply.observation)
        info = decode_info(reply.info)
        if reply.HasField("final_observation"):
            ended = np.logical_or(reply.terminated, reply.truncated)
            final_obs = decode_observations(reply.final_observation)
            per_row = np.empty(self.num_envs, dtype=object)
            for i in np.flatnonzero(ended):
                per_row[i] = _row(final_obs, int(i))
            info["final_obs"] = per_row
            info["_final_obs"] = ended
            info["final_info"] = decode_info(reply.final_info)
            info["_final_info"] = ended
        self._last_obs = obs
        return (
            obs,
            np.array(reply.reward, dtype=np.float64),
            np.array(reply.terminated, dtype=bool),
            np.array(reply.truncated, dtype=bool),
            info,
        )

    def render_frames(
        self,
        indices: Sequence[int] = (),
        *,
        width: int = 0,
        height: int = 0,
        camera: str = "",
    ) -> np.ndarray:
        """uint8 RGB [rows, height, width, 3] of envs `indices` (all when empty)."""
        return self._remote.render(list(indices), width, height, camera)

    def close_extras(self, **kwargs: Any) -> None:
        self._remote.close()


def _scatter(full: Any, rows: Any, indices: Sequence[int]) -> Any:
    if isinstance(full, dict):
        return {name: _scatter(full[name], rows[name], indices) for name in full}
    out = np.array(full, copy=True)
    out[np.asarray(indices, dtype=np.int64)] = rows
    return out


def _widen_info(info: dict[str, Any], indices: Sequence[int], num_envs: int) -> dict[str, Any]:
    """A subset reset's info laid out over the whole batch (rows not reset: absent)."""
    out: dict[str, Any] = {}
    index = np.asarray(indices, dtype=np.int64)
    for name, values in info.items():
        wide = np.zeros((num_envs, *values.shape[1:]), dtype=values.dtype)
        if values.dtype == object:
            wide[:] = ""
        wide[index] = values
        out[name] = wide
    return out
