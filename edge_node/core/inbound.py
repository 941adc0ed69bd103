"""The inbound role: which of a frame's neighbour messages a node may use, before anything
touches tracker state (paper III-D's messages; the trust boundary of ``screen``).

In order: *accept* (this network, a configured neighbour, this frame; in event-triggered
operation also frames up to ``kappa`` old; one message per sender and frame, later copies are
duplicates), *bound* (at most ``max_trackers_per_neighbour`` entries per message, the ids this
node holds first: one message of thousands of plausible phantoms under fresh ids must not make
a node hold them all, it stalled two nodes for good), then *screen* (``Screen``: each entry and
merge checked for meaning). What is refused is counted by reason, the rest used, in a
deterministic order (sender, frame). Then *gather*: in event-triggered operation every
neighbour's newest entry per tracker brought to the frame (``NeighbourMemory``), and the
entries grouped per tracker (``entries.Inbox``). Pure and deterministic.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from edge_node.core.entries import Inbox
from edge_node.core.identity import IdentityBook
from edge_node.core.memory import NeighbourMemory
from edge_node.core.screen import Screen
from protocol.messages import FrameMessage, TrackerId


@dataclass
class Heard:
    """What a frame's messages tell, gathered: ``inbox`` (the entries per tracker) and, in
    event-triggered operation, what the neighbour memory adds: per tracker the frame of the
    oldest message that told of it (``told``), first entries' appearance that came late
    (``late_appearance``), the neighbours' smallest ``ell`` aged by their silences alone
    (``lagless``) and the trackers some neighbour said something about (``news``)."""

    inbox: Inbox
    told: dict[TrackerId, int] | None = None
    late_appearance: dict[TrackerId, np.ndarray] = field(default_factory=dict)
    lagless: dict[TrackerId, int] | None = None
    news: set[TrackerId] | frozenset[TrackerId] = frozenset()


class Inbound:
    """``neighbours``, ``network``: whom a node hears; ``kappa``: the oldest frame an
    event-triggered node still uses (eq. 8's horizon); ``cap``: ``max_trackers_per_neighbour``;
    ``stats``: the node's counters (``ignored_messages``, ``duplicate_messages``)."""

    def __init__(self, neighbours: Iterable[int], network: str, kappa: int, cap: int,
                 screen: Screen, stats, memory: NeighbourMemory | None = None):
        self.memory = memory
        self.neighbours = frozenset(neighbours)
        self.network = network
        self.kappa = kappa
        self.cap = cap
        self.screen = screen
        self.stats = stats
        self.taken: dict[tuple[int, int], None] = {}  # (sender, frame) already used, recent

    def take(self, inbox: Iterable[FrameMessage], k: int, stale_ok: bool, book: IdentityBook,
             held: Callable[[TrackerId], bool]) -> list[FrameMessage]:
        """The messages frame ``k`` uses: accepted, bounded and screened (``held(id)``: this
        node holds the tracker)."""
        return self.screen.messages(self.bounded(self.accept(inbox, k, stale_ok), book, held), book)

    def gather(self, msgs: list[FrameMessage], k: int, stale_ok: bool,
               aliases: dict[TrackerId, TrackerId]) -> Heard:
        """The frame's entries per tracker (merge ``aliases`` followed); event-triggered
        (``stale_ok``), every neighbour's newest entry brought to ``k`` by the memory."""
        if not stale_ok:
            return Heard(Inbox(msgs, aliases))
        mem = self.memory
        mem.remember(msgs)
        msgs = mem.at(k)
        return Heard(Inbox(msgs, aliases, mem.observed), mem.told, mem.late_appearance,
                     mem.lagless_ell, mem.news)

    def accept(self, inbox: Iterable[FrameMessage], k: int, stale_ok: bool) -> list[FrameMessage]:
        """One message per sender and frame (the first one), sorted by (sender, frame)."""
        msgs: list[FrameMessage] = []
        for m in inbox:
            ok = (m.sender in self.neighbours and m.network == self.network
                  and (m.frame == k or (stale_ok and k - self.kappa <= m.frame < k)))
            if not ok:
                self.stats.ignored_messages += 1
                continue
            if (m.sender, m.frame) in self.taken:
                self.stats.duplicate_messages += 1
                continue
            self.taken[(m.sender, m.frame)] = None
            msgs.append(m)
        for key in [key for key in self.taken if key[1] < k - self.kappa]:
            del self.taken[key]  # older frames are ignored anyway: bounded memory
        return sorted(msgs, key=lambda m: (m.sender, m.frame))

    def bounded(self, msgs: list[FrameMessage], book: IdentityBook,
                held: Callable[[TrackerId], bool]) -> list[FrameMessage]:
        """Each message cut to ``cap`` entries: the ids this node holds first, then the others
        in the sender's order; the rest dropped and counted (``too_many_trackers``)."""
        out = []
        for m in msgs:
            n = len(m.block)
            if n <= self.cap:
                out.append(m)
                continue
            mine = [held(book.resolve(t)) for t in m.block.ids()]
            order = [i for i in range(n) if mine[i]] + [i for i in range(n) if not mine[i]]
            keep = sorted(order[:self.cap])
            out.append(replace(m, _block=m.block.take(keep), _infos=None))
            self.screen.rejected["too_many_trackers"] += n - len(keep)
        return out
