"""What a camera process has received from its neighbours, and what it knows of where they are:
the inbox of :class:`~edge_node.runtime.transport.ZenohTransport`, without Zenoh (unit-tested
on its own, ``tests/test_inbox.py``).

Valid messages go into a thread-safe inbox keyed by ``(sender, frame)`` (Zenoh's callback
threads :meth:`accept` them), read by :meth:`FrameInbox.collect` (sync mode: exactly frame
``k``, waiting for live neighbours) or :meth:`FrameInbox.drain` (async mode: whatever arrived,
up to frame ``k``, never waiting).

The frame window. Messages of frames ahead of the node wait in the inbox, at most
``max_pending_frames`` per sender (the farthest ahead dropped first, counted in ``overflow``):
a flood of future frames must not push out the message the node waits for. Where each
neighbour is, however far ahead, is kept apart from the inbox (its newest frame and when it
was heard), so a node that fell behind by any distance learns the network's frame
(:meth:`network_frame`) and skips there (:meth:`skip_to`; the messages of skipped frames are
counted in ``skipped``).
"""
from __future__ import annotations

import math
import threading
import time
from collections import defaultdict
from collections.abc import Iterable
from typing import Callable

from protocol.messages import FrameMessage

GONE_GRACE_S = 0.25  # how long frame k still waits for a neighbour whose liveliness just ended
BACK_GRACE_S = 0.25  # how long a neighbour back after its liveliness ended is waited for unheard
FRESH_S = 2.0  # a neighbour heard within this long tells where the network is (network_frame)
LOSS_RUN = 4  # a neighbour's message of one of the next LOSS_RUN frames shows this frame's lost


class FrameInbox:
    """The inbox and the neighbours' whereabouts of one node (module docstring). ``cond`` is
    shared with the transport (liveliness and start-up waits); ``warn(key, message)`` logs a
    rate-limited warning; ``clock`` is ``time.monotonic`` (tests pass their own)."""

    def __init__(self, node: int, neighbours: Iterable[int], max_pending_frames: int = 256, *,
                 cond: threading.Condition | None = None,
                 warn: Callable[[str, str], None] = lambda key, msg: None,
                 clock: Callable[[], float] = time.monotonic):
        self.node = int(node)
        self.neighbours = tuple(sorted(set(int(n) for n in neighbours) - {self.node}))
        self.max_pending_frames = max_pending_frames
        self.cond = cond or threading.Condition()
        self.warn = warn
        self.clock = clock
        self.closed = False
        # all under cond
        self._inbox: dict[tuple[int, int], FrameMessage] = {}
        self._pending: dict[int, int] = defaultdict(int)  # sender -> entries in _inbox
        self._floor = -1  # sync: frames below this are late
        self.alive: set[int] = set()  # alive neighbours
        self._gone_at: dict[int, float] = {}  # neighbour -> when its liveliness went away
        self._back_at: dict[int, float] = {}  # neighbour -> when it came back after going away
        self._lagging: set[int] = set()  # sync: neighbours that missed a frame and are behind
        self._newest: dict[int, int] = {}  # sender -> newest frame received from it
        self._heard_at: dict[int, float] = {}  # sender -> when its last message came
        self.frame_now: int | None = None  # the frame this node is at (collect / drain)
        # counters, per sender
        self.late: dict[int, int] = defaultdict(int)
        self.lost: dict[int, int] = defaultdict(int)  # sync: frames a newer message showed lost
        self.duplicates: dict[int, int] = defaultdict(int)
        self.overflow: dict[int, int] = defaultdict(int)
        self.skipped: dict[int, int] = defaultdict(int)  # messages of frames this node skipped
        self.timeouts: dict[int, int] = defaultdict(int)  # sync: frames a live neighbour missed

    # -- Zenoh's threads -------------------------------------------------------------------------
    def accept(self, src: int, msg: FrameMessage) -> None:
        """A valid message of neighbour ``src`` (checked by the codec against its link)."""
        with self.cond:
            if self.closed:
                return
            k = msg.frame
            # where the network is, however far ahead (a node behind skips there): one forged
            # frame number cannot fling a node away, as network_frame takes the least of the
            # fresh neighbours' and the loop checks it against the clock
            self._newest[src] = max(k, self._newest.get(src, k))
            self._heard_at[src] = self.clock()
            if k < self._floor:
                self.late[src] += 1
                return
            self._lagging.discard(src)  # in time again: waited for from the next frame on
            key = (src, k)
            if key in self._inbox:
                self.duplicates[src] += 1
                return
            self._inbox[key] = msg
            self._pending[src] += 1
            if self._pending[src] > self.max_pending_frames:
                # drop the frame farthest ahead, not the one needed next: a flood of (forged)
                # future frames must not push out the message this node is waiting for
                newest = max(f for (s, f) in self._inbox if s == src)
                del self._inbox[(src, newest)]
                self._pending[src] -= 1
                self.overflow[src] += 1
            self.cond.notify_all()

    def liveliness(self, n: int, gone: bool) -> None:
        """Neighbour ``n``'s liveliness token appeared or went away."""
        with self.cond:
            self._lagging.discard(n)
            self._newest.pop(n, None)
            if gone:
                if n in self.alive:
                    self._gone_at[n] = self.clock()
                self.alive.discard(n)
            elif n in self.neighbours:
                if n not in self.alive and n in self._gone_at:  # back after going away
                    self._back_at[n] = self.clock()
                self.alive.add(n)
            self.cond.notify_all()

    # -- the node's thread -------------------------------------------------------------------------
    def wait_first_frame(self, timeout: float, stop: threading.Event | None = None) -> int | None:
        """The newest frame any neighbour has sent us, waiting up to ``timeout`` s for one: how
        a restarted node learns where the running network is."""
        deadline = self.clock() + timeout
        with self.cond:
            while not self._inbox:
                remaining = deadline - self.clock()
                if remaining <= 0 or (stop is not None and stop.is_set()):
                    return None
                self.cond.wait(min(remaining, 0.1))
            # Each sender's newest frame; the smallest of those: one key (forged, without the
            # access-control config) cannot make a restarting node jump far ahead.
            newest: dict[int, int] = {}
            for (src, f) in self._inbox:
                newest[src] = max(f, newest.get(src, -1))
            return min(newest.values())

    def network_frame(self) -> int | None:
        """The frame the running network is at, as this node hears it: the least of the newest
        frames of the alive neighbours heard within ``FRESH_S`` (``None`` before any). A node
        that fell behind (a freeze of any length, an overload, a timeout on a lost link) skips
        ahead to it (``runtime/loop.py``); a neighbour that is itself behind (frozen: not
        fresh; catching up) holds it back only until it has caught up, and one neighbour that
        lies about its frame cannot fling it beyond the others."""
        with self.cond:
            return self._network_frame_locked(self.clock())

    def _fresh(self, n: int, now: float) -> bool:
        """Whether neighbour ``n`` was heard within ``FRESH_S``."""
        return now - self._heard_at.get(n, now - FRESH_S) < FRESH_S

    def _network_frame_locked(self, now: float, lead: bool = False) -> int | None:
        frames = [f for n, f in self._newest.items() if n in self.alive and self._fresh(n, now)]
        return (max(frames) if lead else min(frames)) if frames else None

    def network_lead(self) -> int | None:
        """The newest frame of any fresh, alive neighbour (``network_frame`` takes the least):
        how far ahead the most advanced neighbour is. A sync node behind it runs without pause
        until level (``runtime/loop.py``); it cannot run past the neighbours it waits for."""
        with self.cond:
            return self._network_frame_locked(self.clock(), lead=True)

    def skip_to(self, frame: int) -> None:
        """This node skips ahead to ``frame``: the messages of the frames it skips are dropped
        (counted in ``skipped``, not as late) and later ones wait for their frame; every
        neighbour is waited for again (they are at this frame)."""
        with self.cond:
            for key in [key for key in self._inbox if key[1] < frame]:
                del self._inbox[key]
                self._pending[key[0]] -= 1
                self.skipped[key[0]] += 1
            self._floor = max(self._floor, frame)
            self.frame_now = frame
            self._lagging.clear()

    def collect(self, frame: int, timeout: float, stop: threading.Event | None = None, *,
                silent_grace: float | None = None) -> dict[int, FrameMessage]:
        """Sync mode: frame ``frame``'s messages, waiting up to ``timeout`` s for every neighbour
        that is alive (one whose liveliness is lost is not waited for). A neighbour that misses
        the timeout is lagging: it is not waited for again until one of its messages arrives in
        time, so one slow or frozen box costs its neighbours one timeout, not one per frame.
        A neighbour whose message of one of the next ``LOSS_RUN`` frames has arrived is not
        waited for either: a link delivers in order, so its frame-``frame`` message was lost
        (counted in ``lost``), and a lossy link costs a frame period, not the timeout. (Not any
        later frame: a single forged message far ahead must not stop the waits; but when every
        fresh neighbour is beyond that, this node is the one behind and skips next.) Messages of earlier frames are discarded
        (counted as late), now and when they arrive. ``silent_grace`` (a paced node's first
        frame): a neighbour that has sent nothing yet is waited for only that long, then taken
        for one still in its own start-up (waiting for a camera that is not up, say) and not
        waited for until its first message in time."""
        start = self.clock()
        deadline = start + timeout
        with self.cond:
            self.frame_now = frame
            self._floor = frame
            for key in [key for key in self._inbox if key[1] < frame]:
                del self._inbox[key]
                self._pending[key[0]] -= 1
                self.late[key[0]] += 1
            lost: set[int] = set()
            while True:
                have = {s for s in self.neighbours if (s, frame) in self._inbox}
                # A neighbour that just left (its last frame done) may have its last message
                # still in flight behind the liveliness DELETE: wait for it a moment longer.
                now = self.clock()
                leaving = {s for s, t in self._gone_at.items() if now - t < GONE_GRACE_S}
                missing = (self.alive | leaving) - have - self._lagging
                # a neighbour heard lately at a frame far behind this one (back from a freeze,
                # it skips to us next): not waited for until its messages come in time (its
                # neighbours stood still a whole timeout when a frozen node came back)
                far = {s for s in missing
                       if self._newest.get(s, frame) < frame - LOSS_RUN and self._fresh(s, now)}
                self._lagging |= far
                missing -= far
                # a neighbour back after its liveliness went away (a freeze on either side, a
                # restart) and not heard since: its frames and ours are apart, and each side's
                # message of the moment went out before the link was back, so both waited a
                # whole timeout; it is waited for BACK_GRACE_S, then taken for lagging
                back = {s: self._back_at[s] for s in missing if s in self._back_at
                        and self._heard_at.get(s, -math.inf) < self._back_at[s]}
                unheard = {s for s, t in back.items() if now - t >= BACK_GRACE_S}
                self._lagging |= unheard
                missing -= unheard
                if silent_grace is not None and now - start >= silent_grace:
                    silent = missing - set(self._heard_at)
                    self._lagging |= silent
                    missing -= silent
                # in order: a message of one of its next frames shows this one lost (not any
                # later frame: one forged message a second ahead stopped the waits for that
                # neighbour for a second, and its honest messages came late), or every fresh
                # neighbour is beyond them (this node is behind: a freeze; it skips next)
                behind = (self._network_frame_locked(now) or -1) > frame + LOSS_RUN
                gone = {s for s in missing
                        if (behind and self._newest.get(s, -1) > frame)
                        or any((s, f) in self._inbox for f in range(frame + 1, frame + 1 + LOSS_RUN))}
                for s in gone - lost:
                    self.lost[s] += 1
                lost |= gone
                missing -= gone
                if not missing or (stop is not None and stop.is_set()) or self.closed:
                    break
                remaining = deadline - self.clock()
                if silent_grace is not None and missing - set(self._heard_at):
                    remaining = min(remaining, start + silent_grace - self.clock())
                    if remaining <= 0:
                        continue  # the grace is over: silent ones are not waited for
                if back.keys() & missing:
                    remaining = min(remaining, min(back[s] for s in back.keys() & missing)
                                    + BACK_GRACE_S - self.clock())
                    if remaining <= 0:
                        continue  # a returning neighbour's grace is over
                if remaining <= 0:
                    for s in missing:
                        self.timeouts[s] += 1
                    # behind (frozen, overloaded): not waited for again until one of its
                    # messages arrives in time; until then its messages count as late
                    self._lagging |= missing
                    self.warn("timeout", f"node {self.node}: frame {frame}: no message from "
                              f"neighbour(s) {sorted(missing)} within {timeout:g} s; not waiting "
                              "for them until they catch up")
                    break
                self.cond.wait(min(remaining, 0.1))
            for s in lost & have:  # shown lost, then it came while another was waited for
                self.lost[s] -= 1
                if not self.lost[s]:
                    del self.lost[s]
            out = {}
            for s in sorted(have):
                out[s] = self._inbox.pop((s, frame))
                self._pending[s] -= 1
            self._floor = frame + 1
            return out

    def drain(self, frame: int) -> list[FrameMessage]:
        """Async mode: every message received since the last call with frame ``<= frame``, each
        once, sorted by ``(sender, frame)``, never waiting. Messages of later frames (a neighbour
        ahead of us) stay until ``frame`` reaches them. The core keeps each neighbour's newest
        entry per tracker, so late, duplicated and reordered deliveries are harmless."""
        with self.cond:
            self.frame_now = frame
            keys = sorted(key for key in self._inbox if key[1] <= frame)
            out = []
            for key in keys:
                out.append(self._inbox.pop(key))
                self._pending[key[0]] -= 1
            return out

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()

    def counters(self) -> dict:
        """Per-link counters (``"src->node"`` keys) of what came in; call under ``cond``."""
        def links_in(d):
            return {f"{n}->{self.node}": v for n, v in sorted(d.items())}

        return {"late": links_in(self.late), "lost": links_in(self.lost),
                "duplicates": links_in(self.duplicates), "overflow": links_in(self.overflow),
                "skipped": links_in(self.skipped), "timeouts": links_in(self.timeouts),
                "alive_neighbours": sorted(self.alive)}
