"""rigctl/mpcdi/pfm.py against OpenCV's PFM codec."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigctl.mpcdi.pfm import decode_pfm, encode_pfm


@pytest.mark.parametrize("channels", [1, 3])
def test_opencv_reads_what_we_write_and_we_read_what_it_writes(tmp_path, channels):
    rng = np.random.default_rng(channels)
    img = rng.normal(0, 10, (7, 11, channels)).astype(np.float32)
    img[2, 3, 0] = np.nan
    (tmp_path / "a.pfm").write_bytes(encode_pfm(img))
    got = cv2.imread(str(tmp_path / "a.pfm"), cv2.IMREAD_UNCHANGED)
    got = got[:, :, None] if got.ndim == 2 else got[:, :, ::-1]      # OpenCV hands 3 channels as BGR
    np.testing.assert_array_equal(got, img)
    cv2.imwrite(str(tmp_path / "b.pfm"), img[:, :, 0] if channels == 1 else img[:, :, ::-1])
    np.testing.assert_array_equal(decode_pfm((tmp_path / "b.pfm").read_bytes()), img)


def test_big_endian_and_errors():
    img = np.arange(6, dtype=np.float32).reshape(2, 3, 1)
    be = b"Pf\n3 2\n1.0\n" + img[::-1].astype(">f4").tobytes()
    np.testing.assert_array_equal(decode_pfm(be), img)
    with pytest.raises(ValueError, match="x.pfm: not a PFM"):
        decode_pfm(b"P6\n1 1\n255\n\0\0\0", name="x.pfm")
    with pytest.raises(ValueError, match="cut short"):
        decode_pfm(be[:-4])
    with pytest.raises(ValueError, match="holds"):
        encode_pfm(np.zeros((2, 2, 2)))
