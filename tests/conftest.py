"""Shared test fixtures. Every test is checked for leaked processes, threads, venue namespaces and
temporary files.

The session gets its own temporary directory (``TMPDIR`` for the processes the tests start, and
:mod:`tempfile`'s default here), so a test that leaves something in it is told apart from
whatever else runs on the machine; the directory is removed when the session ends."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import pytest

os.environ.setdefault("SHADOWLESS_TEST", "1")
# OpenBLAS's idle threads sleep at once instead of spinning ~0.1 s of a core after each call (as every
# `shadowless` process sets for itself in shadowless.cli.main): the workers' own numpy counts too
os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")
#: the tests' own cache, outside the checkout (SHADOWLESS_TESTS_CACHE; "off": none): bytecode, and each
#: test's last duration (which orders the modules across xdist's workers, see below)
_CACHE = os.environ.get("SHADOWLESS_TESTS_CACHE",
                        str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "shadowless-tests"))
_CACHE = None if _CACHE in ("", "off") else Path(_CACHE)
if _CACHE is not None and sys.dont_write_bytecode and not os.environ.get("PYTHONPYCACHEPREFIX"):
    # Bytecode is not to be written beside the sources here (PYTHONDONTWRITEBYTECODE, as container
    # images often set): it goes to the tests' cache instead, else each of the suite's thousand-odd
    # `python -m shadowless` processes compiles the project again (a quarter of a second of CPU for a
    # coordinator) and each worker rewrites every test module's asserts (half its collection time).
    # Python checks each cached file against its source's mtime and size.
    try:
        (_CACHE / "pycache").mkdir(parents=True, exist_ok=True)
    except OSError:
        pass   # nowhere to cache: the environment's choice stands
    else:
        os.environ.pop("PYTHONDONTWRITEBYTECODE", None)     # the processes the tests start, and xdist's workers
        os.environ["PYTHONPYCACHEPREFIX"] = str(_CACHE / "pycache")
        sys.pycache_prefix = str(_CACHE / "pycache")
        sys.dont_write_bytecode = False
if os.environ.get("PYTEST_XDIST_WORKER"):  # workers side by side: rigs of one never seen by the other
    os.environ["SHADOWLESS_MDNS_SERVICE"] = "_shadowless-" + os.environ["PYTEST_XDIST_WORKER"]

from shadowless.netns import available as venue_available  # noqa: E402 - after the environment above
from waits import WaitTimeout, wait_until  # noqa: E402 - tests/support is on pytest's pythonpath


def child_pids(root: int | None = None, *, exclude: set[int] = frozenset()) -> set[int]:
    """All live descendants of ``root`` (default: this process), not descending into the subtrees
    of ``exclude`` (processes a longer-lived fixture owns; their own children are theirs to manage).

    Read from each process's ``/proc/PID/task/*/children`` (a few files for a few descendants; this
    runs twice a test), or, where the kernel has no such files, from every process's parent in
    ``/proc/*/stat``; zombies are left out either way."""
    root = os.getpid() if root is None else root
    if not Path(f"/proc/{root}/task/{root}/children").exists():
        return _child_pids_by_scan(root, exclude)
    found: set[int] = set()
    frontier = [root]
    while frontier:
        p = frontier.pop()
        try:
            tasks = list(Path(f"/proc/{p}/task").iterdir())
        except OSError:
            continue
        for task in tasks:
            try:
                kids = (task / "children").read_text().split()
            except OSError:
                continue
            for kid in map(int, kids):
                if kid not in found and kid not in exclude and _state(kid) not in ("Z", None):
                    found.add(kid)
                    frontier.append(kid)
    return found


def _state(pid: int) -> str | None:
    """A process's state letter (``R``, ``S``, ``Z``...), or None once it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat[stat.rfind(")") + 2 :].split(maxsplit=1)[0]    # comm may contain spaces and parentheses


def _child_pids_by_scan(root: int, exclude: set[int]) -> set[int]:
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...; comm may contain spaces and parentheses
        fields = stat[stat.rfind(")") + 2 :].split()
        if fields[0] == "Z":
            continue
        parents[int(entry.name)] = int(fields[1])
    found: set[int] = set()
    frontier = [root]
    while frontier:
        p = frontier.pop()
        for pid, ppid in parents.items():
            if ppid == p and pid not in found and pid not in exclude:
                found.add(pid)
                frontier.append(pid)
    return found


def _live_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.is_alive()}


def _is_runtime_thread(t: threading.Thread) -> bool:
    """Threads owned by a library for the whole process, not by a test: asyncio's default
    executor workers and grpc.aio's single completion-queue poller (started on first use)."""
    return t.name.startswith(("asyncio_", "ThreadPoolExecutor")) or "_poll_wrapper" in t.name


#: the session's temporary directory (set in pytest_configure)
_SESSION_TMP: Path | None = None


def _temp_entries() -> set[str]:
    """What lies in the session's temporary directory, except pytest's own ``tmp_path`` tree."""
    if _SESSION_TMP is None:
        return set()
    try:
        return {e.name for e in _SESSION_TMP.iterdir() if not e.name.startswith("pytest-of-")}
    except OSError:
        return set()


def _owned_namespaces() -> set[str]:
    """Network namespaces of venues this process owns (shadowless.netns); only looked up once
    that module is loaded, since nothing else creates them."""
    mod = sys.modules.get("shadowless.netns")
    if mod is None:
        return set()
    try:
        return set(mod.owned_namespaces())
    except Exception:   # noqa: BLE001 - no `ip`, no state directory: nothing of ours can exist
        return set()


@pytest.fixture(autouse=True)
def no_leaks(request):
    """Fail a test that leaves processes, threads, venue namespaces or temporary files behind (after a short
    grace)."""
    before_pids = child_pids()
    before_threads = _live_threads()
    before_ns = _owned_namespaces()
    before_tmp = _temp_entries()
    yield
    if request.node.get_closest_marker("allow_leaks"):
        return
    def leftovers() -> tuple[set[int], set[threading.Thread]]:
        pids = child_pids(exclude=before_pids)
        threads = {t for t in _live_threads() - before_threads if not _is_runtime_thread(t)}
        return pids, threads

    try:   # a short grace: a child or thread that is already on its way out gets to finish
        pids, threads = wait_until(leftovers, lambda left: not left[0] and not left[1],
                                   what="no leaked child processes or threads", timeout=5.0)
    except WaitTimeout:
        pids, threads = leftovers()   # reported below, with the namespaces and temporary files
    namespaces = _owned_namespaces() - before_ns
    temps = _temp_entries() - before_tmp
    for name in temps:      # removed, so the next test starts clean
        shutil.rmtree(_SESSION_TMP / name, ignore_errors=True)
        (_SESSION_TMP / name).unlink(missing_ok=True)
    if namespaces:
        try:   # close the venues still open (their processes and namespaces) before failing
            sys.modules["shadowless.netns"].close_owned(namespaces)
        except Exception:   # noqa: BLE001
            pass
    if not pids and not threads and not namespaces and not temps:
        return
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    problems = []
    if namespaces:
        problems.append(f"leaked network namespaces {sorted(namespaces)}")
    if pids:
        problems.append(f"leaked processes {sorted(pids)}")
    if threads:
        problems.append(f"leaked threads {sorted(t.name for t in threads)}")
    if temps:
        problems.append(f"leaked temporary files {sorted(temps)} (in {_SESSION_TMP})")
    pytest.fail("; ".join(problems), pytrace=False)


#: ``SHADOWLESS_TEST_COSTS=FILE``: every test's cost appended to FILE as a JSON line (see below)
_COSTS = os.environ.get("SHADOWLESS_TEST_COSTS")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With ``SHADOWLESS_TEST_COSTS=FILE``, each test (setup, call and teardown) appends
    ``{"test", "outcome", "wall_s", "cpu_s", "children_cpu_s"}`` to FILE: the wall time, this interpreter's CPU
    time and that of the child processes it waited for (a module-scoped rig's processes count at the
    teardown that stops them). Summed per module, it tells what a module costs the machine, which its
    wall time on a busy machine does not."""
    if not _COSTS:
        yield
        return
    import json
    import resource
    import time

    def children() -> float:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    wall, cpu, kids = time.monotonic(), time.process_time(), children()
    yield
    failed = any(getattr(item, f"_shadowless_{when}_failed", False) for when in ("setup", "call", "teardown"))
    line = json.dumps({"test": item.nodeid, "outcome": "failed" if failed else "passed",
                       "wall_s": round(time.monotonic() - wall, 3),
                       "cpu_s": round(time.process_time() - cpu, 3), "children_cpu_s": round(children() - kids, 3)})
    with open(_COSTS, "a") as f:
        f.write(line + "\n")


# ---- the longest modules first -----------------------------------------------------------------
# `--dist loadfile` hands each worker a module at a time, and pytest-xdist queues the modules with the
# most tests first: its modules of one long test (a benchmark, a rig of real processes) came last,
# and the run ended with one worker on a long module while the others had nothing left. Each session
# records its tests' durations in the tests' cache; the next one queues its modules by their recorded
# time (a test never timed counts DEFAULT_TEST_S), the longest first. The controller reads the record
# once and hands it to its workers, so that every worker collects in one order.
#
# A clean clone (CI) has no record, and its run used to end on whatever long module xdist queued last:
# there the modules of KNOWN_SECONDS (each module's seconds in a whole `make test` on the project's 2-core
# machine on 2026-12-07, under other work's load: only their order matters) go first in that order, and
# every other module counts DEFAULT_TEST_S a test. A module the record has timed (any of its tests) is
# ordered by the record instead, which follows the tests as they change; this list only has to keep the
# long modules ahead of the short ones.
DEFAULT_TEST_S = 0.5
KNOWN_SECONDS: dict[str, float] = {
    "tests/deploy/test_install.py": 160,
    "tests/bench/test_compensation_memory.py": 157,
    "tests/coordinator/compensation/test_mesh_cameras.py": 145,
    "tests/coordinator/calibration/test_job_room.py": 139,
    "tests/coordinator/compensation/test_video_cluster.py": 126,
    "tests/coordinator/compensation/test_job_room.py": 125,
    "tests/coordinator/compensation/test_bench.py": 124,
    "tests/coordinator/console/test_console_workflow.py": 109,
    "tests/node/test_discovery_hostile.py": 107,
    "tests/coordinator/calibration/test_end_to_end.py": 103,
    "tests/coordinator/test_distribution.py": 103,
    "tests/shadowless/test_netns.py": 91,
    "tests/coordinator/blending/test_blend_job_nodes.py": 85,
    "tests/coordinator/compensation/test_job_end_to_end.py": 77,
    "tests/coordinator/console/test_console_browser.py": 72,
    "tests/sim/test_bench_room.py": 70,
    "tests/coordinator/console/test_console_pictures.py": 66,
    "tests/shadowless/test_demo.py": 63,
    "tests/shadowless/test_local_rig.py": 61,
    "tests/imaging/calibration/test_multiplex3d.py": 53,
    "tests/sim/test_room_shared_frames.py": 53,
    "tests/coordinator/console/test_console_thumbnails.py": 52,
    "tests/coordinator/compensation/test_mesh_jobs.py": 46,
    "tests/rigctl/test_rig_target.py": 44,
    "tests/coordinator/test_show_rig.py": 43,
    "tests/coordinator/test_crash_recovery.py": 36,
    "tests/bench/test_venue.py": 35,
    "tests/node/test_render_gles.py": 34,
    "tests/bench/test_swarm.py": 33,
    "tests/imaging/compensation/test_solver.py": 32,
    "tests/planner/test_pointwise.py": 32,
    "tests/coordinator/test_refusals.py": 30,
    "tests/coordinator/console/test_console_blend.py": 28,
    "tests/coordinator/blending/test_watchdog_room.py": 27,
    "tests/protos/test_discovery_refusals.py": 27,
    "tests/coordinator/test_flood.py": 27,
    "tests/bench/test_compensation_bust_oracle.py": 26,
    "tests/coordinator/test_mdns_names.py": 22,
    "tests/deploy/test_pi_path.py": 22,
    "tests/coordinator/test_admission.py": 21,
    "tests/protos/test_service_type.py": 19,
    "tests/shadowless/test_swarm.py": 17,
    "tests/imaging/compensation/test_memory_estimate.py": 17,
    "tests/coordinator/console/test_console_page_tools.py": 16,
    "tests/bench/test_node.py": 16,
    "tests/deploy/test_containers.py": 16,
    "tests/planner/test_placement.py": 15,
    "tests/coordinator/compensation/test_video_job.py": 15,
    "tests/node/test_asset_frames.py": 15,
    "tests/node/test_systemd_node.py": 15,
    "tests/bench/test_console_login_bench.py": 14,
    "tests/coordinator/compensation/test_memory_refusals.py": 13,
    "tests/coordinator/test_live_rig.py": 13,
    "tests/node/test_session_rejoin.py": 11,
    "tests/imaging/compensation/test_precompile.py": 10,
    "tests/coordinator/test_node_left.py": 10,
    "tests/coordinator/blending/test_failover_live.py": 10,
}
_DURATIONS_KEY = "shadowless_durations"
_durations_seen: dict[str, float] = {}


def _durations_file() -> Path | None:
    return None if _CACHE is None else _CACHE / "durations.json"


def _read_durations() -> dict[str, float]:
    import json

    path = _durations_file()
    try:
        data = json.loads(path.read_text()) if path is not None else {}
    except (OSError, ValueError):
        return {}
    return {k: float(v) for k, v in data.items() if isinstance(v, (int, float))} if isinstance(data, dict) else {}


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """(pytest-xdist, in the controller) Under ``--dist loadfile`` every worker gets the controller's
    record of durations (perhaps empty: then KNOWN_SECONDS orders the long modules)."""
    if getattr(node.config.option, "dist", "no") == "loadfile":
        node.workerinput[_DURATIONS_KEY] = node.config._shadowless_durations


def pytest_collection_modifyitems(config, items):
    """In an xdist worker of a ``--dist loadfile`` session: the modules ordered by their recorded time
    (KNOWN_SECONDS for a module never timed), the longest first (a module's tests keep their order)."""
    durations = getattr(config, "workerinput", {}).get(_DURATIONS_KEY)
    if durations is None:    # not a worker of a --dist loadfile session
        return
    cost: dict[str, float] = {}
    timed: set[str] = set()
    for item in items:
        module = item.nodeid.split("::", 1)[0]
        cost[module] = cost.get(module, 0.0) + durations.get(item.nodeid, DEFAULT_TEST_S)
        if item.nodeid in durations:
            timed.add(module)
    for module, seconds in KNOWN_SECONDS.items():
        if module in cost and module not in timed:
            cost[module] = seconds
    first_seen = {m: i for i, m in enumerate(dict.fromkeys(item.nodeid.split("::", 1)[0] for item in items))}
    items.sort(key=lambda item: (-cost[item.nodeid.split("::", 1)[0]], first_seen[item.nodeid.split("::", 1)[0]]))


def pytest_runtest_logreport(report):
    """(In the controller, or a run without workers) each test's setup, call and teardown, summed."""
    _durations_seen[report.nodeid] = _durations_seen.get(report.nodeid, 0.0) + (report.duration or 0.0)


def pytest_sessionfinish(session):
    """The durations of the tests this session ran, merged into the record (in the controller only)."""
    import json

    path = _durations_file()
    if path is None or hasattr(session.config, "workerinput") or not _durations_seen:
        return
    record = _read_durations()
    record.update({k: round(v, 3) for k, v in _durations_seen.items()})
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(record, sort_keys=True))
        tmp.replace(path)
    except OSError:
        pass   # a read-only cache: the next session orders as this one did


def pytest_configure(config):
    global _SESSION_TMP
    config._shadowless_durations = {} if hasattr(config, "workerinput") else _read_durations()
    if getattr(config.option, "dist", "no") == "loadfile":
        config.option.loadscopereorder = False    # the workers' order (above), not "most tests first"
    config.addinivalue_line("markers", "allow_leaks: a module-scoped rig fixture owns processes across tests")
    # beside, not inside, another session's directory: pytest-xdist's workers inherit the TMPDIR set
    # below, and Chromium refuses a socket path longer than 107 bytes
    base = os.environ.setdefault("SHADOWLESS_TESTS_BASE_TMP", tempfile.gettempdir())
    _SESSION_TMP = Path(tempfile.mkdtemp(prefix="shadowless-tests-", dir=base))
    os.environ["TMPDIR"] = str(_SESSION_TMP)
    tempfile.tempdir = str(_SESSION_TMP)


def pytest_unconfigure(config):
    if _SESSION_TMP is not None:
        shutil.rmtree(_SESSION_TMP, ignore_errors=True)


CI = os.environ.get("CI", "").lower() == "true"


@pytest.fixture
def ns():
    """Network namespaces for a virtual venue can be built here (else the test skips, with the
    reason; under CI=true a skip is a failure, see below)."""
    ok, reason = venue_available()
    if not ok:
        pytest.skip(f"no virtual venue network here: {reason}")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Under CI=true nothing may skip: GL, mDNS, namespaces and the pinned codecs are all there,
    so a skip means something is missing, and it fails the run with its reason."""
    outcome = yield
    rep = outcome.get_result()
    if rep.failed:
        setattr(item, f"_shadowless_{rep.when}_failed", True)    # for SHADOWLESS_TEST_COSTS
    if CI and rep.skipped and not hasattr(rep, "wasxfail"):
        reason = rep.longrepr[2] if isinstance(rep.longrepr, tuple) else str(rep.longrepr)
        rep.outcome = "failed"
        rep.longrepr = f"skipped under CI=true, where nothing may skip: {reason}"


@pytest.fixture
def corpus_table():
    """``add(kind, input, message, exit_status)``: a row of the bad-input corpus, appended as a
    markdown table row to the file named by ``SHADOWLESS_CORPUS_TABLE`` when it is set (to list
    every bad input tried, what it printed and the exit status); a no-op otherwise."""
    path = os.environ.get("SHADOWLESS_CORPUS_TABLE")

    def add(kind: str, what: str, message: str, status: object) -> None:
        if path:
            cell = lambda s: str(s).replace("|", "\\|").replace("\n", " ")  # noqa: E731
            with open(path, "a") as f:
                f.write(f"| {cell(kind)} | {cell(what)} | {cell(message)} | {cell(status)} |\n")

    return add


@pytest.fixture
def coordinator_process():
    """``start(rig_dir) -> "127.0.0.1:PORT"``: a real `shadowless coordinator` process on the rig at
    ``rig_dir`` (loopback, no mDNS, no console), once it listens; every one started is stopped after
    the test."""
    procs: list[subprocess.Popen] = []

    def start(rig_dir) -> str:
        port_file = Path(rig_dir).parent / f"coordinator-{len(procs)}.port"
        proc = subprocess.Popen([sys.executable, "-m", "shadowless", "coordinator", "--rig", str(rig_dir), "--listen",
                                 "127.0.0.1:0", "--no-mdns", "--no-console", "--port-file", str(port_file)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        procs.append(proc)
        def port_or_exit() -> tuple[int | None, str]:
            text = port_file.read_text().strip() if port_file.exists() else ""
            return proc.poll(), text

        status, text = wait_until(port_or_exit, lambda seen: seen[0] is not None or bool(seen[1]),
                                  what="the coordinator to write its port file (or exit)")
        assert text, f"the coordinator exited with {status} before writing its port file"
        return f"127.0.0.1:{int(text)}"

    yield start
    for proc in procs:
        proc.terminate()
        proc.wait(timeout=30)


@pytest.fixture
def shadowless_main(capsys):
    """``run(*argv)``: `shadowless ARGV...` in this process, as (exit status, stdout, stderr), the
    parser's refusals (which exit from argparse) included."""
    from shadowless.cli import main

    def run(*argv: str) -> tuple[int, str, str]:
        try:
            code = main(list(argv))
        except SystemExit as exc:
            code = exc.code
        out, err = capsys.readouterr()
        return code, out, err

    return run
