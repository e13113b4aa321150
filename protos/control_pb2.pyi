from protos import common_pb2 as _common_pb2
from protos import node_pb2 as _node_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class NodeState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    NODE_STATE_UNSPECIFIED: _ClassVar[NodeState]
    NODE_STATE_EXPECTED: _ClassVar[NodeState]
    NODE_STATE_JOINED: _ClassVar[NodeState]
    NODE_STATE_LIVE: _ClassVar[NodeState]
    NODE_STATE_LOST: _ClassVar[NodeState]
NODE_STATE_UNSPECIFIED: NodeState
NODE_STATE_EXPECTED: NodeState
NODE_STATE_JOINED: NodeState
NODE_STATE_LIVE: NodeState
NODE_STATE_LOST: NodeState

class UploadFileSpec(_message.Message):
    __slots__ = ("name", "size", "sha256")
    NAME_FIELD_NUMBER: _ClassVar[int]
    SIZE_FIELD_NUMBER: _ClassVar[int]
    SHA256_FIELD_NUMBER: _ClassVar[int]
    name: str
    size: int
    sha256: str
    def __init__(self, name: _Optional[str] = ..., size: _Optional[int] = ..., sha256: _Optional[str] = ...) -> None: ...

class UploadSpec(_message.Message):
    __slots__ = ("files",)
    FILES_FIELD_NUMBER: _ClassVar[int]
    files: _containers.RepeatedCompositeFieldContainer[UploadFileSpec]
    def __init__(self, files: _Optional[_Iterable[_Union[UploadFileSpec, _Mapping]]] = ...) -> None: ...

class UploadState(_message.Message):
    __slots__ = ("upload_id", "have")
    UPLOAD_ID_FIELD_NUMBER: _ClassVar[int]
    HAVE_FIELD_NUMBER: _ClassVar[int]
    upload_id: str
    have: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, upload_id: _Optional[str] = ..., have: _Optional[_Iterable[int]] = ...) -> None: ...

class UploadChunk(_message.Message):
    __slots__ = ("upload_id", "file", "offset", "data")
    UPLOAD_ID_FIELD_NUMBER: _ClassVar[int]
    FILE_FIELD_NUMBER: _ClassVar[int]
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    upload_id: str
    file: int
    offset: int
    data: bytes
    def __init__(self, upload_id: _Optional[str] = ..., file: _Optional[int] = ..., offset: _Optional[int] = ..., data: _Optional[bytes] = ...) -> None: ...

class FinishUploadRequest(_message.Message):
    __slots__ = ("upload_id", "name", "fps")
    UPLOAD_ID_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    FPS_FIELD_NUMBER: _ClassVar[int]
    upload_id: str
    name: str
    fps: float
    def __init__(self, upload_id: _Optional[str] = ..., name: _Optional[str] = ..., fps: _Optional[float] = ...) -> None: ...

class AssetInfo(_message.Message):
    __slots__ = ("asset_id", "manifest", "existed", "notes")
    ASSET_ID_FIELD_NUMBER: _ClassVar[int]
    MANIFEST_FIELD_NUMBER: _ClassVar[int]
    EXISTED_FIELD_NUMBER: _ClassVar[int]
    NOTES_FIELD_NUMBER: _ClassVar[int]
    asset_id: str
    manifest: bytes
    existed: bool
    notes: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, asset_id: _Optional[str] = ..., manifest: _Optional[bytes] = ..., existed: _Optional[bool] = ..., notes: _Optional[_Iterable[str]] = ...) -> None: ...

class AssetList(_message.Message):
    __slots__ = ("assets",)
    ASSETS_FIELD_NUMBER: _ClassVar[int]
    assets: _containers.RepeatedCompositeFieldContainer[AssetInfo]
    def __init__(self, assets: _Optional[_Iterable[_Union[AssetInfo, _Mapping]]] = ...) -> None: ...

class AssetRef(_message.Message):
    __slots__ = ("asset",)
    ASSET_FIELD_NUMBER: _ClassVar[int]
    asset: str
    def __init__(self, asset: _Optional[str] = ...) -> None: ...

class StatusRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class NodeStatus(_message.Message):
    __slots__ = ("slot", "state", "hostname", "pid", "clock_offset_ms", "clock_drift_ppm", "clock_rtt_ms", "last_swap_frame", "last_swap_age_ms", "frames_shown", "frames_late", "frames_dropped", "assignment_revision", "pose_kind", "last_seen_age_ms", "clock_error_ms", "joins", "assets_wanted", "assets_ready", "asset_bytes_have", "asset_bytes_total", "assets", "live_age_ms", "show", "software_version", "output", "gl", "decoder", "decoder_note", "left", "assignment_refused")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    HOSTNAME_FIELD_NUMBER: _ClassVar[int]
    PID_FIELD_NUMBER: _ClassVar[int]
    CLOCK_OFFSET_MS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_DRIFT_PPM_FIELD_NUMBER: _ClassVar[int]
    CLOCK_RTT_MS_FIELD_NUMBER: _ClassVar[int]
    LAST_SWAP_FRAME_FIELD_NUMBER: _ClassVar[int]
    LAST_SWAP_AGE_MS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_SHOWN_FIELD_NUMBER: _ClassVar[int]
    FRAMES_LATE_FIELD_NUMBER: _ClassVar[int]
    FRAMES_DROPPED_FIELD_NUMBER: _ClassVar[int]
    ASSIGNMENT_REVISION_FIELD_NUMBER: _ClassVar[int]
    POSE_KIND_FIELD_NUMBER: _ClassVar[int]
    LAST_SEEN_AGE_MS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_ERROR_MS_FIELD_NUMBER: _ClassVar[int]
    JOINS_FIELD_NUMBER: _ClassVar[int]
    ASSETS_WANTED_FIELD_NUMBER: _ClassVar[int]
    ASSETS_READY_FIELD_NUMBER: _ClassVar[int]
    ASSET_BYTES_HAVE_FIELD_NUMBER: _ClassVar[int]
    ASSET_BYTES_TOTAL_FIELD_NUMBER: _ClassVar[int]
    ASSETS_FIELD_NUMBER: _ClassVar[int]
    LIVE_AGE_MS_FIELD_NUMBER: _ClassVar[int]
    SHOW_FIELD_NUMBER: _ClassVar[int]
    SOFTWARE_VERSION_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_FIELD_NUMBER: _ClassVar[int]
    GL_FIELD_NUMBER: _ClassVar[int]
    DECODER_FIELD_NUMBER: _ClassVar[int]
    DECODER_NOTE_FIELD_NUMBER: _ClassVar[int]
    LEFT_FIELD_NUMBER: _ClassVar[int]
    ASSIGNMENT_REFUSED_FIELD_NUMBER: _ClassVar[int]
    slot: str
    state: NodeState
    hostname: str
    pid: int
    clock_offset_ms: float
    clock_drift_ppm: float
    clock_rtt_ms: float
    last_swap_frame: int
    last_swap_age_ms: float
    frames_shown: int
    frames_late: int
    frames_dropped: int
    assignment_revision: int
    pose_kind: str
    last_seen_age_ms: float
    clock_error_ms: float
    joins: int
    assets_wanted: int
    assets_ready: int
    asset_bytes_have: int
    asset_bytes_total: int
    assets: _containers.RepeatedCompositeFieldContainer[_node_pb2.AssetProgress]
    live_age_ms: float
    show: _node_pb2.NodeShow
    software_version: str
    output: str
    gl: str
    decoder: str
    decoder_note: str
    left: str
    assignment_refused: str
    def __init__(self, slot: _Optional[str] = ..., state: _Optional[_Union[NodeState, str]] = ..., hostname: _Optional[str] = ..., pid: _Optional[int] = ..., clock_offset_ms: _Optional[float] = ..., clock_drift_ppm: _Optional[float] = ..., clock_rtt_ms: _Optional[float] = ..., last_swap_frame: _Optional[int] = ..., last_swap_age_ms: _Optional[float] = ..., frames_shown: _Optional[int] = ..., frames_late: _Optional[int] = ..., frames_dropped: _Optional[int] = ..., assignment_revision: _Optional[int] = ..., pose_kind: _Optional[str] = ..., last_seen_age_ms: _Optional[float] = ..., clock_error_ms: _Optional[float] = ..., joins: _Optional[int] = ..., assets_wanted: _Optional[int] = ..., assets_ready: _Optional[int] = ..., asset_bytes_have: _Optional[int] = ..., asset_bytes_total: _Optional[int] = ..., assets: _Optional[_Iterable[_Union[_node_pb2.AssetProgress, _Mapping]]] = ..., live_age_ms: _Optional[float] = ..., show: _Optional[_Union[_node_pb2.NodeShow, _Mapping]] = ..., software_version: _Optional[str] = ..., output: _Optional[str] = ..., gl: _Optional[str] = ..., decoder: _Optional[str] = ..., decoder_note: _Optional[str] = ..., left: _Optional[str] = ..., assignment_refused: _Optional[str] = ...) -> None: ...

class SyncStats(_message.Message):
    __slots__ = ("frames", "skew_p50_ms", "skew_p99_ms", "skew_max_ms", "skew_source", "clock_error_p99_ms", "frames_late", "frames_dropped", "out_of_order")
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    SKEW_P50_MS_FIELD_NUMBER: _ClassVar[int]
    SKEW_P99_MS_FIELD_NUMBER: _ClassVar[int]
    SKEW_MAX_MS_FIELD_NUMBER: _ClassVar[int]
    SKEW_SOURCE_FIELD_NUMBER: _ClassVar[int]
    CLOCK_ERROR_P99_MS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_LATE_FIELD_NUMBER: _ClassVar[int]
    FRAMES_DROPPED_FIELD_NUMBER: _ClassVar[int]
    OUT_OF_ORDER_FIELD_NUMBER: _ClassVar[int]
    frames: int
    skew_p50_ms: float
    skew_p99_ms: float
    skew_max_ms: float
    skew_source: str
    clock_error_p99_ms: float
    frames_late: int
    frames_dropped: int
    out_of_order: int
    def __init__(self, frames: _Optional[int] = ..., skew_p50_ms: _Optional[float] = ..., skew_p99_ms: _Optional[float] = ..., skew_max_ms: _Optional[float] = ..., skew_source: _Optional[str] = ..., clock_error_p99_ms: _Optional[float] = ..., frames_late: _Optional[int] = ..., frames_dropped: _Optional[int] = ..., out_of_order: _Optional[int] = ...) -> None: ...

class Refusal(_message.Message):
    __slots__ = ("peer", "slot", "reason", "age_s", "count")
    PEER_FIELD_NUMBER: _ClassVar[int]
    SLOT_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    AGE_S_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    peer: str
    slot: str
    reason: str
    age_s: float
    count: int
    def __init__(self, peer: _Optional[str] = ..., slot: _Optional[str] = ..., reason: _Optional[str] = ..., age_s: _Optional[float] = ..., count: _Optional[int] = ...) -> None: ...

class RigStatus(_message.Message):
    __slots__ = ("rig_id", "rig_name", "instance_id", "rig_dir", "protocol_version", "uptime_s", "nodes", "sync", "showing", "refusals", "latency_budget_ms", "cpu_s", "show", "frame_packets_sent", "frame_bytes_sent", "show_updates_sent", "show_bytes_sent", "admission", "console", "blend")
    RIG_ID_FIELD_NUMBER: _ClassVar[int]
    RIG_NAME_FIELD_NUMBER: _ClassVar[int]
    INSTANCE_ID_FIELD_NUMBER: _ClassVar[int]
    RIG_DIR_FIELD_NUMBER: _ClassVar[int]
    PROTOCOL_VERSION_FIELD_NUMBER: _ClassVar[int]
    UPTIME_S_FIELD_NUMBER: _ClassVar[int]
    NODES_FIELD_NUMBER: _ClassVar[int]
    SYNC_FIELD_NUMBER: _ClassVar[int]
    SHOWING_FIELD_NUMBER: _ClassVar[int]
    REFUSALS_FIELD_NUMBER: _ClassVar[int]
    LATENCY_BUDGET_MS_FIELD_NUMBER: _ClassVar[int]
    CPU_S_FIELD_NUMBER: _ClassVar[int]
    SHOW_FIELD_NUMBER: _ClassVar[int]
    FRAME_PACKETS_SENT_FIELD_NUMBER: _ClassVar[int]
    FRAME_BYTES_SENT_FIELD_NUMBER: _ClassVar[int]
    SHOW_UPDATES_SENT_FIELD_NUMBER: _ClassVar[int]
    SHOW_BYTES_SENT_FIELD_NUMBER: _ClassVar[int]
    ADMISSION_FIELD_NUMBER: _ClassVar[int]
    CONSOLE_FIELD_NUMBER: _ClassVar[int]
    BLEND_FIELD_NUMBER: _ClassVar[int]
    rig_id: str
    rig_name: str
    instance_id: str
    rig_dir: str
    protocol_version: int
    uptime_s: float
    nodes: _containers.RepeatedCompositeFieldContainer[NodeStatus]
    sync: SyncStats
    showing: str
    refusals: _containers.RepeatedCompositeFieldContainer[Refusal]
    latency_budget_ms: float
    cpu_s: float
    show: ShowState
    frame_packets_sent: int
    frame_bytes_sent: int
    show_updates_sent: int
    show_bytes_sent: int
    admission: Admission
    console: str
    blend: BlendStatus
    def __init__(self, rig_id: _Optional[str] = ..., rig_name: _Optional[str] = ..., instance_id: _Optional[str] = ..., rig_dir: _Optional[str] = ..., protocol_version: _Optional[int] = ..., uptime_s: _Optional[float] = ..., nodes: _Optional[_Iterable[_Union[NodeStatus, _Mapping]]] = ..., sync: _Optional[_Union[SyncStats, _Mapping]] = ..., showing: _Optional[str] = ..., refusals: _Optional[_Iterable[_Union[Refusal, _Mapping]]] = ..., latency_budget_ms: _Optional[float] = ..., cpu_s: _Optional[float] = ..., show: _Optional[_Union[ShowState, _Mapping]] = ..., frame_packets_sent: _Optional[int] = ..., frame_bytes_sent: _Optional[int] = ..., show_updates_sent: _Optional[int] = ..., show_bytes_sent: _Optional[int] = ..., admission: _Optional[_Union[Admission, _Mapping]] = ..., console: _Optional[str] = ..., blend: _Optional[_Union[BlendStatus, _Mapping]] = ...) -> None: ...

class BlendStatus(_message.Message):
    __slots__ = ("state", "blend_id", "created_at", "headroom", "brightness_cost", "lost", "since", "covered", "lamps", "message")
    STATE_FIELD_NUMBER: _ClassVar[int]
    BLEND_ID_FIELD_NUMBER: _ClassVar[int]
    CREATED_AT_FIELD_NUMBER: _ClassVar[int]
    HEADROOM_FIELD_NUMBER: _ClassVar[int]
    BRIGHTNESS_COST_FIELD_NUMBER: _ClassVar[int]
    LOST_FIELD_NUMBER: _ClassVar[int]
    SINCE_FIELD_NUMBER: _ClassVar[int]
    COVERED_FIELD_NUMBER: _ClassVar[int]
    LAMPS_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    state: str
    blend_id: str
    created_at: float
    headroom: float
    brightness_cost: float
    lost: _containers.RepeatedScalarFieldContainer[str]
    since: float
    covered: bool
    lamps: _containers.RepeatedCompositeFieldContainer[LampGain]
    message: str
    def __init__(self, state: _Optional[str] = ..., blend_id: _Optional[str] = ..., created_at: _Optional[float] = ..., headroom: _Optional[float] = ..., brightness_cost: _Optional[float] = ..., lost: _Optional[_Iterable[str]] = ..., since: _Optional[float] = ..., covered: _Optional[bool] = ..., lamps: _Optional[_Iterable[_Union[LampGain, _Mapping]]] = ..., message: _Optional[str] = ...) -> None: ...

class LampGain(_message.Message):
    __slots__ = ("slot", "gain")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    GAIN_FIELD_NUMBER: _ClassVar[int]
    slot: str
    gain: float
    def __init__(self, slot: _Optional[str] = ..., gain: _Optional[float] = ...) -> None: ...

class Admission(_message.Message):
    __slots__ = ("in_flight_calls", "in_flight_bytes", "peak_bytes", "admitted", "refused", "malformed", "max_calls", "max_bytes", "max_calls_per_address", "max_bytes_per_address", "waited")
    IN_FLIGHT_CALLS_FIELD_NUMBER: _ClassVar[int]
    IN_FLIGHT_BYTES_FIELD_NUMBER: _ClassVar[int]
    PEAK_BYTES_FIELD_NUMBER: _ClassVar[int]
    ADMITTED_FIELD_NUMBER: _ClassVar[int]
    REFUSED_FIELD_NUMBER: _ClassVar[int]
    MALFORMED_FIELD_NUMBER: _ClassVar[int]
    MAX_CALLS_FIELD_NUMBER: _ClassVar[int]
    MAX_BYTES_FIELD_NUMBER: _ClassVar[int]
    MAX_CALLS_PER_ADDRESS_FIELD_NUMBER: _ClassVar[int]
    MAX_BYTES_PER_ADDRESS_FIELD_NUMBER: _ClassVar[int]
    WAITED_FIELD_NUMBER: _ClassVar[int]
    in_flight_calls: int
    in_flight_bytes: int
    peak_bytes: int
    admitted: int
    refused: int
    malformed: int
    max_calls: int
    max_bytes: int
    max_calls_per_address: int
    max_bytes_per_address: int
    waited: int
    def __init__(self, in_flight_calls: _Optional[int] = ..., in_flight_bytes: _Optional[int] = ..., peak_bytes: _Optional[int] = ..., admitted: _Optional[int] = ..., refused: _Optional[int] = ..., malformed: _Optional[int] = ..., max_calls: _Optional[int] = ..., max_bytes: _Optional[int] = ..., max_calls_per_address: _Optional[int] = ..., max_bytes_per_address: _Optional[int] = ..., waited: _Optional[int] = ...) -> None: ...

class NodeList(_message.Message):
    __slots__ = ("nodes",)
    NODES_FIELD_NUMBER: _ClassVar[int]
    nodes: _containers.RepeatedCompositeFieldContainer[NodeStatus]
    def __init__(self, nodes: _Optional[_Iterable[_Union[NodeStatus, _Mapping]]] = ...) -> None: ...

class ShowRequest(_message.Message):
    __slots__ = ("image", "space", "apply_lut", "persist", "name", "fit", "more", "slot_regions")
    class SlotRegionsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: SlotRegions
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[SlotRegions, _Mapping]] = ...) -> None: ...
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    SPACE_FIELD_NUMBER: _ClassVar[int]
    APPLY_LUT_FIELD_NUMBER: _ClassVar[int]
    PERSIST_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    FIT_FIELD_NUMBER: _ClassVar[int]
    MORE_FIELD_NUMBER: _ClassVar[int]
    SLOT_REGIONS_FIELD_NUMBER: _ClassVar[int]
    image: _common_pb2.Image
    space: _node_pb2.Space
    apply_lut: bool
    persist: bool
    name: str
    fit: str
    more: bytes
    slot_regions: _containers.MessageMap[str, SlotRegions]
    def __init__(self, image: _Optional[_Union[_common_pb2.Image, _Mapping]] = ..., space: _Optional[_Union[_node_pb2.Space, str]] = ..., apply_lut: _Optional[bool] = ..., persist: _Optional[bool] = ..., name: _Optional[str] = ..., fit: _Optional[str] = ..., more: _Optional[bytes] = ..., slot_regions: _Optional[_Mapping[str, SlotRegions]] = ...) -> None: ...

class ContentRect(_message.Message):
    __slots__ = ("x", "y", "width", "height")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    x: int
    y: int
    width: int
    height: int
    def __init__(self, x: _Optional[int] = ..., y: _Optional[int] = ..., width: _Optional[int] = ..., height: _Optional[int] = ...) -> None: ...

class SlotRegions(_message.Message):
    __slots__ = ("rects",)
    RECTS_FIELD_NUMBER: _ClassVar[int]
    rects: _containers.RepeatedCompositeFieldContainer[ContentRect]
    def __init__(self, rects: _Optional[_Iterable[_Union[ContentRect, _Mapping]]] = ...) -> None: ...

class ShowReply(_message.Message):
    __slots__ = ("frame_id", "content_id", "pts_ns")
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    CONTENT_ID_FIELD_NUMBER: _ClassVar[int]
    PTS_NS_FIELD_NUMBER: _ClassVar[int]
    frame_id: int
    content_id: str
    pts_ns: int
    def __init__(self, frame_id: _Optional[int] = ..., content_id: _Optional[str] = ..., pts_ns: _Optional[int] = ...) -> None: ...

class PlaySettings(_message.Message):
    __slots__ = ("fps", "loops", "wait", "pattern", "frames", "latency_ms", "settle_s", "fit")
    FPS_FIELD_NUMBER: _ClassVar[int]
    LOOPS_FIELD_NUMBER: _ClassVar[int]
    WAIT_FIELD_NUMBER: _ClassVar[int]
    PATTERN_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    LATENCY_MS_FIELD_NUMBER: _ClassVar[int]
    SETTLE_S_FIELD_NUMBER: _ClassVar[int]
    FIT_FIELD_NUMBER: _ClassVar[int]
    fps: float
    loops: int
    wait: bool
    pattern: str
    frames: int
    latency_ms: float
    settle_s: float
    fit: str
    def __init__(self, fps: _Optional[float] = ..., loops: _Optional[int] = ..., wait: _Optional[bool] = ..., pattern: _Optional[str] = ..., frames: _Optional[int] = ..., latency_ms: _Optional[float] = ..., settle_s: _Optional[float] = ..., fit: _Optional[str] = ...) -> None: ...

class PlayItem(_message.Message):
    __slots__ = ("settings", "frame", "more")
    SETTINGS_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    MORE_FIELD_NUMBER: _ClassVar[int]
    settings: PlaySettings
    frame: _common_pb2.Image
    more: bytes
    def __init__(self, settings: _Optional[_Union[PlaySettings, _Mapping]] = ..., frame: _Optional[_Union[_common_pb2.Image, _Mapping]] = ..., more: _Optional[bytes] = ...) -> None: ...

class PlayReply(_message.Message):
    __slots__ = ("frames_sent", "frames_shown", "frames_late", "frames_dropped", "sync", "coordinator_cpu_s", "nodes", "wall_s", "skews_ms", "clock_errors_ms", "encode_cpu_s")
    FRAMES_SENT_FIELD_NUMBER: _ClassVar[int]
    FRAMES_SHOWN_FIELD_NUMBER: _ClassVar[int]
    FRAMES_LATE_FIELD_NUMBER: _ClassVar[int]
    FRAMES_DROPPED_FIELD_NUMBER: _ClassVar[int]
    SYNC_FIELD_NUMBER: _ClassVar[int]
    COORDINATOR_CPU_S_FIELD_NUMBER: _ClassVar[int]
    NODES_FIELD_NUMBER: _ClassVar[int]
    WALL_S_FIELD_NUMBER: _ClassVar[int]
    SKEWS_MS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_ERRORS_MS_FIELD_NUMBER: _ClassVar[int]
    ENCODE_CPU_S_FIELD_NUMBER: _ClassVar[int]
    frames_sent: int
    frames_shown: int
    frames_late: int
    frames_dropped: int
    sync: SyncStats
    coordinator_cpu_s: float
    nodes: int
    wall_s: float
    skews_ms: _containers.RepeatedScalarFieldContainer[float]
    clock_errors_ms: _containers.RepeatedScalarFieldContainer[float]
    encode_cpu_s: float
    def __init__(self, frames_sent: _Optional[int] = ..., frames_shown: _Optional[int] = ..., frames_late: _Optional[int] = ..., frames_dropped: _Optional[int] = ..., sync: _Optional[_Union[SyncStats, _Mapping]] = ..., coordinator_cpu_s: _Optional[float] = ..., nodes: _Optional[int] = ..., wall_s: _Optional[float] = ..., skews_ms: _Optional[_Iterable[float]] = ..., clock_errors_ms: _Optional[_Iterable[float]] = ..., encode_cpu_s: _Optional[float] = ...) -> None: ...

class StopRequest(_message.Message):
    __slots__ = ("blackout",)
    BLACKOUT_FIELD_NUMBER: _ClassVar[int]
    blackout: bool
    def __init__(self, blackout: _Optional[bool] = ...) -> None: ...

class StopReply(_message.Message):
    __slots__ = ("showing",)
    SHOWING_FIELD_NUMBER: _ClassVar[int]
    showing: str
    def __init__(self, showing: _Optional[str] = ...) -> None: ...

class ConfigureRequest(_message.Message):
    __slots__ = ("slot", "homography", "lut", "gain", "output_width", "output_height", "clear_pose", "projection", "mesh_id")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    HOMOGRAPHY_FIELD_NUMBER: _ClassVar[int]
    LUT_FIELD_NUMBER: _ClassVar[int]
    GAIN_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_WIDTH_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    CLEAR_POSE_FIELD_NUMBER: _ClassVar[int]
    PROJECTION_FIELD_NUMBER: _ClassVar[int]
    MESH_ID_FIELD_NUMBER: _ClassVar[int]
    slot: str
    homography: _node_pb2.Homography
    lut: _node_pb2.Lut
    gain: float
    output_width: int
    output_height: int
    clear_pose: bool
    projection: _node_pb2.ProjectionPose
    mesh_id: str
    def __init__(self, slot: _Optional[str] = ..., homography: _Optional[_Union[_node_pb2.Homography, _Mapping]] = ..., lut: _Optional[_Union[_node_pb2.Lut, _Mapping]] = ..., gain: _Optional[float] = ..., output_width: _Optional[int] = ..., output_height: _Optional[int] = ..., clear_pose: _Optional[bool] = ..., projection: _Optional[_Union[_node_pb2.ProjectionPose, _Mapping]] = ..., mesh_id: _Optional[str] = ...) -> None: ...

class ConfigureReply(_message.Message):
    __slots__ = ("revision",)
    REVISION_FIELD_NUMBER: _ClassVar[int]
    revision: int
    def __init__(self, revision: _Optional[int] = ...) -> None: ...

class JobRequest(_message.Message):
    __slots__ = ("kind", "params_json")
    KIND_FIELD_NUMBER: _ClassVar[int]
    PARAMS_JSON_FIELD_NUMBER: _ClassVar[int]
    kind: str
    params_json: str
    def __init__(self, kind: _Optional[str] = ..., params_json: _Optional[str] = ...) -> None: ...

class JobProgress(_message.Message):
    __slots__ = ("stage", "item", "done", "total", "message", "value")
    STAGE_FIELD_NUMBER: _ClassVar[int]
    ITEM_FIELD_NUMBER: _ClassVar[int]
    DONE_FIELD_NUMBER: _ClassVar[int]
    TOTAL_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    stage: str
    item: str
    done: int
    total: int
    message: str
    value: float
    def __init__(self, stage: _Optional[str] = ..., item: _Optional[str] = ..., done: _Optional[int] = ..., total: _Optional[int] = ..., message: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...

class JobEvent(_message.Message):
    __slots__ = ("progress", "log", "result_json")
    PROGRESS_FIELD_NUMBER: _ClassVar[int]
    LOG_FIELD_NUMBER: _ClassVar[int]
    RESULT_JSON_FIELD_NUMBER: _ClassVar[int]
    progress: JobProgress
    log: str
    result_json: str
    def __init__(self, progress: _Optional[_Union[JobProgress, _Mapping]] = ..., log: _Optional[str] = ..., result_json: _Optional[str] = ...) -> None: ...

class PlayAssetRequest(_message.Message):
    __slots__ = ("asset", "at_ns", "delay_ms", "loop", "fps", "start_without")
    ASSET_FIELD_NUMBER: _ClassVar[int]
    AT_NS_FIELD_NUMBER: _ClassVar[int]
    DELAY_MS_FIELD_NUMBER: _ClassVar[int]
    LOOP_FIELD_NUMBER: _ClassVar[int]
    FPS_FIELD_NUMBER: _ClassVar[int]
    START_WITHOUT_FIELD_NUMBER: _ClassVar[int]
    asset: str
    at_ns: int
    delay_ms: float
    loop: bool
    fps: float
    start_without: bool
    def __init__(self, asset: _Optional[str] = ..., at_ns: _Optional[int] = ..., delay_ms: _Optional[float] = ..., loop: _Optional[bool] = ..., fps: _Optional[float] = ..., start_without: _Optional[bool] = ...) -> None: ...

class ShowControlRequest(_message.Message):
    __slots__ = ("at_ns", "delay_ms", "frame")
    AT_NS_FIELD_NUMBER: _ClassVar[int]
    DELAY_MS_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    at_ns: int
    delay_ms: float
    frame: int
    def __init__(self, at_ns: _Optional[int] = ..., delay_ms: _Optional[float] = ..., frame: _Optional[int] = ...) -> None: ...

class ShowState(_message.Message):
    __slots__ = ("state", "asset_id", "name", "frames", "rate_num", "rate_den", "anchor_ns", "anchor_frame", "loop", "paused", "revision", "frame_id_base", "frame", "now_ns", "change_at_ns")
    STATE_FIELD_NUMBER: _ClassVar[int]
    ASSET_ID_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    RATE_NUM_FIELD_NUMBER: _ClassVar[int]
    RATE_DEN_FIELD_NUMBER: _ClassVar[int]
    ANCHOR_NS_FIELD_NUMBER: _ClassVar[int]
    ANCHOR_FRAME_FIELD_NUMBER: _ClassVar[int]
    LOOP_FIELD_NUMBER: _ClassVar[int]
    PAUSED_FIELD_NUMBER: _ClassVar[int]
    REVISION_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_BASE_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    NOW_NS_FIELD_NUMBER: _ClassVar[int]
    CHANGE_AT_NS_FIELD_NUMBER: _ClassVar[int]
    state: str
    asset_id: str
    name: str
    frames: int
    rate_num: int
    rate_den: int
    anchor_ns: int
    anchor_frame: int
    loop: bool
    paused: bool
    revision: int
    frame_id_base: int
    frame: int
    now_ns: int
    change_at_ns: int
    def __init__(self, state: _Optional[str] = ..., asset_id: _Optional[str] = ..., name: _Optional[str] = ..., frames: _Optional[int] = ..., rate_num: _Optional[int] = ..., rate_den: _Optional[int] = ..., anchor_ns: _Optional[int] = ..., anchor_frame: _Optional[int] = ..., loop: _Optional[bool] = ..., paused: _Optional[bool] = ..., revision: _Optional[int] = ..., frame_id_base: _Optional[int] = ..., frame: _Optional[int] = ..., now_ns: _Optional[int] = ..., change_at_ns: _Optional[int] = ...) -> None: ...

class CueListRequest(_message.Message):
    __slots__ = ("cues_json",)
    CUES_JSON_FIELD_NUMBER: _ClassVar[int]
    cues_json: str
    def __init__(self, cues_json: _Optional[str] = ...) -> None: ...

class CueActionRequest(_message.Message):
    __slots__ = ("action", "cue_id")
    ACTION_FIELD_NUMBER: _ClassVar[int]
    CUE_ID_FIELD_NUMBER: _ClassVar[int]
    action: str
    cue_id: str
    def __init__(self, action: _Optional[str] = ..., cue_id: _Optional[str] = ...) -> None: ...

class SlotToolRequest(_message.Message):
    __slots__ = ("pattern", "slots")
    PATTERN_FIELD_NUMBER: _ClassVar[int]
    SLOTS_FIELD_NUMBER: _ClassVar[int]
    pattern: str
    slots: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, pattern: _Optional[str] = ..., slots: _Optional[_Iterable[str]] = ...) -> None: ...

class CueReply(_message.Message):
    __slots__ = ("state_json", "result")
    STATE_JSON_FIELD_NUMBER: _ClassVar[int]
    RESULT_FIELD_NUMBER: _ClassVar[int]
    state_json: str
    result: str
    def __init__(self, state_json: _Optional[str] = ..., result: _Optional[str] = ...) -> None: ...
