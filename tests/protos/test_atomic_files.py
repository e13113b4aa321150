"""protos/atomic_files.py: the one NumPy-free atomic write every process uses.

Each write fsyncs its temp file, renames it over the target and then fsyncs the target's folder
(the rename is durable only once the folder is); a batch fsyncs every file first, renames them in
order and fsyncs a folder before it renames into another one. The order is read off the real
syscalls, through ``os`` wrappers that record each call and then make it.
"""
from __future__ import annotations

import os
import stat
import subprocess
import sys

import pytest

import protos.atomic_files as atomic_files
import protos.store as store


def test_the_module_imports_no_numpy():
    probe = ("import sys\nimport protos.atomic_files\n"
             "print(sorted(m for m in sys.modules if m == 'numpy' or m.startswith('numpy.')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_protos_store_hands_out_the_same_primitives():
    """Its many importers keep ``from protos.store import ...``; there is one implementation."""
    assert atomic_files.__all__
    for name in atomic_files.__all__:
        assert getattr(store, name) is getattr(atomic_files, name), name
    assert {"atomic_save_npy", "atomic_save_npz"} <= set(store.__all__)


@pytest.fixture
def syscalls(monkeypatch):
    """The fsyncs (of a file, or of a folder by path) and renames made while the test runs, in order."""
    calls: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            calls.append(("fsync dir", os.readlink(f"/proc/self/fd/{fd}")))
        else:
            calls.append(("fsync file", os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))))
        return real_fsync(fd)

    def replace(src, dst, **kw):
        calls.append(("rename", os.path.basename(os.fspath(dst))))
        return real_replace(src, dst, **kw)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    return calls


def test_a_write_fsyncs_the_file_renames_it_then_fsyncs_the_folder(tmp_path, syscalls):
    target = tmp_path / "deep" / "er" / "slot.json"      # folders made on the way
    atomic_files.atomic_write_json(target, {"gain": 0.5})
    assert target.read_text() == '{\n  "gain": 0.5\n}\n'
    assert len(syscalls) == 3
    (k0, temp), rename, fsync_dir = syscalls
    assert k0 == "fsync file" and temp.startswith(".slot.json.") and atomic_files.is_temp_name(temp)
    assert rename == ("rename", "slot.json")
    assert fsync_dir == ("fsync dir", str(target.parent))
    assert (target.stat().st_mode & 0o777) == 0o644
    assert [p.name for p in target.parent.iterdir()] == ["slot.json"]


def test_a_batch_fsyncs_every_file_first_and_each_folder_before_leaving_it(tmp_path, syscalls):
    luts, slots = tmp_path / "luts", tmp_path / "slots"
    atomic_files.atomic_write_files({luts / "a.npy": b"A", luts / "b.npy": b"B", slots / "a.json": b"{}"})
    kinds = [k for k, _ in syscalls]
    assert kinds == ["fsync file"] * 3 + ["rename", "rename", "fsync dir", "rename", "fsync dir"]
    assert syscalls[3:] == [("rename", "a.npy"), ("rename", "b.npy"), ("fsync dir", str(luts)),
                            ("rename", "a.json"), ("fsync dir", str(slots))]
    assert (luts / "b.npy").read_bytes() == b"B" and (slots / "a.json").read_bytes() == b"{}"


def test_a_failed_fsync_of_the_folder_is_raised_after_the_rename(tmp_path, monkeypatch):
    """The new content is in place but not yet durable: the caller hears it (never swallowed)."""
    real_fsync = os.fsync

    def refuse_folders(fd):
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            raise OSError(5, "Input/output error")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", refuse_folders)
    target = tmp_path / "a.bin"
    with pytest.raises(OSError, match="Input/output"):
        atomic_files.atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"new"
