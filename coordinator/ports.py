"""How the coordinator's edges see its core: one Protocol per consumer.

The gRPC services (:mod:`coordinator.wire`) see a :class:`ServiceRig`, the operator console
(:mod:`coordinator.console`) a :class:`ConsoleRig`, as jobs see a
:class:`coordinator.jobs.driver.RigDriver`. Each lists exactly what its consumer calls, so a
consumer cannot reach further into the core than its Protocol says, and a test may drive it with
anything that has these members. :class:`coordinator.server.Coordinator` implements all of them;
this module imports neither it nor any edge, so no edge imports the core's module, and the core
imports no edge.
"""
from __future__ import annotations

import asyncio
from typing import Any, AsyncIterator, Callable, Literal, Mapping, Protocol, Sequence, runtime_checkable

from coordinator.admission import Budget
from coordinator.api import PlayResult, PlaySettings, RigStatus, ShowResult, ShowState, Space
from coordinator.assets import AssetStore
from coordinator.distribution import WantedList
from coordinator.jobs.context import Event
from coordinator.jobs.tracker import JobState
from coordinator.previews import Previews
from coordinator.rig import Content, Rig, SlotState
from coordinator.sessions import Handshake, NodeInfo, NodeSession, Report
from coordinator.show import ShowUpdate
from coordinator.sync import FrameResult
from protos.asset_manifest import Manifest

#: whether a slot's node is connected: no node joined it, its session closed, or it is open
SlotLink = Literal["none", "closed", "open"]


class RigOperations(Protocol):
    """What an operator may do to the rig, through the command line (gRPC) or the console alike."""

    @property
    def rig(self) -> Rig: ...

    def status(self) -> RigStatus: ...

    def prepare_still(self, content: Content, space: Space = Space.CONTENT, *, fit: str = "") -> Content:
        """``content`` fitted to the space and encoded for the nodes (blocking: a worker thread)."""
        ...

    def show(self, content: Content, **kwargs: Any) -> ShowResult: ...

    def stop_all(self, *, blackout: bool = False) -> str: ...

    def update_slot(self, slot: str, **changes: Any) -> SlotState: ...

    def play_asset(self, key: str, *, at_ns: int | None = None, delay_ns: int | None = None, loop: bool = False,
                   fps: float | None = None, start_without: bool = False) -> ShowState: ...

    def cancel_job(self) -> str: ...

    async def show_test_pattern(self, name: str, slots: Sequence[str] | None = None) -> str:
        """Test pattern ``name`` on the chosen slots (None: all), the others black (coordinator/slot_tools.py)."""
        ...

    def solo(self, slots: Sequence[str]) -> str:
        """Only the chosen slots show the still on screen, the others black; ``[]`` ends the solo."""
        ...


@runtime_checkable
class ServiceRig(RigOperations, Protocol):
    """What the gRPC services (NodeLink, RigControl, ContentStore) call on the coordinator."""

    instance_id: str
    clock_id: str
    handshake: Handshake
    admission: Budget
    previews: Previews
    #: what was sent the nodes (the services count the bytes they write)
    frame_packets_sent: int
    frame_bytes_sent: int
    show_updates_sent: int
    show_bytes_sent: int

    @property
    def sessions(self) -> Mapping[str, NodeSession]: ...

    @property
    def content_size(self) -> tuple[int, int]: ...

    @property
    def asset_store(self) -> AssetStore:
        """The rig's asset store (the ContentStore service adds to it)."""
        ...

    @property
    def wanted(self) -> WantedList:
        """The assets every node should hold (its revision changes with the store)."""
        ...

    # the nodes
    def rig_now(self) -> int: ...

    def join(self, *, slot: str, info: NodeInfo, peer: str) -> NodeSession: ...

    def node_session(self, session_id: str) -> NodeSession: ...

    def on_frames_open(self, sess: NodeSession) -> None: ...

    def on_report(self, sess: NodeSession, rep: Report) -> None: ...

    def mark_lost(self, sess: NodeSession) -> None: ...

    def mark_left(self, sess: NodeSession, why: str) -> None: ...

    async def manifest_bytes(self, asset_id: str) -> bytes: ...

    def blob_chunks(self, sha256: str, offset: int) -> AsyncIterator[tuple[int, bytes]]:
        """``(offset, bytes)`` chunks of a store blob from ``offset`` (a Refusal before the first)."""
        ...

    def subscribe_show(self, event: asyncio.Event) -> Callable[[], None]:
        """Set ``event`` whenever the timeline show changes; returns the unsubscribe."""
        ...

    def show_update(self, *, beacon: bool = False) -> ShowUpdate | None: ...

    # the operators
    async def run_job(self, kind: str, params: dict, emit: Callable[[Event], None]) -> dict:
        """Run a job to its end, each of its events to ``emit``; its result."""
        ...

    def prepare_regions(self, content: Content, regions: Mapping[str, Sequence[Sequence[int]]]
                        ) -> dict[str, Content | None]: ...

    async def play_sequence(self, frames: Sequence[Content] | None, settings: PlaySettings) -> PlayResult: ...

    def show_control(self, action: str, *, at_ns: int | None = None, delay_ns: int | None = None,
                     frame: int = 0) -> ShowState: ...


@runtime_checkable
class ConsoleRig(RigOperations, Protocol):
    """What the operator console (its pages, actions and live view) calls on the coordinator."""

    previews: Previews

    @property
    def camera_specs(self) -> list[str]: ...

    def token_matches(self, given: str) -> bool:
        """Whether ``given`` (pasted text) is the rig token, in constant time."""
        ...

    def token_key(self, purpose: bytes) -> bytes:
        """A key derived from the rig token for ``purpose`` (a new token makes a new key)."""
        ...

    def asset_manifests(self) -> Mapping[str, Manifest]:
        """The store's assets: id -> manifest."""
        ...

    def slot_link(self, slot: str) -> SlotLink: ...

    async def identify(self) -> str: ...

    def running_job(self) -> str | None:
        """The kind of the job that holds the rig now, or None."""
        ...

    def current_job(self) -> JobState | None:
        """The running job, or the last one, as the tracker follows it."""
        ...

    def job_snapshot(self) -> dict[str, Any] | None: ...

    def start_job(self, kind: str, params: dict) -> "asyncio.Task[dict]":
        """Start a job that runs on after the call; Refusal if one is running."""
        ...

    def listen_jobs(self, listener: Callable[[], None]) -> Callable[[], None]:
        """Call ``listener()`` whenever the job's state changes; returns the unsubscribe."""
        ...

    def listen_frames(self, listener: Callable[[FrameResult], None]) -> Callable[[], None]:
        """Call ``listener(result)`` for every frame the sync tracker finishes; returns the unsubscribe."""
        ...

