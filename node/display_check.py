"""Whether a desktop holds the display a node's output needs, said in one line before it is opened.

Raspberry Pi OS Bookworm boots to a Wayland desktop (wayfire, later labwc) by default. A node with
``--output kms`` then finds the display taken (the compositor is the DRM master), and one with
``--output window`` reaches only Xwayland, if anything: either way it failed with an X or DRM error
and systemd restarted it every two seconds, for ever. This module names the conflict and what to do
instead, so the node can say it once and stop (the unit does not restart it for
:data:`DISPLAY_HELD_EXIT`).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

__all__ = ["DISPLAY_HELD_EXIT", "WAYLAND_COMPOSITORS", "X_SERVERS", "display_conflict", "running_programs"]

#: the node's exit status when a desktop holds the display (EX_CONFIG; the unit's RestartPreventExitStatus)
DISPLAY_HELD_EXIT = 78
#: compositors that make a Wayland desktop (process names, as /proc/PID/comm shows them: 15 characters)
WAYLAND_COMPOSITORS = frozenset({"wayfire", "labwc", "weston", "sway", "kwin_wayland", "cage", "Hyprland", "river"})
#: X servers that drive the display themselves (Xvfb and Xwayland hold no display: not listed)
X_SERVERS = frozenset({"Xorg", "X"})

_TO_X11 = "switch the desktop to X11 (sudo raspi-config: Advanced Options, Wayland, X11; then reboot)"
_BOOT_CONSOLE = "boot to the console (sudo systemctl set-default multi-user.target; then reboot)"
_RESTART = "then: sudo systemctl restart shadowless-node"


def running_programs(proc: Path = Path("/proc")) -> set[str]:
    """The names (``comm``) of the processes running on this machine (those this user may see)."""
    names = set()
    for entry in proc.iterdir():
        if entry.name.isdigit():
            try:
                names.add((entry / "comm").read_text().strip())
            except OSError:     # gone meanwhile, or hidden
                continue
    return names


def display_conflict(kind: str, env: Mapping[str, str], programs: Iterable[str]) -> str | None:
    """One line saying why output ``kind`` (offscreen, window, kms, room) cannot have the display and
    what to do instead, or None when nothing stands in its way. ``env``: the node's environment;
    ``programs``: the names of the running processes (:func:`running_programs`)."""
    running = set(programs)
    compositors = sorted(running & WAYLAND_COMPOSITORS)
    x_servers = sorted(running & X_SERVERS)
    if kind == "window":
        if compositors:
            return (f"a Wayland desktop ({compositors[0]}) holds the display, and --output window draws through "
                    f"X: {_TO_X11}, or use OUTPUT=kms in /etc/shadowless/node.env and {_BOOT_CONSOLE}; {_RESTART}")
        if env.get("WAYLAND_DISPLAY") and not env.get("DISPLAY"):
            return (f"this is a Wayland session (WAYLAND_DISPLAY={env['WAYLAND_DISPLAY']}, no DISPLAY), and "
                    f"--output window draws through X: {_TO_X11}, or use --output kms and {_BOOT_CONSOLE}")
        return None
    if kind == "kms":
        holders = [f"a Wayland desktop ({c})" for c in compositors[:1]] + [f"an X server ({x})" for x in x_servers[:1]]
        if holders:
            return (f"{' and '.join(holders)} holds the display that --output kms needs: {_BOOT_CONSOLE}, or keep "
                    f"an X11 desktop and use OUTPUT=window (deploy/install-node.sh --output window); {_RESTART}")
    return None
