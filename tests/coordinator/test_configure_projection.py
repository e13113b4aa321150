"""`shadowless configure --projection` sets an object's 3x4 pose with its mesh (sent inline, or one the
rig holds), through the same validation as everything else, and the node renders it."""
from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import numpy as np
import pytest

from cli_inprocess import cli_capture, shadowless_here  # noqa: F401 - cli_capture: the module's autouse fixture
from coordinator.api import NodeState
from shadowless.local import LocalRig
from waits import wait_until_async

QUAD_OBJ = """# a 600 x 300 mm quad on the table, textured across
v 0 0 0
v 600 0 0
v 600 300 0
v 0 300 0
vt 0 1
vt 1 1
vt 1 0
vt 0 0
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""

# a projector 1400 mm above the quad's centre looking straight down: P = K [R | -R C]
K = np.array([[200.0, 0.0, 80.0], [0.0, 200.0, 45.0], [0.0, 0.0, 1.0]])
R = np.diag([1.0, -1.0, -1.0])
P = K @ np.hstack([R, -R @ np.array([[300.0], [150.0], [1400.0]])])


@pytest.fixture
def rig(tmp_path):
    r = LocalRig(["r0c0"], tmp_path, output_size=(160, 90), content_size=(160, 90), mdns=False).create()
    try:
        r.start_coordinator()
        r.wait_ready()
        r.start_node("r0c0")
        yield r
    finally:
        r.close()


def cli(rig: LocalRig, *args: str, process: bool = False) -> subprocess.CompletedProcess:
    """`shadowless ARGS...` against ``rig``: in this interpreter, or with ``process`` as a real process."""
    argv = [*args, "--coordinator", rig.target, "--rig-dir", str(rig.rig_dir)]
    if not process:
        return shadowless_here(argv)
    return subprocess.run([sys.executable, "-m", "shadowless", *argv], capture_output=True, text=True, timeout=120)


def test_a_projection_pose_with_its_mesh_reaches_the_rig_and_the_node(rig, tmp_path):
    (tmp_path / "quad.obj").write_text(QUAD_OBJ)
    np.save(tmp_path / "p.npy", P)
    r = cli(rig, "configure", "--slot", "r0c0", "--projection", str(tmp_path / "p.npy"), "--mesh",
            str(tmp_path / "quad.obj"), process=True)
    assert r.returncode == 0, r.stderr
    doc = json.loads((rig.rig_dir / "slots" / "r0c0.json").read_text())
    assert doc["pose"]["kind"] == "projection"
    assert np.array_equal(np.array(doc["pose"]["matrix"]), P)
    mesh_id = doc["pose"]["mesh"]
    with np.load(rig.rig_dir / "meshes" / f"{mesh_id}.npz") as z:
        assert z["vertices"].shape == (4, 3) and z["faces"].shape == (2, 3)
        assert np.allclose(z["uvs"][2], [1, 1]), "OBJ texture v runs up; the rig's uv origin is the top-left"

    async def live_pose():
        async with await rig.client() as c:
            await rig.wait_live(c, timeout=120)

            async def node():
                return (await c.status()).nodes[0]

            return await wait_until_async(node, lambda n: n.state is NodeState.LIVE and n.pose_kind == "projection"
                                          and n.assignment_revision == doc["revision"],
                                          what=f"r0c0 live on the projection pose of revision {doc['revision']}")

    assert asyncio.run(live_pose()).pose_kind == "projection", "the node applied the 3x4 pose on the mesh"

    # the same mesh again by its id, a new pose given as 12 numbers
    r = cli(rig, "configure", "--slot", "r0c0", "--projection", ",".join(str(v) for v in (P * 2).ravel()),
            "--mesh-id", mesh_id)
    assert r.returncode == 0, r.stderr
    doc2 = json.loads((rig.rig_dir / "slots" / "r0c0.json").read_text())
    assert doc2["pose"]["mesh"] == mesh_id and np.array_equal(np.array(doc2["pose"]["matrix"]), P * 2)


def test_a_mesh_the_rig_does_not_hold_a_mesh_without_uvs_and_an_affine_pose_are_refused(rig, tmp_path):
    before = (rig.rig_dir / "slots").exists() and sorted(p.read_bytes() for p in (rig.rig_dir / "slots").iterdir())
    r = cli(rig, "configure", "--slot", "r0c0", "--projection", ",".join(["1"] * 12), "--mesh-id", "nope")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "the rig holds no mesh 'nope'" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r = cli(rig, "configure", "--slot", "r0c0", "--projection", ",".join(["1"] * 12), "--mesh",
            str(tmp_path / "flat.obj"))
    assert r.returncode == 2 and "no texture coordinates" in r.stderr
    (tmp_path / "quad.obj").write_text(QUAD_OBJ)
    affine = "0.2,0,0,10,0,0.2,0,5,0,0,0,1"      # no depth axis: the nodes could not render it
    r = cli(rig, "configure", "--slot", "r0c0", "--projection", affine, "--mesh", str(tmp_path / "quad.obj"))
    assert r.returncode == 2 and "needs a depth axis" in r.stderr, r.stderr
    after = (rig.rig_dir / "slots").exists() and sorted(p.read_bytes() for p in (rig.rig_dir / "slots").iterdir())
    assert before == after
