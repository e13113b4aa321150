"""The Frames stream's packets: contents, live pictures and frames serialized for the nodes.

A :class:`FramePackets` belongs to one fan-out (:class:`coordinator.fanout.FanOut` makes its own from
the factory it is given): it owns the cache of contents already encoded, so each content is encoded
once whatever the packet count, and two coordinators in one process share nothing. Its
:meth:`FramePackets.encoder` makes the :class:`PacketEncoder` of one send.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Iterable, Sequence

from coordinator.fanout import Frame
from coordinator.live_video import EncodedPicture
from coordinator.rig import Content
from coordinator.wire.node_messages import space_message
from protos import codec, node_pb2

#: bytes of encoded contents a fan-out keeps for resends, late joiners and retries
ENCODED_CONTENTS_BYTES = 256 * 2**20


def content_message(content: Content, *, compress: bool = True) -> node_pb2.Content:
    """The wire form of ``content`` (encode once, reuse for every packet); lossless, compressed
    (protos/codec.py's gradient + zstd) unless ``compress`` is false."""
    return node_pb2.Content(content_id=content.content_id, image=codec.encode_image(content.image, compress=compress))


_VIDEO_CODECS = {"h264": node_pb2.VIDEO_CODEC_H264, "hevc": node_pb2.VIDEO_CODEC_HEVC}


def video_message(pic: EncodedPicture) -> node_pb2.VideoPacket:
    """The wire form of one encoded live picture (:mod:`coordinator.live_video`)."""
    return node_pb2.VideoPacket(stream_id=pic.stream_id, sequence=pic.sequence, keyframe=pic.keyframe, data=pic.data,
                                width=pic.width, height=pic.height, channels=pic.channels, bit_depth=pic.bit_depth,
                                codec=_VIDEO_CODECS[pic.codec], content_id=pic.content_id)


class EncodedContents:
    """Wire forms of contents by id, shared by every :class:`PacketEncoder` of one :class:`FramePackets`.

    A content id is a hash of its pixels (:func:`coordinator.rig.content_id_of`), so an entry never
    goes stale; the least recently used go beyond ``max_bytes``. Filled from worker threads too
    (:meth:`PacketEncoder.prepare`), hence the lock.
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes
        self._items: OrderedDict[str, node_pb2.Content] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, cid: str) -> node_pb2.Content | None:
        with self._lock:
            msg = self._items.get(cid)
            if msg is not None:
                self._items.move_to_end(cid)
            return msg

    def put(self, cid: str, msg: node_pb2.Content) -> None:
        with self._lock:
            if cid in self._items:
                return
            self._items[cid] = msg
            self._bytes += len(msg.image.data)
            while self._bytes > self.max_bytes and len(self._items) > 1:
                _, old = self._items.popitem(last=False)
                self._bytes -= len(old.image.data)


class PacketEncoder:
    """Serializes the Frames packets of one send; each content is encoded once (then kept in the
    ``contents`` cache it is given), whatever the packet count."""

    def __init__(self, contents: EncodedContents) -> None:
        self._cache = contents
        self._contents: dict[str, node_pb2.Content] = {}
        self._video: tuple[EncodedPicture, node_pb2.VideoPacket] | None = None

    def prepare(self, contents: Iterable[Content]) -> None:
        """Encode ``contents`` now (callable from a worker thread), so sends find them encoded."""
        for c in contents:
            self._content(c)

    def _content(self, c: Content) -> node_pb2.Content:
        msg = self._contents.get(c.content_id) or self._cache.get(c.content_id)
        if msg is None:
            msg = content_message(c)
            self._cache.put(c.content_id, msg)
        self._contents[c.content_id] = msg
        return msg

    def packet(self, *, frame: Frame | None, contents: Sequence[Content], evict: Sequence[str] = (),
               video: EncodedPicture | None = None) -> bytes:
        pkt = node_pb2.FramePacket()
        for c in contents:
            pkt.contents.append(self._content(c))
        if video is not None:
            if self._video is None or self._video[0] is not video:
                self._video = (video, video_message(video))
            pkt.video.CopyFrom(self._video[1])
        if frame is not None:
            pkt.frame.CopyFrom(node_pb2.Frame(frame_id=frame.frame_id, pts_ns=frame.pts_ns, content_id=frame.content_id,
                                              space=space_message(frame.space), apply_lut=frame.apply_lut,
                                              tag=frame.tag, slot_content=frame.slot_content,
                                              fade_ns=frame.fade_ns, fade_steps=frame.fade_steps))
        if evict:
            pkt.evict.content_ids.extend(evict)
        return pkt.SerializeToString()


class FramePackets:
    """The packet encoding of one fan-out: its own cache of encoded contents (``max_bytes`` at most)
    and a :class:`PacketEncoder` per send (:meth:`encoder`)."""

    def __init__(self, max_bytes: int = ENCODED_CONTENTS_BYTES) -> None:
        self.contents = EncodedContents(max_bytes)

    def encoder(self) -> PacketEncoder:
        return PacketEncoder(self.contents)
