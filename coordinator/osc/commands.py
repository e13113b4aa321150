"""The OSC address space: what each address does to the rig, and the rig's side of it.

Every command calls the same :class:`~coordinator.server.Coordinator` method as the console and
the command line (through :class:`OscRig`), so OSC validates nothing of its own; :func:`run`
looks the address up in :data:`COMMANDS` and returns the line the action log keeps, or raises the
rig's refusal. The table :data:`ADDRESSES` is the documentation too (``--help``-like text for
docs/show-control.md and the refusal of an unknown address); the service
(:data:`coordinator.osc.service.ANSWERED`) answers exactly the addresses it names.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Awaitable, Callable, Protocol, Sequence

from coordinator.api import RigStatus, ShowState
from coordinator.rig import Rig, SlotState

PREFIX = "/shadowless"


class OscRig(Protocol):
    """What the OSC edge calls on the coordinator (the cue methods are looked up when called:
    a core without a cue list refuses those commands in one line)."""

    @property
    def rig(self) -> Rig: ...

    def status(self) -> RigStatus: ...

    def rig_now(self) -> int: ...

    def stop_all(self, *, blackout: bool = False) -> str: ...

    def update_slot(self, slot: str, **changes: Any) -> SlotState: ...

    def update_slots(self, slots: Sequence[str], **changes: Any) -> list[SlotState]: ...

    def play_asset(self, key: str, *, at_ns: int | None = None, delay_ns: int | None = None, loop: bool = False,
                   fps: float | None = None, start_without: bool = False) -> ShowState: ...

    def show_control(self, action: str, *, at_ns: int | None = None, delay_ns: int | None = None,
                     frame: int = 0) -> ShowState: ...


class OscError(ValueError):
    """A command that cannot be run as sent (unknown address, wrong arguments): one line."""


@dataclass(frozen=True)
class Address:
    """One address: its arguments as the operator types them, and what it does."""

    path: str
    args: str
    does: str
    logged: bool = True         # whether each message is an entry of the action log


#: the address space, in the order docs/show-control.md lists it
ADDRESSES: tuple[Address, ...] = (
    Address(f"{PREFIX}/go", "", "fire the next cue (the first one when none fired yet)"),
    Address(f"{PREFIX}/back", "", "fire the cue before the current one"),
    Address(f"{PREFIX}/jump", "CUE_ID", "fire the cue with this id (a string, or a whole number: 3 or 3.0 for cue 3)"),
    Address(f"{PREFIX}/play", "ASSET [LOOP]", "play an asset (its id, id prefix or name) from its start; LOOP 1 loops"),
    Address(f"{PREFIX}/pause", "", "hold the playing asset on its frame"),
    Address(f"{PREFIX}/resume", "", "go on from the held frame"),
    Address(f"{PREFIX}/stop", "", "stop what plays: the rig's content again (black if it has none)"),
    Address(f"{PREFIX}/blackout", "", "stop what plays and show black"),
    Address(f"{PREFIX}/gain", "SLOT|* VALUE", "set one projector's gain (or every one's with *), 0..16"),
    Address(f"{PREFIX}/status", "", "reply with the status messages (below) to the sender", logged=False),
    Address(f"{PREFIX}/subscribe", "[PORT]", "send the sender (at PORT, default its own) the status on every "
                                             "change for the next 10 minutes; send again to stay subscribed",
            logged=False),
    Address(f"{PREFIX}/unsubscribe", "[PORT]", "stop sending the sender the status", logged=False),
    Address(f"{PREFIX}/timecode", "HH:MM:SS:FF|SECONDS", "the external clock: a playing show seeks when it is "
                                                        "further off than chase_threshold_ms", logged=False),
)
BY_PATH = {a.path: a for a in ADDRESSES}


def usage() -> str:
    """The addresses' last parts in one line (``go, back, ...``), for the refusal of an unknown one."""
    return ", ".join(a.path.removeprefix(PREFIX + "/") for a in ADDRESSES)


def _no_args(address: str, args: Sequence[Any]) -> None:
    if args:
        raise OscError(f"{address} takes no arguments, got {len(args)}")


def _text(address: str, args: Sequence[Any], what: str) -> str:
    if not args or not isinstance(args[0], str) or not args[0].strip():
        raise OscError(f"{address} needs {what} as its first argument (a string)")
    return args[0].strip()


def whole_number(value: Any) -> int | None:
    """An OSC number that is whole, as desks and TouchDesigner send one (an int, or a float such as
    3.0), as an int; None for a fraction, a non-finite float, a bool or anything not a number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    if isinstance(value, float) and (not math.isfinite(value) or value != int(value)):
        return None
    return int(value)


def _cue_id(address: str, args: Sequence[Any]) -> str:
    """The cue's id from /jump's first argument: a string, or a whole number (:func:`whole_number`)
    for a cue whose id is that number."""
    if args and isinstance(args[0], (int, float)) and not isinstance(args[0], bool):
        number = whole_number(args[0])
        if number is None:
            raise OscError(f"{address} needs the cue's id as its first argument: a string, or a whole number; "
                           f"got {args[0]!r}")
        return str(number)
    return _text(address, args, "the cue's id")


def _flag(value: Any, address: str) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in ("0", "1", "true", "false", "loop"):
        return value.strip().lower() in ("1", "true", "loop")
    raise OscError(f"{address}: LOOP must be 0 or 1, got {value!r}")


def _cue_method(coord: OscRig, name: str) -> Callable[..., str]:
    method = getattr(coord, name, None)
    if method is None:
        raise OscError("this coordinator has no cue list: cues arrive with `shadowless cue`")
    return method


def _go(coord: OscRig, address: str, args: Sequence[Any], who: str) -> str | Awaitable[str]:
    _no_args(address, args)
    return _cue_method(coord, "cue_go")(who=who)


def _back(coord: OscRig, address: str, args: Sequence[Any], who: str) -> str | Awaitable[str]:
    _no_args(address, args)
    return _cue_method(coord, "cue_back")(who=who)


def _jump(coord: OscRig, address: str, args: Sequence[Any], who: str) -> str | Awaitable[str]:
    cue_id = _cue_id(address, args)
    return _cue_method(coord, "cue_jump")(cue_id, who=who)


def _play(coord: OscRig, address: str, args: Sequence[Any], who: str) -> str:
    key = _text(address, args, "the asset (id, id prefix or name)")
    if len(args) > 2:
        raise OscError(f"{address} takes ASSET and an optional LOOP, got {len(args)} arguments")
    loop = _flag(args[1], address) if len(args) > 1 else False
    st = coord.play_asset(key, loop=loop)
    return f"{st.state}: {st.name or st.asset_id[:12]} ({st.frames} frames at {st.fps:g} fps" \
           f"{', looped' if loop else ''})"


def _hold_or_go_on(coord: OscRig, address: str, args: Sequence[Any], who: str) -> str:
    _no_args(address, args)
    action = address.rsplit("/", 1)[1]
    st = coord.show_control(action)
    return f"{action}: {st.name or st.asset_id[:12]} {st.state} at frame {st.frame}"


def _stop(coord: OscRig, address: str, args: Sequence[Any], who: str) -> str:
    _no_args(address, args)
    return f"showing {coord.stop_all(blackout=address.endswith('blackout'))}"


def _gain(coord: OscRig, address: str, args: Sequence[Any], who: str) -> str:
    if len(args) != 2 or not isinstance(args[0], str):
        raise OscError(f"{address} takes SLOT (a string, * for every slot) and VALUE, got {list(args)!r}")
    value = args[1]
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise OscError(f"{address}: VALUE must be a number, got {args[1]!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise OscError(f"{address}: VALUE must be a number, got {args[1]!r}")
    if args[0].strip() != "*":
        st = coord.update_slot(args[0].strip(), gain=float(value))
        return f"slot {args[0].strip()} gain {st.gain:g} (revision {st.revision})"
    states = coord.update_slots(list(coord.rig.slots), gain=float(value))   # one batch of file writes
    return f"gain {float(value):g} on {len(states)} slots"


#: what runs each rig command: (coord, address, args, who) -> the action log's line, or an awaitable of it.
#: The service answers the other addresses of :data:`ADDRESSES` itself (status, subscriptions, timecode).
COMMANDS: dict[str, Callable[[OscRig, str, Sequence[Any], str], "str | Awaitable[str]"]] = {
    f"{PREFIX}/go": _go,
    f"{PREFIX}/back": _back,
    f"{PREFIX}/jump": _jump,
    f"{PREFIX}/play": _play,
    f"{PREFIX}/pause": _hold_or_go_on,
    f"{PREFIX}/resume": _hold_or_go_on,
    f"{PREFIX}/stop": _stop,
    f"{PREFIX}/blackout": _stop,
    f"{PREFIX}/gain": _gain,
}


def run(coord: OscRig, address: str, args: Sequence[Any], *, who: str) -> str | Awaitable[str]:
    """Run the command at ``address`` with ``args`` as ``who`` (``osc:<ip>``); the result line (or
    an awaitable of it, for a command that lets the event loop run meanwhile). Raises
    :class:`OscError` for a malformed message, and whatever the rig refuses with."""
    command = COMMANDS.get(address)
    if command is not None:
        return command(coord, address, args, who)
    if address in BY_PATH:      # answered by the service itself (status, subscriptions, timecode)
        raise OscError(f"{address} is not a rig command")
    raise OscError(f"unknown address {address[:80]!r}: shadowless answers {PREFIX}/ followed by one of {usage()}")
