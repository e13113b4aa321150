"""Atomic writes: a reader sees the old file or the new one, never half of one, even when
the writer is killed mid-write."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from coordinator.rig import Content, Rig, RigError, grid_slots, init_rig
from protos.store import STALE_TEMP_S, atomic_file, atomic_save_npz, atomic_write_json, atomic_write_text, remove_stale_temps


def test_a_write_replaces_the_file_with_the_requested_mode(tmp_path):
    f = tmp_path / "sub" / "token"
    atomic_write_text(f, "old", mode=0o600)
    atomic_write_text(f, "new", mode=0o600)
    assert f.read_text() == "new" and (f.stat().st_mode & 0o777) == 0o600
    assert sorted(p.name for p in f.parent.iterdir()) == ["token"], "no temp file left behind"


def test_a_failing_write_keeps_the_old_content_and_removes_its_temp_file(tmp_path):
    f = tmp_path / "rig.json"
    atomic_write_json(f, {"a": 1})
    with pytest.raises(RuntimeError):
        with atomic_file(f) as out:
            out.write(b"{half")
            raise RuntimeError("disk on fire")
    assert f.read_text() == '{\n  "a": 1\n}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["rig.json"]


def test_arrays_round_trip(tmp_path):
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    atomic_save_npz(tmp_path / "t.npz", a=a, b=a.astype(np.uint16))
    with np.load(tmp_path / "t.npz") as z:
        np.testing.assert_array_equal(z["a"], a)
        assert z["b"].dtype == np.uint16


def test_a_writer_killed_mid_write_leaves_the_old_file_whole(tmp_path):
    f = tmp_path / "transport.npz"
    atomic_write_text(f, "the old, complete file")
    script = textwrap.dedent(f"""
        import os, signal, sys
        from protos.store import atomic_file
        with atomic_file({str(f)!r}) as out:
            out.write(b"x" * 1_000_000)
            out.flush()
            sys.stdout.write("writing\\n"); sys.stdout.flush()
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=os.getcwd(), timeout=60)
    assert p.returncode == -signal.SIGKILL and "writing" in p.stdout
    assert f.read_text() == "the old, complete file"
    leftovers = [q for q in tmp_path.iterdir() if q.name != f.name]
    assert len(leftovers) == 1 and leftovers[0].name.startswith(".transport.npz.") and leftovers[0].stat().st_size > 0
    # a fresh temp file may belong to a live writer: kept; an old one is a leftover: removed
    assert remove_stale_temps(tmp_path) == []
    old = leftovers[0].stat().st_mtime - STALE_TEMP_S - 1
    os.utime(leftovers[0], (old, old))
    assert remove_stale_temps(tmp_path) == leftovers
    assert [q.name for q in tmp_path.iterdir()] == [f.name]


def test_loading_a_rig_sweeps_what_killed_writers_left_but_not_the_asset_staging(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32)
    stale = [rig_dir / "slots" / ".r0c0.json.abc123.tmp", rig_dir / "assets" / "tmp" / ".x.tmp"]
    for p in stale:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"half")
        os.utime(p, (0, 0))
    Rig(rig_dir, read_only=True)    # looking at a rig (rig show, rig export) writes nothing
    assert stale[0].exists() and stale[1].exists()
    Rig(rig_dir)
    assert not stale[0].exists() and stale[1].exists()


def test_a_rig_opened_read_only_refuses_every_change(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32)
    before = {p: p.read_bytes() for p in rig_dir.rglob("*") if p.is_file()}
    rig = Rig(rig_dir, read_only=True)
    with pytest.raises(RigError, match="read-only"):
        rig.update_slot("r0c0", gain=0.5)
    with pytest.raises(RigError, match="read-only"):
        rig.set_content(Content(np.zeros((32, 32, 3), np.uint8), name="black"))
    assert {p: p.read_bytes() for p in rig_dir.rglob("*") if p.is_file()} == before


def test_sweep_logs_count_and_bytes_once_and_stays_inside_the_tree(tmp_path, caplog):
    root, outside = tmp_path / "rig", tmp_path / "elsewhere"
    (root / "slots").mkdir(parents=True)
    outside.mkdir()
    stale = [root / ".rig.toml.aaaaaa.tmp", root / "slots" / ".r0.json.bbbbbb.tmp"]
    far = outside / ".x.json.cccccc.tmp"
    for i, p in enumerate(stale + [far]):
        p.write_bytes(b"x" * (5 + i))
        os.utime(p, (0, 0))
    (root / "link").symlink_to(outside, target_is_directory=True)   # a symlinked folder is not followed
    (root / ".dangling.json.dddddd.tmp").symlink_to(far)           # nor is a symlink removed as a temp file
    caplog.set_level("INFO", logger="protos.atomic_files")
    assert sorted(remove_stale_temps(root)) == sorted(stale)
    assert far.exists()
    assert [r.getMessage() for r in caplog.records] == [f"removed 2 temp file(s) (11 bytes) left by interrupted writes under {root}"]
