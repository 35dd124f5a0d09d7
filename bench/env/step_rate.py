"""Served vs in-process step rate on Meta-World reach-v3 (random actions).

    .venv/bin/python bench/env/step_rate.py [--steps 3000] [--address HOST:PORT]

Without --address it starts the bundled server on a free loopback port. Counts env
steps per second: one env, and a batch of 16 (in process: 16 envs stepped in a loop;
served: one 16-env handle, unary Step and the pipelined Session stream).
"""

from __future__ import annotations

import argparse
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import grpc
import numpy as np

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.metaworld_tasks import MetaWorldTaskSampler
from million_env.tensors import encode_tensor

ENV_ID = "metaworld/ML1-train"
TASK = "reach-v3"


def in_process_rate(num_envs: int, steps: int, rng: np.random.Generator) -> float:
    samplers = [MetaWorldTaskSampler("ML1", "train", task=TASK, seed=i) for i in range(num_envs)]
    envs = [s.sample().env for s in samplers]
    for env in envs:
        env.reset()
    actions = rng.uniform(-1, 1, size=(steps, num_envs, 4)).astype(np.float32)
    start = time.perf_counter()
    for row in actions:
        for env, action in zip(envs, row, strict=True):
            *_, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
    elapsed = time.perf_counter() - start
    return steps * num_envs / elapsed


def _make(stub: env_pb2_grpc.EnvServiceStub, num_envs: int) -> str:
    made = stub.Make(
        env_pb2.MakeRequest(
            env_id=ENV_ID, num_envs=num_envs, kwargs={"task": env_pb2.Value(string_value=TASK)}
        )
    )
    stub.Reset(env_pb2.ResetRequest(handle=made.handle, seeds=list(range(num_envs))))
    return made.handle


def served_unary_rate(
    stub: env_pb2_grpc.EnvServiceStub, num_envs: int, steps: int, rng: np.random.Generator
) -> float:
    handle = _make(stub, num_envs)
    tensors = [
        encode_tensor(rng.uniform(-1, 1, size=(num_envs, 4)).astype(np.float32))
        for _ in range(steps)
    ]
    start = time.perf_counter()
    for tensor in tensors:
        stub.Step(env_pb2.StepRequest(handle=handle, action=tensor))
    elapsed = time.perf_counter() - start
    stub.Close(env_pb2.CloseRequest(handle=handle))
    return steps * num_envs / elapsed


def served_stream_rate(
    stub: env_pb2_grpc.EnvServiceStub, num_envs: int, steps: int, rng: np.random.Generator
) -> float:
    handle = _make(stub, num_envs)
    tensors = [
        encode_tensor(rng.uniform(-1, 1, size=(num_envs, 4)).astype(np.float32))
        for _ in range(steps)
    ]

    def requests() -> Iterator[env_pb2.SessionRequest]:
        for i, tensor in enumerate(tensors):
            yield env_pb2.SessionRequest(
                request_id=i, step=env_pb2.StepRequest(handle=handle, action=tensor)
            )

    start = time.perf_counter()
    replies = sum(1 for reply in stub.Session(requests()) if reply.HasField("step"))
    elapsed = time.perf_counter() - start
    stub.Close(env_pb2.CloseRequest(handle=handle))
    assert replies == steps
    return steps * num_envs / elapsed


def start_server() -> tuple[subprocess.Popen, str]:
    script = Path(sys.executable).with_name("million-env-server")
    process = subprocess.Popen(
        [str(script), "--address", "127.0.0.1:0", "--log-level", "WARNING"],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert process.stdout is not None
    match = re.search(r"listening on (\S+:\d+)", process.stdout.readline())
    if match is None:
        process.kill()
        raise RuntimeError("env server did not start")
    return process, match.group(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=3000, help="steps per env (single env)")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--address", default=None)
    args = parser.parse_args()
    batch_steps = max(1, args.steps // args.batch * 2)
    process = None
    address = args.address
    if address is None:
        process, address = start_server()
    try:
        channel = grpc.insecure_channel(address)
        grpc.channel_ready_future(channel).result(timeout=60)
        stub = env_pb2_grpc.EnvServiceStub(channel)
        rng = np.random.default_rng(0)
        rows = [
            ("in-process, 1 env", in_process_rate(1, args.steps, rng)),
            ("served unary, 1 env", served_unary_rate(stub, 1, args.steps, rng)),
            ("served stream, 1 env", served_stream_rate(stub, 1, args.steps, rng)),
            (f"in-process, {args.batch} envs", in_process_rate(args.batch, batch_steps, rng)),
            (
                f"served unary, {args.batch} envs",
                served_unary_rate(stub, args.batch, batch_steps, rng),
            ),
            (
                f"served stream, {args.batch} envs",
                served_stream_rate(stub, args.batch, batch_steps, rng),
            ),
        ]
        print(f"Meta-World {TASK}, random actions; env steps per second")
        for name, rate in rows:
            print(f"  {name:<28} {rate:8.0f}")
        channel.close()
    finally:
        if process is not None:
            process.send_signal(signal.SIGINT)
            process.wait(timeout=30)


if __name__ == "__main__":
    main()
