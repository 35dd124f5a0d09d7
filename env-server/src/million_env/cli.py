"""``million-env-server``: the command line entry point."""

from __future__ import annotations

import argparse
import asyncio
import os
from pathlib import Path

from million_env import logs, metaworld_fast_paths
from million_env.allocator import fix_mmap_threshold
from million_env.compiled_models import COMPILED_MODELS, DEFAULT_COMPILED_MODELS
from million_env.metaworld_tasks import (
    ALL_TASK_NAMES,
    BENCHMARKS,
    BUILT_ENVS,
    DEFAULT_IDLE_ENVS,
)
from million_env.security import TOKEN_ENV_VAR, ServerTls, TlsConfigError
from million_env.service import ServerLimits

# Kept here rather than imported from server.py, which loads Meta-World.
DEFAULT_SHUTDOWN_GRACE_S = 5.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    defaults = ServerLimits()
    parser = argparse.ArgumentParser(
        prog="million-env-server",
        description="Serve Gymnasium and Meta-World environments over the MILLION env API (gRPC).",
        # No abbreviations: the agent refuses --address, --token and --tls-* in a config's
        # runtime.env_server_args by their exact names, so a prefix must not reach them.
        allow_abbrev=False,
    )
    parser.add_argument(
        "--address",
        default="127.0.0.1:50051",
        help="host:port to listen on (loopback by default; port 0 picks a free one)",
    )
    parser.add_argument("--max-envs-per-handle", type=int, default=defaults.max_envs_per_handle)
    parser.add_argument("--max-envs-total", type=int, default=defaults.max_envs_total)
    parser.add_argument(
        "--handle-idle-timeout",
        type=float,
        default=defaults.handle_idle_timeout_s,
        metavar="SECONDS",
        help="close env handles without calls for this long (a client that died); 0 = never",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="threads that make, reset, render and close envs (and step them with "
        "--step-threads); default: auto",
    )
    parser.add_argument(
        "--step-threads",
        action="store_true",
        help="step envs on the worker threads instead of the event loop's thread (for envs "
        "that release the GIL while they step; Python envs step faster inline)",
    )
    parser.add_argument(
        "--idle-envs",
        type=int,
        default=DEFAULT_IDLE_ENVS,
        metavar="N",
        help="built Meta-World envs kept idle for the next task of their class, shared by "
        "every slot of this process (~20 MB each; building one takes ~20 ms with its class's "
        "compiled model kept, ~0.2 s without)",
    )
    parser.add_argument(
        "--compiled-models",
        type=int,
        default=DEFAULT_COMPILED_MODELS,
        metavar="N",
        help="compiled MuJoCo models of Meta-World classes kept so that building an env "
        "copies one (~20 ms) instead of compiling its XML (~0.2 s); ~21 MB each, least "
        "recently used dropped; 0 = compile every env",
    )
    parser.add_argument(
        "--no-fast-paths",
        action="store_true",
        help="run Meta-World's own code for the gripper-contact test and the object "
        "quaternions instead of million_env's fast paths (the same numbers, slower; for "
        "timing the two)",
    )
    parser.add_argument(
        "--preload",
        action="append",
        default=[],
        metavar="BENCHMARK",
        help="build a Meta-World benchmark before serving: ML10, ML45 or ML1:TASK (repeatable)",
    )
    parser.add_argument(
        "--token",
        default=None,
        help=f"require this shared token on every call but health (metadata "
        f"'authorization: Bearer <token>'); default ${TOKEN_ENV_VAR}. Prefer the "
        f"variable: a command line is visible to other users",
    )
    parser.add_argument("--tls-cert", type=Path, default=None, help="PEM certificate chain")
    parser.add_argument("--tls-key", type=Path, default=None, help="PEM private key")
    parser.add_argument(
        "--shutdown-grace",
        type=float,
        default=DEFAULT_SHUTDOWN_GRACE_S,
        metavar="SECONDS",
        help="on SIGTERM, how long calls in flight may take to finish",
    )
    parser.add_argument(
        "--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"]
    )
    parser.add_argument(
        "--log-format", default="text", choices=["text", "json"], help="json: one object a line"
    )
    args = parser.parse_args(argv)
    if args.token is None:
        args.token = os.environ.get(TOKEN_ENV_VAR) or None
    if args.token is not None and not args.token.strip():
        parser.error("--token must not be empty")
    if (args.tls_cert is None) != (args.tls_key is None):
        parser.error("--tls-cert and --tls-key go together")
    if args.shutdown_grace < 0:
        parser.error("--shutdown-grace must be 0 or positive")
    if args.handle_idle_timeout < 0:
        parser.error("--handle-idle-timeout must be 0 (never) or positive")
    if args.max_envs_per_handle < 1 or args.max_envs_total < 1:
        parser.error("--max-envs-per-handle and --max-envs-total must be at least 1")
    if args.idle_envs < 0:
        parser.error("--idle-envs must be 0 or positive")
    if args.compiled_models < 0:
        parser.error("--compiled-models must be 0 or positive")
    for item in args.preload:
        name, _, task = item.partition(":")
        if (
            name not in BENCHMARKS
            or (name == "ML1") != bool(task)
            or (task and task not in ALL_TASK_NAMES)
        ):
            parser.error(f"--preload {item!r}: expected ML10, ML45 or ML1:<task name>")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    logs.configure(args.log_level, args.log_format)
    BUILT_ENVS.max_idle = args.idle_envs
    COMPILED_MODELS.max_models = args.compiled_models
    metaworld_fast_paths.ENABLED = not args.no_fast_paths
    fix_mmap_threshold()
    from million_env.server import serve

    tls = None
    if args.tls_cert is not None:
        try:
            tls = ServerTls.from_files(args.tls_cert, args.tls_key)
        except TlsConfigError as err:
            raise SystemExit(f"million-env-server: {err}") from err
    limits = ServerLimits(args.max_envs_per_handle, args.max_envs_total, args.handle_idle_timeout)
    asyncio.run(
        serve(
            args.address,
            limits,
            args.workers,
            args.preload,
            token=args.token,
            tls=tls,
            shutdown_grace_s=args.shutdown_grace,
            step_threads=args.step_threads,
        )
    )


if __name__ == "__main__":
    main()
