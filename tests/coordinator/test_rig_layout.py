"""`shadowless rig init DIR --layout FILE`: the planner's layout as a rig directory, its planned poses
held apart from calibrated ones."""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import tomllib

import numpy as np
import pytest

from rigctl import rigcli
from coordinator.jobs import JobError
from coordinator.rig import HomographyPose, Rig, parse_config
from coordinator.rig_layout import content_size_of, table_mesh
from protos.spaces import content_to_table
from planner import cli as plan_cli
from sim.scene import load_layout


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    """A small plan of the table: 3 projectors of a 4x4 ceiling grid (what `shadowless plan` writes)."""
    d = tmp_path_factory.mktemp("plan")
    parser = argparse.ArgumentParser()
    plan_cli.configure(parser)
    layout = d / "plan.toml"
    args = parser.parse_args(["--grid", "4x4", "--budget", "3", "--pitch", "50", "--heights", "200", "--yaws", "0",
                              "--layout", str(layout), "--picture", str(d / "plan.png"), "--json"])
    assert plan_cli.run(args) == 0
    return layout


@pytest.fixture
def rig_cmd(shadowless_main):
    """``rig_cmd(*argv)``: `shadowless rig ARGV...` as (exit status, stdout, stderr)."""
    return lambda *argv: shadowless_main("rig", *argv)


def test_the_plan_becomes_the_rig_an_operator_would_type(plan, tmp_path, rig_cmd):
    scene = load_layout(plan, projector_scale=1.0)
    slots = [p.slot for p in scene.projectors]
    code, out, err = rig_cmd("init", str(tmp_path / "planned"), "--layout", str(plan))
    assert code == 0, err
    assert "3 slots from layout" in out and "content 1200x600" in out and "--planned" in out
    code, _, err = rig_cmd("init", str(tmp_path / "typed"), "--slots", ",".join(slots), "--resolution", "1280x800",
                           "--content-size", "1200x600")
    assert code == 0, err
    got = parse_config((tmp_path / "planned" / "rig.toml").read_text())
    typed = parse_config((tmp_path / "typed" / "rig.toml").read_text())
    assert got.slots == typed.slots == {s: (1280, 800) for s in slots}
    assert (got.content_width, got.content_height) == (typed.content_width, typed.content_height) == (1200, 600)
    rig = Rig(tmp_path / "planned", read_only=True)
    entries = {e["slot"]: e for e in tomllib.loads(plan.read_text())["projector"]}
    for p in scene.projectors:
        st = rig.slot(p.slot)
        assert st.pose is None and st.planned is not None                   # planned, not calibrated
        P = st.planned.matrix
        np.testing.assert_allclose(P / P[2, 3], p.native.P / p.native.P[2, 3], rtol=1e-9, atol=1e-9)   # the room's
        # closed forms from the file: the centre is the position, the target lands on the image centre
        e = entries[p.slot]
        np.testing.assert_allclose(-np.linalg.solve(P[:, :3], P[:, 3]), e["position"], atol=1e-6)
        aim = P @ np.r_[e["target"], 1.0]
        np.testing.assert_allclose(aim[:2] / aim[2], [(1280 - 1) / 2, (800 - 1) / 2], atol=1e-6)
        assert P[2, :3] @ (np.asarray(e["target"]) - e["position"]) > 0       # in front
        # onto the table: the table mesh, whose uvs lie where content lies on the table
        m = st.planned.mesh
        cw, ch = 1200, 600
        xy = (content_to_table((cw, ch), (1200.0, 600.0)) @ np.c_[m.uvs * [cw, ch] - 0.5, np.ones(4)].T).T
        np.testing.assert_allclose(xy[:, :2], m.vertices[:, :2], atol=1e-4)
    shown = json.loads(rig_cmd("show", str(tmp_path / "planned"))[1])
    assert all(s["planned"] and s["pose"] is None and s["source"] == "layout" for s in shown["slots"].values())
    # a projector the layout leaves off (as the room's bright single unit) is not a slot, and the command says so
    off = tmp_path / "off.toml"
    off.write_text(plan.read_text().replace("[[projector]]\n", "[[projector]]\npowered = false\n", 1))
    code, out, err = rig_cmd("init", str(tmp_path / "off"), "--layout", str(off))
    assert code == 0, err
    assert "2 slots from layout" in out and f"left out, unpowered in the layout: {slots[0]}" in out
    assert list(parse_config((tmp_path / "off" / "rig.toml").read_text()).slots) == slots[1:]


def test_a_resolution_resamples_the_planned_poses_as_the_room_scales_its_projectors(plan, tmp_path, rig_cmd):
    room = load_layout(plan, projector_scale=0.25)                        # `shadowless room --layout`: 320x200
    code, _, err = rig_cmd("init", str(tmp_path / "r"), "--layout", str(plan), "--resolution", "320x200",
                           "--content-size", "300x150")
    assert code == 0, err
    rig = Rig(tmp_path / "r")
    assert rig.config.slots == {p.slot: (320, 200) for p in room.projectors}
    assert (rig.config.content_width, rig.config.content_height) == (300, 150)
    for p in room.projectors:
        np.testing.assert_allclose(rig.slot(p.slot).planned.matrix, p.pinhole.P, rtol=1e-9, atol=1e-6)
    # a node that drives another size: the plan follows it (a calibrated pose would not)
    s = room.projectors[0]
    st = rig.update_slot(s.slot, size=(1280, 800), source="node")
    np.testing.assert_allclose(st.planned.matrix, s.native.P, rtol=1e-9, atol=1e-6)


def test_jobs_refuse_planned_poses_and_calibration_replaces_them(plan, tmp_path, rig_cmd):
    from bench.calibration import table_points_from_truth
    from bench.compensation_room import points_doc
    from shadowless.room_driver import RoomDriver
    from sim.room import Room

    room = Room(load_layout(plan, projector_scale=0.125, camera_scale=0.125), seed=1)
    code, _, err = rig_cmd("init", str(tmp_path / "r"), "--layout", str(plan), "--resolution", "160x100",
                           "--content-size", "240x120")
    assert code == 0, err
    rig = Rig(tmp_path / "r")
    driver = RoomDriver(room, rig)
    slots = list(rig.slots)
    with pytest.raises(JobError, match="only the pose a layout planned.*calibrate it first"):
        asyncio.run(driver.run("transport", {"slots": slots[:1]}))
    asyncio.run(driver.run("calibrate", {"mode": "multiplexed", "settle_s": 0.0,
                                         "table_points": points_doc(table_points_from_truth(room))}))
    for s in slots:
        st = Rig(tmp_path / "r", read_only=True).slot(s)                   # as persisted
        assert isinstance(st.pose, HomographyPose) and st.planned is None and st.source == "calibration"


def test_mistakes_are_one_line(plan, tmp_path, rig_cmd, capsys):
    bad = tmp_path / "bad.toml"
    cases = {
        "no such file": ["init", str(tmp_path / "a"), "--layout", str(tmp_path / "missing.toml")],
        "not valid TOML": ["init", str(tmp_path / "b"), "--layout", str(bad)],
    }
    bad.write_text("name = \n")
    for what, argv in cases.items():
        code, _, err = rig_cmd(*argv)
        assert code == 2 and what.lower() in err.lower() and len(err.strip().splitlines()) == 1, err
    empty = tmp_path / "empty.toml"
    empty.write_text('name = "x"\n[table]\nsize = [1200, 600]\n[[camera]]\nposition = [0, 0, 1400]\n')
    code, _, err = rig_cmd("init", str(tmp_path / "c"), "--layout", str(empty))
    assert code == 2 and "needs at least one [[projector]]" in err and len(err.strip().splitlines()) == 1
    code, _, err = rig_cmd("init", str(tmp_path / "d"), "--layout", str(plan), "--slots", "a,b")
    assert code == 2 and "not allowed with argument" in err
    assert not (tmp_path / "c").exists() and not (tmp_path / "d").exists()
    # the coordinator on its own cannot build the room's bust: it says what to do instead
    bust = tmp_path / "bust.toml"
    bust.write_text(plan.read_text().replace("[table]", '[mesh]\nbuiltin = "bust"\n\n[table]'))
    parser = argparse.ArgumentParser()
    rigcli.configure(parser)
    assert rigcli.run(parser.parse_args(["init", str(tmp_path / "e"), "--layout", str(bust)])) == 2
    err = capsys.readouterr().err
    assert "builtin 'bust'" in err and "[mesh] path" in err and not (tmp_path / "e").exists()


def test_content_size_is_one_pixel_per_millimetre_of_the_surface():
    m = table_mesh((1200.0, 600.0))
    assert content_size_of(m.vertices, m.uvs, m.faces) == (1200, 600)
    # a cylinder of radius r and height h mapped by angle and height: (2 pi r, h) in the limit; with
    # n flat sides the circumference is the polygon's, 2 n r sin(pi / n)
    r, h, n = 100.0, 300.0, 64
    a = np.linspace(0, 2 * math.pi, n + 1)
    ring = np.c_[r * np.cos(a), r * np.sin(a)]
    vertices = np.r_[np.c_[ring, np.zeros(n + 1)], np.c_[ring, np.full(n + 1, h)]]
    uvs = np.r_[np.c_[a / (2 * math.pi), np.ones(n + 1)], np.c_[a / (2 * math.pi), np.zeros(n + 1)]]
    faces = np.array([f for i in range(n) for f in ([i, i + 1, n + 2 + i], [i, n + 2 + i, n + 1 + i])])
    assert content_size_of(vertices, uvs, faces) == (round(2 * n * r * math.sin(math.pi / n)), round(h))
    with pytest.raises(ValueError, match="no triangle"):
        content_size_of(vertices, np.zeros_like(uvs), faces)
