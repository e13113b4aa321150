"""Contents on the Frames stream: lossless and compressed, encoded once (ahead, on a worker thread,
when the sender can), kept for resends within a memory bound; a live picture rides in the packet."""
from __future__ import annotations

import threading

import numpy as np

from coordinator.wire.frame_packets import EncodedContents, FramePackets
from coordinator.live_video import LiveEncoder
from coordinator.rig import Content
from protos import codec, common_pb2, node_pb2


def photo() -> np.ndarray:
    from skimage import data

    return data.astronaut()


def test_contents_travel_losslessly_compressed_and_are_encoded_once():
    c = Content(photo())
    packets = FramePackets()
    done = threading.Event()

    def prepare():
        packets.encoder().prepare([c])
        done.set()

    threading.Thread(target=prepare).start()
    assert done.wait(30)
    cached = packets.contents.get(c.content_id)
    assert cached is not None and cached.image.encoding == common_pb2.ENCODING_ZSTD_GRADIENT
    pkt = node_pb2.FramePacket.FromString(packets.encoder().packet(frame=None, contents=[c]))
    assert pkt.contents[0] == cached                      # the prepared form, not a second encoding
    back = codec.decode_image(pkt.contents[0].image)
    assert back.tobytes() == c.image.tobytes()            # bit-exact
    assert len(cached.image.data) < 0.7 * c.image.nbytes       # a detailed photograph: 0.57 measured


def test_the_cache_of_encoded_contents_is_bounded_least_recently_used_first():
    cache = EncodedContents(max_bytes=1000)
    msgs = {k: node_pb2.Content(content_id=k, image=common_pb2.Image(data=bytes(400))) for k in "abc"}
    cache.put("a", msgs["a"])
    cache.put("b", msgs["b"])
    assert cache.get("a") is msgs["a"]                    # a is now the most recent
    cache.put("c", msgs["c"])                             # 1200 bytes: b goes
    assert cache.get("b") is None and cache.get("a") is msgs["a"] and cache.get("c") is msgs["c"]


def test_a_live_picture_rides_in_the_packet_with_its_frame():
    pic = LiveEncoder(width=64, height=48, channels=3, bit_depth=8, fps=30).encode(np.zeros((48, 64, 3), np.uint8))
    enc = FramePackets().encoder()
    data = enc.packet(frame=None, contents=[], video=pic)
    v = node_pb2.FramePacket.FromString(data).video
    assert (v.stream_id, v.sequence, v.keyframe, v.data, v.content_id) == \
        (pic.stream_id, 0, True, pic.data, pic.content_id)
    assert (v.width, v.height, v.channels, v.bit_depth, v.codec) == (64, 48, 3, 8, node_pb2.VIDEO_CODEC_H264)
