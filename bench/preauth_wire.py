"""The attacking process of `shadowless bench preauth` (:mod:`bench.preauth`), run on its own:

    python -m bench.preauth_wire TARGET METHOD CALLS SIZE CHANNELS garbage|hello

CALLS concurrent unauthenticated calls of SIZE bytes at METHOD over CHANNELS connections, each given
120 s at most; prints how many ended with each status code, as JSON. ``garbage`` sends bytes that
are no message (they fail to parse); ``hello`` a well-formed HelloRequest whose slot name fills the
size. It speaks gRPC below the generated stubs (raw bytes), hence a wire module of its own.
"""
from __future__ import annotations

import asyncio
import collections
import json
import sys

import grpc


def _payload(kind: str, size: int) -> bytes:
    if kind == "hello":        # a well-formed HelloRequest whose slot name fills the size
        from protos import auth, common_pb2
        from protos.version import PROTOCOL_VERSION
        return common_pb2.HelloRequest(protocol_version=PROTOCOL_VERSION, role="node", client_nonce=auth.new_nonce(),
                                       slot="x" * (size - 64)).SerializeToString()
    return b"\xff" * size      # not a protobuf message: it fails to parse


async def attack(target: str, method: str, calls: int, size: int, channels: int, payload: bytes) -> dict[str, int]:
    """Fire the calls at once; the count of each status code they ended with."""
    chans = [grpc.aio.insecure_channel(target, options=[("grpc.max_send_message_length", size + 1024)])
             for _ in range(channels)]
    codes: collections.Counter = collections.Counter()

    async def one(i: int) -> None:
        call = chans[i % channels].unary_unary(method)
        try:
            await call(payload, timeout=120)
            codes["OK"] += 1
        except grpc.aio.AioRpcError as exc:
            codes[exc.code().name] += 1

    await asyncio.gather(*(one(i) for i in range(calls)))
    for c in chans:
        await c.close()
    return dict(codes)


def main(argv: list[str]) -> None:
    target, method, calls, size, channels, kind = argv[0], argv[1], int(argv[2]), int(argv[3]), int(argv[4]), argv[5]
    print(json.dumps(asyncio.run(attack(target, method, calls, size, channels, _payload(kind, size)))))


if __name__ == "__main__":
    main(sys.argv[1:])
