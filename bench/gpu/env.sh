# Sourced by the GPU scripts (bench/gpu.sh, bench/gpu/ml1-reach.sh, bench/gpu/ml10.sh) from the
# repository root, on the GPU machine:
# sets $bin (the agent) and $python (the Python of the bench's reference side) and the
# environment the agent's local env servers need. On an offline GPU machine it uses what
# `bash bench/gpu/stage.sh` staged in .gpu/; elsewhere it builds with `make build`.
export MILLION_ROOT="$PWD"
if [ -x .gpu/bin/million ]; then
  bin=.gpu/bin/million
  python=$(command -v python3)
  site=/tmp/million-site
  "$python" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$site" .gpu/whl/*.whl
  export PYTHONPATH="$site:$PWD/.gpu/glove:$PWD/env-server/src"
  rm -rf env-server/src/million_env/_proto && cp -r .gpu/proto env-server/src/million_env/_proto
  # The agent was linked against this machine's torch version; use its libraries.
  torch_lib=$("$python" -c 'import os, torch; print(os.path.join(os.path.dirname(torch.__file__), "lib"))')
  export LD_LIBRARY_PATH="$torch_lib:${LD_LIBRARY_PATH:-}"
  # No libEGL there (rendering is not needed to train or time): MuJoCo without a GL context.
  export MUJOCO_GL=disable
  server="$PWD/.gpu/million-env-server"
  printf '#!/bin/sh\nexec "%s" -m million_env.cli "$@"\n' "$python" >"$server"
  chmod +x "$server"
  export MILLION_ENV_SERVER="$server"
else
  make build
  bin=target/release/million
  python=.venv/bin/python
fi
