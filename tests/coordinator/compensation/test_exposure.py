"""The exposure a mesh measurement runs at, against a camera model with a known white: the white lands at the
headroom, one capture whatever the rig unless the probe itself clips, and a fixed camera is warned about."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

from coordinator.compensation.exposure import HEADROOM, PROBE, exposure_for_white


class Camera:
    """A camera whose brightest pixel is ``white`` (a share of full scale at its own exposure); 8-bit, clipped."""

    def __init__(self, white: float) -> None:
        self.white, self.exposures = white, []
        self.scene = np.linspace(0, 1, 64, dtype=np.float32).reshape(8, 8, 1).repeat(3, axis=2)

    async def capture(self, exposure: float | None) -> np.ndarray:
        self.exposures.append(exposure)
        e = 1.0 if exposure is None else exposure
        return np.round(np.clip(self.scene * self.white * e, 0, 1) * 255) / 255


def _run(white: float, adjustable: bool = True) -> tuple[float, float, Camera, list[str]]:
    cam, logs = Camera(white), []
    e, peak = asyncio.run(exposure_for_white(cam.capture, adjustable=adjustable, log=logs.append))
    return e, peak, cam, logs


@pytest.mark.parametrize("white", [0.1, 0.85, 1.3, 3.5])
def test_the_white_lands_at_the_headroom_in_one_capture(white):
    e, peak, cam, logs = _run(white)
    assert cam.exposures == [PROBE]
    assert peak == pytest.approx(white, abs=4 / 255 / PROBE)
    assert e == (1.0 if white <= HEADROOM else pytest.approx(HEADROOM / white, rel=0.02))
    assert (e < 1.0) == bool(logs) and not any("warning" in m for m in logs)


def test_a_white_past_the_probe_halves_the_exposure_until_it_is_read():
    e, peak, cam, logs = _run(20.0)
    assert cam.exposures == [PROBE, PROBE / 2, PROBE / 4, PROBE / 8]      # 20 x 1/32 = 0.63: read
    assert peak == pytest.approx(20.0, rel=0.02) and e == pytest.approx(HEADROOM / 20.0, rel=0.02)


def test_a_camera_that_cannot_change_its_exposure_keeps_it_and_is_warned_when_it_clips():
    e, peak, cam, logs = _run(1.6, adjustable=False)
    assert e == 1.0 and cam.exposures == [None] and any("warning" in m and "clip" in m for m in logs)
    e, peak, cam, logs = _run(0.5, adjustable=False)
    assert e == 1.0 and peak == pytest.approx(0.5, abs=0.01) and not logs
