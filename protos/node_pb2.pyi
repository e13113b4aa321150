from protos import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Space(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SPACE_UNSPECIFIED: _ClassVar[Space]
    SPACE_CONTENT: _ClassVar[Space]
    SPACE_PROJECTOR: _ClassVar[Space]

class VideoCodec(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    VIDEO_CODEC_UNSPECIFIED: _ClassVar[VideoCodec]
    VIDEO_CODEC_H264: _ClassVar[VideoCodec]
    VIDEO_CODEC_HEVC: _ClassVar[VideoCodec]

class DropReason(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DROP_REASON_UNSPECIFIED: _ClassVar[DropReason]
    DROP_REASON_LATE: _ClassVar[DropReason]
    DROP_REASON_SUPERSEDED: _ClassVar[DropReason]
    DROP_REASON_MISSING_CONTENT: _ClassVar[DropReason]
    DROP_REASON_UNRENDERABLE: _ClassVar[DropReason]

class NodeShowState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    NODE_SHOW_UNSPECIFIED: _ClassVar[NodeShowState]
    NODE_SHOW_NONE: _ClassVar[NodeShowState]
    NODE_SHOW_WAITING: _ClassVar[NodeShowState]
    NODE_SHOW_PLAYING: _ClassVar[NodeShowState]
    NODE_SHOW_PAUSED: _ClassVar[NodeShowState]
    NODE_SHOW_SUSPENDED: _ClassVar[NodeShowState]
SPACE_UNSPECIFIED: Space
SPACE_CONTENT: Space
SPACE_PROJECTOR: Space
VIDEO_CODEC_UNSPECIFIED: VideoCodec
VIDEO_CODEC_H264: VideoCodec
VIDEO_CODEC_HEVC: VideoCodec
DROP_REASON_UNSPECIFIED: DropReason
DROP_REASON_LATE: DropReason
DROP_REASON_SUPERSEDED: DropReason
DROP_REASON_MISSING_CONTENT: DropReason
DROP_REASON_UNRENDERABLE: DropReason
NODE_SHOW_UNSPECIFIED: NodeShowState
NODE_SHOW_NONE: NodeShowState
NODE_SHOW_WAITING: NodeShowState
NODE_SHOW_PLAYING: NodeShowState
NODE_SHOW_PAUSED: NodeShowState
NODE_SHOW_SUSPENDED: NodeShowState

class NodeInfo(_message.Message):
    __slots__ = ("hostname", "host_boot_id", "pid", "software_version", "output", "native_width", "native_height", "gl")
    HOSTNAME_FIELD_NUMBER: _ClassVar[int]
    HOST_BOOT_ID_FIELD_NUMBER: _ClassVar[int]
    PID_FIELD_NUMBER: _ClassVar[int]
    SOFTWARE_VERSION_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_FIELD_NUMBER: _ClassVar[int]
    NATIVE_WIDTH_FIELD_NUMBER: _ClassVar[int]
    NATIVE_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    GL_FIELD_NUMBER: _ClassVar[int]
    hostname: str
    host_boot_id: str
    pid: int
    software_version: str
    output: str
    native_width: int
    native_height: int
    gl: str
    def __init__(self, hostname: _Optional[str] = ..., host_boot_id: _Optional[str] = ..., pid: _Optional[int] = ..., software_version: _Optional[str] = ..., output: _Optional[str] = ..., native_width: _Optional[int] = ..., native_height: _Optional[int] = ..., gl: _Optional[str] = ...) -> None: ...

class JoinRequest(_message.Message):
    __slots__ = ("login", "info")
    LOGIN_FIELD_NUMBER: _ClassVar[int]
    INFO_FIELD_NUMBER: _ClassVar[int]
    login: _common_pb2.LoginRequest
    info: NodeInfo
    def __init__(self, login: _Optional[_Union[_common_pb2.LoginRequest, _Mapping]] = ..., info: _Optional[_Union[NodeInfo, _Mapping]] = ...) -> None: ...

class JoinReply(_message.Message):
    __slots__ = ("session", "slot", "rig_id", "instance_id", "heartbeat_interval_ms", "clock_id")
    SESSION_FIELD_NUMBER: _ClassVar[int]
    SLOT_FIELD_NUMBER: _ClassVar[int]
    RIG_ID_FIELD_NUMBER: _ClassVar[int]
    INSTANCE_ID_FIELD_NUMBER: _ClassVar[int]
    HEARTBEAT_INTERVAL_MS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_ID_FIELD_NUMBER: _ClassVar[int]
    session: str
    slot: str
    rig_id: str
    instance_id: str
    heartbeat_interval_ms: int
    clock_id: str
    def __init__(self, session: _Optional[str] = ..., slot: _Optional[str] = ..., rig_id: _Optional[str] = ..., instance_id: _Optional[str] = ..., heartbeat_interval_ms: _Optional[int] = ..., clock_id: _Optional[str] = ...) -> None: ...

class StreamRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class Homography(_message.Message):
    __slots__ = ("m",)
    M_FIELD_NUMBER: _ClassVar[int]
    m: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, m: _Optional[_Iterable[float]] = ...) -> None: ...

class Mesh(_message.Message):
    __slots__ = ("mesh_id", "vertices", "uvs", "faces")
    MESH_ID_FIELD_NUMBER: _ClassVar[int]
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    UVS_FIELD_NUMBER: _ClassVar[int]
    FACES_FIELD_NUMBER: _ClassVar[int]
    mesh_id: str
    vertices: bytes
    uvs: bytes
    faces: bytes
    def __init__(self, mesh_id: _Optional[str] = ..., vertices: _Optional[bytes] = ..., uvs: _Optional[bytes] = ..., faces: _Optional[bytes] = ...) -> None: ...

class ProjectionPose(_message.Message):
    __slots__ = ("p", "mesh", "near_mm", "far_mm")
    P_FIELD_NUMBER: _ClassVar[int]
    MESH_FIELD_NUMBER: _ClassVar[int]
    NEAR_MM_FIELD_NUMBER: _ClassVar[int]
    FAR_MM_FIELD_NUMBER: _ClassVar[int]
    p: _containers.RepeatedScalarFieldContainer[float]
    mesh: Mesh
    near_mm: float
    far_mm: float
    def __init__(self, p: _Optional[_Iterable[float]] = ..., mesh: _Optional[_Union[Mesh, _Mapping]] = ..., near_mm: _Optional[float] = ..., far_mm: _Optional[float] = ...) -> None: ...

class Lut(_message.Message):
    __slots__ = ("channels", "entries", "values")
    CHANNELS_FIELD_NUMBER: _ClassVar[int]
    ENTRIES_FIELD_NUMBER: _ClassVar[int]
    VALUES_FIELD_NUMBER: _ClassVar[int]
    channels: int
    entries: int
    values: bytes
    def __init__(self, channels: _Optional[int] = ..., entries: _Optional[int] = ..., values: _Optional[bytes] = ...) -> None: ...

class Assignment(_message.Message):
    __slots__ = ("revision", "slot", "output_width", "output_height", "homography", "projection", "lut", "gain", "content_width", "content_height", "blend")
    REVISION_FIELD_NUMBER: _ClassVar[int]
    SLOT_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_WIDTH_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    HOMOGRAPHY_FIELD_NUMBER: _ClassVar[int]
    PROJECTION_FIELD_NUMBER: _ClassVar[int]
    LUT_FIELD_NUMBER: _ClassVar[int]
    GAIN_FIELD_NUMBER: _ClassVar[int]
    CONTENT_WIDTH_FIELD_NUMBER: _ClassVar[int]
    CONTENT_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    BLEND_FIELD_NUMBER: _ClassVar[int]
    revision: int
    slot: str
    output_width: int
    output_height: int
    homography: Homography
    projection: ProjectionPose
    lut: Lut
    gain: float
    content_width: int
    content_height: int
    blend: Blend
    def __init__(self, revision: _Optional[int] = ..., slot: _Optional[str] = ..., output_width: _Optional[int] = ..., output_height: _Optional[int] = ..., homography: _Optional[_Union[Homography, _Mapping]] = ..., projection: _Optional[_Union[ProjectionPose, _Mapping]] = ..., lut: _Optional[_Union[Lut, _Mapping]] = ..., gain: _Optional[float] = ..., content_width: _Optional[int] = ..., content_height: _Optional[int] = ..., blend: _Optional[_Union[Blend, _Mapping]] = ...) -> None: ...

class Blend(_message.Message):
    __slots__ = ("width", "height", "alpha", "beta", "blend_id", "at_rig_ns")
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    ALPHA_FIELD_NUMBER: _ClassVar[int]
    BETA_FIELD_NUMBER: _ClassVar[int]
    BLEND_ID_FIELD_NUMBER: _ClassVar[int]
    AT_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    width: int
    height: int
    alpha: bytes
    beta: bytes
    blend_id: str
    at_rig_ns: int
    def __init__(self, width: _Optional[int] = ..., height: _Optional[int] = ..., alpha: _Optional[bytes] = ..., beta: _Optional[bytes] = ..., blend_id: _Optional[str] = ..., at_rig_ns: _Optional[int] = ...) -> None: ...

class Content(_message.Message):
    __slots__ = ("content_id", "image")
    CONTENT_ID_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    content_id: str
    image: _common_pb2.Image
    def __init__(self, content_id: _Optional[str] = ..., image: _Optional[_Union[_common_pb2.Image, _Mapping]] = ...) -> None: ...

class Frame(_message.Message):
    __slots__ = ("frame_id", "pts_ns", "content_id", "space", "apply_lut", "slot_content", "tag", "fade_ns", "fade_steps")
    class SlotContentEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: str
        def __init__(self, key: _Optional[str] = ..., value: _Optional[str] = ...) -> None: ...
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    PTS_NS_FIELD_NUMBER: _ClassVar[int]
    CONTENT_ID_FIELD_NUMBER: _ClassVar[int]
    SPACE_FIELD_NUMBER: _ClassVar[int]
    APPLY_LUT_FIELD_NUMBER: _ClassVar[int]
    SLOT_CONTENT_FIELD_NUMBER: _ClassVar[int]
    TAG_FIELD_NUMBER: _ClassVar[int]
    FADE_NS_FIELD_NUMBER: _ClassVar[int]
    FADE_STEPS_FIELD_NUMBER: _ClassVar[int]
    frame_id: int
    pts_ns: int
    content_id: str
    space: Space
    apply_lut: bool
    slot_content: _containers.ScalarMap[str, str]
    tag: str
    fade_ns: int
    fade_steps: int
    def __init__(self, frame_id: _Optional[int] = ..., pts_ns: _Optional[int] = ..., content_id: _Optional[str] = ..., space: _Optional[_Union[Space, str]] = ..., apply_lut: _Optional[bool] = ..., slot_content: _Optional[_Mapping[str, str]] = ..., tag: _Optional[str] = ..., fade_ns: _Optional[int] = ..., fade_steps: _Optional[int] = ...) -> None: ...

class Evict(_message.Message):
    __slots__ = ("content_ids",)
    CONTENT_IDS_FIELD_NUMBER: _ClassVar[int]
    content_ids: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, content_ids: _Optional[_Iterable[str]] = ...) -> None: ...

class VideoPacket(_message.Message):
    __slots__ = ("stream_id", "sequence", "keyframe", "data", "width", "height", "channels", "bit_depth", "codec", "content_id")
    STREAM_ID_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    CHANNELS_FIELD_NUMBER: _ClassVar[int]
    BIT_DEPTH_FIELD_NUMBER: _ClassVar[int]
    CODEC_FIELD_NUMBER: _ClassVar[int]
    CONTENT_ID_FIELD_NUMBER: _ClassVar[int]
    stream_id: str
    sequence: int
    keyframe: bool
    data: bytes
    width: int
    height: int
    channels: int
    bit_depth: int
    codec: VideoCodec
    content_id: str
    def __init__(self, stream_id: _Optional[str] = ..., sequence: _Optional[int] = ..., keyframe: _Optional[bool] = ..., data: _Optional[bytes] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., channels: _Optional[int] = ..., bit_depth: _Optional[int] = ..., codec: _Optional[_Union[VideoCodec, str]] = ..., content_id: _Optional[str] = ...) -> None: ...

class FramePacket(_message.Message):
    __slots__ = ("contents", "frame", "evict", "video")
    CONTENTS_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    EVICT_FIELD_NUMBER: _ClassVar[int]
    VIDEO_FIELD_NUMBER: _ClassVar[int]
    contents: _containers.RepeatedCompositeFieldContainer[Content]
    frame: Frame
    evict: Evict
    video: VideoPacket
    def __init__(self, contents: _Optional[_Iterable[_Union[Content, _Mapping]]] = ..., frame: _Optional[_Union[Frame, _Mapping]] = ..., evict: _Optional[_Union[Evict, _Mapping]] = ..., video: _Optional[_Union[VideoPacket, _Mapping]] = ...) -> None: ...

class Swaps(_message.Message):
    __slots__ = ("frame_id", "swap_rig_ns", "host_monotonic_ns")
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    SWAP_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    HOST_MONOTONIC_NS_FIELD_NUMBER: _ClassVar[int]
    frame_id: _containers.RepeatedScalarFieldContainer[int]
    swap_rig_ns: _containers.RepeatedScalarFieldContainer[int]
    host_monotonic_ns: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, frame_id: _Optional[_Iterable[int]] = ..., swap_rig_ns: _Optional[_Iterable[int]] = ..., host_monotonic_ns: _Optional[_Iterable[int]] = ...) -> None: ...

class FrameDrop(_message.Message):
    __slots__ = ("frame_id", "reason", "late_by_ns")
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    LATE_BY_NS_FIELD_NUMBER: _ClassVar[int]
    frame_id: int
    reason: DropReason
    late_by_ns: int
    def __init__(self, frame_id: _Optional[int] = ..., reason: _Optional[_Union[DropReason, str]] = ..., late_by_ns: _Optional[int] = ...) -> None: ...

class Heartbeat(_message.Message):
    __slots__ = ("assignment_revision", "clock_offset_ns", "clock_drift_ppm", "clock_rtt_ns", "clock_samples", "frames_shown", "frames_late", "frames_dropped", "render_ms_p50", "host_monotonic_ns", "rig_estimate_ns", "assets", "show", "blend_id", "blend_since_rig_ns", "decoder", "decoder_note", "assignment_refused")
    ASSIGNMENT_REVISION_FIELD_NUMBER: _ClassVar[int]
    CLOCK_OFFSET_NS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_DRIFT_PPM_FIELD_NUMBER: _ClassVar[int]
    CLOCK_RTT_NS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_SAMPLES_FIELD_NUMBER: _ClassVar[int]
    FRAMES_SHOWN_FIELD_NUMBER: _ClassVar[int]
    FRAMES_LATE_FIELD_NUMBER: _ClassVar[int]
    FRAMES_DROPPED_FIELD_NUMBER: _ClassVar[int]
    RENDER_MS_P50_FIELD_NUMBER: _ClassVar[int]
    HOST_MONOTONIC_NS_FIELD_NUMBER: _ClassVar[int]
    RIG_ESTIMATE_NS_FIELD_NUMBER: _ClassVar[int]
    ASSETS_FIELD_NUMBER: _ClassVar[int]
    SHOW_FIELD_NUMBER: _ClassVar[int]
    BLEND_ID_FIELD_NUMBER: _ClassVar[int]
    BLEND_SINCE_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    DECODER_FIELD_NUMBER: _ClassVar[int]
    DECODER_NOTE_FIELD_NUMBER: _ClassVar[int]
    ASSIGNMENT_REFUSED_FIELD_NUMBER: _ClassVar[int]
    assignment_revision: int
    clock_offset_ns: int
    clock_drift_ppm: float
    clock_rtt_ns: int
    clock_samples: int
    frames_shown: int
    frames_late: int
    frames_dropped: int
    render_ms_p50: float
    host_monotonic_ns: int
    rig_estimate_ns: int
    assets: _containers.RepeatedCompositeFieldContainer[AssetProgress]
    show: NodeShow
    blend_id: str
    blend_since_rig_ns: int
    decoder: str
    decoder_note: str
    assignment_refused: str
    def __init__(self, assignment_revision: _Optional[int] = ..., clock_offset_ns: _Optional[int] = ..., clock_drift_ppm: _Optional[float] = ..., clock_rtt_ns: _Optional[int] = ..., clock_samples: _Optional[int] = ..., frames_shown: _Optional[int] = ..., frames_late: _Optional[int] = ..., frames_dropped: _Optional[int] = ..., render_ms_p50: _Optional[float] = ..., host_monotonic_ns: _Optional[int] = ..., rig_estimate_ns: _Optional[int] = ..., assets: _Optional[_Iterable[_Union[AssetProgress, _Mapping]]] = ..., show: _Optional[_Union[NodeShow, _Mapping]] = ..., blend_id: _Optional[str] = ..., blend_since_rig_ns: _Optional[int] = ..., decoder: _Optional[str] = ..., decoder_note: _Optional[str] = ..., assignment_refused: _Optional[str] = ...) -> None: ...

class NodeShow(_message.Message):
    __slots__ = ("revision", "state", "last_frame", "frames_shown", "frames_late", "alone_ms")
    REVISION_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    LAST_FRAME_FIELD_NUMBER: _ClassVar[int]
    FRAMES_SHOWN_FIELD_NUMBER: _ClassVar[int]
    FRAMES_LATE_FIELD_NUMBER: _ClassVar[int]
    ALONE_MS_FIELD_NUMBER: _ClassVar[int]
    revision: int
    state: NodeShowState
    last_frame: int
    frames_shown: int
    frames_late: int
    alone_ms: int
    def __init__(self, revision: _Optional[int] = ..., state: _Optional[_Union[NodeShowState, str]] = ..., last_frame: _Optional[int] = ..., frames_shown: _Optional[int] = ..., frames_late: _Optional[int] = ..., alone_ms: _Optional[int] = ...) -> None: ...

class NodeReport(_message.Message):
    __slots__ = ("heartbeat", "drops", "swaps", "preview", "goodbye")
    HEARTBEAT_FIELD_NUMBER: _ClassVar[int]
    DROPS_FIELD_NUMBER: _ClassVar[int]
    SWAPS_FIELD_NUMBER: _ClassVar[int]
    PREVIEW_FIELD_NUMBER: _ClassVar[int]
    GOODBYE_FIELD_NUMBER: _ClassVar[int]
    heartbeat: Heartbeat
    drops: _containers.RepeatedCompositeFieldContainer[FrameDrop]
    swaps: Swaps
    preview: Preview
    goodbye: str
    def __init__(self, heartbeat: _Optional[_Union[Heartbeat, _Mapping]] = ..., drops: _Optional[_Iterable[_Union[FrameDrop, _Mapping]]] = ..., swaps: _Optional[_Union[Swaps, _Mapping]] = ..., preview: _Optional[_Union[Preview, _Mapping]] = ..., goodbye: _Optional[str] = ...) -> None: ...

class ReportAck(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class PreviewRequest(_message.Message):
    __slots__ = ("request_id",)
    REQUEST_ID_FIELD_NUMBER: _ClassVar[int]
    request_id: int
    def __init__(self, request_id: _Optional[int] = ...) -> None: ...

class Preview(_message.Message):
    __slots__ = ("request_id", "frame_id", "png", "width", "height", "output_width", "output_height")
    REQUEST_ID_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    PNG_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_WIDTH_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    request_id: int
    frame_id: int
    png: bytes
    width: int
    height: int
    output_width: int
    output_height: int
    def __init__(self, request_id: _Optional[int] = ..., frame_id: _Optional[int] = ..., png: _Optional[bytes] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., output_width: _Optional[int] = ..., output_height: _Optional[int] = ...) -> None: ...

class PingRequest(_message.Message):
    __slots__ = ("t0_local_ns",)
    T0_LOCAL_NS_FIELD_NUMBER: _ClassVar[int]
    t0_local_ns: int
    def __init__(self, t0_local_ns: _Optional[int] = ...) -> None: ...

class PingReply(_message.Message):
    __slots__ = ("t0_local_ns", "t1_rig_ns", "t2_rig_ns", "instance_id")
    T0_LOCAL_NS_FIELD_NUMBER: _ClassVar[int]
    T1_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    T2_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    INSTANCE_ID_FIELD_NUMBER: _ClassVar[int]
    t0_local_ns: int
    t1_rig_ns: int
    t2_rig_ns: int
    instance_id: str
    def __init__(self, t0_local_ns: _Optional[int] = ..., t1_rig_ns: _Optional[int] = ..., t2_rig_ns: _Optional[int] = ..., instance_id: _Optional[str] = ...) -> None: ...

class WantedAssets(_message.Message):
    __slots__ = ("revision", "asset_ids", "pinned_ids")
    REVISION_FIELD_NUMBER: _ClassVar[int]
    ASSET_IDS_FIELD_NUMBER: _ClassVar[int]
    PINNED_IDS_FIELD_NUMBER: _ClassVar[int]
    revision: int
    asset_ids: _containers.RepeatedScalarFieldContainer[str]
    pinned_ids: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, revision: _Optional[int] = ..., asset_ids: _Optional[_Iterable[str]] = ..., pinned_ids: _Optional[_Iterable[str]] = ...) -> None: ...

class ManifestRequest(_message.Message):
    __slots__ = ("asset_id",)
    ASSET_ID_FIELD_NUMBER: _ClassVar[int]
    asset_id: str
    def __init__(self, asset_id: _Optional[str] = ...) -> None: ...

class ManifestReply(_message.Message):
    __slots__ = ("manifest",)
    MANIFEST_FIELD_NUMBER: _ClassVar[int]
    manifest: bytes
    def __init__(self, manifest: _Optional[bytes] = ...) -> None: ...

class BlobRequest(_message.Message):
    __slots__ = ("sha256", "offset")
    SHA256_FIELD_NUMBER: _ClassVar[int]
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    sha256: str
    offset: int
    def __init__(self, sha256: _Optional[str] = ..., offset: _Optional[int] = ...) -> None: ...

class BlobChunk(_message.Message):
    __slots__ = ("offset", "data")
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    offset: int
    data: bytes
    def __init__(self, offset: _Optional[int] = ..., data: _Optional[bytes] = ...) -> None: ...

class AssetProgress(_message.Message):
    __slots__ = ("asset_id", "have_bytes", "total_bytes", "ready", "error", "name", "ready_age_ms")
    ASSET_ID_FIELD_NUMBER: _ClassVar[int]
    HAVE_BYTES_FIELD_NUMBER: _ClassVar[int]
    TOTAL_BYTES_FIELD_NUMBER: _ClassVar[int]
    READY_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    READY_AGE_MS_FIELD_NUMBER: _ClassVar[int]
    asset_id: str
    have_bytes: int
    total_bytes: int
    ready: bool
    error: str
    name: str
    ready_age_ms: float
    def __init__(self, asset_id: _Optional[str] = ..., have_bytes: _Optional[int] = ..., total_bytes: _Optional[int] = ..., ready: _Optional[bool] = ..., error: _Optional[str] = ..., name: _Optional[str] = ..., ready_age_ms: _Optional[float] = ...) -> None: ...

class Timeline(_message.Message):
    __slots__ = ("asset_id", "frames", "rate_num", "rate_den", "anchor_ns", "anchor_frame", "loop", "paused", "revision", "frame_id_base", "fade_ns")
    ASSET_ID_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    RATE_NUM_FIELD_NUMBER: _ClassVar[int]
    RATE_DEN_FIELD_NUMBER: _ClassVar[int]
    ANCHOR_NS_FIELD_NUMBER: _ClassVar[int]
    ANCHOR_FRAME_FIELD_NUMBER: _ClassVar[int]
    LOOP_FIELD_NUMBER: _ClassVar[int]
    PAUSED_FIELD_NUMBER: _ClassVar[int]
    REVISION_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_BASE_FIELD_NUMBER: _ClassVar[int]
    FADE_NS_FIELD_NUMBER: _ClassVar[int]
    asset_id: str
    frames: int
    rate_num: int
    rate_den: int
    anchor_ns: int
    anchor_frame: int
    loop: bool
    paused: bool
    revision: int
    frame_id_base: int
    fade_ns: int
    def __init__(self, asset_id: _Optional[str] = ..., frames: _Optional[int] = ..., rate_num: _Optional[int] = ..., rate_den: _Optional[int] = ..., anchor_ns: _Optional[int] = ..., anchor_frame: _Optional[int] = ..., loop: _Optional[bool] = ..., paused: _Optional[bool] = ..., revision: _Optional[int] = ..., frame_id_base: _Optional[int] = ..., fade_ns: _Optional[int] = ...) -> None: ...

class ShowUpdate(_message.Message):
    __slots__ = ("timeline", "stop", "stop_at_ns", "stop_revision", "beacon")
    TIMELINE_FIELD_NUMBER: _ClassVar[int]
    STOP_FIELD_NUMBER: _ClassVar[int]
    STOP_AT_NS_FIELD_NUMBER: _ClassVar[int]
    STOP_REVISION_FIELD_NUMBER: _ClassVar[int]
    BEACON_FIELD_NUMBER: _ClassVar[int]
    timeline: Timeline
    stop: bool
    stop_at_ns: int
    stop_revision: int
    beacon: bool
    def __init__(self, timeline: _Optional[_Union[Timeline, _Mapping]] = ..., stop: _Optional[bool] = ..., stop_at_ns: _Optional[int] = ..., stop_revision: _Optional[int] = ..., beacon: _Optional[bool] = ...) -> None: ...
