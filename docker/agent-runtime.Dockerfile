# The agent image from a prebuilt bundle (docker/agent-bundle.sh): what `make
# test-docker` builds, from the binary `make build` made on the host. Users build
# docker/agent.Dockerfile, which makes the same bundle from source.
#   docker build -f docker/agent-runtime.Dockerfile -t million-agent BUNDLE_DIR
# The context is the bundle directory (bin/ lib/ configs/ and this entry point).
ARG RUNTIME_IMAGE=debian:bookworm-slim
FROM ${RUNTIME_IMAGE}
COPY . /opt/million
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
