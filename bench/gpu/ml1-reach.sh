#!/usr/bin/env bash
# ML1 reach on one GPU machine (configs/bench/gpu-ml1-reach*.toml), with and without
# instructions, two seeds each, four runs side by side (2 env servers each; learners and actors
# share the GPU), stopped after SECONDS with SIGINT so that each ends with its final evaluation
# and checkpoint (only the agent gets the signal: it ends its env servers itself).
#   bash bench/gpu/ml1-reach.sh [OUT_DIR] [SECONDS]   # OUT_DIR/<arm>-seed<N>.jsonl: metrics
# Curves: tools/plot_curves.py on the metrics files (RESULTS.md).
set -euo pipefail
cd "$(dirname "$0")/../.."
out="${1:-runs/gpu-ml1-reach}"
seconds="${2:-480}"
mkdir -p "$out"
. bench/gpu/env.sh >"$out/setup.log" 2>&1
pids=()
for arm in gpu-ml1-reach gpu-ml1-reach-no-instructions; do
  for seed in 1 2; do
    run="runs/$arm-seed$seed"
    rm -rf "$run"
    timeout --foreground --preserve-status -s INT -k 60 "$seconds" "$bin" train --config "configs/bench/$arm.toml" \
      --seed "$seed" --run-dir "$run" >"$out/$arm-seed$seed.log" 2>&1 &
    pids+=($!)
  done
done
status=0
# --preserve-status: the agent's own status (0 after a SIGINT stop), so a failed final
# evaluation or checkpoint is a failure here too.
for pid in "${pids[@]}"; do wait "$pid" || status=$?; done
for arm in gpu-ml1-reach gpu-ml1-reach-no-instructions; do
  for seed in 1 2; do
    cp "runs/$arm-seed$seed/metrics.jsonl" "$out/$arm-seed$seed.jsonl" || status=1
  done
done
(cd "$out" && tar -czf logs.tar.gz --remove-files -- *.log) || status=1
exit "$status"
