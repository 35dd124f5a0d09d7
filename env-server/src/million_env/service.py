"""The EnvService implementation on grpc.aio: handles, budgets and counters.

Environment work (make, reset, step, close) runs in a thread pool so that a slow
batch never blocks the event loop that serves other clients; the calls of one
handle are serialised by that handle's lock.

Who owns a handle: one made by unary ``Make`` lives until ``Close`` or the idle
timeout (the client may use it from many calls and streams, and reconnect). One
made by a ``make`` request inside a ``Session`` stream belongs to that stream and
is closed when the stream ends for any reason (end of input, cancellation, a
dropped connection, server shutdown), so a client that dies mid-stream frees its
environments at once instead of after the idle timeout.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

import grpc

from million_env import __version__
from million_env._proto import env_pb2, env_pb2_grpc
from million_env.batch import AUTORESET_MODES, EnvBatch
from million_env.errors import ApiError, exhausted, invalid, not_found, precondition
from million_env.handlers import UndecodableRequest
from million_env.registry import env_descriptions
from million_env.stats import ServerStats
from million_env.tensors import values_to_python

_LOG = logging.getLogger(__name__)
T = TypeVar("T")

API_MAJOR = 1
# 1.1: Session carries make and close (stream-owned handles); GetStats counters
# sessions_*, steps_per_s, errors.<CODE>; the Render RPC.
API_MINOR = 1
#: Optional features announced in the handshake (`Capabilities.features`).
FEATURES = ("render",)


@dataclass
class ServerLimits:
    max_envs_per_handle: int = 256
    max_envs_total: int = 1024
    # A client that dies without Close would otherwise hold its envs (and the
    # server's budget) forever; 0 keeps idle handles for ever.
    handle_idle_timeout_s: float = 900.0


@dataclass
class _Handle:
    batch: EnvBatch
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    last_used: float = field(default_factory=time.monotonic)
    # Made on a Session stream: closed when that stream ends, never for being idle (a
    # training run's evaluation envs wait between evaluations for longer than the timeout).
    stream_owned: bool = False


def _status_number(code: grpc.StatusCode) -> int:
    return int(code.value[0])


class EnvService(env_pb2_grpc.EnvServiceServicer):
    def __init__(
        self,
        limits: ServerLimits,
        executor: ThreadPoolExecutor,
        stats: ServerStats | None = None,
        step_threads: bool = False,
    ) -> None:
        self._limits = limits
        self._executor = executor
        # Steps run on the event loop's thread unless step_threads: Python envs hold the GIL
        # while they step, so a worker thread adds a hand-off and GIL contention with the
        # loop and no parallelism (measured: 2 servers on 2 cores served 45% more ML10 steps
        # inline; BENCHMARKS.md). Make, Reset, Render and Close stay on the worker threads.
        self._step_threads = step_threads
        self.stats = stats or ServerStats()
        self._handles: dict[str, _Handle] = {}
        self._envs_reserved = 0
        self._steps_served = 0
        self._handles_reaped = 0
        self._background: set[asyncio.Task[None]] = set()

    @property
    def steps_served(self) -> int:
        return self._steps_served

    # -- plumbing -------------------------------------------------------------

    async def _in_thread(self, call: Callable[[], T]) -> T:
        return await asyncio.get_running_loop().run_in_executor(self._executor, call)

    async def _unary(self, context: grpc.aio.ServicerContext, work: Awaitable[T]) -> T:
        try:
            return await work
        except ApiError as err:
            self.stats.error(err.code)
            await context.abort(err.code, err.message)
            raise  # abort raises; this line only satisfies type checkers
        except Exception as err:
            _LOG.exception("unexpected error", extra={"error_type": type(err).__name__})
            self.stats.error(grpc.StatusCode.INTERNAL)
            await context.abort(grpc.StatusCode.INTERNAL, f"{type(err).__name__}: {err}")
            raise

    def _handle(self, name: str) -> _Handle:
        handle = self._handles.get(name)
        if handle is None:
            raise not_found(
                f"no env handle {name!r} (never made, closed, or closed after "
                f"{self._limits.handle_idle_timeout_s:g} s without calls)"
            )
        handle.last_used = time.monotonic()
        return handle

    # -- operations shared by the unary calls and the stream -------------------

    async def _make(
        self, request: env_pb2.MakeRequest, stream_owned: bool = False
    ) -> env_pb2.MakeResponse:
        num_envs = request.num_envs
        if num_envs < 1:
            raise invalid("num_envs must be at least 1")
        if num_envs > self._limits.max_envs_per_handle:
            raise exhausted(
                f"num_envs {num_envs} is above max_envs_per_handle "
                f"{self._limits.max_envs_per_handle}"
            )
        if request.autoreset_mode not in (env_pb2.AUTORESET_MODE_UNSPECIFIED, *AUTORESET_MODES):
            raise invalid(f"unknown autoreset mode {request.autoreset_mode}")
        if self._envs_reserved + num_envs > self._limits.max_envs_total:
            raise exhausted(
                f"{num_envs} more environments would exceed the server's budget of "
                f"{self._limits.max_envs_total} ({self._envs_reserved} alive)"
            )
        kwargs = values_to_python(request.kwargs)
        self._envs_reserved += num_envs
        try:
            batch = await self._in_thread(
                lambda: EnvBatch(request.env_id, kwargs, num_envs, request.autoreset_mode)
            )
        except BaseException:
            self._envs_reserved -= num_envs
            raise
        name = secrets.token_urlsafe(24)
        self._handles[name] = _Handle(batch, stream_owned=stream_owned)
        _LOG.info(
            "made %s x%d as %s…",
            request.env_id,
            num_envs,
            name[:6],
            extra={"env_id": request.env_id, "num_envs": num_envs, "handle": name[:6]},
        )
        return env_pb2.MakeResponse(handle=name, spec=batch.spec)

    async def _reset(self, request: env_pb2.ResetRequest) -> env_pb2.ResetResponse:
        handle = self._handle(request.handle)
        options = values_to_python(request.options)
        async with handle.lock:
            self._handle(request.handle)  # closed while this call waited for the lock
            return await self._in_thread(
                lambda: handle.batch.reset(list(request.env_indices), list(request.seeds), options)
            )

    async def _step(self, request: env_pb2.StepRequest) -> env_pb2.StepResponse:
        handle = self._handle(request.handle)
        async with handle.lock:
            self._handle(request.handle)
            if self._step_threads:
                response = await self._in_thread(lambda: handle.batch.step(request.action))
            else:
                response = handle.batch.step(request.action)
        self._steps_served += handle.batch.num_envs
        self.stats.steps(handle.batch.num_envs)
        return response

    async def _render(self, request: env_pb2.RenderRequest) -> env_pb2.RenderResponse:
        handle = self._handle(request.handle)
        async with handle.lock:
            self._handle(request.handle)
            return await self._in_thread(
                lambda: handle.batch.render(
                    list(request.env_indices), request.width, request.height, request.camera
                )
            )

    async def _close(self, name: str) -> None:
        handle = self._handles.pop(name, None)
        if handle is None:
            raise not_found(f"no env handle {name!r} (never made, or already closed)")
        async with handle.lock:
            await self._in_thread(handle.batch.close)
        self._envs_reserved -= handle.batch.num_envs

    async def close_idle(self) -> int:
        """Closes the handles made by unary Make and unused for longer than the idle
        timeout; returns how many. Stream-owned handles end with their stream."""
        timeout = self._limits.handle_idle_timeout_s
        if timeout <= 0:
            return 0
        now = time.monotonic()
        idle = [
            name
            for name, handle in self._handles.items()
            if now - handle.last_used > timeout
            and not handle.lock.locked()
            and not handle.stream_owned
        ]
        for name in idle:
            _LOG.warning(
                "closing handle %s… after %.0f s without calls",
                name[:6],
                timeout,
                extra={"handle": name[:6], "idle_timeout_s": timeout},
            )
            await self._close(name)
        self._handles_reaped += len(idle)
        return len(idle)

    async def close_all(self) -> None:
        # A stream's own cleanup may close some of these concurrently.
        await self._release(set(self._handles))

    def _spawn(self, work: Awaitable[None]) -> asyncio.Task[None]:
        """A task kept referenced until it finishes (asyncio holds tasks weakly)."""
        task = asyncio.ensure_future(work)
        self._background.add(task)
        task.add_done_callback(self._background.discard)
        return task

    async def _release(self, owned: set[str]) -> int:
        """Closes a stream's handles that are still open; idempotent (empties
        ``owned``), so the stream's own cleanup and its done callback can both run it."""
        freed = 0
        while owned:
            name = owned.pop()
            if name not in self._handles:
                continue  # closed by the client or the idle reaper
            try:
                await self._close(name)
                freed += 1
            except ApiError:
                continue  # closed concurrently
        return freed

    # -- RPCs -----------------------------------------------------------------

    async def Handshake(
        self, request: env_pb2.HandshakeRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.HandshakeResponse:
        async def work() -> env_pb2.HandshakeResponse:
            if request.client_version.major != API_MAJOR:
                raise precondition(
                    f"client speaks API major version {request.client_version.major}; "
                    f"this server speaks {API_MAJOR}"
                )
            _LOG.info("handshake from %r", request.client_name)
            return env_pb2.HandshakeResponse(
                server_version=env_pb2.ApiVersion(major=API_MAJOR, minor=API_MINOR),
                server_name=f"million-env-server/{__version__}",
                capabilities=env_pb2.Capabilities(
                    max_envs_per_handle=self._limits.max_envs_per_handle,
                    max_envs_total=self._limits.max_envs_total,
                    autoreset_modes=list(AUTORESET_MODES),
                    streaming=True,
                    features=list(FEATURES),
                ),
            )

        return await self._unary(context, work())

    async def ListEnvs(
        self, request: env_pb2.ListEnvsRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.ListEnvsResponse:
        async def work() -> env_pb2.ListEnvsResponse:
            described = await self._in_thread(env_descriptions)
            return env_pb2.ListEnvsResponse(
                envs=[env_pb2.EnvIdInfo(env_id=k, description=v) for k, v in described.items()]
            )

        return await self._unary(context, work())

    async def Make(
        self, request: env_pb2.MakeRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.MakeResponse:
        return await self._unary(context, self._make(request))

    async def Reset(
        self, request: env_pb2.ResetRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.ResetResponse:
        return await self._unary(context, self._reset(request))

    async def Step(
        self, request: env_pb2.StepRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.StepResponse:
        return await self._unary(context, self._step(request))

    async def Session(
        self,
        request_iterator: AsyncIterator[env_pb2.SessionRequest | UndecodableRequest],
        context: grpc.aio.ServicerContext,
    ) -> AsyncIterator[env_pb2.SessionResponse]:
        owned: set[str] = set()
        self.stats.session_opened()
        finishing: asyncio.Task[None] | None = None

        async def finish() -> None:
            freed = await self._release(owned)
            if freed:
                _LOG.info("session ended; closed its %d handle(s)", freed, extra={"freed": freed})
            self.stats.session_ended(freed)

        # grpc does not always resume the generator when a call is cancelled (it
        # may be parked in grpc's own write), so the call's done callback frees
        # the handles too; both share one task, so it runs once.
        def start_finish(_context: Any = None) -> asyncio.Task[None]:
            nonlocal finishing
            if finishing is None:
                finishing = self._spawn(finish())
            return finishing

        context.add_done_callback(start_finish)
        try:
            async for request in request_iterator:
                yield await self._session_reply(request, owned)
        finally:
            await asyncio.shield(start_finish())

    async def _session_reply(
        self, request: env_pb2.SessionRequest | UndecodableRequest, owned: set[str]
    ) -> env_pb2.SessionResponse:
        if isinstance(request, UndecodableRequest):
            self.stats.error(grpc.StatusCode.INVALID_ARGUMENT)
            return env_pb2.SessionResponse(
                error=env_pb2.Error(
                    code=_status_number(grpc.StatusCode.INVALID_ARGUMENT),
                    message=request.describe(),
                )
            )
        reply = env_pb2.SessionResponse(request_id=request.request_id)
        kind = request.WhichOneof("request")
        try:
            if kind == "reset":
                reply.reset.CopyFrom(await self._reset(request.reset))
            elif kind == "step":
                reply.step.CopyFrom(await self._step(request.step))
            elif kind == "make":
                made = await self._make(request.make, stream_owned=True)
                owned.add(made.handle)
                reply.make.CopyFrom(made)
            elif kind == "close":
                await self._close(request.close.handle)
                owned.discard(request.close.handle)
                reply.close.SetInParent()
            else:
                raise invalid("a SessionRequest must carry make, reset, step or close")
        except ApiError as err:
            self.stats.error(err.code)
            reply.ClearField("response")
            reply.error.CopyFrom(env_pb2.Error(code=_status_number(err.code), message=err.message))
        except Exception as err:
            _LOG.exception("unexpected error in a Session request")
            self.stats.error(grpc.StatusCode.INTERNAL)
            reply.ClearField("response")
            reply.error.CopyFrom(
                env_pb2.Error(
                    code=_status_number(grpc.StatusCode.INTERNAL),
                    message=f"{type(err).__name__}: {err}",
                )
            )
        return reply

    async def Close(
        self, request: env_pb2.CloseRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.CloseResponse:
        await self._unary(context, self._close(request.handle))
        return env_pb2.CloseResponse()

    async def Render(
        self, request: env_pb2.RenderRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.RenderResponse:
        return await self._unary(context, self._render(request))

    async def GetStats(
        self, request: env_pb2.GetStatsRequest, context: grpc.aio.ServicerContext
    ) -> env_pb2.GetStatsResponse:
        from million_env.compiled_models import COMPILED_MODELS
        from million_env.metaworld_tasks import BUILT_ENVS
        from million_env.million import protocol_stats

        counters: dict[str, Any] = {
            "envs_alive": float(sum(h.batch.num_envs for h in self._handles.values())),
            "handles_alive": float(len(self._handles)),
            "steps_served": float(self._steps_served),
            "handles_closed_idle": float(self._handles_reaped),
        }
        counters.update(self.stats.counters())
        counters.update(protocol_stats())
        counters.update(BUILT_ENVS.counters())
        counters.update(COMPILED_MODELS.counters())
        return env_pb2.GetStatsResponse(counters=counters)
