#!/usr/bin/env bash
# The GPU benchmarks (issue 9): build from a fresh clone, then time the learner on CUDA
# (alone, and against the PyTorch reference) and ML10 end to end with one env server per
# core. Needs an NVIDIA GPU and driver; nothing else in the project depends on this script.
#   bash bench/gpu.sh [OUT_DIR]      # results: OUT_DIR/*.json and *.txt (default runs/gpu)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-runs/gpu}"
mkdir -p "$out"
make build >"$out/build.log" 2>&1
export MILLION_ROOT="$PWD"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$out/gpu.txt"
nproc | tee "$out/cores.txt"
bin=target/release/million
# The learner alone on CUDA (runtime.device = "cuda").
$bin bench learner --config configs/bench/ml10-gpu.toml --iters 20 | tee "$out/learner.txt"
# The same update in the PyTorch reference on the same device, losses checked first.
$bin bench learner --config configs/bench/ml10-gpu.toml --reference --json \
  | tee "$out/learner-reference.json"
# End to end: 14 local env servers, learner and actor on the GPU.
$bin bench train --config configs/bench/ml10-gpu.toml --seconds 150 --json \
  | tee "$out/train.json"
