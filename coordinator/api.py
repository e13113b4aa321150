"""The plain types the coordinator speaks to its callers: the operator client, jobs,
commands and benchmarks. Only ``coordinator/wire/`` turns them into messages.

Every figure is a float or int; NaN means "not measured" (e.g. a clock error for a node on
another host). :func:`dataclasses.asdict` gives their JSON form.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum

from protos.records import DropReason  # noqa: F401 - why a node did not show a frame; one definition with the node's


class NodeState(str, Enum):
    """Where a slot's node is in its life."""

    EXPECTED = "expected"   # a slot in the rig with no node yet
    JOINED = "joined"       # authenticated, streams opening
    LIVE = "live"           # reports arriving
    LOST = "lost"           # was live, reports stopped


class NodeShowState(str, Enum):
    """Where a node is with the show's timeline, by its own account."""

    NONE = "none"              # no show, or stopped
    WAITING = "waiting"        # a show is scheduled but its asset is not ready on the node
    PLAYING = "playing"
    PAUSED = "paused"
    SUSPENDED = "suspended"    # a coordinator frame (a still, a pattern) took the output


@dataclass(frozen=True)
class NodeShow:
    """The show as one node follows it (from its heartbeats)."""

    revision: int = 0          # newest show revision the node holds (0: none)
    state: NodeShowState = NodeShowState.NONE
    last_frame: int = -1       # the asset's frame index last swapped in (-1: none yet)
    frames_shown: int = 0      # timeline frames swapped in since the node started
    frames_late: int = 0       # timeline ticks the node missed since it started
    alone_ms: float = 0.0      # how long the node last went on without its coordinator (0: never)


class Space(str, Enum):
    """What a frame's pixels are."""

    CONTENT = "content"       # the shared image; each node warps it through its pose
    PROJECTOR = "projector"   # already in one projector's pixels (calibration patterns)


@dataclass(frozen=True)
class SyncSummary:
    """Swap figures over a set of frames (see :func:`coordinator.sync.summarize`)."""

    frames: int = 0                       # frames swapped by every node expected to
    skew_p50_ms: float = math.nan
    skew_p99_ms: float = math.nan
    skew_max_ms: float = math.nan
    skew_source: str = ""                 # "host-clock" (same host: the truth), "estimates" or ""
    clock_error_p99_ms: float = math.nan  # NaN unless nodes share the coordinator's host
    frames_late: int = 0
    frames_dropped: int = 0
    out_of_order: int = 0


@dataclass(frozen=True)
class PlaySettings:
    """How to play a sequence."""

    fps: float = 30.0
    loops: int = 0                 # 0 = once
    wait: bool = True              # return when playback ends, with its figures
    pattern: str = ""              # "counter": generated on the coordinator; "": the given frames
    frames: int = 0                # with a pattern: how many (0: 5 s worth)
    latency_ms: float = 0.0        # 0: the coordinator's budget
    settle_s: float = 0.0          # extra wait for the last swap reports (0: 1 s)
    fit: str = ""                  # frames of another aspect: "stretch", "contain", "cover"; "": refused


@dataclass(frozen=True)
class PlayResult:
    """What a played sequence did. ``frames_shown`` counts frames every live node swapped in."""

    frames_sent: int = 0
    frames_shown: int = 0
    frames_late: int = 0
    frames_dropped: int = 0
    nodes: int = 0
    wall_s: float = 0.0
    coordinator_cpu_s: float = 0.0
    encode_cpu_s: float = 0.0
    skews_ms: tuple[float, ...] = ()          # per frame, in frame order
    clock_errors_ms: tuple[float, ...] = ()
    sync: SyncSummary = field(default_factory=SyncSummary)


@dataclass(frozen=True)
class AssetProgress:
    """How far a node is with one asset it must hold (fetched ahead of use)."""

    asset_id: str
    have_bytes: int = 0         # on the node's disk, complete and partial blobs
    total_bytes: int = 0        # the asset's bytes (0 when nobody knows yet)
    ready: bool = False         # every blob complete and verified on the node
    error: str = ""             # why the node gave up on it; "" = none
    name: str = ""
    ready_age_ms: float = math.nan   # status only: since the coordinator first saw it ready on the node
                                     # (its own clock; NaN: not ready, or not yet seen ready)


@dataclass(frozen=True)
class NodeStatus:
    """One slot of the rig and its node, as the coordinator sees it."""

    slot: str
    state: NodeState = NodeState.EXPECTED
    hostname: str = ""
    pid: int = 0
    clock_offset_ms: float = 0.0
    clock_drift_ppm: float = 0.0
    clock_rtt_ms: float = 0.0
    clock_error_ms: float = math.nan
    last_swap_frame: int = 0
    last_swap_age_ms: float = math.nan
    last_seen_age_ms: float = 0.0
    frames_shown: int = 0
    frames_late: int = 0
    frames_dropped: int = 0
    assignment_revision: int = 0
    pose_kind: str = "none"       # "homography", "projection" or "none"
    joins: int = 0
    assets_wanted: int = 0        # assets the node must hold (every asset of the rig's store, for now)
    assets_ready: int = 0         # of those, complete and verified on the node
    asset_bytes_have: int = 0     # over the wanted assets, from the node's last heartbeat
    asset_bytes_total: int = 0
    assets: tuple[AssetProgress, ...] = ()   # one per wanted asset, in fetch order
    live_age_ms: float = math.nan   # since the node's session turned live (the coordinator's clock; NaN: not live)
    show: NodeShow = field(default_factory=NodeShow)   # the show as the node follows it (its last heartbeat)
    software_version: str = ""    # the node's shadowless version
    output: str = ""              # its output kind (offscreen, window, kms, room://…)
    gl: str = ""                  # the GL it renders with, e.g. "OpenGL 3.1, GLSL 1.40, V3D 4.2"
    decoder: str = ""             # what it decodes videos with: "software", "h264_v4l2m2m", "vaapi (hwaccel)"; "" unknown
    decoder_note: str = ""        # why its --decoder wish was not granted ("" it was, or unknown)
    assignment_refused: str = ""  # the newest assignment the node refused: "rN: why" ("" none, or unknown)
    left: str = ""                # lost because it stopped on purpose: why, from its goodbye ("" silent, or not lost)


@dataclass(frozen=True)
class RefusedPeer:
    """Joins or calls the coordinator refused, and why: ``count`` of them from ``peer`` (an
    address) for ``slot`` with ``reason``, the last ``age_s`` seconds ago. (A refusal itself is
    :class:`coordinator.errors.Refusal`; this is what ``status`` tells of them.)"""

    peer: str
    slot: str
    reason: str
    age_s: float
    count: int = 1


@dataclass(frozen=True)
class AdmissionFigures:
    """Calls that carried no session (handshakes, and anything sent before one): the budget they
    get (``coordinator/admission.py``), what is in flight now and what was refused since start.
    Bytes are reserved at the largest allowed message until a call's message arrived."""

    in_flight_calls: int = 0
    in_flight_bytes: int = 0
    peak_bytes: int = 0           # the most reserved or held at once
    admitted: int = 0
    refused: int = 0              # over the budget, refused unread
    malformed: int = 0            # a message that was not the method's request
    max_calls: int = 0
    max_bytes: int = 0
    max_calls_per_address: int = 0
    max_bytes_per_address: int = 0
    waited: int = 0               # calls that waited for room before they were admitted or refused


@dataclass(frozen=True)
class ShowState:
    """The timeline show (see :mod:`coordinator.show`): which asset plays, from where, how.

    ``state`` is ``none`` (never a show), ``scheduled`` (starts at ``anchor_ns``), ``playing``,
    ``paused``, ``ended`` (a show that does not loop showed its last frame) or ``stopped``.
    ``frame`` is the asset frame on the projectors at ``now_ns`` (-1: none); ``change_at_ns`` the
    rig instant the last change takes (took) effect. Rates are exact: ``rate_num / rate_den`` fps.
    """

    state: str = "none"
    asset_id: str = ""
    name: str = ""
    frames: int = 0
    rate_num: int = 0
    rate_den: int = 1
    anchor_ns: int = 0
    anchor_frame: int = 0
    loop: bool = False
    paused: bool = False
    revision: int = 0
    frame_id_base: int = 0
    frame: int = -1
    now_ns: int = 0
    change_at_ns: int = 0

    @property
    def fps(self) -> float:
        return self.rate_num / self.rate_den if self.rate_den else 0.0


@dataclass(frozen=True)
class BlendStatus:
    """The rig's per-pixel blend and any failover, as operators see it."""

    state: str = "none"            # "none" | "blended" | "failover"
    blend_id: str = ""
    created_at: float = 0.0         # unix time the blend was measured
    headroom: float = 0.0           # fraction of each point's light held in reserve
    brightness_cost: float = 0.0    # fraction of brightness that reserve costs against none
    lost: tuple[str, ...] = ()      # slots out of the blend (node lost, or lamp named by the watchdog)
    since: float = 0.0              # unix time the current failover began (0: none)
    covered: bool = True            # the remaining projectors cover every lost footprint, uniformity kept
    lamps: tuple[tuple[str, float], ...] = ()   # the watchdog's gain estimates that differ from 1
    message: str = ""               # one line, e.g. "r2c3 lost 12 s ago: 24 projectors cover its footprint"


@dataclass(frozen=True)
class RigStatus:
    """The whole rig at one instant."""

    rig_id: str
    rig_name: str
    instance_id: str = ""
    rig_dir: str = ""
    protocol_version: int = 0
    uptime_s: float = 0.0
    showing: str = ""
    latency_budget_ms: float = 0.0
    cpu_s: float = 0.0
    nodes: tuple[NodeStatus, ...] = ()
    sync: SyncSummary = field(default_factory=SyncSummary)
    refusals: tuple[RefusedPeer, ...] = ()
    show: ShowState = field(default_factory=ShowState)
    frame_packets_sent: int = 0     # FramePackets handed to the nodes' Frames streams since start
    frame_bytes_sent: int = 0
    show_updates_sent: int = 0      # Show stream messages (timelines, stops, beacons) since start
    show_bytes_sent: int = 0
    admission: AdmissionFigures = field(default_factory=AdmissionFigures)
    #: where the operator console is served (``http://HOST:PORT/``), ``NOT SERVED (why)`` when it
    #: could not be and the coordinator was told to run on, or ``off`` (``--no-console``)
    console: str = ""
    #: the per-pixel blend and any failover (``state`` "none" when the rig was never blended)
    blend: BlendStatus = field(default_factory=BlendStatus)
    #: frames each node missed (late or dropped) lately: slot -> count over the last
    #: ``late_window_s`` seconds (only slots that missed any; :mod:`coordinator.late_window`)
    late_recent: tuple[tuple[str, int], ...] = ()
    late_window_s: float = 0.0
    #: the warning content shown now draws for slots without a pose ("" when every slot has one),
    #: worded as the command line words it (:func:`coordinator.unposed.unposed_warning`)
    unposed_warning: str = ""


@dataclass(frozen=True)
class ShowResult:
    """A still sent to every node."""

    frame_id: int
    content_id: str
    pts_ns: int


@dataclass(frozen=True)
class CueState:
    """The cue list and where the show is in it (:mod:`coordinator.cues`). ``cues`` holds
    :class:`protos.cues.Cue` records; ``current`` and ``next`` are indices into it (None: no cue
    fired yet, or none after the current one); ``fired_at`` the wall time (Unix s) the current cue
    fired; ``fading`` whether its crossfade is still under way; ``follow_at`` the wall time its
    auto-follow fires the next cue (None: it waits for GO)."""

    cues: tuple = ()
    current: int | None = None
    next: int | None = None
    fired_at: float | None = None
    fading: bool = False
    follow_at: float | None = None

    def to_json(self) -> dict:
        """What the console and scripts read (``GET /api/cues``)."""
        return {"cues": [c.to_json() for c in self.cues], "current": self.current, "next": self.next,
                "fired_at": self.fired_at, "fading": self.fading, "follow_at": self.follow_at}
