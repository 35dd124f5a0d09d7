#!/opt/venv/bin/python
"""Exit 0 when the env server answers grpc.health.v1 Check with SERVING (the image's probe).

Usage: million-env-health [HOST:PORT]   (default 127.0.0.1:50051)
"""

import sys

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc

address = sys.argv[1] if len(sys.argv) > 1 else "127.0.0.1:50051"
try:
    with grpc.insecure_channel(address) as channel:
        reply = health_pb2_grpc.HealthStub(channel).Check(
            health_pb2.HealthCheckRequest(), timeout=3
        )
except grpc.RpcError as e:
    print(f"{address}: {e.code().name} {e.details()}", file=sys.stderr)
    sys.exit(1)
status = health_pb2.HealthCheckResponse.ServingStatus.Name(reply.status)
print(f"{address}: {status}")
sys.exit(0 if reply.status == health_pb2.HealthCheckResponse.SERVING else 1)
