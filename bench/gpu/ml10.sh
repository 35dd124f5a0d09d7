#!/usr/bin/env bash
# ML10 (configs/bench/gpu-ml10.toml) on one GPU machine for SECONDS, then SIGINT (final
# evaluation and checkpoint). Only the agent gets the signal; it ends its env servers itself.
#   bash bench/gpu/ml10.sh [OUT_DIR] [SECONDS]   # OUT_DIR/gpu-ml10.jsonl: metrics
set -euo pipefail
cd "$(dirname "$0")/../.."
out="${1:-runs/gpu-ml10}"
seconds="${2:-480}"
mkdir -p "$out"
. bench/gpu/env.sh >"$out/setup.log" 2>&1
run=runs/gpu-ml10-run
rm -rf "$run"
status=0
# --preserve-status: the agent's own status (0 after a SIGINT stop).
timeout --foreground --preserve-status -s INT -k 90 "$seconds" "$bin" train \
  --config configs/bench/gpu-ml10.toml --run-dir "$run" >"$out/gpu-ml10.log" 2>&1 || status=$?
cp "$run/metrics.jsonl" "$out/gpu-ml10.jsonl" || status=1
gzip -f "$out/gpu-ml10.log"
exit "$status"
