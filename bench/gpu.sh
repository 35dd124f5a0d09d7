#!/usr/bin/env bash
# The GPU benchmarks: the learner on CUDA (alone, and against the PyTorch
# reference on the same GPU) and ML10 end to end with one env server per core and the
# learner and actor on the GPU. Needs an NVIDIA GPU and driver; nothing else in the project
# depends on this script.
#   bash bench/gpu.sh [OUT_DIR] [SECONDS]    # results: OUT_DIR/*.json and *.txt (default runs/gpu)
# Two ways to get the agent:
#   - a machine with network access: `make build` here (the CUDA torch wheel in .venv);
#   - an offline GPU machine with its own Python and CUDA torch: stage the agent and the
#     env server's wheels elsewhere with `bash bench/gpu/stage.sh` (writes .gpu/), copy the
#     repository with .gpu/, and this script uses them.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-runs/gpu}"
seconds="${2:-150}"
mkdir -p "$out"
. bench/gpu/env.sh >"$out/setup.log" 2>&1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$out/gpu.txt"
nproc | tee "$out/cores.txt"
# The learner alone on CUDA (runtime.device = "cuda").
"$bin" bench learner --config configs/bench/ml10-gpu.toml --iters 20 | tee "$out/learner.txt"
# The same update in the PyTorch reference on the same device, losses checked first.
"$bin" bench learner --config configs/bench/ml10-gpu.toml --reference --python "$python" --iters 20 --rounds 3 \
  --threads 1 --json | tee "$out/learner-reference.json"
# End to end: 14 local env servers, learner and actor on the GPU.
"$bin" bench train --config configs/bench/ml10-gpu.toml --seconds "$seconds" --json \
  | tee "$out/train.json"
