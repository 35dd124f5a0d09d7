#!/usr/bin/env bash
# Local stand-ins for the public base images, for machines that cannot pull from a
# registry (the project's CI machines have a Docker engine but no registry).
#
#   docker/make-base-images.sh            # python + debian images (what `make test-docker` needs)
#   docker/make-base-images.sh --rust     # also a Rust toolchain image (the agent built from source)
#
# Each image is a Debian bookworm root file system made with debootstrap and loaded with
# `docker import`; an image that already exists is kept (delete it to rebuild). They are
# passed to the Dockerfiles as the build arguments that default to the public images:
#
#   million-base/python:3.11-slim    PYTHON_IMAGE    (public: python:3.11-slim; Debian's python3.11)
#   million-base/debian:bookworm-slim RUNTIME_IMAGE  (public: debian:bookworm-slim)
#   million-base/rust:1.95-bookworm  RUST_IMAGE      (public: rust:1.95-bookworm; the host's rustup toolchain)
#
# Needs root, debootstrap (apt-get install debootstrap) and a Debian mirror
# (MIRROR, default http://deb.debian.org/debian). Root file systems and debootstrap's
# package cache live in $MILLION_DOCKER_CACHE (default .docker-cache/, ignored by git).
set -euo pipefail
cd "$(dirname "$0")/.."
CACHE=${MILLION_DOCKER_CACHE:-$PWD/.docker-cache}
MIRROR=${MIRROR:-http://deb.debian.org/debian}
SUITE=bookworm
WITH_RUST=0
[[ ${1:-} == --rust ]] && WITH_RUST=1

have_image() { docker image inspect "$1" >/dev/null 2>&1; }

# make_image IMAGE PACKAGES [EXTRA_SETUP_FUNCTION]
make_image() {
    local image=$1 packages=$2 setup=${3:-}
    if have_image "$image"; then
        echo "base image $image: present"
        return
    fi
    local started=$SECONDS
    local root="$CACHE/rootfs-${image//[\/:]/-}"
    rm -rf "$root"
    mkdir -p "$CACHE/debs"
    echo "base image $image: debootstrap $SUITE into $root"
    debootstrap --variant=minbase --cache-dir="$CACHE/debs" \
        ${packages:+--include="$packages"} "$SUITE" "$root" "$MIRROR" >"$root.log" 2>&1 || {
        tail -20 "$root.log"
        exit 1
    }
    # As in Docker's own Debian images: no package caches or lists, no docs.
    rm -rf "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/* \
        "$root"/usr/share/doc/* "$root"/usr/share/man/* "$root"/usr/share/locale/*
    [[ -n $setup ]] && "$setup" "$root"
    tar --numeric-owner -C "$root" -c . | docker import \
        -c 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8' \
        -c 'CMD ["bash"]' - "$image" >/dev/null
    rm -rf "$root"
    echo "base image $image: made in $((SECONDS - started)) s ($(docker image inspect -f '{{.Size}}' "$image" | numfmt --to=iec))"
}

python_setup() {
    # The public python image has `python`; Debian's has python3 only.
    ln -sf /usr/bin/python3 "$1/usr/local/bin/python"
}

rust_setup() {
    # The host's rustup toolchain (no other can be fetched here), without its docs.
    local toolchain
    toolchain=$(rustc --print sysroot)
    mkdir -p "$1/usr/local/rust"
    tar -C "$toolchain" --exclude=share/doc -c . | tar -C "$1/usr/local/rust" -x
    for tool in cargo rustc rustdoc; do
        ln -sf "/usr/local/rust/bin/$tool" "$1/usr/local/bin/$tool"
    done
}

command -v debootstrap >/dev/null || {
    echo "debootstrap is missing: apt-get install debootstrap" >&2
    exit 1
}
make_image million-base/debian:bookworm-slim ca-certificates
make_image million-base/python:3.11-slim ca-certificates,python3,python3-venv python_setup
if ((WITH_RUST)); then
    make_image million-base/rust:1.95-bookworm \
        ca-certificates,gcc,g++,libc6-dev,make,pkg-config,python3,python3-venv rust_setup
fi
