"""The container files (deploy/docker) hold together without Docker: every command they run
parses with the real command line, every file they copy exists, every extra they install is
one pyproject.toml defines, and the simulated rig's services agree on names, ports, slots,
sizes and the shared token. The entrypoint and the health check run here for real.
"""
from __future__ import annotations

import fnmatch
import importlib.util
import json
import os
import re
import shlex
import stat
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCKER = REPO / "deploy" / "docker"
DOCKERFILES = ["Dockerfile.coordinator", "Dockerfile.sim"]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"deploy_{name}", Path(__file__).with_name(f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


parse_with_the_cli = _load("cli_check").parse_with_the_cli
yaml_subset = _load("yaml_subset")


# -- Dockerfiles ---------------------------------------------------------------------------------

def instructions(name: str) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments left out."""
    out, pending = [], ""
    for line in (DOCKER / name).read_text().splitlines():
        if line.lstrip().startswith("#") or (not line.strip() and not pending):
            continue
        pending += line.strip()
        if pending.endswith("\\"):
            pending = pending[:-1] + " "
            continue
        word, _, rest = pending.partition(" ")
        out.append((word.upper(), rest.strip()))
        pending = ""
    assert not pending, f"{name} ends inside a continued line"
    return out


def copies(name: str) -> list[tuple[list[str], str]]:
    """Each COPY's (sources, destination), sources relative to the build context."""
    out = []
    for word, rest in instructions(name):
        if word == "COPY":
            args = [a for a in shlex.split(rest) if not a.startswith("--")]
            assert not any(a.startswith("--from") for a in shlex.split(rest)), "no multi-stage copies here"
            out.append((args[:-1], args[-1]))
    return out


def installed_programs(name: str) -> set[str]:
    """Programs a COPY puts on the image's PATH (/usr/local/bin)."""
    return {dest.rsplit("/", 1)[1] for _, dest in copies(name) if dest.startswith("/usr/local/bin/")}


def exec_form(name: str, word: str) -> list[str] | None:
    found = [rest for w, rest in instructions(name) if w == word]
    if not found:
        return None
    argv = json.loads(found[-1])        # the exec form: no shell between Docker and the process
    assert isinstance(argv, list) and all(isinstance(a, str) for a in argv)
    return argv


@pytest.mark.parametrize("name", DOCKERFILES)
def test_every_copied_file_exists_and_every_package_is_copied(name):
    sources = []
    for srcs, dest in copies(name):
        for s in srcs:
            assert (REPO / s).exists(), f"{name}: COPY {s}: no such file in the repository"
            sources.append(s.rstrip("/"))
    assert {"pyproject.toml", "constraints.txt", "README.md"} <= set(sources), "the build needs them"
    patterns = PYPROJECT["tool"]["setuptools"]["packages"]["find"]["include"]
    packages = {p.name for p in REPO.iterdir() if (p / "__init__.py").exists()
                and any(fnmatch.fnmatch(p.name, pat) for pat in patterns)}
    assert packages and packages <= set(sources), f"{name} leaves out packages: {sorted(packages - set(sources))}"


@pytest.mark.parametrize("name,extra", [("Dockerfile.coordinator", "coordinator"), ("Dockerfile.sim", "all")])
def test_the_image_installs_an_extra_of_pyproject_with_the_pins(name, extra):
    first = instructions(name)[0]
    assert first[0] == "FROM" and re.fullmatch(r"python:3\.1[1-9]-slim-\w+", first[1]), first
    assert PYPROJECT["project"]["requires-python"] == ">=3.11"
    pips = [rest for word, rest in instructions(name) if word == "RUN" and "pip install" in rest]
    assert len(pips) == 1
    assert "-c constraints.txt" in pips[0], "installed at the repository's pinned versions"
    extras = re.findall(r'"\.\[([\w,-]+)\]"', pips[0])
    assert extras == [extra]
    for e in extra.split(","):
        assert e in PYPROJECT["project"]["optional-dependencies"], f"{name}: no extra {e!r} in pyproject.toml"


@pytest.mark.parametrize("name", DOCKERFILES)
def test_what_the_image_runs_parses_and_is_installed(name):
    programs = installed_programs(name)
    assert {"shadowless-entrypoint", "shadowless-healthcheck"} <= programs
    cmd = exec_form(name, "CMD")
    entrypoint = exec_form(name, "ENTRYPOINT")
    assert cmd and cmd[0] == "shadowless"
    parse_with_the_cli(cmd[1:])
    if entrypoint:
        assert entrypoint[0] in programs
    assert ("VOLUME", "/rig") in instructions(name)
    assert ("USER", "shadowless") in instructions(name), "not root"


def test_the_coordinator_image_serves_the_network_and_says_when_it_is_healthy():
    name = "Dockerfile.coordinator"
    args = parse_with_the_cli(exec_form(name, "CMD")[1:])
    assert (args.rig, args.listen, args.console) == ("/rig", "0.0.0.0:7600", "0.0.0.0:7680")
    assert exec_form(name, "ENTRYPOINT") == ["shadowless-entrypoint"], "creates the rig on the first start"
    (health,) = [rest for word, rest in instructions(name) if word == "HEALTHCHECK"]
    test = json.loads(health[health.index("CMD") + 3:].strip())
    assert test == ["shadowless-healthcheck", "127.0.0.1:7600"]


# -- compose.yaml --------------------------------------------------------------------------------

def real_yaml(path: Path):
    """PyYAML's reading of ``path`` (here, or the system Python's), or None if neither has it."""
    try:
        import yaml
    except ImportError:
        yaml = None
    if yaml is not None:
        return yaml.safe_load(path.read_text())
    for py in ("/usr/bin/python3",):
        if os.access(py, os.X_OK):
            r = subprocess.run([py, "-c", "import json, sys, yaml; json.dump(yaml.safe_load(open(sys.argv[1])), sys.stdout)",
                                str(path)], capture_output=True, text=True, timeout=60, check=False)
            if r.returncode == 0:
                return json.loads(r.stdout)
    return None


@pytest.fixture(scope="module")
def compose():
    path = DOCKER / "compose.yaml"
    doc = yaml_subset.load(path.read_text())
    real = real_yaml(path)
    if real is not None:
        assert real == doc, "PyYAML reads compose.yaml differently from the subset reader"
    return doc


def arg(argv: list[str], flag: str) -> str:
    return argv[argv.index(flag) + 1]


def test_the_subset_reader_refuses_what_it_does_not_know():
    with pytest.raises(yaml_subset.YamlSubsetError, match="line 2"):
        yaml_subset.load("a:\n  b: &anchor 1\n")
    with pytest.raises(yaml_subset.YamlSubsetError, match="twice"):
        yaml_subset.load("a: 1\na: 2\n")
    with pytest.raises(yaml_subset.YamlSubsetError, match="quote it"):
        yaml_subset.load("a: yes\n")
    assert yaml_subset.load('a:\n  - "x"  # c\n  - y:z\nb: [ "p", "q" ]\n') == {"a": ["x", "y:z"], "b": ["p", "q"]}


def test_every_service_builds_the_sim_image_from_the_repository(compose):
    services = compose["services"]
    assert {"room", "coordinator"} <= set(services)
    nodes = [s for s in services if s.startswith("node")]
    assert len(nodes) >= 4
    for name, svc in services.items():
        build = svc["build"]
        assert (DOCKER / build["context"]).resolve() == REPO, name
        assert (REPO / build["dockerfile"]).resolve() == DOCKER / "Dockerfile.sim", name
        assert svc["image"] == "shadowless-sim:local" and svc["pull_policy"] == "build", \
            f"{name}: one local image, built, never pulled from a registry"
        for dep in svc.get("depends_on", {}):
            assert dep in services, f"{name} depends on {dep}, which is not a service"


def test_every_command_in_compose_parses(compose):
    programs = installed_programs("Dockerfile.sim")
    for name, svc in compose["services"].items():
        command = svc["command"]
        assert command[0] == "shadowless", name
        parse_with_the_cli(command[1:])
        if "entrypoint" in svc:
            assert svc["entrypoint"][0] in programs, f"{name}: {svc['entrypoint'][0]} is not in the image"
        if "healthcheck" in svc:
            test = svc["healthcheck"]["test"]
            assert test[0] == "CMD" and test[1] in programs, name
        init = (svc.get("environment") or {}).get("RIG_INIT_ARGS")
        if init is not None:
            parse_with_the_cli(["rig", "init", "/rig", *shlex.split(init)])


def test_the_simulated_rig_holds_together(compose):
    from sim.scene import PROJECTOR_NATIVE, _scaled_size

    services = compose["services"]
    room = parse_with_the_cli(services["room"]["command"][1:])
    assert room.host == "0.0.0.0"
    room_address = f"room://room:{room.port}"

    coord_svc = services["coordinator"]
    coordinator = parse_with_the_cli(coord_svc["command"][1:])
    coord_port = coordinator.listen.rsplit(":", 1)[1]
    assert coordinator.camera == [room_address], "the coordinator captures from the room's camera"
    assert coordinator.no_mdns, "the nodes are told where it is; mDNS is not needed between containers"
    assert coord_svc["entrypoint"] == ["shadowless-entrypoint"]
    assert coord_svc["environment"]["RIG_DIR"] == coordinator.rig
    assert f"rig:{coordinator.rig}" in coord_svc["volumes"]
    assert coord_svc["depends_on"]["room"]["condition"] == "service_healthy"
    assert "rig" in compose["volumes"]

    init = parse_with_the_cli(["rig", "init", coordinator.rig, *shlex.split(coord_svc["environment"]["RIG_INIT_ARGS"])])
    assert tuple(init.resolution) == _scaled_size(PROJECTOR_NATIVE, room.projector_scale), \
        "the rig's projectors are the room's size"

    slots = []
    for name, svc in services.items():
        if not name.startswith("node"):
            continue
        argv = svc["command"]
        node = parse_with_the_cli(argv[1:])
        slots.append(node.slot)
        assert name == f"node-{node.slot}"
        assert arg(argv, "--output") == room_address
        assert node.coordinator == f"coordinator:{coord_port}"
        token_dir = os.path.dirname(node.token_file)
        assert token_dir == coordinator.rig and f"rig:{token_dir}:ro" in svc["volumes"], \
            f"{name} reads the rig's token from the coordinator's volume, read-only"
        assert svc["depends_on"]["coordinator"]["condition"] == "service_healthy", \
            "the token exists once the coordinator is healthy"
    assert sorted(slots) == sorted(init.slots), "one node per slot of the rig"


# -- the entrypoint and the health check, run here ----------------------------------------------

def entrypoint(rig: Path, *command: str, init_args: str = "--name sim --slots a,b"):
    env = {**os.environ, "RIG_DIR": str(rig), "RIG_INIT_ARGS": init_args,
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    return subprocess.run(["sh", str(DOCKER / "entrypoint.sh"), *command], capture_output=True, text=True,
                          env=env, timeout=120, check=False)


def test_the_entrypoint_creates_the_rig_once_then_runs_the_command(tmp_path):
    rig = tmp_path / "rig"
    rig.mkdir()
    r = entrypoint(rig, "sh", "-c", "echo started $0", "coordinator")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().endswith("started coordinator")
    toml = (rig / "rig.toml").read_text()
    assert 'name = "sim"' in toml and stat.S_IMODE((rig / "token").stat().st_mode) == 0o600
    token = (rig / "token").read_text()

    r = entrypoint(rig, "true", init_args="--name other")
    assert r.returncode == 0 and "creating" not in r.stderr
    assert (rig / "rig.toml").read_text() == toml and (rig / "token").read_text() == token


def test_the_entrypoint_keeps_a_given_token_and_refuses_a_stranger_directory(tmp_path):
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "token").write_text("carried-over\n")
    assert entrypoint(kept, "true").returncode == 0
    assert (kept / "token").read_text() == "carried-over\n" and (kept / "rig.toml").exists()

    stranger = tmp_path / "stranger"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("not a rig")
    r = entrypoint(stranger, "echo", "should not run")
    assert r.returncode == 2 and "should not run" not in r.stdout
    assert "no rig.toml" in r.stderr and not (stranger / "rig.toml").exists()


def test_the_health_check_asks_the_grpc_health_service():
    from concurrent import futures

    import grpc
    from grpc_health.v1 import health, health_pb2, health_pb2_grpc

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=2))
    servicer = health.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(servicer, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()

    def check():
        return subprocess.run([sys.executable, str(DOCKER / "healthcheck.py"), f"127.0.0.1:{port}"],
                              capture_output=True, text=True, timeout=60, check=False)
    try:
        servicer.set("", health_pb2.HealthCheckResponse.SERVING)
        r = check()
        assert r.returncode == 0 and "SERVING" in r.stdout, r.stderr
        servicer.set("", health_pb2.HealthCheckResponse.NOT_SERVING)
        r = check()
        assert r.returncode == 1 and "NOT_SERVING" in r.stdout
    finally:
        server.stop(None).wait()
        servicer.enter_graceful_shutdown()
    r = check()
    assert r.returncode == 1 and "UNAVAILABLE" in r.stderr
