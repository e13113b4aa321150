#!/usr/bin/env python3
"""The containers' HEALTHCHECK: ask the gRPC server at HOST:PORT (default 127.0.0.1:7600, the
coordinator; the virtual room serves it too) through the standard health service
(grpc.health.v1) and exit 0 only if it answers SERVING. The coordinator answers SERVING once it
serves, NOT_SERVING while it shuts down.

    shadowless-healthcheck [HOST:PORT [SERVICE]]

It speaks plaintext gRPC: a coordinator started with --tls-cert needs another check.
"""
from __future__ import annotations

import sys

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    address = argv[0] if argv else "127.0.0.1:7600"
    service = argv[1] if len(argv) > 1 else ""
    try:
        with grpc.insecure_channel(address) as channel:
            reply = health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(service=service), timeout=3)
    except grpc.RpcError as exc:
        print(f"{address}: {exc.code().name}: {exc.details()}", file=sys.stderr)
        return 1
    print(f"{address}: {health_pb2.HealthCheckResponse.ServingStatus.Name(reply.status)}")
    return 0 if reply.status == health_pb2.HealthCheckResponse.SERVING else 1


if __name__ == "__main__":
    raise SystemExit(main())
