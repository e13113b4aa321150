"""The blend store (coordinator/blend_store.py): a blend and the contributions round-trip bit for
bit, a save is all or nothing even under kill -9, malformed files are refused in one line naming
the file, and start-up recovery settles what a crash left."""
from __future__ import annotations

import inspect
import json
import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from coordinator.blend_store import (BlendStoreError, StoredBlend, blend_dir, clear_blend, load_blend,
                                     load_contributions, save_blend, save_contributions)
from coordinator.errors import CoordinatorError
from coordinator.recovery import QUARANTINE, recover
from protos.blend import BlendMaps
from waits import wait_until

ROOT = Path(__file__).resolve().parents[2]
SLOTS = ("r0c0", "r0c1", "r1c0")


def _blend(n: int, *, h: int = 12, w: int = 16) -> StoredBlend:
    """Blend number ``n``: every value a function of ``n``, so a mix of two blends is seen."""
    rng = np.random.default_rng(n)
    maps = {s: BlendMaps(rng.random((h, w, 3), dtype=np.float32), rng.random((h, w), dtype=np.float32))
            for s in SLOTS}
    pictures = {"before": rng.random((5, 7), dtype=np.float32) + 0.5, "after": np.full((5, 7), np.nan, np.float32)}
    return StoredBlend(maps, {"n": n, "headroom": 0.25, "brightness_cost": 0.2, "captures": 4}, pictures)


def _contributions(n: int) -> tuple[dict[str, np.ndarray], dict]:
    rng = np.random.default_rng(1000 + n)
    arrays = {f"white/{s}": rng.random((6, 8, 3), dtype=np.float32) for s in SLOTS}
    arrays["camera_to_projector"] = rng.random((len(SLOTS), 3, 3))
    arrays["mask"] = rng.random((6, 8)) > 0.5
    return arrays, {"n": n, "slots": list(SLOTS), "scale": 4}


def _same_blend(a: StoredBlend, b: StoredBlend) -> bool:
    if a.info != b.info or set(a.maps) != set(b.maps) or set(a.pictures) != set(b.pictures):
        return False
    for s in a.maps:
        if a.maps[s].blend_id != b.maps[s].blend_id:
            return False
        if not (np.array_equal(a.maps[s].alpha, b.maps[s].alpha) and np.array_equal(a.maps[s].beta, b.maps[s].beta)):
            return False
    return all(np.array_equal(a.pictures[k], b.pictures[k], equal_nan=True) for k in a.pictures)


def _same_arrays(a: dict, b: dict) -> bool:
    return set(a) == set(b) and all(a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]) for k in a)


def _generation(rig: Path, sub: str = "") -> Path:
    root = blend_dir(rig) / sub
    return root / (root / "current").read_text().strip()


def _rehash(gen: Path) -> None:
    """Make ``gen``'s index agree with its files again (to reach the checks behind the checksum)."""
    import hashlib
    index = json.loads((gen / "index.json").read_text())
    index["files"] = {f: hashlib.sha256((gen / f).read_bytes()).hexdigest() for f in index["files"]}
    (gen / "index.json").write_text(json.dumps(index))


def test_a_blend_and_contributions_round_trip_bit_for_bit(tmp_path):
    assert load_blend(tmp_path) is None and load_contributions(tmp_path) is None
    blend = _blend(1)
    save_blend(tmp_path, blend)
    back = load_blend(tmp_path)
    assert _same_blend(back, blend)
    assert back.maps["r0c0"].alpha.dtype == np.float32 and back.pictures["before"].dtype == np.float32
    assert back.blend_id == blend.blend_id and back.blend_id != _blend(2).blend_id
    arrays, meta = _contributions(1)
    save_contributions(tmp_path, arrays, meta)
    got_arrays, got_meta = load_contributions(tmp_path)
    assert _same_arrays(got_arrays, arrays) and got_meta == meta
    assert got_arrays["mask"].dtype == bool and got_arrays["camera_to_projector"].dtype == np.float64

    # a new save replaces the old one and leaves one generation of each
    save_blend(tmp_path, _blend(2))
    save_contributions(tmp_path, *_contributions(2))
    assert _same_blend(load_blend(tmp_path), _blend(2))
    assert load_contributions(tmp_path)[1]["n"] == 2
    assert sorted(p.name for p in blend_dir(tmp_path).iterdir() if p.name.startswith("g")) == [_generation(tmp_path).name]
    assert len([p for p in (blend_dir(tmp_path) / "contributions").iterdir() if p.name[1:].isdigit()]) == 1

    # the figures may be NumPy numbers (what a job computes): they are stored as plain JSON
    save_blend(tmp_path, StoredBlend(_blend(4).maps, {"headroom": np.float32(0.25), "gains": np.array([1.0, 0.5]),
                                                      "captures": np.int64(4)}))
    assert load_blend(tmp_path).info == {"headroom": 0.25, "gains": [1.0, 0.5], "captures": 4}

    # clearing the blend alone keeps the contributions; clearing all removes both
    clear_blend(tmp_path, contributions=False)
    assert load_blend(tmp_path) is None and load_contributions(tmp_path) is not None
    save_blend(tmp_path, _blend(3))
    clear_blend(tmp_path)
    assert load_blend(tmp_path) is None and load_contributions(tmp_path) is None
    assert not [p for p in blend_dir(tmp_path).rglob("*") if p.is_dir() and p.name[0] in "gc" and p.name[1:].isdigit()]


def test_the_blend_jobs_contributions_come_back_whole(tmp_path):
    """What the blend job stores (imaging.blending.Contributions.to_arrays) reads back as the same
    Contributions: the failover recomputes from it."""
    from imaging.blending.contributions import Contributions

    rng = np.random.default_rng(5)
    c = Contributions((64, 48), 4, {s: rng.random((12, 16, 3), dtype=np.float32) for s in SLOTS},
                      {s: rng.random((12, 16, 3), dtype=np.float32) * 0.01 for s in SLOTS},
                      {s: rng.random((3, 3)) + np.eye(3) for s in SLOTS}, {s: (32, 24) for s in SLOTS})
    save_contributions(tmp_path, *c.to_arrays())
    back = Contributions.from_arrays(*load_contributions(tmp_path))
    assert (back.camera_size, back.scale, back.projector_size) == (c.camera_size, c.scale, c.projector_size)
    for s in SLOTS:
        for a, b in ((back.white, c.white), (back.black, c.black), (back.camera_to_projector, c.camera_to_projector)):
            assert a[s].dtype == b[s].dtype and np.array_equal(a[s], b[s])


@pytest.mark.parametrize("bad, words", [
    (lambda b: StoredBlend({"r0 c0": b.maps["r0c0"]}, b.info, b.pictures), "not a slot name"),
    (lambda b: StoredBlend({"r0c0": (b.maps["r0c0"].alpha, b.maps["r0c0"].beta)}, b.info), "expected BlendMaps"),
    (lambda b: StoredBlend(b.maps, {"when": object()}, b.pictures), "JSON-able"),
    (lambda b: StoredBlend(b.maps, b.info, {"before": np.zeros((4, 4, 3), np.float32)}), "(h, w) array"),
    (lambda b: StoredBlend(b.maps, b.info, {"../x": np.zeros((4, 4), np.float32)}), "picture name"),
])
def test_a_malformed_blend_is_refused_in_one_line_and_nothing_stored_changes(tmp_path, bad, words):
    save_blend(tmp_path, _blend(1))
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    with pytest.raises(BlendStoreError) as e:
        save_blend(tmp_path, bad(_blend(2)))
    assert words in str(e.value) and "\n" not in str(e.value)
    assert isinstance(e.value, CoordinatorError)
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before
    assert _same_blend(load_blend(tmp_path), _blend(1))


def test_malformed_contributions_are_refused_and_nothing_stored_changes(tmp_path):
    save_contributions(tmp_path, *_contributions(1))
    for arrays, meta, words in (({"x": np.array(["a", "b"])}, {}, "numbers or booleans"),
                                ({"": np.zeros(2)}, {}, "non-empty names"),
                                ({"x": np.zeros(2)}, {"f": {1, 2}}, "JSON-able")):
        with pytest.raises(BlendStoreError, match=words):
            save_contributions(tmp_path, arrays, meta)
    assert load_contributions(tmp_path)[1]["n"] == 1


def _damage_truncate(gen: Path) -> str:
    f = gen / "alpha-r0c1.npy"
    f.write_bytes(f.read_bytes()[:100])
    return "alpha-r0c1.npy: damaged"


def _damage_missing(gen: Path) -> str:
    (gen / "beta-r1c0.npy").unlink()
    return "beta-r1c0.npy: missing"


def _damage_index(gen: Path) -> str:
    (gen / "index.json").write_text('{"version": 1, "kind": "bl')
    return "index.json: not valid JSON"


def _damage_out_of_range(gen: Path) -> str:
    np.save(gen / "alpha-r0c0.npy", np.full((12, 16, 3), 2.0, np.float32))
    _rehash(gen)
    return "alpha-r0c0.npy: alpha map must lie in 0..1"


def _damage_dtype(gen: Path) -> str:
    np.save(gen / "beta-r0c0.npy", np.zeros((12, 16), np.float64))
    _rehash(gen)
    return "beta-r0c0.npy: beta map of slot r0c0 must be float32"


def _damage_info(gen: Path) -> str:
    (gen / "info.json").write_text("[1, 2]\n")
    _rehash(gen)
    return "info.json: not a JSON object"


def _damage_pointer(gen: Path) -> str:
    (gen.parent / "current").write_text("../../etc\n")
    return "current: does not name a generation folder"


def _damage_pointer_target(gen: Path) -> str:
    (gen.parent / "current").write_text("g000099\n")
    return "current: names g000099, which is missing"


DAMAGE = [_damage_truncate, _damage_missing, _damage_index, _damage_out_of_range, _damage_dtype, _damage_info,
          _damage_pointer, _damage_pointer_target]


@pytest.mark.parametrize("damage", DAMAGE, ids=lambda f: f.__name__[8:])
def test_a_damaged_blend_is_refused_naming_the_file_and_recovery_quarantines_it(tmp_path, damage):
    save_blend(tmp_path, _blend(1))
    gen = _generation(tmp_path)
    words = damage(gen)
    with pytest.raises(BlendStoreError) as e:
        load_blend(tmp_path)
    msg = str(e.value)
    assert words in msg and str(blend_dir(tmp_path)) in msg and "\n" not in msg, msg
    r = recover(tmp_path)
    assert r.errors == []
    assert [a.verb for a in r.actions if "blend/" in a.path and a.verb == "quarantined"], r.actions
    assert load_blend(tmp_path) is None               # the rig starts without a blend
    assert any((tmp_path / QUARANTINE).rglob("current"))
    save_blend(tmp_path, _blend(2))                   # and the next blend is stored as usual
    assert _same_blend(load_blend(tmp_path), _blend(2))


def test_damaged_contributions_are_refused_naming_the_file(tmp_path):
    save_contributions(tmp_path, *_contributions(1))
    gen = _generation(tmp_path, "contributions")
    (gen / "meta.json").write_text('{"n": 2}')
    with pytest.raises(BlendStoreError, match=r"contributions/c000001/meta\.json: damaged"):
        load_contributions(tmp_path)


def test_recovery_removes_generations_no_pointer_names_and_keeps_the_live_one(tmp_path):
    save_blend(tmp_path, _blend(1))
    save_contributions(tmp_path, *_contributions(1))
    live = _generation(tmp_path)
    # a save cut before its commit (a later number), an old one whose clean-up was cut, a temp file
    (blend_dir(tmp_path) / "g000007").mkdir()
    (blend_dir(tmp_path) / "g000007" / "alpha-r0c0.npy").write_bytes(b"\x93NUMPY")
    (blend_dir(tmp_path) / "g000000").mkdir()
    (blend_dir(tmp_path) / "contributions" / "c000005").mkdir()
    (live / ".beta-r0c0.npy.abcd1234.tmp").write_bytes(b"x")
    r = recover(tmp_path)
    assert r.errors == []
    done = {(a.verb, a.path) for a in r.actions}
    assert {("rolled back", "blend/g000007"), ("rolled back", "blend/g000000"),
            ("rolled back", "blend/contributions/c000005")} <= done, done
    assert ("removed", f"blend/{live.name}/.beta-r0c0.npy.abcd1234.tmp") in done
    assert _same_blend(load_blend(tmp_path), _blend(1))
    assert load_contributions(tmp_path)[1]["n"] == 1
    assert recover(tmp_path).actions == []            # nothing left to do
    # a clear cut after the pointer went: the folders go, no blend is read
    (blend_dir(tmp_path) / "current").unlink()
    r = recover(tmp_path)
    assert [(a.verb, a.path) for a in r.actions] == [("rolled back", f"blend/{live.name}")]
    assert load_blend(tmp_path) is None


def test_a_reader_beside_a_saving_thread_always_reads_one_whole_blend(tmp_path):
    """The console and a failover read while a job saves: each read is one whole blend."""
    import threading

    save_blend(tmp_path, _blend(0))
    done = threading.Event()
    errors: list[BaseException] = []

    def writer():
        try:
            for n in range(1, 11):
                save_blend(tmp_path, _blend(n))
        except BaseException as exc:       # noqa: BLE001 - reported by the test
            errors.append(exc)
        finally:
            done.set()

    t = threading.Thread(target=writer)
    t.start()
    reads = []
    try:
        while not done.is_set() or not reads:
            got = load_blend(tmp_path)
            assert _same_blend(got, _blend(got.info["n"])), "a mix of blends"
            reads.append(got.info["n"])
    finally:
        t.join(60)
    assert errors == [] and reads == sorted(reads)
    assert load_blend(tmp_path).info["n"] == 10


_WRITER = """
import sys
sys.path.insert(0, {root!r})
from pathlib import Path
import numpy as np
from coordinator.blend_store import StoredBlend, save_blend, save_contributions
from protos.blend import BlendMaps
SLOTS = {slots!r}
{generators}
rig = Path(sys.argv[1])
n = int(sys.argv[2])
while True:
    n += 1
    save_contributions(rig, *_contributions(n))
    save_blend(rig, _blend(n, h=96, w=128))
"""


def test_kill_9_during_saves_leaves_the_old_or_the_new_blend_whole(tmp_path):
    """A real process saves blend after blend and is killed at a random point of a save (when the
    new generation holds a random number of files); what is read is one whole blend, never a mix,
    recovery leaves only it, and the next save works. Six kills."""
    rng = random.Random(37)
    # the writer runs this module's own generators, without importing the test module (and pytest)
    script = _WRITER.format(root=str(ROOT), slots=SLOTS,
                            generators="\n".join(inspect.getsource(f) for f in (_blend, _contributions)))
    rig = tmp_path / "rig"
    save_contributions(rig, *_contributions(0))
    save_blend(rig, _blend(0, h=96, w=128))
    last = 0
    cut = 0                                           # trials killed with a save under way
    files_per_blend = 2 * len(SLOTS) + 2 + 2          # maps, pictures, info, index
    for trial in range(6):
        proc = subprocess.Popen([sys.executable, "-c", script, str(rig), str(last)], cwd=ROOT)
        try:
            target = rng.randint(0, files_per_blend - 1)

            def uncommitted_files() -> int:
                """Files in a generation newer than the committed one (-1: none yet)."""
                root = blend_dir(rig)
                try:
                    live = int((root / "current").read_text().strip()[1:])
                    newer = [p for p in root.iterdir()
                             if p.name.startswith("g") and p.name[1:].isdigit() and int(p.name[1:]) > live]
                    return max((len(os.listdir(p)) for p in newer), default=-1)
                except (FileNotFoundError, ValueError):
                    return -1

            wait_until(uncommitted_files, lambda k: k >= target, what=f"a save with {target} files written",
                       interval=0.002)
            proc.send_signal(signal.SIGKILL)
        finally:
            proc.kill()
            proc.wait(30)
        got = load_blend(rig)
        n = got.info["n"]
        assert n >= last and _same_blend(got, _blend(n, h=96, w=128)), f"trial {trial}: a mix of blends"
        arrays, meta = load_contributions(rig)
        assert meta["n"] in (n, n + 1) and _same_arrays(arrays, _contributions(meta["n"])[0])
        r = recover(rig)
        assert r.errors == [] and not [a for a in r.actions if a.verb == "quarantined"], r.actions
        cut += any(a.verb == "rolled back" for a in r.actions)
        assert _same_blend(load_blend(rig), got)
        assert len([p for p in blend_dir(rig).iterdir() if p.name.startswith("g")]) == 1
        assert not [p for p in rig.rglob("*.tmp")]
        last = n
    assert cut >= 1                                   # the kills did land inside saves
    save_blend(rig, _blend(100))
    assert load_blend(rig).info["n"] == 100
