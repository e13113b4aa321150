"""Wire protocol version. Every Hello/Join carries it; a mismatch is refused."""
import os
import re

#: 2: frame contents may be packed ENCODING_ZSTD_GRADIENT and sequences travel as live video
#: (FramePacket.video), which a version-1 node could not show.
#: 3: a report's swaps travel as delta-coded columns (NodeReport.swaps, a Swaps message).
#: 4: Show is a client stream and images travel in parts of at most 1 MiB, so the coordinator
#: accepts small messages only (MAX_REQUEST_BYTES); Stop can black out; fit modes.
PROTOCOL_VERSION = 4

#: the software's own version (pyproject.toml says the same; a test checks): what ``shadowless
#: --version`` prints and a node reports when it joins. Kept here, not read through importlib.metadata,
#: whose 31 modules cost a node's network process 1.4 MB resident for this one string.
SOFTWARE_VERSION = "0.1.0"


def _service_type() -> str:
    """``_NAME._tcp.local.`` with ``_NAME`` from ``SHADOWLESS_MDNS_SERVICE`` (unset or empty: ``_shadowless``).

    NAME follows RFC 6763's service names: 1 to 15 letters, digits and single hyphens, starting and
    ending with a letter or digit. A process started with another value stops at once with one line
    naming it (every program of the rig reads this on start), not at its first advertisement.
    """
    name = os.environ.get("SHADOWLESS_MDNS_SERVICE") or "_shadowless"  # set but empty: the default
    if not re.fullmatch(r"_(?=.*[A-Za-z])(?!.*--)[A-Za-z0-9](?:[A-Za-z0-9-]{0,13}[A-Za-z0-9])?", name):
        raise SystemExit(f"SHADOWLESS_MDNS_SERVICE={name!r} is not an mDNS service name: '_' and then 1 to 15 "
                         "letters, digits or single hyphens, starting and ending with a letter or digit "
                         "(e.g. _shadowless-b)")
    return name + "._tcp.local."


#: mDNS service type the coordinator advertises. ``SHADOWLESS_MDNS_SERVICE`` (e.g. ``_shadowless-b``)
#: gives rigs that must not see each other on one network, such as test sessions run side by
#: side, a service of their own.
SERVICE_TYPE = _service_type()

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

#: Largest message the coordinator accepts. Everything that reaches it is small (handshakes,
#: reports, 1 MiB upload chunks, images in 1 MiB parts). gRPC refuses a larger message with
#: RESOURCE_EXHAUSTED, but may hold much of it first (grpc/grpc#43012), so this alone does not bound
#: what an unauthenticated peer makes the coordinator buffer: the receive window does
#: (COORDINATOR_WINDOW_BYTES).
MAX_REQUEST_BYTES = 4 * 1024 * 1024

#: The coordinator's HTTP/2 receive window per stream. gRPC's bandwidth-delay probe would grow it
#: on a fast link until a peer can push hundreds of MiB of an oversized message into memory
#: before the refusal (4 peers sending 200 MiB made a bare server, 33 MiB idle, peak at up to
#: 278 MiB; with the probe off and this window, at 39-43 MiB). 1 MiB allows ~1 GB/s over a 1 ms
#: round trip, beyond a venue's gigabit link. Nodes keep the probe: their large downloads need it.
COORDINATOR_WINDOW_BYTES = 1024 * 1024

#: Servers accept the clients' keepalive pings (every 10 s, also between calls): gRPC's
#: default refuses pings more often than every 5 minutes and closes idle channels with
#: GOAWAY "too_many_pings".
SERVER_GRPC_OPTIONS = GRPC_OPTIONS + [
    ("grpc.http2.min_ping_interval_without_data_ms", 5_000),
    ("grpc.http2.max_ping_strikes", 0),
]

#: The coordinator's server: small messages in (MAX_REQUEST_BYTES), large frames out.
COORDINATOR_GRPC_OPTIONS = [(k, MAX_REQUEST_BYTES if k == "grpc.max_receive_message_length" else v)
                            for k, v in SERVER_GRPC_OPTIONS] + [
    ("grpc.http2.bdp_probe", 0),
    ("grpc.http2.lookahead_bytes", COORDINATOR_WINDOW_BYTES),
]
