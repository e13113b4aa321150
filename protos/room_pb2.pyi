from protos import common_pb2 as _common_pb2
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class DescribeProjectorRequest(_message.Message):
    __slots__ = ("slot",)
    SLOT_FIELD_NUMBER: _ClassVar[int]
    slot: str
    def __init__(self, slot: _Optional[str] = ...) -> None: ...

class ProjectorDescription(_message.Message):
    __slots__ = ("slot", "width", "height")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    slot: str
    width: int
    height: int
    def __init__(self, slot: _Optional[str] = ..., width: _Optional[int] = ..., height: _Optional[int] = ...) -> None: ...

class DisplayedFrame(_message.Message):
    __slots__ = ("slot", "frame_id", "swap_rig_ns", "host_monotonic_ns", "image")
    SLOT_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    SWAP_RIG_NS_FIELD_NUMBER: _ClassVar[int]
    HOST_MONOTONIC_NS_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    slot: str
    frame_id: int
    swap_rig_ns: int
    host_monotonic_ns: int
    image: _common_pb2.Image
    def __init__(self, slot: _Optional[str] = ..., frame_id: _Optional[int] = ..., swap_rig_ns: _Optional[int] = ..., host_monotonic_ns: _Optional[int] = ..., image: _Optional[_Union[_common_pb2.Image, _Mapping]] = ...) -> None: ...

class DisplayAck(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class CaptureRequest(_message.Message):
    __slots__ = ("camera",)
    CAMERA_FIELD_NUMBER: _ClassVar[int]
    camera: int
    def __init__(self, camera: _Optional[int] = ...) -> None: ...

class CaptureReply(_message.Message):
    __slots__ = ("image", "host_monotonic_ns")
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    HOST_MONOTONIC_NS_FIELD_NUMBER: _ClassVar[int]
    image: _common_pb2.Image
    host_monotonic_ns: int
    def __init__(self, image: _Optional[_Union[_common_pb2.Image, _Mapping]] = ..., host_monotonic_ns: _Optional[int] = ...) -> None: ...
