"""The node's own plain data: what travels between its parts, without protobuf.

:mod:`node.wire` turns the coordinator's messages into these and back; every other
module of the node speaks only these (dataclasses, numpy arrays, plain values).

numpy and the blend maps are named here for the types only: the node process (network, session,
cache) holds no array (an assignment crosses it as :class:`AssignmentBytes`) and imports no numpy.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

# the records the coordinator speaks too are defined once, in protos.records; the node's parts
# name them from here with the rest
from protos.records import DropReason, NodeInfo
from protos.timeline import Timeline

if TYPE_CHECKING:
    import numpy as np

    from protos.blend import BlendMaps


# ------------------------------------------------------------------ coordinator -> node


@dataclass(frozen=True)
class MeshData:
    mesh_id: str
    vertices: np.ndarray   # (V, 3) float32, world mm
    uvs: np.ndarray        # (V, 2) float32 in [0, 1]
    faces: np.ndarray      # (F, 3) uint32


@dataclass(frozen=True)
class NodeAssignment:
    revision: int
    slot: str
    width: int
    height: int
    pose_kind: str                       # "homography", "projection" or "none"
    homography: np.ndarray | None        # (3, 3) float64, content px -> projector px
    projection: np.ndarray | None        # (3, 4) float64, world mm -> projector px
    mesh: MeshData | None
    near_mm: float
    far_mm: float
    lut: np.ndarray | None               # (C, E) float32
    gain: float
    content_size: tuple[int, int]
    blend: BlendMaps | None = None       # the slot's blend maps (None: none)
    blend_at_ns: int = 0                 # rig instant from which they are shown (0: at once)
    blend_error: str = ""                # the assignment carried maps that cannot be used: why ("" none)
    received_host_ns: int = 0            # host monotonic time the node process received it (0: unknown)
    # host monotonic time it was decoded (0: unknown): by the presenter process, once it crossed the pipe
    # as AssignmentBytes, so the time from received to decoded includes the pipe's
    decoded_host_ns: int = 0


@dataclass(frozen=True)
class AssignmentBytes:
    """An assignment as the node process passes it on: the message's bytes, decoded into a
    :class:`NodeAssignment` by the presenter process (:func:`node.wire.assignment_from_bytes`), which
    needs its arrays; the node process only compares it with the one it passed last."""

    revision: int
    data: bytes                          # the Assignment message without its revision (deterministic encoding)
    received_host_ns: int = 0            # host monotonic time the node process received it (0: unknown)
    problem: str = ""                    # why the presenter could not take it ("" it can): refused by the node


@dataclass(frozen=True)
class FrameOrder:
    frame_id: int
    pts_ns: int
    content_id: str                      # "" = black
    space: str                           # "content" or "projector"
    apply_lut: bool
    tag: str
    fade_ns: int = 0                     # a crossfade from what is on screen (protos/fade.py)
    fade_steps: int = 0


@dataclass(frozen=True)
class ContentBlob:
    """One content of a frame packet, decoded; ``image`` is None when it could not be."""

    content_id: str
    image: np.ndarray | None
    error: str = ""


@dataclass(frozen=True)
class WantedAssets:
    """The assets this node must hold (the coordinator's ``Wanted`` stream)."""

    revision: int
    asset_ids: tuple[str, ...]           # in the order to fetch them
    pinned_ids: tuple[str, ...] = ()     # scheduled to play: never evicted


@dataclass(frozen=True)
class BlobChunkData:
    """A piece of a blob: ``data`` starts at byte ``offset``."""

    offset: int
    data: bytes


@dataclass(frozen=True)
class FramePacketData:
    """A frame packet, for one slot, in the order a node handles it: contents, frame, evictions."""

    contents: tuple[ContentBlob, ...] = ()
    frame: FrameOrder | None = None
    evict: tuple[str, ...] | None = None     # None: the packet has no eviction part


@dataclass(frozen=True)
class ShowUpdateData:
    """One message of the coordinator's Show stream: a timeline (start, change, beacon), or a stop.

    Tick ``k`` of ``timeline`` (its ``k``-th frame period from the anchor) is frame id
    ``frame_id_base + k`` in swap and drop reports.
    """

    timeline: Timeline | None = None
    frame_id_base: int = 0
    stop_at_ns: int = 0          # with no timeline: the show stops at this rig instant
    stop_revision: int = 0
    beacon: bool = False

    @property
    def revision(self) -> int:
        return self.timeline.revision if self.timeline is not None else self.stop_revision


@dataclass(frozen=True)
class AssetFiles:
    """What the presenter process needs to read a cached asset without opening the cache:
    the manifest's canonical bytes and the path of every complete blob (the node process owns
    the cache and its lock; the files are only read)."""

    asset_id: str
    manifest: bytes
    blob_paths: dict[str, str]


# ------------------------------------------------------------------ node -> coordinator


@dataclass(frozen=True)
class SwapRecord:
    """A frame that was shown."""

    frame_id: int
    pts_ns: int
    swap_rig_ns: int          # the node's estimate of the rig clock at the swap
    host_monotonic_ns: int    # the host's CLOCK_MONOTONIC at the swap
    timeline: bool = False    # a tick of the show's timeline (its report may wait, see node.report_batch)


@dataclass(frozen=True)
class DropRecord:
    """A frame that was not shown."""

    frame_id: int
    reason: DropReason
    late_by_ns: int = 0
    timeline: bool = False    # a tick of the show's timeline


@dataclass(frozen=True)
class ClockStatus:
    """The node's clock estimate, as a heartbeat carries it."""

    offset_ns: int            # rig - local at the node's current local time
    drift_ppm: float
    rtt_ns: int
    samples: int
    rig_estimate_ns: int      # the rig clock at ``HeartbeatRecord.host_monotonic_ns``


@dataclass(frozen=True)
class AssetProgressRecord:
    """How far the node is with one asset it must hold."""

    asset_id: str
    have_bytes: int = 0       # on disk, complete and partial blobs
    total_bytes: int = 0      # 0 until the manifest is fetched
    ready: bool = False       # every blob complete and verified
    error: str = ""           # why the node gave up on it ("" = it did not)
    name: str = ""


@dataclass(frozen=True)
class HeartbeatRecord:
    assignment_revision: int
    frames_shown: int
    frames_late: int
    frames_dropped: int
    render_ms_p50: float
    host_monotonic_ns: int
    clock: ClockStatus | None = None      # None until the node has a clock estimate
    assets: tuple[AssetProgressRecord, ...] = ()
    show: ShowStatus | None = None
    blend_id: str = ""                    # the blend on screen ("" none)
    blend_since_rig_ns: int = 0           # pts of the first frame shown with it (0: none)
    decoder: str = ""                     # what videos are decoded with (DecoderChoice.label; "" unknown)
    decoder_note: str = ""                # why the --decoder wish was not granted ("" it was)
    assignment_refused: str = ""          # the newest assignment refused: "rN: why" ("" none)


@dataclass(frozen=True)
class PreviewRecord:
    """A small picture of what the projector shows (a console thumbnail, see :mod:`node.preview`)."""

    request_id: int           # the newest coordinator request it answers
    frame_id: int             # the frame on the projector when it was read back (0: none)
    png: bytes                # 8-bit RGB PNG of width x height pixels
    width: int
    height: int
    output_width: int         # the projector pixels it was area-averaged from
    output_height: int


@dataclass(frozen=True)
class ReportBatch:
    """One message of the report stream: a heartbeat, or the swaps and drops of a few ms (and a
    preview when one was made)."""

    heartbeat: HeartbeatRecord | None = None
    swaps: tuple[SwapRecord, ...] = ()
    drops: tuple[DropRecord, ...] = ()
    preview: PreviewRecord | None = None
    goodbye: str = ""         # the node stops on purpose: why (its last message); "" not leaving


# ------------------------------------------------------------------ handshake


@dataclass(frozen=True)
class HelloReply:
    rig_id: str
    rig_name: str
    server_nonce: bytes
    server_proof: bytes


@dataclass(frozen=True)
class JoinRequest:
    protocol_version: int
    slot: str
    client_nonce: bytes
    server_nonce: bytes
    client_proof: bytes
    info: NodeInfo


@dataclass(frozen=True)
class JoinReply:
    session: str
    instance_id: str
    heartbeat_interval_ms: int
    #: the rig clock's identity; "" (an older coordinator) counts as a new clock at every instance
    clock_id: str = ""


@dataclass(frozen=True)
class PingReply:
    t1_rig_ns: int
    t2_rig_ns: int


# ------------------------------------------------------------------ presenter -> node process


@dataclass(frozen=True)
class ShowStatus:
    """The show as this node follows it (its heartbeat's ``show``)."""

    revision: int = 0          # newest show revision the presenter holds (0: none)
    state: str = "none"        # "none", "waiting" (asset not ready here), "playing", "paused", "suspended"
    last_frame: int = -1       # the asset's frame index last swapped in (-1: none yet)
    shown: int = 0             # timeline frames swapped in since the node started
    late: int = 0              # timeline ticks missed (reported late) since the node started
    alone_ms: float = 0.0      # how long the node last went on without its coordinator (0: never)


@dataclass(frozen=True)
class PresenterStatus:
    """The presenter's counters, as its heartbeat reports them."""

    shown: int = 0
    late: int = 0
    dropped: int = 0
    render_ms_p50: float = 0.0
    revision: int = 0          # of the assignment in use (0: none yet)
    show: ShowStatus = ShowStatus()
    blend_id: str = ""         # the blend maps on screen ("" none)
    blend_since_rig_ns: int = 0   # pts (rig clock) of the first frame shown with them (0: none)
    decoder: str = ""          # what videos are decoded with: the open video's decoder, else the wish's
    decoder_note: str = ""     # why the --decoder wish was not granted ("" it was)
