"""The calibrate job's options: JSON validation, rig.toml's [calibration] table as defaults under
what a request names, and the resolution of points files, boards, meshes and intrinsics."""
from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.calibration.options import AlignmentOptions, CalibrateOptions, decide, resolve, rig_defaults
from coordinator.jobs import JobError, parse_options


def opts(params: dict) -> CalibrateOptions:
    return parse_options(CalibrateOptions, params, what="calibrate")


def with_rig_defaults(params: dict, rig_dir) -> CalibrateOptions:
    """What the calibrate job runs with: the request over rig.toml's table (the registry's
    defaults hook), mode and surface decided."""
    defaults, source = rig_defaults(rig_dir)
    return decide(parse_options(CalibrateOptions, params, what="calibrate", defaults=defaults, defaults_source=source))


def rig_toml(rig_dir, section: str) -> None:
    (rig_dir / "rig.toml").write_text('name = "t"\n[calibration]\n' + section)


def test_the_request_wins_over_rig_toml_which_wins_over_the_defaults(tmp_path):
    rig_toml(tmp_path, 'mode = "sequential"\nsettle_s = 0.5\ntable_mm = [1000, 500]\nrounds = 6\n')
    o = with_rig_defaults(({}), tmp_path)
    assert (o.mode, o.surface, o.settle_s, o.table_mm, o.rounds, o.min_pixels) == \
        ("sequential", "table", 0.5, (1000.0, 500.0), 6, 2000)
    # naming an option's default value still overrides the rig's setting
    o = with_rig_defaults(({"mode": "multiplexed", "settle_s": 0.1}), tmp_path)
    assert (o.mode, o.settle_s, o.rounds) == ("multiplexed", 0.1, 6)


def test_mode_and_surface_follow_the_mesh_and_refuse_contradictions(tmp_path):
    assert with_rig_defaults(({"mesh": "bust.obj"}), tmp_path).mode == "sequential"
    assert with_rig_defaults(({"mesh": "bust.obj"}), tmp_path).surface == "mesh"
    o = with_rig_defaults(({"mode": "multiplexed", "mesh": "bust.obj"}), tmp_path)     # the multiplexed 3D mode
    assert (o.mode, o.surface) == ("multiplexed", "mesh")
    with pytest.raises(JobError, match="surface 'mesh' needs a mesh file"):
        with_rig_defaults(({"surface": "mesh"}), tmp_path)
    rig_toml(tmp_path, 'mesh = "bust.obj"\n')         # the mesh may come from the rig file
    assert with_rig_defaults(({"surface": "mesh"}), tmp_path).mesh == "bust.obj"


def test_bad_values_are_refused_naming_the_parameter_or_the_rig_file(tmp_path):
    for params, message in [({"colour": 1}, "unknown calibrate parameter"), ({"settle_s": 31}, "settle_s must be in 0..30"),
                            ({"min_pixels": 5}, "min_pixels must be in 12.."), ({"rounds": 0}, "rounds must be in 1..16"),
                            ({"min_contrast": 0}, r"min_contrast must be in \(0, 1\)"), ({"mode": "fast"}, "mode must be one of"),
                            ({"table_mm": [0, 5]}, "table_mm must be in 1.."), ({"charuco": 3}, "charuco must be a table"),
                            ({"table_points": 7}, "table_points must be a file path"), ({"use_table": "no"}, "use_table must be true or false"),
                            ({"intrinsics": {"0": [[1, 0], [0, 1]]}}, "intrinsics for camera 0 must be a 3x3 matrix")]:
        with pytest.raises(JobError, match=message):
            opts(params)
    rig_toml(tmp_path, 'settle_s = "long"\n')
    with pytest.raises(JobError, match=r"rig.toml \[calibration\]: settle_s must be a number"):
        with_rig_defaults(({}), tmp_path)
    rig_toml(tmp_path, "colour = 1\n")
    with pytest.raises(JobError, match=r"unknown \[calibration\] key\(s\) colour"):
        with_rig_defaults(({}), tmp_path)
    with pytest.raises(JobError, match="unknown alignment parameter"):
        parse_options(AlignmentOptions, {"colour": 1}, what="alignment")


def test_files_and_documents_resolve_against_the_rig_directory(tmp_path):
    (tmp_path / "marks.json").write_text(json.dumps({"points": [{"xy": [0, 0], "pixel": [1, 2]}, {"xy": [5, 0], "pixel": [3, 2]}]}))
    doc = {"frame": "model", "points": [{"xyz": [0, 0, 1], "pixel": [4, 5], "camera": 1}]}
    board = {"squares_x": 9, "squares_y": 6, "square_mm": 60.0, "marker_mm": 45.0}
    inputs = resolve(opts({"table_points": "marks.json", "landmarks": doc, "charuco": board, "mesh": "bust.obj",
                           "intrinsics": {"1": np.eye(3).tolist()}}), tmp_path)
    assert len(inputs.table_points[0]) == 2 and inputs.table_points[0].planar
    assert inputs.landmarks[0].frame == "model" and inputs.landmarks[0].camera == 1
    assert inputs.charuco.squares_x == 9 and inputs.mesh_path == str(tmp_path / "bust.obj")
    np.testing.assert_array_equal(inputs.intrinsics[1], np.eye(3))
    rows = resolve(opts({"table_points": [[0, 0, 1, 2], [5, 0, 3, 2]]}), tmp_path).table_points
    assert rows[0].camera == 0 and len(rows[0]) == 2
    with pytest.raises(JobError, match="cannot read points file"):
        resolve(opts({"table_points": "none.json"}), tmp_path)
    with pytest.raises(JobError, match="table_points must be in the world frame"):
        resolve(opts({"table_points": doc}), tmp_path)
    with pytest.raises(JobError, match="0 < marker_mm < square_mm"):
        resolve(opts({"charuco": {**board, "marker_mm": 70.0}}), tmp_path)
