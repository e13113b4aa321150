"""A node that stops on purpose says goodbye: the coordinator logs "node r0c0 left" (not "lost")
and still hands its footprint to the others; a normal coordinator shutdown logs no node lost. The
node's heartbeat names its video decoder in a field of its own, which `status` shows: a node asked
for a hardware decoder that is not here decodes in software and says why. Real processes: a
coordinator and a node, their logs read from their stderr."""
from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from pathlib import Path

from coordinator.api import NodeState
from coordinator.console.health import health_view
from coordinator.rig import init_rig
from protos.auth import read_token
from rigctl.link import Client
from waits import wait_until


def _status(address: str, token: bytes):
    async def ask():
        async with await Client.connect(address, token) as c:
            return await c.status()
    return asyncio.run(ask())


def _coordinator(rig_dir: Path, listen: str, log: Path, port_file: Path) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-m", "shadowless", "coordinator", "--rig", str(rig_dir), "--listen",
                             listen, "--no-mdns", "--no-console", "--port-file", str(port_file)],
                            stdout=subprocess.DEVNULL, stderr=log.open("w"))
    wait_until(lambda: proc.poll() is not None or (port_file.exists() and port_file.read_text().strip()),
               what="the coordinator's port file")
    assert proc.poll() is None, log.read_text()
    return proc, f"127.0.0.1:{int(port_file.read_text())}"


def test_a_node_stopped_on_purpose_left_and_names_its_decoder(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="goodbye", slots=["r0c0"], width=32, height=32)
    token = read_token(rig_dir / "token")
    first_log, second_log, node_log = tmp_path / "first.log", tmp_path / "second.log", tmp_path / "node.log"
    procs: list[subprocess.Popen] = []
    try:
        coord, address = _coordinator(rig_dir, "127.0.0.1:0", first_log, tmp_path / "port1")
        procs.append(coord)
        # a V4L2 M2M decoder: in this FFmpeg, but no such device here
        node = subprocess.Popen([sys.executable, "-m", "shadowless", "node", "--slot", "r0c0", "--coordinator",
                                 address, "--token-file", str(rig_dir / "token"), "--cache-dir",
                                 str(tmp_path / "cache"), "--decoder", "v4l2m2m"],
                                stdout=subprocess.DEVNULL, stderr=node_log.open("w"))
        procs.insert(0, node)

        def node_status():
            return next(n for n in _status(address, token).nodes if n.slot == "r0c0")

        live = wait_until(node_status, lambda n: n.state == NodeState.LIVE and n.decoder != "",
                          what="the node live, its heartbeat naming its decoder")
        assert live.decoder == "software", live
        assert "h264_v4l2m2m" in live.decoder_note, live.decoder_note     # and why not the one asked for
        shown = subprocess.run([sys.executable, "-m", "shadowless", "status", "--coordinator", address, "--rig-dir",
                                str(rig_dir)], capture_output=True, text=True, timeout=60)
        assert shown.returncode == 0, shown.stderr
        assert "every node decodes video with software (h264_v4l2m2m" in shown.stdout, shown.stdout

        # a normal coordinator shutdown, its node joined: no "node lost"
        coord.send_signal(signal.SIGTERM)
        assert coord.wait(60) == 0, first_log.read_text()
        assert " lost" not in first_log.read_text(), first_log.read_text()

        # the node rejoins a coordinator started again on the same address, then stops on purpose
        coord, again = _coordinator(rig_dir, address, second_log, tmp_path / "port2")
        procs.append(coord)
        assert again == address
        wait_until(node_status, lambda n: n.state == NodeState.LIVE, what="the node live again")
        node.send_signal(signal.SIGTERM)
        assert node.wait(60) == 0
        assert "this node leaves (stopped (SIGTERM))" in node_log.read_text()
        gone = wait_until(node_status, lambda n: n.state != NodeState.LIVE, what="the node's slot no longer live")
        assert gone.state == NodeState.LOST      # its projector is gone all the same: the failover runs
        assert gone.left == "stopped (SIGTERM)", gone      # carried over the wire to the operators
        banner = [a["text"] for a in health_view(_status(address, token))["alarms"] if a["kind"] == "lost"]
        assert banner == ["r0c0 left (stopped (SIGTERM))"], banner
        text = second_log.read_text()
        assert "node r0c0 left (stopped (SIGTERM))" in text, text
        assert "node r0c0 lost" not in text, text
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.terminate()
                proc.wait(timeout=30)
