"""The exposure a mesh measurement runs at, against a camera model with a known white: the white lands at the
headroom, one capture whatever the rig unless the probe itself clips, and a fixed camera is warned about; the
dots captured longer come back in the white's units, a pattern that clips is taken again."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

from imaging.compensation.exposure import (
    DOT_GAIN_MAX,
    DOT_HEADROOM,
    HEADROOM,
    PROBE,
    dot_exposure,
    dot_gain,
    exposure_for_white,
)


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


@pytest.mark.parametrize("peak, gain", [(0.06, 10.0), (0.3, 2.0), (0.6, 1.0), (0.95, 1.0), (0.001, DOT_GAIN_MAX)])
def test_the_dots_are_captured_as_much_longer_as_their_first_pattern_allows(peak, gain):
    assert dot_gain(peak, adjustable=True) == pytest.approx(gain)
    # the first pattern lands at the dots' headroom unless the gain is capped (or a dot is as bright as the white)
    if 1.0 < gain < DOT_GAIN_MAX:
        assert peak * dot_gain(peak, adjustable=True) == pytest.approx(DOT_HEADROOM)
    assert dot_gain(peak, adjustable=False) == 1.0
    assert dot_gain(float("nan"), adjustable=True) == dot_gain(0.0, adjustable=True) == 1.0


class Dots:
    """A camera over a dot pattern whose brightest pixel is ``peak`` of full scale at the camera's own exposure,
    plus a black level; 12-bit, clipped; ``bright`` patterns are four times brighter."""

    def __init__(self, peak: float, bright: tuple[int, ...] = ()) -> None:
        self.peak, self.bright, self.shots, self.k = peak, bright, [], None
        rng = np.random.default_rng(0)
        self.scene = rng.random((6, 6, 3)).astype(np.float32)
        self.scene /= self.scene.max()

    def show(self, k: int | None) -> None:
        self.k = k

    async def shown(self, k: int | None) -> None:
        self.show(k)

    async def capture(self, exposure: float | None, frames: int) -> np.ndarray:
        e = 1.0 if exposure is None else exposure
        self.shots.append((self.k, exposure, frames))
        lit = 0.0 if self.k is None else self.peak * (4.0 if self.k in self.bright else 1.0)
        return np.round(np.clip((0.01 + self.scene * lit) * e, 0, 1) * 4095) / 4095


def test_the_dots_come_back_in_the_whites_units_and_a_clipped_pattern_is_taken_again():
    cam = Dots(0.1, bright=(2,))
    black = asyncio.run(cam.capture(0.5, 1))
    logs = []
    dots = asyncio.run(dot_exposure(cam.capture, show_first=lambda: cam.shown(0), show_black=lambda: cam.shown(None),
                                    black=black, exposure=0.5, adjustable=True, frames=3, log=logs.append))
    # the first pattern at the white's exposure peaks at 0.055: 0.6 / 0.055 times longer, then the black at that
    assert dots.gain == pytest.approx(DOT_HEADROOM / 0.055, rel=2e-3) and dots.gain < DOT_GAIN_MAX
    assert cam.shots[1:] == [(0, 0.5, 1), (None, dots.long, 3)] and dots.long == pytest.approx(0.5 * dots.gain)
    assert any("times the white's exposure" in m for m in logs)
    for k in range(3):
        cam.show(k)
        img = asyncio.run(dots.take(k, cam.capture, 3))
        direct = (0.01 + cam.scene * cam.peak * (4.0 if k == 2 else 1.0)) * 0.5      # what the white's exposure sees
        # within the quantisation of the black at the white's exposure, and of the long captures over the gain
        np.testing.assert_allclose(img, direct, atol=0.5 / 4095 + (0 if k == 2 else 1 / 4095 / dots.gain) + 1e-6)
    # pattern 2 clipped at the longer exposure: captured again at the white's, once
    assert dots.again == [2] and dots.clipped == [] and cam.shots[-2:] == [(2, dots.long, 3), (2, 0.5, 3)]
    dots.report(3, logs.append)
    assert "1 of 3 dot patterns clipped" in logs[-1] and not any("warning" in m for m in logs)


def test_a_fixed_camera_captures_the_dots_at_its_own_exposure_and_is_warned_when_they_clip():
    cam = Dots(1.5)
    black = asyncio.run(cam.capture(None, 1))
    logs = []
    dots = asyncio.run(dot_exposure(cam.capture, show_first=lambda: cam.shown(0), show_black=lambda: cam.shown(None),
                                    black=black, exposure=None, adjustable=False, frames=1, log=logs.append))
    assert dots.gain == 1.0 and len(cam.shots) == 1 and not logs          # nothing captured to decide
    cam.show(0)
    img = asyncio.run(dots.take(0, cam.capture, 1))
    assert float(img.max()) == 1.0 and dots.clipped == [0] and dots.again == []
    dots.report(1, logs.append)
    assert logs[-1].startswith("warning: 1 of 1 dot patterns reached the camera's full scale")
