"""`shadowless bench specular` on a small observer image: the peak highlight falls as the closed form says."""
from __future__ import annotations

import argparse
import json

import cv2
import pytest

from bench import specular
from bench.specular import specular_figures
from sim.specular import Gloss


@pytest.fixture(scope="module")
def doc(tmp_path_factory):
    return specular_figures(gloss=Gloss("table", 0.1, 0.02), observer=(0.0, -60.0, 900.0), observer_px=(200, 150),
                            subsets=("P1", "P9D", "P25"), projector_scale=0.125,
                            picture=str(tmp_path_factory.mktemp("specular") / "views.png"))


def test_peak_highlight_falls_as_one_lens_share_of_the_light(doc):
    p1, p9, p25 = (doc["configurations"][k] for k in ("P1", "P9", "P25"))
    # matched brightness: the same diffuse light at the table's centre, measured
    assert p9["diffuse_over_reference"] == pytest.approx(1.0, abs=1e-4)
    assert p25["diffuse_over_reference"] == pytest.approx(1.0, abs=1e-4)
    # P1 / P9 within 1 % of the closed form (each lens's share of the matched light at its own highlight) ...
    assert p1["peak"] / p9["peak"] == pytest.approx(1.0 / p9["closed_form"], rel=0.01)
    # ... which is within 7 % of 9: the dense 3 x 3's outer lenses add less light at the centre than the middle one
    assert 9 * 0.93 < p1["peak"] / p9["peak"] < 9
    # the peaks themselves against the closed form, pixel sampling included (a 200 x 150 eye: about 6 mm a pixel)
    for c in (p1, p9, p25):
        assert abs(c["peak_error"]) < 0.05
    # the targets
    assert doc["P25_peak_over_P1"] <= 1.2 / 25
    assert doc["closed_form_error"] < 0.05
    # N separate highlights, their count and their area as the closed form says
    assert (p1["highlights"], p9["highlights"], p25["highlights"]) == (1, 9, 25)
    for c in (p1, p9, p25):
        assert abs(c["area_error"]) < 0.05
    assert p1["area_mm2"] < p9["area_mm2"] < p25["area_mm2"]
    # the render against the BRDF evaluated by brute force, down to a thousandth of the peak
    assert doc["lobe_check"]["max_error"] < 1e-4
    json.dumps(doc, allow_nan=False)
    # the picture: the three views side by side, P1's highlight white, the diffuse table grey
    views = cv2.imread(doc["picture"], cv2.IMREAD_GRAYSCALE)
    assert views.shape == (150, 600)
    assert views[40:, :200].max() >= 250 and views[40:, 400:].max() < 160   # below the names


def test_bench_specular_refuses_bad_options_in_one_line():
    parser = argparse.ArgumentParser()
    specular.configure(parser)
    for argv, words in ((["--gloss", "mesh:0.1:0.02"], "glossy table"), (["--gloss", "table:0.1"], "SURFACE:STRENGTH:ROUGHNESS"),
                        (["--observer", "0,0"], "X,Y,Z"), (["--observer", "0,0,-10"], "above the table"), (["--subsets", "P1,P7"], "unknown configuration P7"),
                        (["--observer-px", "12"], "WIDTHxHEIGHT")):
        with pytest.raises(SystemExit) as err:
            specular.run(parser.parse_args(argv))
        assert words in str(err.value) and "\n" not in str(err.value)
