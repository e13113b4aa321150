""":func:`open_output`: the output named by a ``--output`` spec."""
from __future__ import annotations

from pathlib import Path

from node.outputs.base import SPEC_FORMS, Output, OutputError, check_slot, parse_room_spec
from node.outputs.offscreen import OffscreenOutput
from node.outputs.window import WindowOutput


def open_output(spec: str, *, slot: str, snapshot_dir: Path | None = None) -> Output:
    """Open the output named by ``spec`` for node ``slot``.

    ``spec`` is one of :data:`SPEC_FORMS`: ``offscreen`` (headless; the default when
    empty), ``window`` or ``window:MONITOR`` (fullscreen on monitor MONITOR, 0-based, through
    X), ``kms`` or ``kms:DISPLAY`` (fullscreen without X, SDL2 on KMS/DRM; a display index or
    connector name), or ``room://HOST:PORT`` (frames go to the virtual room).

    ``snapshot_dir``: if given, every frame whose tag starts with ``show`` is
    also written to ``snapshot_dir/<slot>.png`` (atomically) for inspection.

    Raises
    ------
    OutputError
        Unknown or malformed spec (the message lists the accepted forms), or the
        output cannot be opened.
    """
    if not isinstance(spec, str):
        raise OutputError(f"output spec must be a string, got {type(spec).__name__}")
    text = spec.strip()
    forms = ", ".join(SPEC_FORMS)
    if text in ("", "offscreen"):
        return OffscreenOutput(slot=slot, snapshot_dir=snapshot_dir)
    if text == "window" or text.startswith("window:"):
        index_text = text.partition(":")[2] if ":" in text else "0"
        if not index_text.isdigit():
            raise OutputError(f"output {spec!r}: the monitor must be a 0-based index like window:1 (accepted: {forms})")
        return WindowOutput(slot=slot, monitor=int(index_text), snapshot_dir=snapshot_dir)
    if text == "kms" or text.startswith("kms:"):
        display = text.partition(":")[2]
        if text.endswith(":"):
            raise OutputError(f"output {spec!r}: name the display after kms:, an index or a connector like "
                              f"kms:HDMI-A-1 (accepted: {forms})")
        # Lazy: SDL2 is loaded only by a node that drives a display without X.
        from node.outputs.kms import KmsOutput

        return KmsOutput(slot=slot, display=display, snapshot_dir=snapshot_dir)
    if text.startswith("room://"):
        check_slot(slot)
        parse_room_spec(spec)
        # Lazy: the room output brings grpc and the room's protobuf messages, which only a node
        # driving the virtual room needs (the presenter process of a real projector never loads them).
        from node.outputs.room import RoomOutput

        return RoomOutput(text, slot=slot, snapshot_dir=snapshot_dir)
    raise OutputError(f"unknown output {spec!r}; accepted: {forms}")
