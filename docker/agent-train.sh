#!/bin/sh
# The agent image's entry point: `million train` that resumes when its run directory
# (--run-dir) already holds a checkpoint (a restarted container, a rescheduled pod),
# and starts fresh otherwise. Every argument goes to `million train`.
#   million-train --config configs/quickstart.toml --env-server env-server:50051 --run-dir /runs/quickstart
set -eu
run_dir=
prev=
resume=
for arg in "$@"; do
    [ "$prev" = --run-dir ] && run_dir=$arg
    case $arg in --run-dir=*) run_dir=${arg#--run-dir=} ;; --resume) resume=1 ;; esac
    prev=$arg
done
set -- train "$@"
if [ -z "$resume" ] && [ -n "$run_dir" ] && ls "$run_dir"/checkpoints/step-*.safetensors >/dev/null 2>&1; then
    echo "million-train: $run_dir has checkpoints; resuming" >&2
    set -- "$@" --resume
fi
exec million "$@"
