"""The one sending path of a camera node, shared by the in-process network and the Zenoh runtime.

Every frame the node's message goes through the same steps, in one process or in many:

1. event-triggered operation only: ``EventTrigger.filter`` keeps the tracker entries the
   neighbours need, or says to stay silent this frame;
2. the message is encoded once; a neighbour that came back (restart, late join) gets the
   resync message instead: every tracker of the frame (also those the trigger withheld) with
   its appearance;
3. the fault plan (``edge_node.faults``) decides per link whether the message is lost, late by
   some frames or duplicated; late ones wait here until their frame;
4. what was handed to each link is counted: bytes, tracker entries, appearance.

A neighbour whose frames jump (``heard``: more than ``rejoin_gap`` frames since the last of its
messages the core took, or since this node's first frame for one not heard before) skipped
ahead after a freeze and started its core afresh, booted late, or was cut off for that long: it
gets the resync message at the next frame, as a neighbour that came back does (unless it got
one within the last ``rejoin_gap`` frames). A message over the wire's limits (a node made to hold more trackers than a message may
carry) is cut to fit, never left unsent: the trackers this node measured first, then the
others in id order; the cut is counted (``trackers_cut``).

Pure: no clock, no I/O. ``send`` and ``due`` return ``(destination, payload)`` pairs; the shell
hands them to its transport. A message that would break the wire rules is never sent: it is
counted under ``encode_errors`` and ``last_error`` says why.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from edge_node.core.trigger import EventTrigger
from edge_node.faults import NO_FAULTS, FaultPlan
from protocol import codec
from protocol.errors import ProtocolError
from protocol.messages import FrameMessage

Delivery = tuple[int, bytes]  # (destination node, encoded message)


@dataclass
class OutboxCounters:
    """What a node handed to its links (before the fault plan loses or delays anything)."""

    bytes_per_link: dict[int, int] = field(default_factory=dict)  # destination -> bytes
    messages: int = 0  # (message, link) pairs
    frames_sent: int = 0  # frames with a message
    frames_skipped: int = 0  # event-triggered: frames the trigger kept silent
    tracker_entries: int = 0  # (tracker, link) entries
    appearance_entries: int = 0  # (tracker, link) entries that carried appearance
    appearance_bytes: int = 0  # bytes of those appearance fields
    bytes_saved: int = 0  # event-triggered: bytes not sent against the full message, all links
    encode_errors: int = 0
    trackers_cut: int = 0  # tracker entries left out of messages over the wire's limits
    resyncs: int = 0  # resync messages sent (one per link)

    @property
    def total_bytes(self) -> int:
        return sum(self.bytes_per_link.values())

    def add(self, other: "OutboxCounters") -> "OutboxCounters":
        """The sum of two lives of a node (before and after a restart)."""
        out = OutboxCounters(dict(self.bytes_per_link))
        for dst, b in other.bytes_per_link.items():
            out.bytes_per_link[dst] = out.bytes_per_link.get(dst, 0) + b
        for name in ("messages", "frames_sent", "frames_skipped", "tracker_entries",
                     "appearance_entries", "appearance_bytes", "bytes_saved", "encode_errors",
                     "trackers_cut", "resyncs"):
            setattr(out, name, getattr(self, name) + getattr(other, name))
        return out


class Outbox:
    """Sends one node's frame messages to its neighbours."""

    def __init__(self, node: int, neighbours: Iterable[int], faults: FaultPlan = NO_FAULTS,
                 trigger: EventTrigger | None = None, rejoin_gap: int | None = None,
                 limits: codec.Limits = codec.DEFAULT_LIMITS):
        """``rejoin_gap``: frames a neighbour's messages may jump before it is resynced
        (``heard``; the core's ``kappa``: a shorter skip keeps its trackers); ``None``: never."""
        self.node = int(node)
        self.neighbours = tuple(sorted(int(n) for n in neighbours))
        self.faults = faults
        self.trigger = trigger  # None: synchronous operation, every frame's message is sent
        self.rejoin_gap = rejoin_gap
        self.limits = limits
        self.counters = OutboxCounters()
        self.last_error: str | None = None
        self.rejoined: set[int] = set()  # neighbours whose frames jumped: resync them
        self._heard: dict[int, int] = {}  # neighbour -> newest frame of its the core took
        self._start: int | None = None  # the first frame heard() was called at
        self._resynced_at: dict[int, int] = {}  # neighbour -> the frame of its last resync
        self._delayed: dict[int, list[Delivery]] = {}  # frame due -> deliveries

    def heard(self, msgs: Iterable[FrameMessage], k: int, stale_ok: bool = False) -> None:
        """The neighbours' messages the core takes at frame ``k`` (synchronous: of frame ``k``;
        event-triggered: up to ``rejoin_gap`` frames old): a sender whose frame is more than
        ``rejoin_gap`` past the last one taken from it is resynced at the next ``send``. Both
        shells call this with the messages they hand the core, so both resync alike."""
        if self.rejoin_gap is None:
            return
        if self._start is None:
            self._start = k
        for m in msgs:
            if m.frame > k or m.frame < k - self.rejoin_gap or (not stale_ok and m.frame != k):
                continue
            last = self._heard.get(m.sender, self._start)
            if m.frame > last + self.rejoin_gap \
                    and k - self._resynced_at.get(m.sender, -self.rejoin_gap - 1) > self.rejoin_gap:
                self.rejoined.add(m.sender)
            if m.frame > last or m.sender not in self._heard:
                self._heard[m.sender] = m.frame

    def send(self, msg: FrameMessage, *, resync: Iterable[int] = (),
             resync_message: Callable[[FrameMessage], FrameMessage] | None = None,
             sent_at: float | None = None,
             covariance: Callable[[], np.ndarray] | None = None) -> list[Delivery]:
        """The deliveries of ``msg`` due now (late ones are kept for ``due``).

        ``resync``: neighbours that came back; they get ``resync_message(msg)``.
        ``sent_at``: the wall-clock stamp a real process puts on the message.
        ``covariance``: the sender's predicted covariances of ``msg``'s rows, asked for only
        when the event trigger weighs withheld information (``CameraNode.covariances``).
        """
        if not self.neighbours:
            return []
        c = self.counters
        full = msg
        resync = (set(resync) | self.rejoined) & set(self.neighbours) \
            if resync_message is not None else set()
        self.rejoined.clear()
        stayers = len(self.neighbours) - len(resync)  # the neighbours the trigger's cut goes to
        if self.trigger is not None:
            msg = self.trigger.filter(full, covariance)
            if msg is None:
                self._count_saved(full, 0, stayers)
        if sent_at is not None:
            full = replace(full, sent_at=sent_at)
            msg = None if msg is None else replace(msg, sent_at=sent_at)
        plain = None  # (message, payload) for the neighbours that stayed
        if msg is not None:
            payload = self._encode(msg)
            if payload is not None:
                plain = (msg, payload)
                if self.trigger is not None and len(msg.trackers) < len(full.trackers):
                    self._count_saved(full, len(payload), stayers)
        special = None
        if resync:
            # the whole frame, not what the trigger kept: a neighbour that came back with an
            # empty state needs every tracker now (with its appearance), not at its heartbeat;
            # also in a frame the trigger keeps silent
            special_msg = resync_message(full)
            special_payload = self._encode(special_msg)
            special = (special_msg, special_payload) if special_payload is not None else None
        now: list[Delivery] = []
        k = full.frame
        if plain is not None or special is not None:
            c.frames_sent += 1
        elif msg is None:
            c.frames_skipped += 1  # the trigger kept the frame silent
        for dst in self.neighbours:
            pair = special if (dst in resync and special is not None) else plain
            if pair is None:
                continue
            m, p = pair
            if pair is special:
                c.resyncs += 1
                self._resynced_at[dst] = k
            c.bytes_per_link[dst] = c.bytes_per_link.get(dst, 0) + len(p)
            c.messages += 1
            c.tracker_entries += len(m.trackers)
            c.appearance_entries += sum(t.appearance is not None for t in m.trackers)
            c.appearance_bytes += codec.appearance_bytes(m, p)
            for delay in self.faults.deliveries(self.node, dst, k):
                if delay == 0:
                    now.append((dst, p))
                else:
                    self._delayed.setdefault(k + delay, []).append((dst, p))
        return now

    def due(self, k: int) -> list[Delivery]:
        """Late (fault-delayed) deliveries whose frame ``k`` has come."""
        out = []
        for frame in sorted(f for f in self._delayed if f <= k):
            out.extend(self._delayed.pop(frame))
        return out

    def _encode(self, msg: FrameMessage) -> bytes | None:
        try:
            return codec.encode(msg, limits=self.limits)
        except ProtocolError as e:
            if e.reason == "oversize":
                cut = self._cut(msg)
                if cut is not None:
                    return cut
            # our own message breaks the wire rules otherwise: never send it
            self.counters.encode_errors += 1
            self.last_error = f"frame {msg.frame}: {e}"
            return None

    def _cut(self, msg: FrameMessage) -> bytes | None:
        """``msg`` cut to the wire's limits: its trackers this node measured (``U != 0``) first,
        then the others in id order, as many as fit; merges beyond ``max_merges`` left out."""
        lim = self.limits
        block = msg.block
        measured = np.flatnonzero(block.U.reshape(len(block), -1).any(axis=1))
        others = np.setdiff1d(np.arange(len(block)), measured)
        order = np.concatenate([measured, others])

        def part(n: int) -> FrameMessage:
            return replace(msg, _block=block.take(np.sort(order[:n])), _infos=None,
                           merges=msg.merges[:lim.max_merges])

        lo, hi = 0, min(len(order), lim.max_trackers)  # lo fits (if anything does)
        try:
            if codec.encoded_size(part(hi), limits=lim) <= lim.max_bytes:
                lo = hi
            while lo < hi:
                mid = (lo + hi + 1) // 2
                if codec.encoded_size(part(mid), limits=lim) <= lim.max_bytes:
                    lo = mid
                else:
                    hi = mid - 1
            payload = codec.encode(part(lo), limits=lim)
        except ProtocolError:
            return None
        self.counters.trackers_cut += len(block) - lo
        self.last_error = (f"frame {msg.frame}: {len(block)} trackers, {len(msg.merges)} merges: "
                           f"sent {lo} trackers (the {len(measured)} it measured first)")
        return payload

    def _count_saved(self, full: FrameMessage, sent: int, links: int) -> None:
        """Bytes not sent on ``links`` links against sending ``full`` on them (its length from
        the layout, ``codec.encoded_size``: encoding it again only to count cost ~70 us a
        frame)."""
        try:
            n = codec.encoded_size(full)
        except ProtocolError:
            n = 0
        self.counters.bytes_saved += max(n - sent, 0) * links
