"""One node's frame, the same in both shells: the in-process network
(``sim_cluster/network/inprocess.py``) and a camera process (``edge_node/runtime/loop.py``)
drive every frame of a node through one :class:`FrameDriver`, so they agree by construction,
not only because tests compare them.

A frame (paper Fig. 1, the node's side of the exchange):

1. ``due(k)``: messages the fault plan delayed until frame ``k``;
2. ``prepare(k, detections)``: the core predicts, associates and builds its message (a faulty
   node's detections and message as its fault makes them: ``forgery``);
3. ``send(msg)``: through the node's :class:`~edge_node.outbox.Outbox` (event trigger in
   asynchronous operation, the whole frame with appearance to neighbours that came back, the
   fault plan, counters); the shell hands the deliveries to its transport;
4. the shell gathers the neighbours' messages (in process: all nodes sent first; a camera
   process waits for them, or takes what came in asynchronous operation);
5. ``receive(k, inbox)``: the outbox notes whose frames jumped (they get a resync at the next
   send), then the core's ``update`` gives the frame's tracks.

What differs between the shells is outside: how messages travel (a dictionary or Zenoh), how
time passes (lockstep or a paced clock), and what a crash is (a node set aside or a killed
process). Pure: no clock, no I/O.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence

from edge_node.core.node import CameraNode
from edge_node.core.trigger import EventTrigger, TriggerConfig
from edge_node.core.types import Detection, Track
from edge_node.faults import NO_FAULTS, FaultPlan
from edge_node.forgery import Forger
from edge_node.outbox import Delivery, Outbox, OutboxCounters
from protocol.messages import FrameMessage


class FrameDriver:
    """Drives ``node`` frame by frame over links to ``neighbours``: event-triggered when
    ``trigger`` is given (its settings), else every frame's whole message. ``counters``: an
    earlier outbox's counters to go on from (a core restarted in the same process)."""

    def __init__(self, node: CameraNode, neighbours: Iterable[int],
                 faults: FaultPlan = NO_FAULTS, trigger: TriggerConfig | None = None,
                 counters: OutboxCounters | None = None):
        c = node.cfg
        event = None if trigger is None else EventTrigger(trigger, c.dt, c.units_per_metre,
                                                          c.kappa, c.hold_frames)
        self.node = node
        self.outbox = Outbox(node.id, neighbours, faults, event, rejoin_gap=c.kappa)
        if counters is not None:
            self.outbox.counters = counters
        self.resync: set[int] = set()  # neighbours that came back: they get the whole frame
        # a faulty node's lies on its detections and messages (edge_node/forgery.py)
        self.forger = Forger(faults.faults_of(node.id), node.cameras[0], c.units_per_metre, c.dt)

    @property
    def neighbours(self) -> tuple[int, ...]:
        return self.outbox.neighbours

    def due(self, k: int) -> list[Delivery]:
        """Deliveries the fault plan delayed until frame ``k``."""
        return self.outbox.due(k)

    def rejoined(self, neighbours: Iterable[int]) -> None:
        """``neighbours`` came back (restarted, joined late): the next send gives them the
        whole frame with every tracker's appearance (``CameraNode.resync_message``)."""
        self.resync |= set(neighbours)

    def prepare(self, k: int, detections: Sequence[Detection]) -> FrameMessage:
        """The node's frame ``k`` (a faulty node's detections as its fault makes them)."""
        if self.forger:
            detections = self.forger.detections(k, detections)
        msg = self.node.prepare(k, detections)
        return self.forger.message(k, msg) if self.forger else msg

    def send(self, msg: FrameMessage, *, live: Iterable[int] | None = None,
             sent_at: float | None = None) -> tuple[list[Delivery], set[int]]:
        """``msg`` through the outbox: the deliveries due now, and the neighbours resynced.
        ``live``: the neighbours that can receive now (a resync for one that is down again is
        forgotten: it will be resynced when it comes back); ``sent_at``: a real process's
        wall-clock stamp."""
        resync = self.resync if live is None else self.resync & set(live)
        out = self.outbox.send(msg, resync=resync, resync_message=self.node.resync_message,
                               sent_at=sent_at, covariance=self.node.covariances)
        self.resync = set()
        return out, resync

    def receive(self, k: int, inbox: list[FrameMessage], stale_ok: bool = False) -> list[Track]:
        """The neighbours' messages in: a neighbour whose frames jumped is resynced at the next
        send (``Outbox.heard``); then the core's update (``stale_ok``: event-triggered)."""
        self.outbox.heard(inbox, k, stale_ok)
        return self.node.update(inbox, stale_ok=stale_ok)
