"""The coordinator's side of the wire: what a node encodes comes back as it was, and a refusal
ends a call with its own status."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.wire import node_messages
from node import wire as node_wire
from node.records import ReportBatch, SwapRecord
from protos import node_pb2


def test_a_nodes_swaps_come_back_as_the_columns_it_sent():
    rng = np.random.default_rng(5)
    ids = np.concatenate([np.arange(1_000, 1_030), [1_010, 7]])               # out of order at the end
    rig = 1_700_000_000_000_000_000 + np.cumsum(rng.integers(30_000_000, 36_000_000, size=ids.size))
    host = rig - 123_456_789_000 + rng.integers(-50_000, 50_000, size=ids.size)
    batch = ReportBatch(swaps=tuple(SwapRecord(int(f), 0, int(r), int(h)) for f, r, h in zip(ids, rig, host)))
    data = node_wire.report_message(batch).SerializeToString()
    rep = node_messages.report_from_message(node_pb2.NodeReport.FromString(data))
    assert len(rep.swaps) == ids.size and rep.heartbeat is None and rep.drops == ()
    for got, want in ((rep.swaps.frame_id, ids), (rep.swaps.swap_rig_ns, rig), (rep.swaps.host_monotonic_ns, host)):
        assert got.dtype == np.int64 and got.tolist() == want.tolist()
    # deltas keep a second of ticks small: about 5 bytes per swap and column after the first
    assert len(data) < 20 + 3 * 10 + 3 * 5 * (ids.size - 1)


def test_a_report_without_swaps_has_none_and_columns_of_unequal_length_are_refused():
    rep = node_messages.report_from_message(node_pb2.NodeReport())
    assert len(rep.swaps) == 0 and rep.swaps.frame_id.dtype == np.int64
    bad = node_pb2.NodeReport(swaps=node_pb2.Swaps(frame_id=[1, 1], swap_rig_ns=[5], host_monotonic_ns=[5, 5]))
    with pytest.raises(ValueError, match="differ in length"):
        node_messages.report_from_message(bad)


class _Aborted(Exception):
    pass


class _Context:
    """What a handler's gRPC context does on abort: end the call with a status (recorded here)."""

    def __init__(self):
        self.status = None

    async def abort(self, code, details):
        self.status = (code, details)
        raise _Aborted


def test_every_refusal_kind_has_a_status_of_its_own_and_handlers_end_with_it():
    import asyncio

    import grpc

    from coordinator.errors import CoordinatorError, Refusal, RefusalKind
    from coordinator.wire.calls import STATUS_CODES, guard

    assert set(STATUS_CODES) == set(RefusalKind)
    assert len(set(STATUS_CODES.values())) == len(RefusalKind)

    class Service:
        @guard
        async def call(self, request, context):
            raise request

    def status(exc):
        ctx = _Context()
        with pytest.raises(_Aborted):
            asyncio.run(Service().call(exc, ctx))
        return ctx.status

    assert status(Refusal(RefusalKind.NOT_FOUND, "no slot r9c9")) == (grpc.StatusCode.NOT_FOUND, "no slot r9c9")
    assert status(Refusal(RefusalKind.CONFLICT, "r0c0 is live")) == (grpc.StatusCode.ALREADY_EXISTS, "r0c0 is live")
    assert status(ValueError("bad fps")) == (grpc.StatusCode.INVALID_ARGUMENT, "bad fps")
    assert status(CoordinatorError("a job runs")) == (grpc.StatusCode.FAILED_PRECONDITION, "a job runs")
    with pytest.raises(KeyError):                  # not a refusal: the handler's own error stays one
        asyncio.run(Service().call(KeyError("x"), _Context()))
