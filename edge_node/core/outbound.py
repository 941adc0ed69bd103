"""The outbound role: what a node tells its neighbours of frame ``k`` (paper III-D).

One message per frame: per tracker ``(ID, x_bar, u, U, ell, born)`` (``ell`` and ``x_bar`` as
this node reports them: eq. 8's counter, 0 where its camera saw the target, and the prediction
at the wire's precision), the appearance of the trackers new to this sender, and the merge
announcements. It is built as one ``TrackerBlock`` straight from the node's table, no
per-tracker objects. With regional scope (``scope_hops``) a tracker is sent only while a
receiver one hop farther may keep it. ``resync`` attaches every appearance for a neighbour
that came back empty. Pure and deterministic.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from edge_node.core.identity import IdentityBook
from edge_node.core.manager import ell_sent
from edge_node.core.model import quantize
from edge_node.core.state import NodeState
from protocol.messages import MAX_DESCRIPTORS, FrameMessage, TrackerBlock


class Outbound:
    """``network``, ``sender``: what the messages say they are; ``scope_hops``: the regional
    scope (0: every tracker is sent); ``book``: the node's ``IdentityBook`` (announcements)."""

    def __init__(self, network: str, sender: int, scope_hops: int, book: IdentityBook):
        self.network = network
        self.sender = sender
        self.scope = scope_hops
        self.book = book
        self.rows = np.zeros(0, np.intp)  # the last message's rows of the table
        self._P = np.zeros((0, 6, 6))

    def sent_values(self, state: NodeState) -> None:
        """``ell`` and ``x_bar`` of every tracker as the message says them (eq. 8's branches:
        0 if a camera of this node saw it, else its consensus value plus one)."""
        if len(state):
            state.x_bar_sent = quantize(state.x_bar)
            state.ell_sent = np.where(state.seen_any(), 0, state.ell + 1)

    def message(self, state: NodeState, k: int) -> FrameMessage:
        """This frame's message (module docstring)."""
        rows = np.arange(len(state))
        if self.scope and len(rows):
            rows = np.flatnonzero(state.ell_sent - state.coast < self.scope)
        self.rows = rows
        self._P = state.P.take(rows, axis=0)
        apps = []
        for at, i in enumerate(rows.tolist()):
            g = state.galleries[i]
            if not state.announced[i] and len(g):
                apps.append((at, np.asarray(g.newest(MAX_DESCRIPTORS), float)))  # a copy
                state.announced[i] = True
        if len(rows):
            # fresh arrays of the block's dtypes and shapes, made read-only: what the checked
            # constructor would copy them into (``encode`` checks the wire's value rules)
            ids = np.array([state.ids[i] for i in rows.tolist()], np.int64).reshape(-1, 2)
            cols = (ids[:, 0].copy(), ids[:, 1].copy(), state.born.take(rows),
                    state.ell_sent.take(rows), state.x_bar_sent.take(rows, axis=0),
                    state.u.take(rows, axis=0), state.U.take(rows, axis=0))
            for a in (*cols, *(d for _, d in apps)):
                a.setflags(write=False)
            block = TrackerBlock._trusted(*cols, tuple(apps))
        else:
            block = TrackerBlock.empty()
        return FrameMessage.from_block(self.network, self.sender, k, block,
                                       self.book.announcements())

    def covariances(self) -> np.ndarray:
        """The predicted covariances ``P`` ``(n, 6, 6)`` of the last message's rows, in its
        order (the event trigger's prior)."""
        return self._P.copy()

    @staticmethod
    def resync(msg: FrameMessage, state: NodeState) -> FrameMessage:
        """``msg`` with every tracker's appearance attached: what this node sends a neighbour
        that came back with an empty state (restart) or joined late, so that it adopts the
        network's trackers with their galleries and keeps their ids."""
        infos = []
        for t in msg.trackers:
            i = state.index.get(t.id)
            if t.appearance is None and i is not None and len(state.galleries[i]):
                t = replace(t, appearance=state.galleries[i].newest(MAX_DESCRIPTORS))
            infos.append(t)
        return replace(msg, trackers=tuple(infos))


__all__ = ["Outbound", "ell_sent"]
