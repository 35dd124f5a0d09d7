"""Matrix-product rates of a learner update's shapes at one thread, float32 against bfloat16.

What bounds a learner update (BENCHMARKS.md, "The learner"): at configs/ml10.toml's sizes about
half of an update is these products. `.venv/bin/python bench/learner_gemm.py`.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

# (rows, inner, columns) of the update's largest products at configs/ml10.toml's sizes:
# 16 segments x 32 steps = 512 rows, d = 64, the gates' 3d, the feed-forward's 256, and the
# keys and values of [memory; segment] (16 x 96 = 1536 rows).
SHAPES = [(512, 64, 192), (512, 64, 256), (512, 256, 64), (1536, 64, 128), (64, 512, 64)]


def seconds_per_product(a: torch.Tensor, b: torch.Tensor, calls: int = 2000) -> float:
    for _ in range(50):
        a @ b
    start = time.perf_counter()
    for _ in range(calls):
        a @ b
    return (time.perf_counter() - start) / calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--calls", type=int, default=2000, help="timed products per shape")
    parser.add_argument("--json", action="store_true", help="one JSON object instead of text")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = []
    for m, k, n in SHAPES:
        a, b = torch.randn(m, k), torch.randn(k, n)
        flop = 2 * m * k * n
        f32 = flop / seconds_per_product(a, b, args.calls) / 1e9
        bf16 = flop / seconds_per_product(a.bfloat16(), b.bfloat16(), args.calls) / 1e9
        rows.append({"shape": [m, k, n], "float32_gflops": f32, "bfloat16_gflops": bf16})
    if args.json:
        print(json.dumps({"threads": 1, "products": rows}))
        return
    print("rows inner cols   float32 GFLOP/s   bfloat16 GFLOP/s")
    for r in rows:
        m, k, n = r["shape"]
        print(f"{m:4d} {k:5d} {n:4d}   {r['float32_gflops']:15.1f}   {r['bfloat16_gflops']:16.1f}")


if __name__ == "__main__":
    main()
