"""Env server memory per env slot: one server, N envs of one id, random actions.

    .venv/bin/python bench/env/server_memory.py \
        --env million/ML10-train --num-envs 32 --resets 400 [--idle-envs 16] \
        [--compiled-models 10] [--json]

Starts a server (``--idle-envs`` and ``--compiled-models`` go to it), makes one batch of N
envs, steps it with random actions until the envs have begun ``--resets`` episodes in all
(each episode samples a task, which is where Meta-World envs get built), and samples the
server's resident memory (VmRSS, and its peak VmHWM) along the way. Reports the peak in MB
per env slot, the envs the server built per episode begun and how many of those compiled
their XML rather than copied a kept model (its GetStats counters), and the server's CPU
seconds per agent step: fewer idle envs and kept models cost less memory and more builds.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import time
from pathlib import Path

import grpc
import numpy as np

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.client import RemoteVectorEnv
from million_env.server_process import start_server, stop_server


def memory_mb(pid: int) -> dict[str, float]:
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            fields[key] = int(value.split()[0]) / 1024
    return fields


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (/proc/PID/stat fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measure(
    process: subprocess.Popen, address: str, env_id: str, num_envs: int, resets: int
) -> dict[str, float]:
    idle = memory_mb(process.pid)["VmRSS"]
    env = RemoteVectorEnv(address, env_id, num_envs, timeout=600.0)
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    env.reset(seed=0)
    made = memory_mb(process.pid)["VmRSS"]
    cpu_after_make = cpu_seconds(process.pid)
    begun = num_envs
    steps = 0
    while begun < resets:
        actions = rng.uniform(-1, 1, size=(num_envs, *env.single_action_space.shape))
        _, _, terminated, truncated, _ = env.step(actions.astype(np.float32))
        begun += int(np.sum(terminated | truncated))
        steps += 1
    elapsed = time.perf_counter() - start
    final = memory_mb(process.pid)
    stepping_cpu = cpu_seconds(process.pid) - cpu_after_make
    env.close()
    with grpc.insecure_channel(address) as channel:
        stats = env_pb2_grpc.EnvServiceStub(channel).GetStats(env_pb2.GetStatsRequest(), timeout=30)
    built = stats.counters["metaworld_envs_built"]
    compiled = stats.counters.get("metaworld_models_compiled", built)
    return {
        "num_envs": num_envs,
        "episodes_begun": begun,
        "batch_steps": steps,
        "seconds": round(elapsed, 1),
        "rss_idle_server_mb": round(idle, 1),
        "rss_after_make_mb": round(made, 1),
        "rss_final_mb": round(final["VmRSS"], 1),
        "rss_peak_mb": round(final["VmHWM"], 1),
        "peak_mb_per_slot": round(final["VmHWM"] / num_envs, 1),
        "envs_built": int(built),
        "builds_per_episode": round(built / begun, 3),
        "compiles_per_episode": round(compiled / begun, 3),
        "server_cpu_ms_per_step": round(1e3 * stepping_cpu / (steps * num_envs), 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="million/ML10-train")
    parser.add_argument("--num-envs", type=int, default=32)
    parser.add_argument("--resets", type=int, default=400)
    parser.add_argument("--idle-envs", type=int, default=None)
    parser.add_argument("--compiled-models", type=int, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    extra = [] if args.idle_envs is None else ["--idle-envs", str(args.idle_envs)]
    if args.compiled_models is not None:
        extra += ["--compiled-models", str(args.compiled_models)]
    process, address = start_server(*extra)
    try:
        result = measure(process, address, args.env, args.num_envs, args.resets)
    finally:
        stop_server(process)
    result = {
        "env": args.env,
        "idle_envs": args.idle_envs,
        "compiled_models": args.compiled_models,
        **result,
    }
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:>20}: {value}")


if __name__ == "__main__":
    main()
