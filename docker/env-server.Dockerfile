# The MILLION env server: Gymnasium + Meta-World v3 + the MILLION protocol over gRPC.
# Build from the repository root:
#   docker build -f docker/env-server.Dockerfile -t million-env-server .
# Base image: PYTHON_IMAGE (default python:3.11-slim; any Debian-like image with python3
# and its venv module). Python packages come from PyPI, or, when the build context holds
# wheels in docker/offline/env-server/ (made by `docker/offline.sh env-server` on a host
# that reaches PyPI), from those wheels only.
ARG PYTHON_IMAGE=python:3.11-slim

FROM ${PYTHON_IMAGE} AS build
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1 PYTHONDONTWRITEBYTECODE=1
WORKDIR /src
COPY docker/offline /offline
COPY requirements/env-server.lock requirements/env-server.lock
# Two venvs: /opt/venv is what the server runs with (the lock minus test/lint tools and
# the code generator); /opt/gen only generates the Python code of the proto.
RUN set -eu; \
    if [ -d /offline/env-server ]; then from="--no-index --find-links /offline/env-server"; else from=""; fi; \
    grep -viE '^(pytest|iniconfig|pluggy|pygments|pyyaml|ruff|grpcio-tools)==' requirements/env-server.lock > /tmp/runtime.txt; \
    grep -iE '^(grpcio|grpcio-tools|protobuf|setuptools)==' requirements/env-server.lock > /tmp/gen.txt; \
    python3 -m venv /opt/venv && /opt/venv/bin/pip install --quiet $from -r /tmp/runtime.txt; \
    python3 -m venv /opt/gen && /opt/gen/bin/pip install --quiet $from -r /tmp/gen.txt
COPY proto proto
COPY env-server env-server
RUN set -eu; out=env-server/src/million_env/_proto; rm -rf $out; mkdir -p $out; \
    /opt/gen/bin/python -m grpc_tools.protoc -I proto/million/env/v1 --python_out=$out \
      --pyi_out=$out --grpc_python_out=$out proto/million/env/v1/env.proto; \
    sed -i 's/^import env_pb2 as/from . import env_pb2 as/' $out/env_pb2_grpc.py; \
    touch $out/__init__.py; \
    /opt/venv/bin/pip install --quiet --no-deps --no-build-isolation ./env-server; \
    find /opt/venv -name __pycache__ -prune -exec rm -rf {} +

FROM ${PYTHON_IMAGE}
ENV PATH=/opt/venv/bin:$PATH PYTHONUNBUFFERED=1 MUJOCO_GL=egl
# Headless MuJoCo rendering for the Render RPC (videos): EGL with Mesa's software renderer.
RUN apt-get update \
 && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /opt/venv /opt/venv
COPY docker/env-server-health.py /usr/local/bin/million-env-health
RUN useradd --system --no-create-home million
USER million
EXPOSE 50051
# Inside a container the server listens on all interfaces; publish the port only
# where it should be reachable.
ENTRYPOINT ["million-env-server", "--address", "0.0.0.0:50051"]
HEALTHCHECK --interval=5s --timeout=4s --start-period=60s --retries=3 CMD ["million-env-health"]
