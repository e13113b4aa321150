from protos import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class DescribeProjectorRequest(_message.Message):
    __slots__ = ("slot",)
    SLOT_FIELD_NUMBER: _ClassVar[int]
    slot: str
    def __init__(self, slot: _Optional[str] = ...) -> None: ...

class ProjectorDescription(_message.Message):
    __slots__ = ("slot", "width", "height", "powered")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    POWERED_FIELD_NUMBER: _ClassVar[int]
    slot: str
    width: int
    height: int
    powered: bool
    def __init__(self, slot: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., powered: _Optional[bool] = ...) -> None: ...

class DescribeRoomRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class CameraDescription(_message.Message):
    __slots__ = ("index", "name", "width", "height", "bits")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    BITS_FIELD_NUMBER: _ClassVar[int]
    index: int
    name: str
    width: int
    height: int
    bits: int
    def __init__(self, index: _Optional[int] = ..., name: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., bits: _Optional[int] = ...) -> None: ...

class RoomDescription(_message.Message):
    __slots__ = ("name", "projectors", "rig_slots", "cameras", "surface")
    NAME_FIELD_NUMBER: _ClassVar[int]
    PROJECTORS_FIELD_NUMBER: _ClassVar[int]
    RIG_SLOTS_FIELD_NUMBER: _ClassVar[int]
    CAMERAS_FIELD_NUMBER: _ClassVar[int]
    SURFACE_FIELD_NUMBER: _ClassVar[int]
    name: str
    projectors: _containers.RepeatedCompositeFieldContainer[ProjectorDescription]
    rig_slots: _containers.RepeatedScalarFieldContainer[str]
    cameras: _containers.RepeatedCompositeFieldContainer[CameraDescription]
    surface: str
    def __init__(self, name: _Optional[str] = ..., projectors: _Optional[_Iterable[_Union[ProjectorDescription, _Mapping]]] = ..., rig_slots: _Optional[_Iterable[str]] = ..., cameras: _Optional[_Iterable[_Union[CameraDescription, _Mapping]]] = ..., surface: _Optional[str] = ...) -> None: ...

class DisplayedFrame(_message.Message):
    __slots__ = ("slot", "frame_id", "swap_rig_ns", "host_monotonic_ns", "image", "tag", "shared")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    SWAP_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    HOST_MONOTONIC_NS_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    TAG_FIELD_NUMBER: _ClassVar[int]
    SHARED_FIELD_NUMBER: _ClassVar[int]
    slot: str
    frame_id: int
    swap_rig_ns: int
    host_monotonic_ns: int
    image: _common_pb2.Image
    tag: str
    shared: SharedFrame
    def __init__(self, slot: _Optional[str] = ..., frame_id: _Optional[int] = ..., swap_rig_ns: _Optional[int] = ..., host_monotonic_ns: _Optional[int] = ..., image: _Optional[_Union[_common_pb2.Image, _Mapping]] = ..., tag: _Optional[str] = ..., shared: _Optional[_Union[SharedFrame, _Mapping]] = ...) -> None: ...

class SharedFrame(_message.Message):
    __slots__ = ("pid", "fd", "offset", "seq", "width", "height")
    PID_FIELD_NUMBER: _ClassVar[int]
    FD_FIELD_NUMBER: _ClassVar[int]
    OFFSET_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    pid: int
    fd: int
    offset: int
    seq: int
    width: int
    height: int
    def __init__(self, pid: _Optional[int] = ..., fd: _Optional[int] = ..., offset: _Optional[int] = ..., seq: _Optional[int] = ..., width: _Optional[int] = ..., height: _Optional[int] = ...) -> None: ...

class DisplayAck(_message.Message):
    __slots__ = ("frames",)
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    frames: int
    def __init__(self, frames: _Optional[int] = ...) -> None: ...

class CaptureRequest(_message.Message):
    __slots__ = ("camera", "not_before_rig_ns", "timeout_ms", "exposure", "compress")
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    NOT_BEFORE_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    EXPOSURE_FIELD_NUMBER: _ClassVar[int]
    COMPRESS_FIELD_NUMBER: _ClassVar[int]
    camera: int
    not_before_rig_ns: int
    timeout_ms: int
    exposure: float
    compress: bool
    def __init__(self, camera: _Optional[int] = ..., not_before_rig_ns: _Optional[int] = ..., timeout_ms: _Optional[int] = ..., exposure: _Optional[float] = ..., compress: _Optional[bool] = ...) -> None: ...

class FrameUsed(_message.Message):
    __slots__ = ("slot", "frame_id", "swap_rig_ns")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    SWAP_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    slot: str
    frame_id: int
    swap_rig_ns: int
    def __init__(self, slot: _Optional[str] = ..., frame_id: _Optional[int] = ..., swap_rig_ns: _Optional[int] = ...) -> None: ...

class CaptureReply(_message.Message):
    __slots__ = ("image", "host_monotonic_ns", "bits", "frames", "late_slots")
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    HOST_MONOTONIC_NS_FIELD_NUMBER: _ClassVar[int]
    BITS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    LATE_SLOTS_FIELD_NUMBER: _ClassVar[int]
    image: _common_pb2.Image
    host_monotonic_ns: int
    bits: int
    frames: _containers.RepeatedCompositeFieldContainer[FrameUsed]
    late_slots: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, image: _Optional[_Union[_common_pb2.Image, _Mapping]] = ..., host_monotonic_ns: _Optional[int] = ..., bits: _Optional[int] = ..., frames: _Optional[_Iterable[_Union[FrameUsed, _Mapping]]] = ..., late_slots: _Optional[_Iterable[str]] = ...) -> None: ...

class SlotRequest(_message.Message):
    __slots__ = ("slot", "camera")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    slot: str
    camera: int
    def __init__(self, slot: _Optional[str] = ..., camera: _Optional[int] = ...) -> None: ...

class CameraRequest(_message.Message):
    __slots__ = ("camera",)
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    camera: int
    def __init__(self, camera: _Optional[int] = ...) -> None: ...

class ProjectorTruth(_message.Message):
    __slots__ = ("slot", "k", "r", "t", "p", "width", "height", "native_width", "native_height", "center", "gamma", "black", "peak", "aperture_mm", "focus_mm", "falloff", "powered", "white", "lamp", "hotspot", "hotspot_width", "hotspot_center", "vignetting")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    K_FIELD_NUMBER: _ClassVar[int]
    R_FIELD_NUMBER: _ClassVar[int]
    T_FIELD_NUMBER: _ClassVar[int]
    P_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    NATIVE_WIDTH_FIELD_NUMBER: _ClassVar[int]
    NATIVE_HEIGHT_FIELD_NUMBER: _ClassVar[int]
    CENTER_FIELD_NUMBER: _ClassVar[int]
    GAMMA_FIELD_NUMBER: _ClassVar[int]
    BLACK_FIELD_NUMBER: _ClassVar[int]
    PEAK_FIELD_NUMBER: _ClassVar[int]
    APERTURE_MM_FIELD_NUMBER: _ClassVar[int]
    FOCUS_MM_FIELD_NUMBER: _ClassVar[int]
    FALLOFF_FIELD_NUMBER: _ClassVar[int]
    POWERED_FIELD_NUMBER: _ClassVar[int]
    WHITE_FIELD_NUMBER: _ClassVar[int]
    LAMP_FIELD_NUMBER: _ClassVar[int]
    HOTSPOT_FIELD_NUMBER: _ClassVar[int]
    HOTSPOT_WIDTH_FIELD_NUMBER: _ClassVar[int]
    HOTSPOT_CENTER_FIELD_NUMBER: _ClassVar[int]
    VIGNETTING_FIELD_NUMBER: _ClassVar[int]
    slot: str
    k: _containers.RepeatedScalarFieldContainer[float]
    r: _containers.RepeatedScalarFieldContainer[float]
    t: _containers.RepeatedScalarFieldContainer[float]
    p: _containers.RepeatedScalarFieldContainer[float]
    width: int
    height: int
    native_width: int
    native_height: int
    center: _containers.RepeatedScalarFieldContainer[float]
    gamma: _containers.RepeatedScalarFieldContainer[float]
    black: _containers.RepeatedScalarFieldContainer[float]
    peak: float
    aperture_mm: float
    focus_mm: float
    falloff: float
    powered: bool
    white: _containers.RepeatedScalarFieldContainer[float]
    lamp: _containers.RepeatedScalarFieldContainer[float]
    hotspot: float
    hotspot_width: float
    hotspot_center: _containers.RepeatedScalarFieldContainer[float]
    vignetting: float
    def __init__(self, slot: _Optional[str] = ..., k: _Optional[_Iterable[float]] = ..., r: _Optional[_Iterable[float]] = ..., t: _Optional[_Iterable[float]] = ..., p: _Optional[_Iterable[float]] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., native_width: _Optional[int] = ..., native_height: _Optional[int] = ..., center: _Optional[_Iterable[float]] = ..., gamma: _Optional[_Iterable[float]] = ..., black: _Optional[_Iterable[float]] = ..., peak: _Optional[float] = ..., aperture_mm: _Optional[float] = ..., focus_mm: _Optional[float] = ..., falloff: _Optional[float] = ..., powered: _Optional[bool] = ..., white: _Optional[_Iterable[float]] = ..., lamp: _Optional[_Iterable[float]] = ..., hotspot: _Optional[float] = ..., hotspot_width: _Optional[float] = ..., hotspot_center: _Optional[_Iterable[float]] = ..., vignetting: _Optional[float] = ...) -> None: ...

class CameraTruth(_message.Message):
    __slots__ = ("k", "r", "t", "p", "width", "height", "center", "gain", "exposure", "full_well", "read_noise", "bits")
    K_FIELD_NUMBER: _ClassVar[int]
    R_FIELD_NUMBER: _ClassVar[int]
    T_FIELD_NUMBER: _ClassVar[int]
    P_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    CENTER_FIELD_NUMBER: _ClassVar[int]
    GAIN_FIELD_NUMBER: _ClassVar[int]
    EXPOSURE_FIELD_NUMBER: _ClassVar[int]
    FULL_WELL_FIELD_NUMBER: _ClassVar[int]
    READ_NOISE_FIELD_NUMBER: _ClassVar[int]
    BITS_FIELD_NUMBER: _ClassVar[int]
    k: _containers.RepeatedScalarFieldContainer[float]
    r: _containers.RepeatedScalarFieldContainer[float]
    t: _containers.RepeatedScalarFieldContainer[float]
    p: _containers.RepeatedScalarFieldContainer[float]
    width: int
    height: int
    center: _containers.RepeatedScalarFieldContainer[float]
    gain: float
    exposure: float
    full_well: float
    read_noise: float
    bits: int
    def __init__(self, k: _Optional[_Iterable[float]] = ..., r: _Optional[_Iterable[float]] = ..., t: _Optional[_Iterable[float]] = ..., p: _Optional[_Iterable[float]] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., center: _Optional[_Iterable[float]] = ..., gain: _Optional[float] = ..., exposure: _Optional[float] = ..., full_well: _Optional[float] = ..., read_noise: _Optional[float] = ..., bits: _Optional[int] = ...) -> None: ...

class SetActiveRequest(_message.Message):
    __slots__ = ("slots",)
    SLOTS_FIELD_NUMBER: _ClassVar[int]
    slots: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, slots: _Optional[_Iterable[str]] = ...) -> None: ...

class SetActiveReply(_message.Message):
    __slots__ = ("active",)
    ACTIVE_FIELD_NUMBER: _ClassVar[int]
    active: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, active: _Optional[_Iterable[str]] = ...) -> None: ...

class SetLampRequest(_message.Message):
    __slots__ = ("slot", "gain")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    GAIN_FIELD_NUMBER: _ClassVar[int]
    slot: str
    gain: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, slot: _Optional[str] = ..., gain: _Optional[_Iterable[float]] = ...) -> None: ...

class SetLampReply(_message.Message):
    __slots__ = ("slot", "lamp")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    LAMP_FIELD_NUMBER: _ClassVar[int]
    slot: str
    lamp: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, slot: _Optional[str] = ..., lamp: _Optional[_Iterable[float]] = ...) -> None: ...

class HandSpec(_message.Message):
    __slots__ = ("x", "y", "height", "yaw_deg", "pose", "scale", "side")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    YAW_DEG_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    SCALE_FIELD_NUMBER: _ClassVar[int]
    SIDE_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    height: float
    yaw_deg: float
    pose: str
    scale: float
    side: str
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., height: _Optional[float] = ..., yaw_deg: _Optional[float] = ..., pose: _Optional[str] = ..., scale: _Optional[float] = ..., side: _Optional[str] = ...) -> None: ...

class BoxSpec(_message.Message):
    __slots__ = ("center", "size", "yaw_deg")
    CENTER_FIELD_NUMBER: _ClassVar[int]
    SIZE_FIELD_NUMBER: _ClassVar[int]
    YAW_DEG_FIELD_NUMBER: _ClassVar[int]
    center: _containers.RepeatedScalarFieldContainer[float]
    size: _containers.RepeatedScalarFieldContainer[float]
    yaw_deg: float
    def __init__(self, center: _Optional[_Iterable[float]] = ..., size: _Optional[_Iterable[float]] = ..., yaw_deg: _Optional[float] = ...) -> None: ...

class HandKeyframe(_message.Message):
    __slots__ = ("time_s", "x", "y", "height")
    TIME_S_FIELD_NUMBER: _ClassVar[int]
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    time_s: float
    x: float
    y: float
    height: float
    def __init__(self, time_s: _Optional[float] = ..., x: _Optional[float] = ..., y: _Optional[float] = ..., height: _Optional[float] = ...) -> None: ...

class HandPathSpec(_message.Message):
    __slots__ = ("keyframes", "loop", "hand")
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    LOOP_FIELD_NUMBER: _ClassVar[int]
    HAND_FIELD_NUMBER: _ClassVar[int]
    keyframes: _containers.RepeatedCompositeFieldContainer[HandKeyframe]
    loop: bool
    hand: HandSpec
    def __init__(self, keyframes: _Optional[_Iterable[_Union[HandKeyframe, _Mapping]]] = ..., loop: _Optional[bool] = ..., hand: _Optional[_Union[HandSpec, _Mapping]] = ...) -> None: ...

class SetOccludersRequest(_message.Message):
    __slots__ = ("hands", "boxes", "path")
    HANDS_FIELD_NUMBER: _ClassVar[int]
    BOXES_FIELD_NUMBER: _ClassVar[int]
    PATH_FIELD_NUMBER: _ClassVar[int]
    hands: _containers.RepeatedCompositeFieldContainer[HandSpec]
    boxes: _containers.RepeatedCompositeFieldContainer[BoxSpec]
    path: HandPathSpec
    def __init__(self, hands: _Optional[_Iterable[_Union[HandSpec, _Mapping]]] = ..., boxes: _Optional[_Iterable[_Union[BoxSpec, _Mapping]]] = ..., path: _Optional[_Union[HandPathSpec, _Mapping]] = ...) -> None: ...

class SetOccludersReply(_message.Message):
    __slots__ = ("primitives",)
    PRIMITIVES_FIELD_NUMBER: _ClassVar[int]
    primitives: int
    def __init__(self, primitives: _Optional[int] = ...) -> None: ...

class TruthImage(_message.Message):
    __slots__ = ("image",)
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    image: _common_pb2.Image
    def __init__(self, image: _Optional[_Union[_common_pb2.Image, _Mapping]] = ...) -> None: ...

class SparseMatrix(_message.Message):
    __slots__ = ("rows", "cols", "indptr", "indices", "values")
    ROWS_FIELD_NUMBER: _ClassVar[int]
    COLS_FIELD_NUMBER: _ClassVar[int]
    INDPTR_FIELD_NUMBER: _ClassVar[int]
    INDICES_FIELD_NUMBER: _ClassVar[int]
    VALUES_FIELD_NUMBER: _ClassVar[int]
    rows: int
    cols: int
    indptr: bytes
    indices: bytes
    values: bytes
    def __init__(self, rows: _Optional[int] = ..., cols: _Optional[int] = ..., indptr: _Optional[bytes] = ..., indices: _Optional[bytes] = ..., values: _Optional[bytes] = ...) -> None: ...
