"""Rig directories: creation, validation, persistence across reloads, atomic writes."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.errors import RigError
from coordinator.rig import Content, HomographyPose, Mesh, ProjectionPose, Rig, grid_slots, init_rig, parse_config


def make_rig(tmp_path, **kw):
    return Rig(init_rig(tmp_path / "rig", name="t", slots=grid_slots(2, 3), **kw))


def test_init_creates_config_and_private_token(tmp_path):
    rig = make_rig(tmp_path)
    assert list(rig.slots) == ["r0c0", "r0c1", "r0c2", "r1c0", "r1c1", "r1c2"]
    assert (rig.path / "token").stat().st_mode & 0o077 == 0
    with pytest.raises(RigError, match="already holds a rig"):
        init_rig(rig.path, name="t", slots=["a"])


def test_large_rigs_default_to_sparser_heartbeats(tmp_path):
    small = Rig(init_rig(tmp_path / "small", name="s", slots=grid_slots(8, 8)))
    large = Rig(init_rig(tmp_path / "large", name="l", slots=grid_slots(5, 13)))
    assert (small.config.heartbeat_ms, small.config.lost_after_ms) == (1000, 5000)
    assert (large.config.heartbeat_ms, large.config.lost_after_ms) == (2000, 10000)
    assert "heartbeat_ms = 2000" in (large.path / "rig.toml").read_text()     # written out, for the operator to see
    bare = 'name = "b"\nid = "x"\n[slots]\n' + "".join(f"s{k} = {{}}\n" for k in range(65))
    assert (parse_config(bare).heartbeat_ms, parse_config(bare).lost_after_ms) == (2000, 10000)
    assert parse_config(bare.replace("[slots]", "heartbeat_ms = 700\n[slots]")).heartbeat_ms == 700   # set: kept


def test_state_survives_a_reload(tmp_path):
    rig = make_rig(tmp_path)
    h = np.array([[1.1, 0.01, 3], [0.02, 0.9, -4], [1e-5, 2e-5, 1]])
    lut = np.linspace(0, 1, 1024, dtype=np.float32)[None].repeat(3, 0) ** 0.45
    rig.update_slot("r0c1", pose=HomographyPose(h), lut=lut, gain=0.8)
    mesh = Mesh("m", np.random.rand(4, 3), np.random.rand(4, 2), np.array([[0, 1, 2], [1, 2, 3]]))
    p = np.hstack([np.eye(3), np.ones((3, 1))])
    rig.update_slot("r1c2", pose=ProjectionPose(p, mesh, 10.0, 5000.0))
    img = (np.random.rand(6, 8, 3) * 65535).astype(np.uint16)
    rig.set_content(Content(img, name="x"))

    again = Rig(rig.path)
    s = again.slot("r0c1")
    assert s.revision == 1 and s.gain == pytest.approx(0.8)
    np.testing.assert_array_equal(s.pose.matrix, h)
    np.testing.assert_array_equal(s.lut, lut)
    s2 = again.slot("r1c2")
    np.testing.assert_array_equal(s2.pose.mesh.faces, mesh.faces)
    np.testing.assert_array_equal(again.content.image, img)
    assert again.content.content_id == rig.content.content_id


def test_old_lut_files_are_cleaned_and_no_temp_files_remain(tmp_path):
    rig = make_rig(tmp_path)
    for g in (0.5, 0.6, 0.7):
        rig.update_slot("r0c0", lut=np.tile(np.linspace(0, 1, 8, dtype=np.float32) * g, (1, 1)))
    luts = sorted(p.name for p in (rig.path / "luts").iterdir())
    assert luts == ["r0c0.r3.npy"]
    assert not list(rig.path.rglob(".*.tmp"))


@pytest.mark.parametrize("text,msg", [
    ("name = 'a'\n", "`id`"),
    ("name = 'a'\nid = 'b'\n", "slots"),
    ("name = 'a'\nid = 'b'\n[slots]\n'bad name' = {}\n", "slot name"),
    ("name = 'a'\nid = 'b'\n[slots]\nr0 = { width = 5, height = 5 }\n", "16..16384"),
    ("name = 'a'\nid = 'b'\nlatency_ms = -1\n[slots]\nr0 = {}\n", "latency_ms"),
    ("name = [\n", "not valid TOML"),
    ("name = 'a'\nid = 'b'\nlatancy_ms = 5\n[slots]\nr0 = {}\n", r"unknown key 'latancy_ms' \(did you mean 'latency_ms'\?\)"),
    ("name = 'a'\nid = 'b'\nlatency_ms = nan\n[slots]\nr0 = {}\n", "latency_ms must be a finite number"),
    ("name = 'a'\nid = 'b'\n[slots]\nr0 = { width = 64, hieght = 64 }\n", r"unknown key 'hieght' in \[slots.r0\]"),
])
def test_invalid_config_names_the_problem(text, msg):
    with pytest.raises(RigError, match=msg):
        parse_config(text)


def test_bad_inputs_are_refused_and_nothing_stored_is_lost(tmp_path):
    rig = make_rig(tmp_path)
    rig.update_slot("r0c0", gain=0.5)
    with pytest.raises(ValueError):
        rig.update_slot("r0c0", lut=np.full((2, 10), 0.5, np.float32))
    with pytest.raises(ValueError):
        HomographyPose(np.zeros((3, 3)))
    with pytest.raises(RigError, match="not in rig"):
        rig.update_slot("zz", gain=1.0)
    assert Rig(rig.path).slot("r0c0").gain == pytest.approx(0.5)


def test_corrupt_slot_file_is_reported_with_its_path(tmp_path):
    rig = make_rig(tmp_path)
    rig.update_slot("r0c0", gain=0.5)
    path = rig.path / "slots" / "r0c0.json"
    good = path.read_text()
    path.write_text("{not json")
    with pytest.raises(RigError, match="r0c0.json"):
        Rig(rig.path)
    for bad in ("NaN", "-0.5", "17", '"1.0"', "true"):
        path.write_text(good.replace('"gain": 0.5', f'"gain": {bad}'))
        with pytest.raises(RigError, match=r"r0c0.json: gain must be a number in 0..16"):
            Rig(rig.path)
