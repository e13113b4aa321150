"""`shadowless rig export` / `shadowless rig import` through the real command: a rig's calibration
to MPCDI and back into another rig directory, and every refusal as one line with exit status 2.

The command runs in the test's interpreter (``shadowless.cli.main``, output captured at the file
descriptors); the round trip's export and import and a refusal also run as real processes."""
from __future__ import annotations

import hashlib
import math
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from cli_inprocess import cli_capture, run_here  # noqa: F401 - cli_capture: the module's autouse fixture
from rigctl.mpcdi.frustum import normalised
from coordinator.rig import HomographyPose, Mesh, ProjectionPose, Rig, init_rig
from coordinator.rig_lock import RigLock, RigLockError, holder
from shadowless.local import LocalRig

SIZE = (64, 40)
CONTENT = (120, 60)
TABLE_SLOTS = ["p1", "p2", "p3", "spare"]


def rig_cli(*args: str, process: bool = False, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """`shadowless rig ARGS...` in this interpreter, or with ``process`` as a real process."""
    argv = ["rig", *map(str, args)]
    if process:
        return subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True,
                              timeout=timeout)
    code, out, err = run_here(argv)
    return subprocess.CompletedProcess(argv, code, out, err)


def one_line_error(r: subprocess.CompletedProcess) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


def tree_digest(path) -> dict[str, str]:
    """sha256 of every file under ``path`` (hidden ones too), by relative name."""
    return {str(f.relative_to(path)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(path.rglob("*")) if f.is_file()}


def norm_h(h: np.ndarray) -> np.ndarray:
    h = np.asarray(h, np.float64) / np.linalg.norm(h)
    return -h if h[2, 2] < 0 else h


def table_homography(cx: float, cy: float, *, f: float = 40.0, yaw: float = 0.0) -> np.ndarray:
    """Content px -> projector px of a projector looking down at the content plane (closed form)."""
    c, s = math.cos(yaw), math.sin(yaw)
    k = np.array([[f, 0.0, SIZE[0] / 2 - 0.5], [0.0, f, SIZE[1] / 2 - 0.5], [0.0, 0.0, 1.0]])
    rt = np.array([[c, s, -(c * cx + s * cy)], [s, -c, -(s * cx - c * cy)], [0.0, 0.0, 80.0]])
    return k @ rt


def lut(gamma: float) -> np.ndarray:
    """(3, 33) float32 inverse-response LUT."""
    return np.stack([np.linspace(0, 1, 33) ** (gamma + 0.05 * c) for c in range(3)]).astype(np.float32)


def new_rig(path, slots=TABLE_SLOTS, size=SIZE, content=CONTENT) -> Rig:
    return Rig(init_rig(path, name=path.name, slots=list(slots), width=size[0], height=size[1],
                        content_width=content[0], content_height=content[1]))


@pytest.fixture
def table(tmp_path) -> Rig:
    rig = new_rig(tmp_path / "table")
    rig.update_slot("p1", pose=HomographyPose(table_homography(30, 20)), gain=0.8, lut=lut(0.45))
    rig.update_slot("p2", pose=HomographyPose(table_homography(80, 35, yaw=0.3)), gain=0.6)
    rig.update_slot("p3", pose=HomographyPose(table_homography(60, 30, f=55.0)), lut=lut(0.5))
    return rig


def test_a_table_rig_round_trips_into_a_fresh_rig(table, tmp_path):
    out = tmp_path / "table.mpcdi"
    r = rig_cli("export", table.path, out, process=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("\n") == 1 and "profile 2d" in r.stdout and "4 slots" in r.stdout
    assert "1 without a pose (spare)" in r.stdout and "KiB" in r.stdout
    assert zipfile.is_zipfile(out) and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]

    again = rig_cli("export", table.path, out)              # never overwritten unasked
    assert "exists; pass --force" in one_line_error(again)
    assert rig_cli("export", table.path, out, "--force").returncode == 0

    fresh = new_rig(tmp_path / "fresh")
    r = rig_cli("import", out, fresh.path, process=True)
    assert r.returncode == 0, r.stderr
    assert "p1: homography, changed (pose, gain, LUT; revision 0 -> 1)" in r.stdout
    assert "spare: no pose, unchanged" in r.stdout
    back = Rig(fresh.path)
    for name in TABLE_SLOTS:
        a, b = table.slot(name), back.slot(name)
        assert b.gain == a.gain and (b.width, b.height) == (a.width, a.height)
        if a.pose is None:
            assert b.pose is None and b.revision == 0
            continue
        assert b.revision == 1 and b.source == "mpcdi"
        assert np.allclose(norm_h(b.pose.matrix), norm_h(a.pose.matrix), atol=1e-9, rtol=0)
        if a.lut is None:
            assert b.lut is None
        else:
            np.testing.assert_array_equal(b.lut, a.lut)

    r = rig_cli("import", out, fresh.path)                  # the same archive again: nothing to change
    assert r.returncode == 0 and "0 changed, 4 unchanged" in r.stdout
    assert [Rig(fresh.path).slot(n).revision for n in TABLE_SLOTS] == [1, 1, 1, 0]


def look_at(c, target, *, f: float = 60.0) -> np.ndarray:
    """(3, 4) world mm -> projector px of a pinhole at ``c`` looking at ``target`` (z up)."""
    c, target = np.asarray(c, float), np.asarray(target, float)
    fwd = (target - c) / np.linalg.norm(target - c)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    r = np.stack([right, np.cross(fwd, right), fwd])
    k = np.array([[f, 0, SIZE[0] / 2 + 3], [0, f * 1.01, SIZE[1] / 2 - 2], [0, 0, 1]])
    return k @ np.concatenate([r, (-r @ c)[:, None]], axis=1)


def test_an_object_rig_round_trips_with_its_mesh(tmp_path):
    from sim.mesh import bust

    b = bust(segments=12, rings=20)
    mesh = Mesh("bust", b.vertices, b.uvs, b.faces)
    rig = new_rig(tmp_path / "object", slots=["o1", "o2", "o3"])
    for i, name in enumerate(["o1", "o2"]):
        a = 2 * math.pi * i / 3
        p = look_at((1500 * math.cos(a), 1500 * math.sin(a), 1200), (0, 0, 300))
        rig.update_slot(name, pose=ProjectionPose(p, mesh, 200.0 + i, 5000.0), gain=0.9 - 0.1 * i)
    out = tmp_path / "object.mpcdi"
    r = rig_cli("export", rig.path, out)
    assert r.returncode == 0 and "profile sl" in r.stdout and "(o3)" in r.stdout, r.stderr

    fresh = new_rig(tmp_path / "fresh", slots=["o1", "o2", "o3"])
    r = rig_cli("import", out, fresh.path)
    assert r.returncode == 0 and "o1: projection, changed (pose, gain; revision 0 -> 1)" in r.stdout, r.stderr
    back = Rig(fresh.path)
    assert (fresh.path / "meshes" / "bust.npz").is_file()
    for name in ["o1", "o2"]:
        a, b = rig.slot(name), back.slot(name)
        assert isinstance(b.pose, ProjectionPose) and b.revision == 1 and b.gain == a.gain
        assert np.allclose(normalised(b.pose.matrix), normalised(a.pose.matrix), atol=1e-9, rtol=0)
        assert (b.pose.near_mm, b.pose.far_mm) == (a.pose.near_mm, a.pose.far_mm)
        for field in ("vertices", "uvs", "faces"):
            np.testing.assert_array_equal(getattr(b.pose.mesh, field), getattr(a.pose.mesh, field))
    assert back.slot("o3").pose is None and back.slot("o3").revision == 0


def test_only_the_rigs_slots_are_imported_and_mismatched_ones_are_refused(table, tmp_path):
    out = tmp_path / "table.mpcdi"
    assert rig_cli("export", table.path, out).returncode == 0
    other = new_rig(tmp_path / "other", slots=["p1", "p2", "extra"])
    r = rig_cli("import", out, other.path, "--slots", "p2")
    assert r.returncode == 0, r.stderr
    slot_lines = [ln.strip() for ln in r.stdout.splitlines() if ln.startswith("  ")]    # not the paths above
    assert r.stderr == "" and len(slot_lines) == 1 and slot_lines[0].startswith("p2: homography, changed"), r.stdout
    back = Rig(other.path)
    assert back.slot("p1").pose is None and back.slot("p2").revision == 1

    r = rig_cli("import", out, other.path)                     # p3 and spare are not in this rig
    assert r.returncode == 0
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and "lacks, not imported: p3, spare" in r.stderr
    assert Rig(other.path).slot("p1").revision == 1 and Rig(other.path).slot("extra").revision == 0

    assert "'nope' is not in rig" in one_line_error(rig_cli("import", out, other.path, "--slots", "nope"))
    assert "'extra' is not in" in one_line_error(rig_cli("import", out, other.path, "--slots", "extra"))

    small = new_rig(tmp_path / "small", slots=["p1", "p2"], size=(32, 20))
    toml = (small.path / "rig.toml").read_text()
    (small.path / "rig.toml").write_text(toml.replace("p2 = {}", "p2 = { width = 64, height = 40 }"))
    r = rig_cli("import", out, small.path, "--slots", "p1,p2")
    assert r.returncode == 2
    assert "slot p1 refused: the archive's p1 is 64x40 px, the rig's is 32x20" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "p2: homography, changed" in r.stdout
    assert Rig(small.path).slot("p1").pose is None and Rig(small.path).slot("p2").revision == 1


def test_dry_run_writes_nothing(table, tmp_path):
    out = tmp_path / "table.mpcdi"
    assert rig_cli("export", table.path, out).returncode == 0
    fresh = new_rig(tmp_path / "fresh")
    fresh.update_slot("p2", gain=0.3)
    before = tree_digest(fresh.path)
    r = rig_cli("import", out, fresh.path, "--dry-run")
    assert r.returncode == 0, r.stderr
    assert "p2: homography, would change (pose, gain; revision 1 -> 2)" in r.stdout and "nothing written" in r.stdout
    assert tree_digest(fresh.path) == before


def test_a_damaged_archive_is_one_line_and_changes_nothing(table, tmp_path):
    out = tmp_path / "table.mpcdi"
    assert rig_cli("export", table.path, out).returncode == 0
    fresh = new_rig(tmp_path / "fresh")
    before = tree_digest(fresh.path)
    data = out.read_bytes()
    truncated = tmp_path / "truncated.mpcdi"
    truncated.write_bytes(data[: len(data) // 2])
    assert "not an MPCDI archive" in one_line_error(rig_cli("import", truncated, fresh.path, process=True))
    no_xml = tmp_path / "no_xml.mpcdi"
    with zipfile.ZipFile(out) as z, zipfile.ZipFile(no_xml, "w") as w:
        for name in z.namelist():
            if name != "mpcdi.xml":
                w.writestr(name, z.read(name))
    assert "no mpcdi.xml" in one_line_error(rig_cli("import", no_xml, fresh.path))
    assert tree_digest(fresh.path) == before


def test_the_lock_names_its_holder_and_goes_with_it(tmp_path):
    rig = new_rig(tmp_path / "r")
    assert holder(rig.path) is None
    with RigLock(rig.path):
        assert holder(rig.path)[1] == "coordinator"
        with pytest.raises(RigLockError, match=r"already served by the coordinator with pid \d+"):
            RigLock(rig.path, role="rig import").acquire()
    assert holder(rig.path) is None
    with RigLock(rig.path, role="rig import"), pytest.raises(RigLockError, match="locked by `shadowless rig import`"):
        RigLock(rig.path).acquire()


def test_import_is_refused_while_a_coordinator_serves_the_rig(tmp_path):
    local = LocalRig(["r0c0"], tmp_path, output_size=(32, 18), content_size=(32, 18), mdns=False).create()
    try:
        local.start_coordinator()
        local.wait_ready()
        pid = local.coordinator.pid
        out = tmp_path / "served.mpcdi"
        r = rig_cli("export", local.rig_dir, out)             # export only reads: fine while it serves
        assert r.returncode == 0, r.stderr
        before = tree_digest(local.rig_dir)
        msg = one_line_error(rig_cli("import", out, local.rig_dir))
        assert f"is already served by the coordinator with pid {pid}" in msg
        second = subprocess.run([sys.executable, "-m", "shadowless", "coordinator", "--rig", str(local.rig_dir),
                                 "--listen", "127.0.0.1:0", "--no-mdns", "--no-console"],
                                capture_output=True, text=True, timeout=60)
        assert second.returncode != 0
        lines = second.stderr.strip().splitlines()
        assert len(lines) == 1 and f"rig {local.rig_dir} is already served by the coordinator with pid {pid}" in lines[0]
        assert tree_digest(local.rig_dir) == before
    finally:
        local.close()
    r = rig_cli("import", out, local.rig_dir)                 # once it stopped
    assert r.returncode == 0 and "r0c0: no pose, unchanged" in r.stdout, r.stderr
