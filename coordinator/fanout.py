"""Frame fan-out: one serialized packet per group of nodes that lack the same contents.

Contents are encoded once per send and each distinct packet is serialized once; the same
bytes go to every node of its group, so the coordinator's cost per frame does not grow with
the node count beyond the queue appends. A node is sent only the content its own slot
shows, and only once until it is evicted. A live video picture
(:class:`coordinator.live_video.EncodedPicture`) goes to every node of the send: each node needs
every picture of its stream to decode the next.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Mapping, Protocol, Sequence

from coordinator.api import Space
from coordinator.live_video import EncodedPicture
from coordinator.rig import Content
from coordinator.sessions import NodeSession
from coordinator.sync import SyncTracker
from protos.fade import step_pts


@dataclass(frozen=True)
class Frame:
    """One frame for every node: content ``content_id`` (or a per-slot override) at ``pts_ns``."""

    frame_id: int
    pts_ns: int                         # presentation time on the rig clock
    content_id: str                     # "" shows black
    space: Space
    apply_lut: bool
    tag: str                            # what it belongs to: "show", "play:…", "pattern"
    slot_content: Mapping[str, str] = field(default_factory=dict)   # slot -> content id ("" = black)
    fade_ns: int = 0                    # a crossfade from what is on screen (protos/fade.py)
    fade_steps: int = 0                 # reported as frame_id + 1 .. frame_id + fade_steps

    def content_for(self, slot: str) -> str:
        return self.slot_content[slot] if slot in self.slot_content else self.content_id


class PacketEncoder(Protocol):
    """Serializes the packets of one send (each content encoded once for all of them)."""

    def prepare(self, contents: Iterable[Content]) -> None: ...

    def packet(self, *, frame: Frame | None, contents: Sequence[Content], evict: Sequence[str] = (),
               video: EncodedPicture | None = None) -> bytes: ...


class PacketEncoding(Protocol):
    """The packet encoding a fan-out owns: what it keeps between sends (contents already encoded)
    and a :class:`PacketEncoder` per send."""

    def encoder(self) -> PacketEncoder: ...


class FanOut:
    """Queues frames and their contents for node sessions and tells the sync tracker what to expect.

    ``encoding`` is a factory (the wire's :class:`coordinator.wire.frame_packets.FramePackets`): the
    fan-out makes its own encoding from it, so what one fan-out keeps encoded is nobody else's, and
    asks it for an encoder per send, so contents are encoded once per send.
    """

    def __init__(self, sync: SyncTracker, encoding: Callable[[], PacketEncoding]):
        self.sync = sync
        self.encoding = encoding()
        #: CPU seconds spent building and serializing packets
        self.encode_cpu_s = 0.0

    def prepare(self, contents: Iterable[Content]) -> None:
        """Encode ``contents`` for the wire ahead of their send (thread-safe: run it on a worker
        thread, so a large still or pattern is not encoded on the event loop after its frame's
        presentation time was fixed)."""
        self.encoding.encoder().prepare(contents)

    def send(self, sessions: Iterable[NodeSession], *, frame: Frame | None = None,
             contents: Mapping[str, Content] | None = None, evict: Sequence[str] = (),
             video: EncodedPicture | None = None) -> None:
        t0 = time.thread_time()
        sessions = list(sessions)
        contents = contents or {}
        groups: dict[frozenset[str], list[NodeSession]] = {}
        for s in sessions:
            needed = ({frame.content_for(s.slot)} & contents.keys()) if frame is not None else set(contents)
            missing = frozenset(cid for cid in needed if cid not in s.sent_content)
            groups.setdefault(missing, []).append(s)
        encoder = self.encoding.encoder()
        for missing, members in groups.items():
            data = encoder.packet(frame=frame, contents=[contents[cid] for cid in sorted(missing)], evict=evict,
                                  video=video)
            self.encode_cpu_s += time.thread_time() - t0
            for s in members:
                s.push(data)
                s.sent_content |= missing
                if evict:
                    s.sent_content.difference_update(evict)
            t0 = time.thread_time()
        if frame is not None:
            self.sync.expect(frame.frame_id, frame.pts_ns, frame.tag, {s.slot for s in sessions})
            for k in range(1, frame.fade_steps + 1):      # a crossfade's steps, each a frame of its own
                self.sync.expect(frame.frame_id + k, step_pts(frame.pts_ns, frame.fade_ns, k, frame.fade_steps),
                                 frame.tag, {s.slot for s in sessions})
