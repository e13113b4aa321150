"""The wire package: generated code is fresh, images round-trip, proofs bind their inputs."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from protos import auth, codec, common_pb2

ROOT = Path(__file__).resolve().parents[2]


def test_generated_code_is_not_stale():
    result = subprocess.run(
        [sys.executable, str(ROOT / "protos" / "generate.py"), "--check"], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float16, np.float32])
@pytest.mark.parametrize("compress", [False, True])
def test_image_round_trip_is_lossless(dtype, compress):
    rng = np.random.default_rng(1)
    if np.issubdtype(dtype, np.integer):
        img = rng.integers(0, np.iinfo(dtype).max, size=(7, 5, 3), endpoint=True).astype(dtype)
    else:
        img = rng.random((7, 5, 3)).astype(dtype)
    msg = codec.encode_image(img, compress=compress)
    back = codec.decode_image(common_pb2.Image.FromString(msg.SerializeToString()))
    assert back.dtype == img.dtype and back.shape == img.shape
    np.testing.assert_array_equal(back, img)


def test_grey_image_gains_a_channel_axis():
    img = np.arange(12, dtype=np.uint16).reshape(3, 4)
    assert codec.decode_image(codec.encode_image(img)).shape == (3, 4, 1)


def test_truncated_image_is_refused_with_sizes():
    msg = codec.encode_image(np.zeros((4, 4, 3), np.uint8))
    msg.data = msg.data[:-1]
    with pytest.raises(codec.ImageCodecError, match="47 bytes.*needs 48"):
        codec.decode_image(msg)


def test_bad_shapes_and_dtypes_raise_value_error():
    with pytest.raises(ValueError):
        codec.encode_image(np.zeros((2, 2, 5), np.uint8))
    with pytest.raises(ValueError):
        codec.encode_image(np.zeros((2, 2), np.int32))


def test_proofs_bind_every_input():
    token, cn, sn = b"t" * 32, auth.new_nonce(), auth.new_nonce()
    base = auth.client_proof(token, "node", "rig", "r0c0", cn, sn)
    assert auth.verify(base, auth.client_proof(token, "node", "rig", "r0c0", cn, sn))
    variants = [
        auth.client_proof(b"u" * 32, "node", "rig", "r0c0", cn, sn),
        auth.client_proof(token, "operator", "rig", "r0c0", cn, sn),
        auth.client_proof(token, "node", "rig2", "r0c0", cn, sn),
        auth.client_proof(token, "node", "rig", "r0c1", cn, sn),
        auth.client_proof(token, "node", "rig", "r0c0", sn, cn),
        auth.coordinator_proof(token, "rig", cn, sn),
    ]
    assert all(not auth.verify(base, v) for v in variants)


def test_token_file_errors_name_the_file(tmp_path):
    with pytest.raises(auth.TokenError, match="does not exist"):
        auth.read_token(tmp_path / "missing")
    short = tmp_path / "short"
    short.write_text("abc\n")
    with pytest.raises(auth.TokenError, match=str(short)):
        auth.read_token(short)
    good = tmp_path / "token"
    good.write_text(auth.new_token() + "\n")
    for mode, who in ((0o644, "its group and every user"), (0o640, "its group"), (0o604, "every user")):
        good.chmod(mode)
        with pytest.raises(auth.TokenError, match=f"read by {who} \\(mode 0{mode:o}\\).*chmod 600 {good}"):
            auth.read_token(good)
    good.chmod(0o600)
    assert len(auth.read_token(good)) >= 32
    for name, data, says in (("empty", b"", "is empty"), ("blank", b" \n\n", "is empty"),
                             ("binary", b"\xff\xd8\xff\xe0", "is not text"), ("nul", b"a" * 20 + b"\x00" * 4, "not a token"),
                             ("words", b"two words-of-a-token-here", "not a token")):
        f = tmp_path / name
        f.write_bytes(data)
        f.chmod(0o600)
        with pytest.raises(auth.TokenError, match=f"{f} .*{says}") as exc:
            auth.read_token(f)
        assert "\n" not in str(exc.value)
    with pytest.raises(auth.TokenError, match="is a directory"):
        auth.read_token(tmp_path)
