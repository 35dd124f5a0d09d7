#!/usr/bin/env bash
# Packs a built `million` binary and the part of libtorch it needs at run time into a
# directory laid out as /opt/million in the agent image:
#
#   docker/agent-bundle.sh BINARY OUT_DIR
#     OUT_DIR/bin/million    the binary, debug info stripped, rpath $ORIGIN/../lib
#     OUT_DIR/lib/           libtorch_cpu, libc10, libgomp, ... (what ldd finds outside
#                            the system's own library directories), rpath $ORIGIN
#     OUT_DIR/configs/       the run configs
#
# The torch wheel is a CUDA build: its libtorch_cuda (and the 2.7 GB of CUDA libraries
# behind it) is dropped from the binary's needed libraries, so the image is CPU only
# (tch then reports no CUDA device). libtorch_cpu itself still needs libcudart and
# libcupti, which are small and kept. Needs patchelf, ldd and strip. Used by the agent
# image's build stage and, for `make test-docker`, on the host.
set -euo pipefail
binary=$1
out=$2
here=$(cd "$(dirname "$0")/.." && pwd)
rm -rf "$out"
mkdir -p "$out/bin" "$out/lib"
cp "$binary" "$out/bin/million"
chmod u+w "$out/bin/million"
strip --strip-debug "$out/bin/million"
for lib in libtorch_cuda.so libc10_cuda.so libtorch_cuda_linalg.so libtorch.so libtorch_nvshmem.so; do
    if patchelf --print-needed "$out/bin/million" | grep -qx "$lib"; then
        patchelf --remove-needed "$lib" "$out/bin/million"
    fi
done
# ldd resolves through the binary's original rpath (torch's lib/), still set here.
ldd "$out/bin/million" | awk '$2 == "=>" && $3 ~ /^\// {print $3}' | while read -r path; do
    case $path in
    /lib/* | /lib64/* | /usr/lib/* | /usr/lib64/*) ;; # the base image's own
    *) cp -L "$path" "$out/lib/" ;;
    esac
done
if ldd "$out/bin/million" | grep -q "not found"; then
    ldd "$out/bin/million" | grep "not found" >&2
    exit 1
fi
patchelf --set-rpath '$ORIGIN/../lib' "$out/bin/million"
for lib in "$out"/lib/*; do
    chmod u+w "$lib"
    patchelf --set-rpath '$ORIGIN' "$lib"
done
cp -r "$here/configs" "$out/configs"
du -sh "$out" | sed 's/^/agent bundle: /'
