# The MILLION agent (`million` CLI), built from source against the libtorch of the
# torch wheel, on a CPU-only runtime image. Build from the repository root:
#   docker build -f docker/agent.Dockerfile -t million-agent .
# Base images: RUST_IMAGE (default rust:1.95-bookworm) to build, RUNTIME_IMAGE (default
# debian:bookworm-slim) to run. Packages come from PyPI and crates.io, or, when the
# build context holds them in docker/offline/agent/ (`docker/offline.sh agent`), from
# there only.
ARG RUST_IMAGE=rust:1.95-bookworm
ARG RUNTIME_IMAGE=debian:bookworm-slim

FROM ${RUST_IMAGE} AS build
RUN apt-get update \
 && apt-get install -y --no-install-recommends python3 python3-venv patchelf binutils \
 && rm -rf /var/lib/apt/lists/*
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1 LIBTORCH_USE_PYTORCH=1 \
    CARGO_NET_GIT_FETCH_WITH_CLI=true
WORKDIR /src
COPY docker/offline docker/offline
COPY requirements/agent.lock requirements/agent.lock
# libtorch comes from the torch wheel, as on the host (tch finds it through python3).
RUN set -eu; \
    if [ -d docker/offline/agent/wheels ]; then from="--no-index --find-links docker/offline/agent/wheels"; else from=""; fi; \
    python3 -m venv /opt/torch && /opt/torch/bin/pip install --quiet $from -r requirements/agent.lock; \
    rm -rf docker/offline/agent/wheels
ENV PATH=/opt/torch/bin:$PATH
COPY Cargo.toml Cargo.lock ./
COPY proto proto
COPY agent agent
# million-env embeds the contract's check list (include_str!).
COPY tests/contract/checks.toml tests/contract/checks.toml
RUN set -eu; \
    if [ -d docker/offline/agent/vendor ]; then \
      mkdir -p .cargo; \
      printf '[source.crates-io]\nreplace-with = "vendored"\n[source.vendored]\ndirectory = "docker/offline/agent/vendor"\n' > .cargo/config.toml; \
    fi; \
    cargo build --release --locked -p million --bin million
COPY configs configs
COPY docker/agent-bundle.sh docker/agent-train.sh docker/
RUN docker/agent-bundle.sh target/release/million /bundle \
 && cp docker/agent-train.sh /bundle/bin/million-train

FROM ${RUNTIME_IMAGE}
COPY --from=build /bundle /opt/million
RUN useradd --system --uid 10001 --no-create-home million \
 && ln -s /opt/million/bin/million /usr/local/bin/million \
 && ln -s /opt/million/bin/million-train /usr/local/bin/million-train \
 && mkdir -p /runs && chown million /runs
USER million
WORKDIR /opt/million
VOLUME /runs
# million stops on SIGINT after writing a final checkpoint (docker stop sends this).
STOPSIGNAL SIGINT
ENTRYPOINT ["million-train"]
CMD ["--config", "configs/ml10.toml", "--env-server", "env-server:50051", "--run-dir", "/runs/ml10"]
