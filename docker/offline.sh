#!/usr/bin/env bash
# Packages for image builds on machines whose containers cannot fetch them (here: TLS
# to PyPI and crates.io from inside a container fails with "self-signed certificate in
# certificate chain"; the host reaches both). Downloads on the host, into the build
# context, what the Dockerfiles then install with no network:
#
#   docker/offline.sh env-server   wheels of requirements/env-server.lock -> docker/offline/env-server/
#   docker/offline.sh agent        wheels of requirements/agent.lock      -> docker/offline/agent/wheels/
#                                  and `cargo vendor` of Cargo.lock        -> docker/offline/agent/vendor/
#
# docker/offline/ is ignored by git; without it the Dockerfiles use PyPI and crates.io.
# The build context is the repository root, so docker/offline/agent (about 3 GB) is sent
# with every image build while it exists: delete it once the agent image is built.
set -euo pipefail
cd "$(dirname "$0")/.."
PIP=${PIP:-.venv/bin/pip}
out=docker/offline
case ${1:-} in
env-server)
    mkdir -p "$out/env-server"
    # The lock is complete (every dependency pinned), so --no-deps; wheels come from
    # pip's cache when the host's .venv was installed from the same lock.
    "$PIP" wheel --quiet --disable-pip-version-check --no-deps \
        -r requirements/env-server.lock -w "$out/env-server"
    ;;
agent)
    mkdir -p "$out/agent/wheels"
    "$PIP" wheel --quiet --disable-pip-version-check --no-deps \
        -r requirements/agent.lock -w "$out/agent/wheels"
    cargo vendor --locked --quiet "$out/agent/vendor" >/dev/null
    ;;
*)
    echo "usage: $0 env-server|agent" >&2
    exit 2
    ;;
esac
du -sh "$out/${1}" | sed 's/^/offline packages: /'
