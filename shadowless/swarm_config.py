"""What a swarm (:mod:`shadowless.swarm`) is told to do, and the counters it keeps: shared by the
swarm and each of its nodes (:mod:`shadowless.swarm_node`), which import this module and not each
other."""
from __future__ import annotations

from dataclasses import dataclass, field

FETCH_MODES = ("one", "all", "manifest")


@dataclass
class SwarmConfig:
    """What every node of the swarm does (see ``shadowless swarm --help``)."""

    slots: list[str]
    token: bytes
    coordinator: str | None = None          # HOST:PORT; None = mDNS
    rig: str | None = None                  # rig name or id among advertisements
    mdns_interfaces: list[str] | None = None
    fetch: str = "one"
    ping_hz: float = 4.0                    # as node.app: until the clock is settled ...
    ping_settled_s: float | None = 10.0     # ... then one exchange every this long (None: ping_hz always)
    report_batch_ms: float = 50.0           # as node.app: streamed frames' swaps and drops
    timeline_batch_ms: float | None = None  # as node.app: timeline ticks' reports wait (None: for the heartbeat)
    late_ms: float = 10.0
    heartbeat_ms: float | None = None       # None: the interval the coordinator asks for when joining
    clock_offset_ms: float = 0.0
    clock_drift_ppm: float = 0.0
    own_connections: bool = True            # a TCP connection per node, as real nodes have
    join_concurrency: int = 16
    fetch_concurrency: int = 8
    backoff_min_s: float = 0.2
    backoff_max_s: float = 5.0
    refusal_backoff_s: float = 10.0

    def __post_init__(self) -> None:
        if not self.slots:
            raise ValueError("a swarm needs at least one slot")
        if len(set(self.slots)) != len(self.slots):
            raise ValueError("every swarm node needs a slot of its own (duplicate slot names)")
        if self.fetch not in FETCH_MODES:
            raise ValueError(f"--fetch must be one of {', '.join(FETCH_MODES)}, got {self.fetch!r}")
        if not self.ping_hz > 0 or (self.ping_settled_s is not None and not self.ping_settled_s > 0):
            raise ValueError("ping rates must be > 0 per second")
        for name in ("report_batch_ms", "timeline_batch_ms"):
            if getattr(self, name) is not None and not 0 <= getattr(self, name) <= 10_000:
                raise ValueError(f"--{name.replace('_', '-')} must be within 0..10000, got {getattr(self, name):g}")


@dataclass
class SwarmStats:
    """Counters over the whole swarm (since it started)."""

    joins: int = 0
    sessions_lost: int = 0
    errors: int = 0
    pings: int = 0
    heartbeats: int = 0
    reports: int = 0
    assignments: int = 0
    show_updates: int = 0
    packets: int = 0
    live_frames: int = 0
    ticks: int = 0
    swaps: int = 0
    late: int = 0                # late drops reported: woke_late + arrived_late
    woke_late: int = 0           # the swarm woke up for it more than late_ms after its instant
    arrived_late: int = 0        # a live frame that arrived after its pts
    superseded: int = 0
    assets_ready: int = 0
    blobs_verified: int = 0
    bytes_fetched: int = 0
    discovery_waits: int = 0     # lookups that found no coordinator advertised yet (waited out, not errors)
    late_hist: list[int] = field(default_factory=lambda: [0] * 8)   # wake-up lateness of swaps: <0.5,1,2,4,8,16,32,more ms

    def lateness(self, late_ns: int) -> None:
        ms, i = late_ns / 1e6, 0
        while i < 7 and ms >= 0.5 * (1 << i):
            i += 1
        self.late_hist[i] += 1
