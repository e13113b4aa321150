"""rigctl/mpcdi/archive.py: a rig to MPCDI and back, exactly through the extension, and
close through the standard data alone (which other tools read)."""
from __future__ import annotations

import io
import math
import zipfile
from xml.etree import ElementTree as ET

import cv2
import numpy as np
import pytest

from rigctl.mpcdi.archive import export_mpcdi, import_mpcdi
from rigctl.mpcdi.frustum import normalised
from rigctl.mpcdi.pfm import decode_pfm
from coordinator.rig import HomographyPose, Mesh, ProjectionPose, SlotState
from protos.spaces import content_to_table

CONTENT = (1200, 600)
TABLE_MM = (1200.0, 600.0)


def table_homography(centre_xy, *, height_mm=1800.0, f=1500.0, size=(1280, 800), yaw=0.0) -> np.ndarray:
    """Content px -> projector px of a projector above the table looking down (closed form)."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    r = np.array([[cy, sy, 0.0], [sy, -cy, 0.0], [0.0, 0.0, -1.0]])      # looking down, x right
    c = np.array([centre_xy[0], centre_xy[1], height_mm])
    k = np.array([[f, 0, size[0] / 2 - 0.5], [0, f, size[1] / 2 - 0.5], [0, 0, 1]])
    p = k @ np.concatenate([r, (-r @ c)[:, None]], axis=1)
    plane = p[:, [0, 1, 3]]                                              # z = 0
    return plane @ content_to_table(CONTENT, TABLE_MM)


def planar_slots():
    lut = np.stack([np.linspace(0, 1, 33) ** g for g in (0.45, 0.5, 0.55)]).astype(np.float32)
    return [
        SlotState("p1", 1280, 800, gain=0.8, pose=HomographyPose(table_homography((-200, 100))), lut=lut),
        SlotState("p2", 1280, 800, gain=1.0, pose=HomographyPose(table_homography((250, -50), yaw=0.3))),
        SlotState("p3", 1280, 800, gain=0.0, pose=HomographyPose(table_homography((900, 700)))),   # off the table
        SlotState("spare", 1920, 1080),
    ]


def test_planar_rig_round_trips_exactly(tmp_path):
    out = tmp_path / "rig.mpcdi"
    assert export_mpcdi(out, rig_name="table", content_size=CONTENT, slots=planar_slots()) == "2d"
    back = import_mpcdi(out)
    assert back.exact and back.profile == "2d" and back.content_size == CONTENT and back.name == "table"
    for a, b in zip(planar_slots(), back.slots, strict=True):
        assert (a.name, a.width, a.height, a.gain) == (b.name, b.width, b.height, b.gain)
        if a.pose is None:
            assert b.pose is None
        else:
            np.testing.assert_array_equal(a.pose.matrix, b.pose.matrix)
        if a.lut is None:
            assert b.lut is None
        else:
            np.testing.assert_array_equal(a.lut, b.lut)
    assert not list(tmp_path.glob("*.partial"))


def test_2d_warps_are_what_the_homography_says(tmp_path):
    """The standard data alone: each warp sample, mapped from its region box back to content px and
    then through the pose with OpenCV, lands on the projector point the sample stands for."""
    out = tmp_path / "rig.mpcdi"
    slots = planar_slots()
    export_mpcdi(out, rig_name="table", content_size=CONTENT, slots=slots)
    with zipfile.ZipFile(out) as z:
        root = ET.fromstring(z.read("mpcdi.xml"))
        assert root.get("profile") == "2d"
        for s in slots[:2]:
            region = root.find(f"display/buffer/region[@id='{s.name}']")
            box = [float(region.get(k)) for k in ("x", "y", "xsize", "ysize")]
            path = root.find(f"files/fileset[@region='{s.name}']/geometryWarpFile/path").text
            warp = decode_pfm(z.read(path))
            gh, gw = warp.shape[:2]
            px, py = np.meshgrid((np.arange(gw) + 0.5) * s.width / gw - 0.5, (np.arange(gh) + 0.5) * s.height / gh - 0.5)
            cx = (box[0] + warp[..., 0] * box[2]) * CONTENT[0] - 0.5
            cy = (box[1] + warp[..., 1] * box[3]) * CONTENT[1] - 0.5
            ok = np.isfinite(cx)
            assert ok.mean() > 0.2
            mapped = cv2.perspectiveTransform(np.stack([cx[ok], cy[ok]], 1)[None].astype(np.float64),
                                              s.pose.matrix)[0]
            err = np.hypot(mapped[:, 0] - px[ok], mapped[:, 1] - py[ok])
            assert err.max() < 0.05, err.max()           # float32 warp samples
            assert 0 <= box[0] <= 1 and 0 < box[2] <= 1


def test_standard_data_alone_gives_the_poses_back_closely(tmp_path):
    out = tmp_path / "rig.mpcdi"
    slots = planar_slots()[:2]
    export_mpcdi(out, rig_name="table", content_size=CONTENT, slots=slots)
    stripped = tmp_path / "plain.mpcdi"
    with zipfile.ZipFile(out) as z, zipfile.ZipFile(stripped, "w") as w:
        root = ET.fromstring(z.read("mpcdi.xml"))
        root.remove(root.find("extensionSet"))
        w.writestr("mpcdi.xml", ET.tostring(root))
        for name in z.namelist():
            if name.endswith(".pfm") and ".lut." not in name:
                w.writestr(name, z.read(name))
    back = import_mpcdi(stripped)
    assert not back.exact
    for a, b in zip(slots, back.slots, strict=True):
        pts = np.array([[[100.0, 100.0], [600.0, 300.0], [1000.0, 500.0]]])
        d = cv2.perspectiveTransform(pts, a.pose.matrix) - cv2.perspectiveTransform(pts, b.pose.matrix)
        assert np.abs(d).max() < 0.05


def bust_mesh() -> Mesh:
    from sim.mesh import bust

    b = bust(segments=24, rings=30)
    return Mesh("bust", b.vertices, b.uvs, b.faces)


def look_at(c, target, *, f=1800.0, size=(1920, 1080), skew=0.0) -> np.ndarray:
    c, target = np.asarray(c, float), np.asarray(target, float)
    fwd = (target - c) / np.linalg.norm(target - c)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    r = np.stack([right, down, fwd])
    k = np.array([[f, skew, size[0] / 2 + 30], [0, f * 1.01, size[1] / 2 - 20], [0, 0, 1]])
    return k @ np.concatenate([r, (-r @ c)[:, None]], axis=1)


def test_object_rig_round_trips_exactly_and_frusta_alone_within_1e_9(tmp_path):
    mesh = bust_mesh()
    slots = [SlotState(f"p{i}", 1920, 1080, gain=1.0 - 0.1 * i,
                       pose=ProjectionPose(look_at((1500 * math.cos(a), 1500 * math.sin(a), 1200), (0, 0, 300),
                                                   skew=0.0 if i else 2.0), mesh, 200.0, 5000.0))
             for i, a in enumerate(np.linspace(0, 2 * math.pi, 4, endpoint=False))]
    out = tmp_path / "bust.mpcdi"
    assert export_mpcdi(out, rig_name="bust", content_size=(1024, 1024), slots=slots) == "sl"
    back = import_mpcdi(out)
    assert back.exact and back.profile == "sl"
    for a, b in zip(slots, back.slots, strict=True):
        np.testing.assert_array_equal(a.pose.matrix, b.pose.matrix)
        np.testing.assert_array_equal(a.pose.mesh.vertices, b.pose.mesh.vertices)
        np.testing.assert_array_equal(a.pose.mesh.uvs, b.pose.mesh.uvs)
        np.testing.assert_array_equal(a.pose.mesh.faces, b.pose.mesh.faces)
        assert (a.pose.near_mm, a.pose.far_mm, a.gain) == (b.pose.near_mm, b.pose.far_mm, b.gain)

    stripped = tmp_path / "plain.mpcdi"
    with zipfile.ZipFile(out) as z, zipfile.ZipFile(stripped, "w") as w:
        root = ET.fromstring(z.read("mpcdi.xml"))
        root.remove(root.find("extensionSet"))
        w.writestr("mpcdi.xml", ET.tostring(root))
    plain = import_mpcdi(stripped)
    assert not plain.exact and [s.pose for s in plain.slots] == [None] * 4
    for a, (name, p) in zip(slots[1:], plain.projections[1:], strict=True):   # p0 has skew: not expressible
        q = normalised(a.pose.matrix)
        assert name == a.name and np.abs(p - q).max() <= 1e-9 * np.abs(q).max()


def test_refusals(tmp_path):
    mesh = bust_mesh()
    mixed = [SlotState("a", 100, 100, pose=HomographyPose(np.eye(3))),
             SlotState("b", 100, 100, pose=ProjectionPose(look_at((0, -1000, 500), (0, 0, 0)), mesh))]
    with pytest.raises(ValueError, match="mixes"):
        export_mpcdi(tmp_path / "x.mpcdi", rig_name="r", content_size=(100, 100), slots=mixed)
    (tmp_path / "junk.mpcdi").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="junk.mpcdi: not an MPCDI archive"):
        import_mpcdi(tmp_path / "junk.mpcdi")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("readme.txt", "hi")
    (tmp_path / "empty.mpcdi").write_bytes(buf.getvalue())
    with pytest.raises(ValueError, match="no mpcdi.xml"):
        import_mpcdi(tmp_path / "empty.mpcdi")


def test_a_malformed_description_is_one_clear_error(tmp_path):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("mpcdi.xml", '<MPCDI profile="2d"><display><buffer id="b"><region id="r"/></buffer></display></MPCDI>')
    (tmp_path / "bad.mpcdi").write_bytes(buf.getvalue())
    with pytest.raises(ValueError, match="bad.mpcdi: malformed mpcdi.xml"):
        import_mpcdi(tmp_path / "bad.mpcdi")
