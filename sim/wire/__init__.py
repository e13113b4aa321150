"""The room's gRPC edge: its messages (``messages``) and its services (``service``: Room for
nodes and the coordinator, RoomTruth for tests and benchmarks). The room's own client is
:mod:`sim.link`.
"""
