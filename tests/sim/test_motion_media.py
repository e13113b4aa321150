"""The motion study's pictures: the movie decodes back to what was drawn, the plot draws every system."""
from __future__ import annotations

import av
import cv2
import numpy as np
import pytest

from sim.motion import MotionFrame, MotionResult
from sim.motion_media import COLORS, MotionMovie, light_to_grey, nice_step, plot_png


def test_grey_levels_are_the_stated_gamma():
    np.testing.assert_array_equal(light_to_grey(np.array([0.0, 0.5, 1.0, 1.6, 3.0])),
                                  np.round(255 * np.clip(np.array([0.0, 0.5, 1.0, 1.6, 3.0]) / 1.6, 0, 1) ** (1 / 2.2)).astype(np.uint8))
    assert light_to_grey(np.array([1.0]))[0] == 206


@pytest.mark.parametrize(("span", "step"), [(1.0, 0.2), (97.0, 20.0), (0.5, 0.1), (4.99, 1.0), (1234.0, 500.0), (0.0, 1.0)])
def test_nice_steps(span, step):
    assert nice_step(span) == pytest.approx(step)


def _frames(n: int, shape=(60, 80)):
    hr, wr = shape
    table = np.ones(hr * wr, bool)
    for k in range(n):
        dark = np.ones(hr * wr, np.float32)
        dark.reshape(shape)[20:40, 10 + 5 * k:30 + 5 * k] = 0.0  # a black square moving right
        bright = np.full(hr * wr, 1.5, np.float32)
        hand = np.zeros(hr * wr, bool)
        yield MotionFrame(k, k / 10.0, shape, {"A": dark, "B": bright}, hand, table)


def test_movie_decodes_to_the_panels_drawn(tmp_path):
    path = tmp_path / "m.mp4"
    with MotionMovie(path, [("A", "a system"), ("B", "another")], fps=10, shape=(60, 80), note="test") as movie:
        frames = list(_frames(4))
        for f in frames:
            movie.add(f)
        expected = movie.picture(frames[2])
        size = movie.size
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        assert stream.codec_context.name == "h264" and (stream.width, stream.height) == size
        decoded = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)]
    assert len(decoded) == 4
    got = decoded[2].astype(np.float64)
    top = MotionMovie.HEADER
    x_a, x_b = MotionMovie.GAP, 2 * MotionMovie.GAP + 80
    assert np.abs(got[top + 28, x_a + 30] - 0).max() < 20  # inside the black square (moved 10 px)
    assert np.abs(got[top + 5, x_a + 5] - 206).max() < 12  # intended light
    assert np.abs(got[top + 30, x_b + 40] - light_to_grey(np.array([1.5]))[0]).max() < 12  # over-bright
    # the whole picture, within H.264's loss
    assert np.abs(got - expected.astype(np.float64)).mean() < 6.0


def test_movie_refuses_another_shape(tmp_path):
    with MotionMovie(tmp_path / "m.mp4", [("A", "")], fps=10, shape=(60, 80)) as movie, pytest.raises(ValueError, match="shape"):
        movie.add(next(_frames(1, shape=(50, 80))))
    with pytest.raises(ValueError):
        MotionMovie(tmp_path / "n.mp4", [], fps=10, shape=(60, 80))


def test_plot_draws_each_system_in_its_colour(tmp_path):
    t = np.arange(20) / 10.0
    ones = np.ones(20)
    frames = {
        "P1": {"max_drop": ones, "area_above_50_mm2": 3e4 * ones, "area_above_90_mm2": 3e4 * ones},
        "R": {"max_drop": 0.4 * ones, "area_above_50_mm2": 0 * ones, "area_above_90_mm2": 0 * ones,
              "area_overbright_above_10_mm2": np.linspace(0, 5e4, 20)},
    }
    res = MotionResult(fps=10.0, times=t, frames=frames, projectors={"P1": 1, "R": 25}, reactive={}, table_mm2=1.0)
    path = tmp_path / "p.png"
    plot_png(res, path)
    img = cv2.imread(str(path))
    assert img is not None and img.shape[1] == 1100
    for k in range(2):
        assert (np.abs(img.astype(int) - COLORS[k]).sum(axis=2) < 30).sum() > 200
    with pytest.raises(ValueError, match="no system"):
        plot_png(res, path, systems=["X"])
