"""What a node remembers of its neighbours in event-triggered operation (docs/concepts.md,
"How it is built"; the paper's asynchronous remark at the end of Sec. III-A, after He et al. 2017).

Neighbours send a tracker only when they have something new about it, and messages may come
late, twice or out of order. The memory keeps each neighbour's newest entry per tracker and,
every frame ``k``, hands back those entries brought to ``k``: ``x_bar`` predicted forward with
the constant-velocity model, ``ell`` as sent while the neighbour is heard from but silent about
the tracker (for up to ``hold_frames``: its silence means "no change" until its heartbeat is
due; the trigger sends when its ``ell`` changes) and aged by one per frame beyond that and for
every frame the neighbour itself is not heard from (late or lost messages: eq. 8's ageing), and
``u, U`` only once and only within ``staleness_frames`` (older measurement information would
pull the estimate to where the target was; moved along the velocity to where it is now).
Entries older than ``kappa`` frames are forgotten: a neighbour that died
or dropped the tracker.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.dkf import carried
from edge_node.core.model import STATE_DIM, transition
from protocol.messages import FrameMessage, TrackerId, TrackerInfo


@dataclass(frozen=True)
class MemorySettings(Slice):
    """What the neighbour memory reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    hold_frames: int
    kappa: int
    staleness_frames: int
    units_per_metre: float
    fps: float


class NeighbourMemory:
    def __init__(self, cfg: MemorySettings, network: str):
        self.cfg = cfg
        self.network = network
        # neighbour -> tracker -> (frame, entry, u/U already fused)
        self.entries: dict[int, dict[TrackerId, tuple[int, TrackerInfo, bool]]] = {}
        self.newest: dict[int, int] = {}  # neighbour -> frame of its newest message (any)
        # tracker -> the smallest ell of the entries handed back by ``at``, aged by the senders'
        # silences only: what eq. 8 would give were no link late (``lagless``)
        self.lagless_ell: dict[TrackerId, int] = {}
        # trackers some neighbour said something about since the previous ``at``: a message of
        # that neighbour newer than any before arrived (``news``)
        self.news: set[TrackerId] = set()
        self._heard: dict[int, int] = {}  # neighbour -> its newest frame at the previous ``at``
        # (neighbour, tracker) whose newest entry, at most ``hold_frames`` old, said its camera
        # saw the target (ell 0 as sent): what a late or withheld entry still tells (``observed``)
        self.observed: set[tuple[int, TrackerId]] = set()
        # tracker -> descriptors of a sender's first entry of it that came after a newer entry
        # of the same sender (``late_appearance``, set by ``remember``)
        self.late_appearance: dict[TrackerId, np.ndarray] = {}
        # tracker -> the frame of the oldest message that told of it among those arrived since
        # the previous ``at`` (``told``, set by ``at``: what a late adoption is judged as of)
        self.told: dict[TrackerId, int] = {}
        self._told: dict[TrackerId, int] = {}

    def remember(self, arrived: Iterable[FrameMessage]) -> None:
        """Keep each sender's newest entry per tracker. A sender attaches a tracker's appearance
        to its first entry only, so a newer entry does not lose it: one that replaces the first
        before ``at`` handed it back (two messages of a sender arrived in one frame) takes its
        appearance, and a first entry that comes after a newer one (reordered on a late link)
        gives its appearance to the newer one kept and names it in ``late_appearance`` (the
        receiver may have adopted the tracker without it). Before, with every message 1-4 frames
        late, terrace-gt's nodes adopted 27 of 105 trackers without appearance, and held trackers
        with an empty gallery in 243 node-frames (now 3)."""
        self.late_appearance = {}
        for m in arrived:
            self.newest[m.sender] = max(self.newest.get(m.sender, m.frame), m.frame)
            mem = self.entries.setdefault(m.sender, {})
            for t in m.trackers:
                self._told[t.id] = min(self._told.get(t.id, m.frame), m.frame)
                old = mem.get(t.id)
                if old is None or m.frame > old[0]:
                    if t.appearance is None and old is not None and not old[2] \
                            and old[1].appearance is not None:
                        t = replace(t, appearance=old[1].appearance)
                    mem[t.id] = (m.frame, t, False)
                elif t.appearance is not None and old[1].appearance is None:
                    mem[t.id] = (old[0], replace(old[1], appearance=t.appearance), old[2])
                    self.late_appearance[t.id] = t.appearance

    def at(self, k: int) -> list[FrameMessage]:
        """Every neighbour's newest entry per tracker brought to frame ``k``, one message per
        neighbour (senders and trackers in order: deterministic)."""
        out = []
        self.lagless_ell, self.news, self.observed = {}, set(), set()
        self.told, self._told = self._told, {}
        for sender in sorted(self.entries):
            mem = self.entries[sender]
            newest = self.newest.get(sender, k)
            heard = newest > self._heard.get(sender, newest - 1)
            self._heard[sender] = newest
            if heard:
                self.news.update(mem)
            aged = []
            for tid in sorted(mem):
                frame, t, consumed = mem[tid]
                age = k - frame
                if age > self.cfg.kappa:
                    del mem[tid]
                    continue
                keep_info = not consumed and age <= self.cfg.staleness_frames
                if t.ell == 0 and age <= self.cfg.hold_frames:
                    self.observed.add((sender, tid))
                mem[tid] = (frame, t, True)  # its u, U are fused at most once
                if age == 0 and keep_info:
                    aged.append(t)
                    self._lagless(tid, t.ell)
                    continue
                A = transition(age * self.cfg.dt)
                u, U = np.zeros(STATE_DIM), np.zeros((STATE_DIM, STATE_DIM))
                if keep_info:  # a measurement of where the target was, moved to where it is now
                    U = t.U
                    u = carried(t.u, U, age * self.cfg.dt * np.asarray(t.x_bar)[4:6])
                silent = self._silent(frame, newest)
                aged.append(replace(t, x_bar=A @ t.x_bar, u=u, U=U,
                                    ell=t.ell + self._lag(k, frame, newest) + silent))
                self._lagless(tid, t.ell + silent)
            out.append(FrameMessage(self.network, sender, k, tuple(aged)))
        return out

    def _lagless(self, tid: TrackerId, ell: int) -> None:
        self.lagless_ell[tid] = min(ell, self.lagless_ell.get(tid, ell))

    @staticmethod
    def _lag(k: int, frame: int, newest: int) -> int:
        """How much a neighbour's ``ell`` sent at ``frame`` has aged by frame ``k`` through the
        link's lag: the frames since the sender's newest message (``newest``). Late or lost
        messages: nobody says what changed, and ``ell`` ages by one per frame, as eq. 8 assumes
        of a neighbour it does not hear from."""
        return max(0, k - max(newest, frame))

    def _silent(self, frame: int, newest: int) -> int:
        """How much it has aged through the sender's silence about it since (up to its newest
        message): deliberate, "nothing changed", so it holds for ``hold_frames`` (the trigger's
        heartbeat), then ages by one per frame."""
        return max(0, max(0, newest - frame) - self.cfg.hold_frames)
