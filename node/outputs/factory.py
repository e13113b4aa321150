""":func:`open_output`: the output named by a ``--output`` spec."""
from __future__ import annotations

from pathlib import Path

from node.output_spec import SPEC_FORMS, parse_output_spec  # noqa: F401 (SPEC_FORMS: in the docstring)
from node.outputs.base import Output, OutputError, check_slot
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
    try:
        parsed = parse_output_spec(spec)
    except ValueError as exc:
        raise OutputError(str(exc)) from None
    if parsed.kind == "offscreen":
        return OffscreenOutput(slot=slot, snapshot_dir=snapshot_dir)
    if parsed.kind == "window":
        return WindowOutput(slot=slot, monitor=parsed.monitor, snapshot_dir=snapshot_dir)
    if parsed.kind == "kms":
        # Lazy: SDL2 is loaded only by a node that drives a display without X.
        from node.outputs.kms import KmsOutput

        return KmsOutput(slot=slot, display=parsed.display, snapshot_dir=snapshot_dir)
    check_slot(slot)
    # Lazy: the room output brings grpc and the room's protobuf messages, which only a node
    # driving the virtual room needs (the presenter process of a real projector never loads them).
    from node.outputs.room_link import RoomOutput

    return RoomOutput(spec.strip(), slot=slot, snapshot_dir=snapshot_dir)
