"""`shadowless rig export` / `rig import` carry a rig's stored blend: into another rig's blend store
bit for bit, only for the slots imported, and an archive with a malformed blend map is refused in
one line with nothing in the rig changed. The command runs in the test's interpreter (output captured at
the file descriptors), one export as a real process."""
from __future__ import annotations

import hashlib
import math
import subprocess
import sys
import zipfile
from xml.etree import ElementTree as ET

import numpy as np

from cli_inprocess import cli_capture, run_here  # noqa: F401 - cli_capture: the module's autouse fixture
from coordinator.blend_store import StoredBlend, load_blend, save_blend
from coordinator.rig import HomographyPose, Rig, init_rig
from protos.blend import BlendMaps

SIZE = (64, 40)


def rig_cli(*args, process: bool = False) -> subprocess.CompletedProcess:
    """`shadowless rig ARGS...` in this interpreter (output captured at the file descriptors), or with
    ``process`` as a real process."""
    argv = ["rig", *map(str, args)]
    if process:
        return subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True, timeout=120)
    code, out, err = run_here(argv)
    return subprocess.CompletedProcess(argv, code, out, err)


def one_line_error(r: subprocess.CompletedProcess) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    return lines[0]


def tree_digest(path) -> dict[str, str]:
    return {str(f.relative_to(path)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(path.rglob("*")) if f.is_file()}


def table_homography(cx: float, cy: float, *, f: float = 40.0, yaw: float = 0.0) -> np.ndarray:
    """Content px -> projector px of a projector looking down at the content plane."""
    c, s = math.cos(yaw), math.sin(yaw)
    k = np.array([[f, 0.0, SIZE[0] / 2 - 0.5], [0.0, f, SIZE[1] / 2 - 0.5], [0.0, 0.0, 1.0]])
    return k @ np.array([[c, s, -(c * cx + s * cy)], [s, -c, -(s * cx - c * cy)], [0.0, 0.0, 80.0]])


def new_rig(path) -> Rig:
    return Rig(init_rig(path, name=path.name, slots=["p1", "p2", "p3", "spare"], width=SIZE[0], height=SIZE[1],
                        content_width=120, content_height=60))


def maps_for(names, seed: int) -> dict[str, BlendMaps]:
    rng = np.random.default_rng(seed)
    return {n: BlendMaps(rng.random((10, 16, 3), dtype=np.float32), rng.random((10, 16), dtype=np.float32) * 0.05)
            for n in names}


def same(a: BlendMaps, b: BlendMaps) -> bool:
    return np.array_equal(a.alpha, b.alpha) and np.array_equal(a.beta, b.beta)


def blended_table(path) -> Rig:
    rig = new_rig(path)
    rig.update_slot("p1", pose=HomographyPose(table_homography(30, 20)))
    rig.update_slot("p2", pose=HomographyPose(table_homography(80, 35, yaw=0.3)))
    rig.update_slot("p3", pose=HomographyPose(table_homography(60, 30, f=55.0)))
    save_blend(rig.path, StoredBlend(maps_for(["p1", "p2", "p3"], 1), {"headroom": 0.3, "uniformity_after": 0.01},
                                     {"after": np.ones((4, 4), np.float32)}))
    return rig


def test_a_blend_travels_from_rig_to_rig_bit_for_bit(tmp_path):
    rig = blended_table(tmp_path / "table")
    out = tmp_path / "table.mpcdi"
    r = rig_cli("export", rig.path, out, process=True)
    assert r.returncode == 0 and "blend maps for 3" in r.stdout, r.stderr
    fresh = new_rig(tmp_path / "fresh")
    r = rig_cli("import", out, fresh.path, "--dry-run")
    assert r.returncode == 0 and "blend maps: would store for 3 slots" in r.stdout, r.stderr
    assert load_blend(fresh.path) is None
    r = rig_cli("import", out, fresh.path)
    assert r.returncode == 0, r.stderr
    assert "blend maps: stored for 3 slots (from the extension's float32 maps)" in r.stdout
    src, got = load_blend(rig.path), load_blend(fresh.path)
    assert set(got.maps) == {"p1", "p2", "p3"} and all(same(src.maps[n], got.maps[n]) for n in got.maps)
    assert got.info["headroom"] == 0.3 and got.info["source"] == "mpcdi" and got.info["exact"] is True
    assert got.blend_id == src.blend_id


def test_import_of_some_slots_keeps_the_others_maps(tmp_path):
    rig = blended_table(tmp_path / "table")
    out = tmp_path / "table.mpcdi"
    assert rig_cli("export", rig.path, out).returncode == 0
    fresh = new_rig(tmp_path / "fresh")
    save_blend(fresh.path, StoredBlend(maps_for(["p1", "p2"], 2)))
    before = load_blend(fresh.path)
    r = rig_cli("import", out, fresh.path, "--slots", "p2")
    assert r.returncode == 0 and "blend maps: stored for 1 slot (from the extension's float32 maps); kept for p1" in r.stdout
    got = load_blend(fresh.path)
    assert set(got.maps) == {"p1", "p2"}
    assert same(got.maps["p1"], before.maps["p1"]) and same(got.maps["p2"], load_blend(rig.path).maps["p2"])


def test_an_archive_with_a_malformed_blend_map_changes_nothing(tmp_path):
    rig = blended_table(tmp_path / "table")
    out = tmp_path / "table.mpcdi"
    assert rig_cli("export", rig.path, out).returncode == 0
    bad = tmp_path / "bad.mpcdi"
    with zipfile.ZipFile(out) as z, zipfile.ZipFile(bad, "w") as w:
        root = ET.fromstring(z.read("mpcdi.xml"))
        root.find("files/fileset[@region='p2']/betaMap/bitDepth").text = "8"
        w.writestr("mpcdi.xml", ET.tostring(root))
        for n in z.namelist():
            if n != "mpcdi.xml":
                w.writestr(n, z.read(n))
    fresh = new_rig(tmp_path / "fresh")
    save_blend(fresh.path, StoredBlend(maps_for(["p1"], 4)))
    before = tree_digest(fresh.path)
    line = one_line_error(rig_cli("import", bad, fresh.path))
    assert "bad.mpcdi" in line and "beta-p2.png: beta map declares bitDepth 8, its PNG has 16-bit samples" in line
    assert tree_digest(fresh.path) == before


def test_a_damaged_stored_blend_is_said_on_export_and_refuses_an_import_into_it(tmp_path):
    rig = blended_table(tmp_path / "table")
    live = rig.path / "blend" / (rig.path / "blend" / "current").read_text().strip()
    (live / "alpha-p2.npy").write_bytes(b"\x93NUMPY broken")
    out = tmp_path / "table.mpcdi"
    r = rig_cli("export", rig.path, out)
    assert r.returncode == 0 and "blend maps" not in r.stdout
    assert "warning: the archive gets no blend maps" in r.stderr and "alpha-p2.npy: damaged" in r.stderr
    other = blended_table(tmp_path / "other")
    assert rig_cli("export", other.path, tmp_path / "other.mpcdi").returncode == 0
    before = tree_digest(rig.path)
    line = one_line_error(rig_cli("import", tmp_path / "other.mpcdi", rig.path))
    assert "alpha-p2.npy: damaged" in line
    assert tree_digest(rig.path) == before


def test_a_coordinator_started_on_the_imported_rig_gives_each_slot_its_maps(tmp_path):
    """After an import, the coordinator serving the rig (its own start, no nodes) assigns each slot
    the imported maps and reports the rig blended."""
    import asyncio

    from inprocess_coordinator import inprocess_coordinator
    from protos.auth import read_token

    rig = blended_table(tmp_path / "table")
    out = tmp_path / "table.mpcdi"
    assert rig_cli("export", rig.path, out).returncode == 0
    fresh = new_rig(tmp_path / "fresh")
    assert rig_cli("import", out, fresh.path).returncode == 0
    want = load_blend(rig.path).maps

    async def go():
        async with inprocess_coordinator(Rig(fresh.path), read_token(fresh.path / "token")) as app:
            served = {n: app.coordinator.rig.slot(n).blend for n in ("p1", "p2", "p3", "spare")}
            return served, app.coordinator.blend_status()

    served, status = asyncio.run(go())
    assert served["spare"] is None
    assert all(served[n] is not None and same(served[n], want[n]) for n in ("p1", "p2", "p3"))
    assert status.state == "blended" and status.blend_id
