"""Wire protocol version. Every Hello/Join carries it; a mismatch is refused."""

#: 2: frame contents may be packed ENCODING_ZSTD_GRADIENT and sequences travel as live video
#: (FramePacket.video), which a version-1 node could not show.
#: 3: a report's swaps travel as delta-coded columns (NodeReport.swaps, a Swaps message).
PROTOCOL_VERSION = 3

#: mDNS service type the coordinator advertises.
SERVICE_TYPE = "_shadowless._tcp.local."

#: gRPC metadata key that carries the session id after the handshake.
SESSION_KEY = "x-shadowless-session"

#: Largest gRPC message either side accepts (a 16-bit 4K still is ~50 MB raw).
MAX_MESSAGE_BYTES = 256 * 1024 * 1024

GRPC_OPTIONS = [
    ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
    ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
    ("grpc.keepalive_time_ms", 10_000),
    ("grpc.keepalive_timeout_ms", 5_000),
    ("grpc.keepalive_permit_without_calls", 1),
    ("grpc.http2.max_pings_without_data", 0),
]

#: Servers accept the clients' keepalive pings (every 10 s, also between calls): gRPC's
#: default refuses pings more often than every 5 minutes and closes idle channels with
#: GOAWAY "too_many_pings".
SERVER_GRPC_OPTIONS = GRPC_OPTIONS + [
    ("grpc.http2.min_ping_interval_without_data_ms", 5_000),
    ("grpc.http2.max_ping_strikes", 0),
]
