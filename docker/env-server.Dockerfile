# The MILLION env server: Gymnasium + Meta-World v3 + the MILLION protocol over gRPC.
# Build from the repository root:  docker build -f docker/env-server.Dockerfile -t million-env-server .
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PIP_NO_CACHE_DIR=1 MUJOCO_GL=egl
WORKDIR /opt/million
COPY requirements/env-server.lock requirements/env-server.lock
RUN pip install --disable-pip-version-check -r requirements/env-server.lock
COPY proto proto
COPY env-server env-server
RUN mkdir -p env-server/src/million_env/_proto \
 && python -m grpc_tools.protoc -I proto/million/env/v1 \
      --python_out=env-server/src/million_env/_proto --pyi_out=env-server/src/million_env/_proto \
      --grpc_python_out=env-server/src/million_env/_proto proto/million/env/v1/env.proto \
 && sed -i 's/^import env_pb2 as/from . import env_pb2 as/' env-server/src/million_env/_proto/env_pb2_grpc.py \
 && touch env-server/src/million_env/_proto/__init__.py \
 && pip install --disable-pip-version-check --no-deps -e env-server

EXPOSE 50051
# Inside a container the server must listen on all interfaces; publish the port
# only where it should be reachable.
ENTRYPOINT ["million-env-server", "--address", "0.0.0.0:50051"]
HEALTHCHECK --interval=10s --timeout=3s CMD python -c "import grpc; from grpc_health.v1 import health_pb2, health_pb2_grpc; s = health_pb2_grpc.HealthStub(grpc.insecure_channel('127.0.0.1:50051')); assert s.Check(health_pb2.HealthCheckRequest(), timeout=2).status == 1"
