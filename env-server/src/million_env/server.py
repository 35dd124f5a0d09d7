"""Building and running the gRPC server: EnvService, health and reflection.

Security (optional): a shared token checked on every call but health's
(``security.TokenInterceptor``) and TLS (``--tls-cert``/``--tls-key``).
Shutdown on SIGTERM or SIGINT: health turns NOT_SERVING first, new calls are
refused, calls in flight get ``shutdown_grace_s`` to finish, then every handle
is closed and the process exits.
"""

from __future__ import annotations

import asyncio
import logging
import signal
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from million_env.handlers import SERVICE_NAME, method_handlers
from million_env.metaworld_envs import split_observation_space
from million_env.metaworld_tasks import DEFAULT_BENCHMARK_SEED, SPLITS
from million_env.registry import env_descriptions
from million_env.security import ServerTls, TokenInterceptor
from million_env.service import EnvService, ServerLimits
from million_env.stats import ServerStats

_LOG = logging.getLogger(__name__)
# The largest request or reply, both ways (documented in env.proto; the Rust and
# Python clients use the same). gRPC itself answers RESOURCE_EXHAUSTED above it.
MAX_MESSAGE_BYTES = 64 * 1024 * 1024


def preload(benchmarks: list[str]) -> None:
    """Builds Meta-World benchmarks (``ML10``, ``ML45``, ``ML1:reach-v3``) and their
    split observation spaces now, so that the first Make of them is quick."""
    for item in benchmarks:
        name, _, task = item.partition(":")
        for split in SPLITS:
            _LOG.info("preloading Meta-World %s %s", item, split)
            split_observation_space(name, split, task or None, DEFAULT_BENCHMARK_SEED)


async def _close_idle_handles(service: EnvService, timeout_s: float) -> None:
    if timeout_s <= 0:
        return
    while True:
        await asyncio.sleep(min(timeout_s / 4, 30.0))
        await service.close_idle()


async def serve(
    address: str,
    limits: ServerLimits,
    workers: int | None = None,
    preloads: Sequence[str] = (),
    *,
    token: str | None = None,
    tls: ServerTls | None = None,
    shutdown_grace_s: float = 5.0,
    step_threads: bool = False,
) -> None:
    """Serves until SIGINT/SIGTERM; prints the bound port for scripts that pass :0.
    Health turns SERVING once the preloads are built."""
    env_descriptions()  # registers every id before the first client asks
    executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="env")
    stats = ServerStats()
    server = grpc.aio.server(
        interceptors=[TokenInterceptor(token, stats.error)] if token else None,
        options=[
            ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
            ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
        ],
    )
    service = EnvService(limits, executor, stats, step_threads=step_threads)
    server.add_generic_rpc_handlers((method_handlers(service, stats.error),))
    health_servicer = health.aio.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
    reflection.enable_server_reflection(
        (SERVICE_NAME, health.SERVICE_NAME, reflection.SERVICE_NAME), server
    )
    if tls is None:
        port = server.add_insecure_port(address)
    else:
        port = server.add_secure_port(address, tls.credentials())
    if port == 0:
        raise OSError(f"cannot bind {address}")
    await server.start()
    if preloads:
        await asyncio.get_running_loop().run_in_executor(executor, preload, list(preloads))
    for name in ("", SERVICE_NAME):
        await health_servicer.set(name, health_pb2.HealthCheckResponse.SERVING)
    host = address.rsplit(":", 1)[0]
    _LOG.info(
        "million-env-server listening on %s:%d",
        host,
        port,
        extra={"port": port, "tls": tls is not None, "token_required": bool(token)},
    )
    print(f"listening on {host}:{port}", flush=True)

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    received: list[str] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, lambda s=sig: (received.append(s.name), stop.set()))
    reaper = asyncio.create_task(_close_idle_handles(service, limits.handle_idle_timeout_s))
    await stop.wait()
    _LOG.info(
        "shutting down: health NOT_SERVING, %g s for calls in flight",
        shutdown_grace_s,
        extra={"signal": received[0] if received else None, "grace_s": shutdown_grace_s},
    )
    reaper.cancel()
    # Probes see NOT_SERVING before anything is refused; open Watch streams get it.
    await health_servicer.enter_graceful_shutdown()
    await server.stop(grace=shutdown_grace_s)
    await service.close_all()
    executor.shutdown(wait=True)
    _LOG.info("stopped", extra={"steps_served": service.steps_served})
