"""`shadowless configure --lut`: a (3, E) LUT is a curve per channel, an (E,) LUT one curve for
every channel (stored and sent as (1, E), which the renderer repeats for R, G and B); any other
shape or value is refused in one line before anything is sent (the corpus: test_bad_args.py)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from rigctl.client import OperatorError
from rigctl.commands import read_lut
from coordinator.rig import Rig, init_rig


def test_read_lut_shapes(tmp_path):
    curve = np.linspace(0, 1, 256) ** 2.2                       # float64 on disk
    np.save(tmp_path / "one.npy", curve)
    lut = read_lut(tmp_path / "one.npy")
    assert lut.shape == (1, 256) and lut.dtype == np.float32
    np.testing.assert_array_equal(lut[0], curve.astype(np.float32))
    three = np.stack([curve, curve ** 0.5, curve ** 2]).astype(np.float32)
    np.save(tmp_path / "three.npy", three)
    np.testing.assert_array_equal(read_lut(tmp_path / "three.npy"), three)
    np.save(tmp_path / "nan.npy", np.array([0.0, np.nan, 1.0], np.float32))
    with pytest.raises(OperatorError, match=r"nan\.npy: LUT values must be finite"):
        read_lut(tmp_path / "nan.npy")


def test_a_one_dimensional_lut_reaches_the_rig_as_one_curve_for_every_channel(tmp_path, coordinator_process):
    rig_dir = init_rig(tmp_path / "rig", name="luts", slots=["r0c0"], width=32, height=32)
    curve = np.linspace(0, 1, 64, dtype=np.float32) ** 0.5
    np.save(tmp_path / "curve.npy", curve)
    address = coordinator_process(rig_dir)
    r = subprocess.run([sys.executable, "-m", "shadowless", "configure", "--slot", "r0c0", "--lut",
                        str(tmp_path / "curve.npy"), "--coordinator", address, "--rig-dir", str(rig_dir)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "now at revision" in r.stdout, r.stderr
    stored = Rig(rig_dir, read_only=True).slots["r0c0"].lut
    assert stored.shape == (1, 64)
    np.testing.assert_array_equal(stored[0], curve)
