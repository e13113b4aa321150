from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class DType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DTYPE_UNSPECIFIED: _ClassVar[DType]
    DTYPE_UINT8: _ClassVar[DType]
    DTYPE_UINT16: _ClassVar[DType]
    DTYPE_FLOAT16: _ClassVar[DType]
    DTYPE_FLOAT32: _ClassVar[DType]

class Encoding(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    ENCODING_UNSPECIFIED: _ClassVar[Encoding]
    ENCODING_RAW: _ClassVar[Encoding]
    ENCODING_ZLIB: _ClassVar[Encoding]
    ENCODING_ZSTD_GRADIENT: _ClassVar[Encoding]
DTYPE_UNSPECIFIED: DType
DTYPE_UINT8: DType
DTYPE_UINT16: DType
DTYPE_FLOAT16: DType
DTYPE_FLOAT32: DType
ENCODING_UNSPECIFIED: Encoding
ENCODING_RAW: Encoding
ENCODING_ZLIB: Encoding
ENCODING_ZSTD_GRADIENT: Encoding

class Image(_message.Message):
    __slots__ = ("width", "height", "channels", "dtype", "encoding", "data")
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    CHANNELS_FIELD_NUMBER: _ClassVar[int]
    DTYPE_FIELD_NUMBER: _ClassVar[int]
    ENCODING_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    width: int
    height: int
    channels: int
    dtype: DType
    encoding: Encoding
    data: bytes
    def __init__(self, width: _Optional[int] = ..., height: _Optional[int] = ..., channels: _Optional[int] = ..., dtype: _Optional[_Union[DType, str]] = ..., encoding: _Optional[_Union[Encoding, str]] = ..., data: _Optional[bytes] = ...) -> None: ...

class HelloRequest(_message.Message):
    __slots__ = ("protocol_version", "client_nonce", "role", "slot")
    PROTOCOL_VERSION_FIELD_NUMBER: _ClassVar[int]
    CLIENT_NONCE_FIELD_NUMBER: _ClassVar[int]
    ROLE_FIELD_NUMBER: _ClassVar[int]
    SLOT_FIELD_NUMBER: _ClassVar[int]
    protocol_version: int
    client_nonce: bytes
    role: str
    slot: str
    def __init__(self, protocol_version: _Optional[int] = ..., client_nonce: _Optional[bytes] = ..., role: _Optional[str] = ..., slot: _Optional[str] = ...) -> None: ...

class HelloReply(_message.Message):
    __slots__ = ("protocol_version", "rig_id", "rig_name", "server_nonce", "server_proof", "instance_id")
    PROTOCOL_VERSION_FIELD_NUMBER: _ClassVar[int]
    RIG_ID_FIELD_NUMBER: _ClassVar[int]
    RIG_NAME_FIELD_NUMBER: _ClassVar[int]
    SERVER_NONCE_FIELD_NUMBER: _ClassVar[int]
    SERVER_PROOF_FIELD_NUMBER: _ClassVar[int]
    INSTANCE_ID_FIELD_NUMBER: _ClassVar[int]
    protocol_version: int
    rig_id: str
    rig_name: str
    server_nonce: bytes
    server_proof: bytes
    instance_id: str
    def __init__(self, protocol_version: _Optional[int] = ..., rig_id: _Optional[str] = ..., rig_name: _Optional[str] = ..., server_nonce: _Optional[bytes] = ..., server_proof: _Optional[bytes] = ..., instance_id: _Optional[str] = ...) -> None: ...

class LoginRequest(_message.Message):
    __slots__ = ("protocol_version", "role", "slot", "client_nonce", "server_nonce", "client_proof")
    PROTOCOL_VERSION_FIELD_NUMBER: _ClassVar[int]
    ROLE_FIELD_NUMBER: _ClassVar[int]
    SLOT_FIELD_NUMBER: _ClassVar[int]
    CLIENT_NONCE_FIELD_NUMBER: _ClassVar[int]
    SERVER_NONCE_FIELD_NUMBER: _ClassVar[int]
    CLIENT_PROOF_FIELD_NUMBER: _ClassVar[int]
    protocol_version: int
    role: str
    slot: str
    client_nonce: bytes
    server_nonce: bytes
    client_proof: bytes
    def __init__(self, protocol_version: _Optional[int] = ..., role: _Optional[str] = ..., slot: _Optional[str] = ..., client_nonce: _Optional[bytes] = ..., server_nonce: _Optional[bytes] = ..., client_proof: _Optional[bytes] = ...) -> None: ...

class LoginReply(_message.Message):
    __slots__ = ("session", "rig_id", "instance_id")
    SESSION_FIELD_NUMBER: _ClassVar[int]
    RIG_ID_FIELD_NUMBER: _ClassVar[int]
    INSTANCE_ID_FIELD_NUMBER: _ClassVar[int]
    session: str
    rig_id: str
    instance_id: str
    def __init__(self, session: _Optional[str] = ..., rig_id: _Optional[str] = ..., instance_id: _Optional[str] = ...) -> None: ...
