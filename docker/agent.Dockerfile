# The MILLION agent (`million` CLI), built against the libtorch of the torch wheel.
# Build from the repository root:  docker build -f docker/agent.Dockerfile -t million-agent .
FROM rust:1.95-slim-bookworm AS build
RUN apt-get update && apt-get install -y --no-install-recommends python3 python3-venv g++ make \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY requirements/agent.lock requirements/agent.lock
RUN python3 -m venv /opt/venv && /opt/venv/bin/pip install --disable-pip-version-check -r requirements/agent.lock
ENV PATH=/opt/venv/bin:$PATH LIBTORCH_USE_PYTORCH=1
COPY Cargo.toml Cargo.lock ./
COPY proto proto
COPY agent agent
RUN cargo build --release --locked -p million --bin million

FROM python:3.11-slim
COPY --from=build /opt/venv /opt/venv
COPY --from=build /src/target/release/million /usr/local/bin/million
COPY configs /opt/million/configs
ENV PATH=/opt/venv/bin:$PATH \
    LD_LIBRARY_PATH=/opt/venv/lib/python3.11/site-packages/torch/lib
WORKDIR /opt/million
ENTRYPOINT ["million"]
CMD ["train", "--config", "configs/ml10.toml", "--env-server", "http://env-server:50051", "--run-dir", "/runs/ml10"]
