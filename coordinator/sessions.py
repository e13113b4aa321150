"""Who is talking to the coordinator: the rig-token handshake, node sessions and operator
sessions.

Both nodes and operators first prove they know the rig's token (Hello, then Join or
Login; nonces are single use and expire), then carry a session id in their calls' metadata.
A node's session holds its outgoing packet queue and what it reported last.
"""
from __future__ import annotations

import asyncio
import hashlib
import hmac
import logging
import secrets
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Iterable

import numpy as np

from coordinator.api import AssetProgress, NodeShow, NodeState
from coordinator.errors import Refusal, RefusalKind
from coordinator.previews import Preview
from coordinator.refusals import MAX_SLOT_CHARS, clipped, peer_address
from coordinator.schema import SLOT_RE
from protos import auth
from protos.host import boot_id
from protos.records import NodeInfo  # what a node says about itself, one definition with the node's
from protos.version import PROTOCOL_VERSION

log = logging.getLogger(__name__)

NONCE_TTL_S = 30.0
#: used nonces kept before the expired ones are swept (only logins that proved the token add one)
MAX_USED_NONCES = 1024
MAX_OPERATOR_SESSIONS = 256
OPERATOR_SESSION_TTL_S = 12 * 3600.0
MAX_PENDING_PACKETS = 512


@dataclass(frozen=True)
class Heartbeat:
    """A node's periodic state: its clock estimate and the assignment it renders with."""

    assignment_revision: int = 0
    clock_offset_ns: int = 0
    clock_drift_ppm: float = 0.0
    clock_rtt_ns: int = 0
    host_monotonic_ns: int = 0
    rig_estimate_ns: int = 0
    assets: tuple[AssetProgress, ...] = ()   # the node's progress with the assets it was told it wants
    show: NodeShow = NodeShow()              # the show as the node follows it
    blend_id: str = ""                       # the blend maps on the node's screen ("": none)
    blend_since_rig_ns: int = 0              # pts of the first frame the node showed with them (0: none)
    decoder: str = ""                        # what it decodes videos with ("software", "h264_v4l2m2m"; "" unknown)
    decoder_note: str = ""                   # why its --decoder wish was not granted ("" it was)
    assignment_refused: str = ""             # the newest assignment it refused: "rN: why" ("" none)


@dataclass(frozen=True, eq=False)
class Swaps:
    """A node's swaps in one report, as columns of the same length n (int64, shape (n,)):
    ``frame_id``, ``swap_rig_ns`` (the node's estimate of the rig clock at the swap) and
    ``host_monotonic_ns`` (the node host's own monotonic clock at the swap)."""

    frame_id: np.ndarray
    swap_rig_ns: np.ndarray
    host_monotonic_ns: np.ndarray

    @classmethod
    def of(cls, rows: Iterable[tuple[int, int, int]] = ()) -> "Swaps":
        """From ``(frame_id, swap_rig_ns, host_monotonic_ns)`` rows."""
        cols = np.array(list(rows), dtype=np.int64).reshape(-1, 3)
        return cls(cols[:, 0].copy(), cols[:, 1].copy(), cols[:, 2].copy())

    def __len__(self) -> int:
        return int(self.frame_id.shape[0])


NO_SWAPS = Swaps.of()


@dataclass(frozen=True)
class Report:
    """One batch of what a node did: heartbeat, swaps, drops ``(frame_id, DropReason)``, and the
    preview it was asked for (a console thumbnail)."""

    heartbeat: Heartbeat | None = None
    swaps: Swaps = NO_SWAPS
    drops: tuple = ()
    preview: Preview | None = None
    goodbye: str = ""          # the node stops on purpose: why (its last report); "" not leaving


@dataclass(frozen=True)
class HelloResult:
    rig_id: str
    rig_name: str
    server_nonce: bytes
    server_proof: bytes
    instance_id: str


@dataclass
class NodeSession:
    """One joined node: its outgoing packets and what it reported."""

    session: str
    slot: str
    peer: str
    info: NodeInfo
    instance_joins: int
    joined: float
    last_seen: float
    state: NodeState = NodeState.JOINED
    closed: bool = False
    left: str = ""          # why the node stopped on purpose (its goodbye); "" it went silent or is here
    frames_open: bool = False
    packets: deque = field(default_factory=deque)
    packet_event: asyncio.Event = field(default_factory=asyncio.Event)
    assignment_event: asyncio.Event = field(default_factory=asyncio.Event)
    wanted_event: asyncio.Event = field(default_factory=asyncio.Event)   # the wanted assets changed
    preview_event: asyncio.Event = field(default_factory=asyncio.Event)  # its thumbnail became wanted
    sent_content: set[str] = field(default_factory=set)
    heartbeat: Heartbeat | None = None
    last_swap_frame: int = 0
    last_swap_at: float = 0.0
    shown: int = 0
    late: int = 0
    dropped: int = 0
    #: the pid of the node process on the same machine whose session this one took over (0: none)
    replaced_pid: int = 0
    still_frames: set[int] = field(default_factory=set)   # ids of still frames sent to this node
    still_retries: int = 0
    #: called when the node's backlog was dropped (it lost pictures of a live video: it needs a keyframe)
    on_backlog_dropped: Callable[[], None] = field(default=lambda: None, repr=False)
    #: events of the node's streams that wait on one of their own, set when the session closes
    _close_wakes: set[asyncio.Event] = field(default_factory=set, repr=False)

    @property
    def blend_id(self) -> str:
        """The blend on the node's screen as its last heartbeat said ("" none, or no heartbeat yet)."""
        return self.heartbeat.blend_id if self.heartbeat is not None else ""

    @property
    def blend_since_rig_ns(self) -> int:
        """The pts (rig clock) of the first frame the node showed with :attr:`blend_id` (0: none)."""
        return self.heartbeat.blend_since_rig_ns if self.heartbeat is not None else 0

    @property
    def same_host(self) -> bool:
        """Whether the node runs on the coordinator's host (its monotonic clock is the rig clock)."""
        return bool(boot_id()) and self.info.host_boot_id == boot_id()

    def push(self, packet: bytes) -> None:
        """Queue a serialized packet; a node that stopped draining loses its backlog (and gets contents again)."""
        if self.closed:
            return
        if len(self.packets) >= MAX_PENDING_PACKETS:
            log.warning("node %s is not keeping up; dropping %d queued packets", self.slot, len(self.packets))
            self.packets.clear()
            self.sent_content.clear()
            self.on_backlog_dropped()
        self.packets.append(packet)
        self.packet_event.set()

    def wake_on_close(self, event: asyncio.Event) -> Callable[[], None]:
        """``event`` is set when the session closes (at once if it is closed); returns the call that
        forgets it. For a stream that waits on an event of its own (the Show stream's, which the show's
        changes set), so that it ends with the session as the others do, not at its next beacon."""
        if self.closed:
            event.set()
        self._close_wakes.add(event)
        return lambda: self._close_wakes.discard(event)

    def close(self) -> None:
        self.closed = True
        self.packet_event.set()
        self.assignment_event.set()
        self.wanted_event.set()
        self.preview_event.set()
        for event in list(self._close_wakes):
            event.set()


class Handshake:
    """The rig-token handshake and the operator sessions it opens.

    Hello keeps no state: the server nonce carries its own expiry and a MAC (under a secret of
    this coordinator instance) over the client's nonce, so a flood of Hello calls fills no
    table and cannot push out the handshake of a node that is joining. Only nonces used in a
    login that proved the token are remembered (until they expire), so each is used once.

    Parameters
    ----------
    token : bytes
        The rig's secret.
    rig_id, rig_name, instance_id : str
    clock : callable
        Seconds, monotonic (injectable for tests).
    on_refusal : callable
        ``(peer, slot, message) -> line or None``, called for every refusal (the status counts
        them); a returned line is logged as a warning.
    """

    def __init__(self, token: bytes, *, rig_id: str, rig_name: str, instance_id: str, clock: Callable[[], float],
                 on_refusal: Callable[[str, str, str], str | None]):
        self.token = token
        self.rig_id, self.rig_name, self.instance_id = rig_id, rig_name, instance_id
        self.clock = clock
        self._on_refusal = on_refusal
        self._secret = secrets.token_bytes(32)
        self.used: dict[bytes, float] = {}                    # server nonces of proven logins -> expiry
        self.operators: dict[str, float] = {}                 # operator session -> last use

    def refuse(self, peer: str, slot: str, kind: RefusalKind, message: str) -> Refusal:
        """A :class:`~coordinator.errors.Refusal` to raise, counted (and logged as ``on_refusal`` says)."""
        line = self._on_refusal(peer, slot, message)
        if line:
            log.warning("%s", line)
        return Refusal(kind, message)

    def _nonce_mac(self, client_nonce: bytes, head: bytes) -> bytes:
        return hmac.new(self._secret, head + client_nonce, hashlib.sha256).digest()[:16]

    def _server_nonce(self, client_nonce: bytes, now: float) -> bytes:
        """32 bytes: expiry (ms, 8), random (8), MAC over them and the client's nonce (16)."""
        head = int((now + NONCE_TTL_S) * 1000).to_bytes(8, "big") + secrets.token_bytes(8)
        return head + self._nonce_mac(client_nonce, head)

    def _nonce_expiry(self, server_nonce: bytes, client_nonce: bytes) -> float | None:
        """The expiry (s) of a server nonce this instance issued for ``client_nonce``, else None."""
        if len(server_nonce) != auth.NONCE_BYTES:
            return None
        head, mac = server_nonce[:16], server_nonce[16:]
        if not hmac.compare_digest(mac, self._nonce_mac(client_nonce, head)):
            return None
        return int.from_bytes(head[:8], "big") / 1000.0

    def _check_slot_name(self, peer: str, slot: str) -> None:
        """A slot a peer claims is a slot name (or empty, for an operator): the name travels into
        replies, refusals and the log."""
        if slot and not SLOT_RE.match(slot):
            shown = clipped(slot, MAX_SLOT_CHARS)
            raise self.refuse(peer, shown, RefusalKind.INVALID,
                              f"{shown!r} is not a slot name (1-32 letters, digits, '_', '-' or '.')")

    def hello(self, *, protocol_version: int, client_nonce: bytes, role: str, slot: str, peer: str) -> HelloResult:
        """The first half: prove the coordinator knows the token and hand out a server nonce."""
        if protocol_version != PROTOCOL_VERSION:
            raise self.refuse(peer, slot, RefusalKind.FAILED_PRECONDITION,
                              f"protocol version mismatch: {clipped(role, 16) or 'client'} "
                              f"{clipped(slot, MAX_SLOT_CHARS)} speaks shadowless protocol "
                              f"{protocol_version}, coordinator of rig {self.rig_name!r} speaks {PROTOCOL_VERSION}; "
                              f"install the same shadowless release on both")
        if len(client_nonce) != auth.NONCE_BYTES:
            raise self.refuse(peer, slot, RefusalKind.INVALID, "client nonce must be 32 bytes")
        self._check_slot_name(peer, slot)
        server_nonce = self._server_nonce(client_nonce, self.clock())
        return HelloResult(rig_id=self.rig_id, rig_name=self.rig_name, server_nonce=server_nonce,
                           server_proof=auth.coordinator_proof(self.token, self.rig_id, client_nonce, server_nonce),
                           instance_id=self.instance_id)

    def check_login(self, *, protocol_version: int, role: str, slot: str, client_nonce: bytes, server_nonce: bytes,
                    client_proof: bytes, peer: str, expected_role: str) -> None:
        """The second half: the client proves it knows the token (each nonce once)."""
        if protocol_version != PROTOCOL_VERSION:
            raise self.refuse(peer, slot, RefusalKind.FAILED_PRECONDITION,
                              f"protocol version mismatch: {expected_role} speaks {protocol_version}, "
                              f"coordinator speaks {PROTOCOL_VERSION}")
        if role != expected_role:
            raise self.refuse(peer, slot, RefusalKind.INVALID,
                              f"this call is for role {clipped(expected_role, 16)!r}, not {clipped(role, 16)!r}")
        self._check_slot_name(peer, slot)
        now = self.clock()
        expiry = self._nonce_expiry(server_nonce, client_nonce)
        if expiry is None or expiry < now or server_nonce in self.used:
            raise self.refuse(peer, slot, RefusalKind.UNAUTHENTICATED,
                              "handshake expired or unknown: call Hello again (nonces are single use)")
        expected = auth.client_proof(self.token, expected_role, self.rig_id, slot, client_nonce, server_nonce)
        if not auth.verify(expected, client_proof):
            who = f"node {slot}" if expected_role == "node" else "operator"
            raise self.refuse(peer, slot, RefusalKind.UNAUTHENTICATED,
                              f"rig token mismatch: {who} at {peer_address(peer)} does not know the token of rig "
                              f"{self.rig_name!r} (id {self.rig_id}); give it this rig's token file")
        if len(self.used) >= MAX_USED_NONCES:   # only proven logins get here: forget the expired ones
            for n, exp in list(self.used.items()):
                if exp < now:
                    del self.used[n]
        self.used[server_nonce] = expiry

    def open_operator_session(self) -> str:
        """A new operator session id (the oldest are forgotten beyond MAX_OPERATOR_SESSIONS)."""
        session = secrets.token_hex(16)
        self.operators[session] = self.clock()
        if len(self.operators) > MAX_OPERATOR_SESSIONS:   # every CLI call logs in: forget the oldest
            for old in sorted(self.operators, key=self.operators.get)[: len(self.operators) - MAX_OPERATOR_SESSIONS]:
                del self.operators[old]
        return session

    def check_operator(self, session: str) -> None:
        """Refuse a call without a live operator session (idle sessions expire)."""
        now = self.clock()
        if session not in self.operators or now - self.operators[session] > OPERATOR_SESSION_TTL_S:
            self.operators.pop(session, None)
            raise Refusal(RefusalKind.UNAUTHENTICATED, "not logged in: call Hello and Login with the rig token")
        self.operators[session] = now
