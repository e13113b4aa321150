"""The compensation jobs' options: one definition gives the validation, the command-line flags
(today's names) and the parameters sent; the CLI and the image encoder stay light to import."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np
import pytest

from rigctl import compensation_cli as cli
from coordinator.compensation.image_param import decode_image_param
from coordinator.compensation.options import (
    METHODS,
    REGULARIZATION,
    CompensateOptions,
    ResponseOptions,
    SequenceOptions,
    TransportOptions,
)
from imaging.compensation.ridge import DEFAULT_REGULARIZATION
from imaging.compensation.solver import METHODS as SOLVER_METHODS
from coordinator.jobs import JobError, parse_options


def parse(configure, argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    configure(p)
    return p.parse_args(argv)


def test_the_options_mirror_the_numerics_defaults():
    assert METHODS == SOLVER_METHODS and REGULARIZATION == DEFAULT_REGULARIZATION
    t = parse_options(TransportOptions, {})
    assert t.frames is None and t.frame_count == 1 and t.baseline_frame_count == 1 and t.given == {}
    t = parse_options(TransportOptions, {"radius": 3, "frames": 2})
    assert t.given == {"radius": 3, "frames": 2} and t.baseline_frame_count == 2
    r = parse_options(ResponseOptions, {"grid": [3, 5], "reference": 12})
    assert r.grid == (3, 5) and r.reference == 12.0 and r.mode == "patches" and r.settle_s == 0.05


@pytest.mark.parametrize("kind, params, message", [
    (TransportOptions, {"radios": 3}, "unknown transport parameter"),
    (TransportOptions, {"radius": 0}, "radius must be in 1..16"),
    (TransportOptions, {"force": "yes"}, "force must be true or false"),
    (ResponseOptions, {"grid": [17, 2]}, "grid must be in 1..16"),
    (ResponseOptions, {"mode": "half"}, "mode must be one of"),
    (ResponseOptions, {"reference": -1}, "a reference luminance must be positive"),
    (ResponseOptions, {"reference": [1]}, "reference must be a slot name or a luminance"),
    (CompensateOptions, {"image": "x.png"}, "image parameter must be"),
    (CompensateOptions, {"image_path": "x.png", "method": "newton"}, "method must be one of"),
    (SequenceOptions, {}, "missing parameter"),
    (SequenceOptions, {"frames": []}, "frames must be a non-empty list of images"),
    (SequenceOptions, {"frames": [{"name": "a"}], "fps": 0}, "image parameter must be"),
])
def test_bad_parameters_are_refused_by_name(kind, params, message):
    with pytest.raises(JobError, match=message):
        parse_options(kind, params, what="transport" if kind is TransportOptions else "")


def test_response_flags_keep_their_names_and_send_only_what_was_given():
    args = parse(cli.configure_response, ["--settle", "0", "--camera-index", "1", "--camera", "room://h:1", "--camera",
                                          "room://h:2", "--grid", "3x5", "--reference", "p1", "--slots", "a,b", "--force"])
    assert cli.response_params(args) == {"settle_s": 0.0, "camera": 1, "cameras": ["room://h:1", "room://h:2"],
                                         "grid": [3, 5], "reference": "p1", "slots": ["a", "b"], "force": True}
    assert cli.response_params(parse(cli.configure_response, ["--reference", "12.5"])) == {"reference": 12.5}
    assert cli.response_params(parse(cli.configure_response, [])) == {}
    # what the CLI sends, the job accepts
    parse_options(ResponseOptions, {k: v for k, v in cli.response_params(args).items() if k != "cameras"})


def test_transport_and_compensate_flags(tmp_path):
    args = parse(cli.configure_transport, ["--baseline", "--radius", "3", "--spacing", "4", "--frames", "2",
                                           "--baseline-frames", "8"])
    assert cli.transport_params(args) == {"baseline": True, "radius": 3, "spacing": 4, "frames": 2,
                                          "baseline_frames": 8}
    image = tmp_path / "pic.npy"
    np.save(image, np.full((4, 6), 0.5, np.float32))
    args = parse(cli.configure_compensate, [str(image), "--no-show", "--no-measure", "--evaluate", "--baseline",
                                            "--eval-frames", "2", "--level", "0.8", "--method", "lbfgsb",
                                            "--max-iter", "50", "--regularization", "0", "--srgb", "--json"])
    params = cli.compensate_params(args)
    img, name = decode_image_param(params.pop("image"))
    assert name == "pic.npy" and img.shape == (4, 6, 1)
    assert params == {"persist": False, "measure": False, "evaluate": True, "baseline": True, "eval_frames": 2,
                      "level": 0.8, "method": "lbfgsb", "max_iter": 50, "regularization": 0.0, "srgb": True}
    opts = parse_options(CompensateOptions, {**params, "image_path": str(image)})
    assert not opts.persist and opts.baseline and opts.frame_count == 1
    with pytest.raises(SystemExit, match="cannot read"):
        cli.compensate_params(parse(cli.configure_compensate, [str(tmp_path / "missing.png")]))
    json.dumps(params)


def test_the_command_line_side_does_not_load_the_numerical_stack():
    code = ("import sys, rigctl.compensation_cli, coordinator.compensation.options, "
            "coordinator.compensation.image_param; "
            "print(sorted(m for m in ('scipy', 'cv2', 'skimage') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
